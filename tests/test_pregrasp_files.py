"""Pre-grasp files: read when their task's env is built (not at import), checked whole (every entry's shape,
the joint ranges, the task they belong to) with one error naming the file and the entry; a task takes a
user's file (``task.pregrasps``), and ``dexmots-pregrasp`` writes where the user says, never into the package."""

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
from dexmots_rl.envs.pregrasp import FORMAT, PregraspError, pregrasp_path

ROOT = Path(__file__).resolve().parents[1]


def _shipped(task: str = "stapler") -> dict:
    return json.loads(pregrasp_path(task).read_text())


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


def test_a_task_starts_from_a_users_pregrasp_file(tmp_path):
    data = _shipped()
    data["poses"] = data["poses"][:1]  # one pose: every world starts there
    env = make_env("stapler", num_envs=4, seed=0, joint_noise=0.0, pregrasps=str(_write(tmp_path, data)))
    starts = env.reset()["sim", "joint_q"][:, :16].double().numpy()
    np.testing.assert_allclose(starts, np.repeat(np.asarray(data["poses"]), 4, axis=0), atol=1e-5)


@pytest.mark.parametrize("change, message", [
    (lambda d: d["poses"][1].pop(), r"poses\[1\] must be a list of 16 joint angles, got 15 values"),
    (lambda d: d["poses"].__setitem__(0, [100.0] * 16), r"poses\[0\]\[0\] = 100 rad is outside joint 0's range"),
    (lambda d: d["poses"][2].__setitem__(3, "abc"), r"poses\[2\]\[3\] must be a finite joint angle"),
    (lambda d: d.__setitem__("task", "scissors"), r"field 'task' is 'scissors', but the file is loaded for task "
                                                  r"'stapler'"),
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


def test_another_tasks_file_and_a_missing_file_are_refused(tmp_path):
    with pytest.raises(PregraspError, match="field 'task' is 'scissors'"):
        make_env("stapler", num_envs=1, pregrasps=str(pregrasp_path("scissors")))
    with pytest.raises(PregraspError, match="no pre-grasp file"):
        make_env("stapler", num_envs=1, pregrasps=str(tmp_path / "missing.json"))
    make_env("scissors", num_envs=1)  # the other tasks are unaffected


def test_dexmots_pregrasp_writes_to_the_current_directory_by_default(tmp_path, monkeypatch, capsys):
    shipped = pregrasp_path("stapler")
    before = (shipped.read_bytes(), shipped.stat().st_mtime_ns)
    poses = np.asarray(_shipped()["poses"])
    monkeypatch.setattr("dexmots_rl.envs.pregrasp.find_pregrasps", lambda *a, **k: poses)  # the search is slow
    monkeypatch.chdir(tmp_path)
    pregrasp_app.main(["--task", "stapler"])
    out = tmp_path / "stapler.json"
    assert capsys.readouterr().out.strip() == str(out)
    assert json.loads(out.read_text())["format"] == FORMAT and json.loads(out.read_text())["task"] == "stapler"
    (tmp_path / "mine").mkdir()
    pregrasp_app.main(["--task", "stapler", "--out", "mine"])
    assert (tmp_path / "mine" / "stapler.json").is_file()
    assert (shipped.read_bytes(), shipped.stat().st_mtime_ns) == before  # the package's file untouched
    make_env("stapler", num_envs=1, pregrasps=str(out))  # what it writes is a valid file for the task
