"""Pre-grasp files: read when their task's env is built (not at import), checked whole (every entry's shape,
the joint ranges, the task and object they belong to) with one error naming the file and the entry; a tool task
takes a user's file (``task.pregrasps``), and ``dexmots-pregrasp`` writes where the user says, never into the
package."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dexmots_rl.apps import pregrasp as pregrasp_app
from dexmots_rl.envs import make_env
from dexmots_rl.envs.object_pregrasp import operate_pregrasp_path
from dexmots_rl.envs.pregrasp import FORMAT, PregraspError

ROOT = Path(__file__).resolve().parents[1]


def _shipped(object_name: str = "stapler_a") -> dict:
    return json.loads(operate_pregrasp_path(object_name).read_text())


def _write(tmp_path, data: dict, name: str = "user.json") -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(data))
    return path


def test_importing_the_envs_reads_no_pregrasp_file():
    code = ("import sys; opened = []\n"
            "sys.addaudithook(lambda event, args: opened.append(str(args[0])) if event == 'open' else None)\n"
            "import dexmots_rl.envs\n"
            "print([p for p in opened if 'pregrasps' in p])")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "[]"


def test_a_tool_task_starts_from_a_users_pregrasp_file(tmp_path):
    data = _shipped()
    data["poses"] = data["poses"][:1]  # one pose: every world starts there
    env = make_env("stapler", num_envs=4, seed=0, joint_noise=0.0, pregrasps=str(_write(tmp_path, data)), raw=True)
    starts = env.reset()["sim", "joint_q"][:, :16].double().numpy()
    np.testing.assert_allclose(starts, np.repeat(np.asarray(data["poses"]), 4, axis=0), atol=1e-5)


@pytest.mark.parametrize("change, message", [
    (lambda d: d["poses"][1].pop(), r"poses\[1\] must be a list of 16 joint angles, got 15 values"),
    (lambda d: d["poses"].__setitem__(0, [100.0] * 16), r"poses\[0\]\[0\] = 100 rad is outside joint 0's range"),
    (lambda d: d["poses"][1].__setitem__(3, "abc"), r"poses\[1\]\[3\] must be a finite joint angle"),
    (lambda d: d.__setitem__("task", "stapler"), r"field 'task' is 'stapler', but the file is loaded for task "
                                                 r"'operate'"),
    (lambda d: d.__setitem__("object", "scissors_a"), r"field 'object' is 'scissors_a', but the file is loaded for "
                                                      r"object 'stapler_a'"),
    (lambda d: d.__setitem__("poses", []), r"field 'poses' must be a non-empty list"),
    (lambda d: d.__setitem__("format", "v0"), r"field 'format'"),
])
def test_a_bad_user_file_is_one_error_naming_the_file_and_entry(tmp_path, change, message):
    data = _shipped()
    change(data)
    path = _write(tmp_path, data)
    with pytest.raises(PregraspError, match=message) as err:
        make_env("stapler", num_envs=1, pregrasps=str(path))
    assert str(err.value).startswith(str(path))


def test_another_objects_file_and_a_missing_file_are_refused(tmp_path):
    with pytest.raises(PregraspError, match="field 'object' is 'scissors_a'"):
        make_env("stapler", num_envs=1, pregrasps=str(operate_pregrasp_path("scissors_a")))
    with pytest.raises(PregraspError, match="no pre-grasp file"):
        make_env("stapler", num_envs=1, pregrasps=str(tmp_path / "missing.json"))
    make_env("scissors", num_envs=1)  # the other tasks are unaffected


def test_dexmots_pregrasp_writes_to_the_current_directory_by_default(tmp_path, monkeypatch, capsys):
    shipped = operate_pregrasp_path("stapler_a")
    before = (shipped.read_bytes(), shipped.stat().st_mtime_ns)
    poses = np.asarray(_shipped()["poses"])
    # the search is slow (test_operate_pregrasps runs it): here only where the file goes and what it holds
    monkeypatch.setattr("dexmots_rl.envs.object_pregrasp.find_object_pregrasps", lambda *a, **k: poses)
    monkeypatch.chdir(tmp_path)
    pregrasp_app.main(["--task", "stapler"])
    out = tmp_path / "stapler_a.json"
    assert capsys.readouterr().out.strip() == str(out)
    data = json.loads(out.read_text())
    assert data["format"] == FORMAT and data["task"] == "operate" and data["object"] == "stapler_a"
    (tmp_path / "mine").mkdir()
    pregrasp_app.main(["--task", "stapler", "--out", "mine"])
    assert (tmp_path / "mine" / "stapler_a.json").is_file()
    assert (shipped.read_bytes(), shipped.stat().st_mtime_ns) == before  # the package's file untouched
    make_env("stapler", num_envs=1, pregrasps=str(out))  # what it writes is a valid file for the task
