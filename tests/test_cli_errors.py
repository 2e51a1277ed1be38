"""A GPU the machine lacks and a full disk are one line from every console script that meets them, and a
training run refuses the device before it creates (and locks) its run directory."""

from __future__ import annotations

import builtins
import errno
import io
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir

from dexmots_rl.apps import bench, rollout
from dexmots_rl.apps import train as train_app
from dexmots_rl.apps._cli import os_errors_as_one_line

ROOT = Path(__file__).resolve().parents[1]
SMALL = ["algo=shac", "task.num_envs=2", "algo.horizon=4", "algo.iterations=1", "algo.hidden=[8]",
         "eval.episodes=1", "task.max_episode_steps=4", "progress=false"]


@pytest.fixture
def no_gpu(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 0)


def _one_line(err: pytest.ExceptionInfo, prog: str) -> str:
    msg = str(err.value.code)
    assert msg.startswith(f"{prog}: ") and "\n" not in msg, msg
    return msg


def test_train_refuses_a_missing_gpu_before_creating_the_run_dir(tmp_path, no_gpu):
    run_dir = tmp_path / "run"
    with initialize_config_dir(config_dir=str(train_app.CONFIG_DIR), version_base="1.3"):
        cfg = compose("config", overrides=[*SMALL, f"run_dir={run_dir}", "device=cuda"])
    with pytest.raises(ValueError, match="device 'cuda' is not available"):
        train_app.run(cfg)
    assert not run_dir.exists()


@pytest.mark.skipif(torch.cuda.is_available(), reason="the command line run needs a machine without a GPU")
def test_train_cli_missing_gpu_is_one_line_and_leaves_no_run_dir(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "dexmots_rl.apps.train", *SMALL, f"run_dir={tmp_path / 'run'}",
                           "device=cuda"], capture_output=True, text=True, cwd=tmp_path, timeout=300,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    lines = [line for line in proc.stderr.splitlines() if line.strip() and "Warp CUDA warning" not in line]
    assert proc.returncode != 0 and len(lines) == 1 and "device 'cuda'" in lines[0], proc.stderr
    assert not (tmp_path / "run").exists()


def test_rollout_missing_gpu_is_one_line(no_gpu):
    with pytest.raises(SystemExit) as err:
        rollout.main(["--device", "cuda", "--num-envs", "1", "--steps", "2"])
    assert "cuda" in _one_line(err, "dexmots-rollout")


@pytest.mark.parametrize("argv", [["throughput", "--num-envs", "1"], ["grad"], ["pipeline", "--num-envs", "1"]])
def test_bench_missing_gpu_is_one_line(no_gpu, argv):
    with pytest.raises(SystemExit) as err:
        bench.main([*argv, "--device", "cuda"])
    assert "cuda" in _one_line(err, "dexmots-bench")


@pytest.fixture
def full_disk(monkeypatch, tmp_path):
    """Every file opened for writing under ``tmp_path / "full"`` fails with ENOSPC."""
    full = str(tmp_path / "full")
    real_open = builtins.open

    def open_on_a_full_disk(file, mode="r", *args, **kwargs):
        if str(file).startswith(full) and any(c in mode for c in "wax+"):
            raise OSError(errno.ENOSPC, "No space left on device", str(file))
        return real_open(file, mode, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", open_on_a_full_disk)
    return Path(full)


def test_train_on_a_full_disk_is_one_line(full_disk, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["dexmots-train", *SMALL, f"run_dir={full_disk / 'run'}"])
    with pytest.raises(SystemExit) as err:
        train_app.main()
    assert "no space left on device" in _one_line(err, "dexmots-train")


def test_bench_train_on_a_full_disk_is_one_line(full_disk):
    with pytest.raises(SystemExit) as err:
        bench.main(["train", "--algo", "shac", "--run-dir", str(full_disk / "run"), *SMALL[1:]])
    assert "no space left on device" in _one_line(err, "dexmots-bench")


@pytest.fixture
def full_after(monkeypatch, tmp_path):
    """``full_after(n)``: files opened through ``os.fdopen`` (every atomic write) under ``tmp_path / "full"``
    take ``n`` bytes in all, then each write fails with ENOSPC, as a disk filling up mid-write."""
    full, real_fdopen = tmp_path / "full", os.fdopen
    left = {"bytes": 0}

    class FillingFile(io.BufferedWriter):
        def write(self, data):
            left["bytes"] -= len(data)
            if left["bytes"] < 0:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            return super().write(data)

    def fdopen(fd, mode="r", *args, **kwargs):
        if "w" in mode and Path(os.readlink(f"/proc/self/fd/{fd}")).is_relative_to(full):
            return FillingFile(io.FileIO(fd, "w"))
        return real_fdopen(fd, mode, *args, **kwargs)

    def set_room(n: int) -> Path:
        left["bytes"] = n
        monkeypatch.setattr(os, "fdopen", fdopen)
        return full

    return set_room


def test_a_disk_filling_up_mid_checkpoint_is_one_line_and_keeps_the_last_checkpoint(full_after, monkeypatch):
    from dexmots_rl.algorithms.checkpoint import load_checkpoint

    run = full_after(10**9) / "run"  # room for the first iteration's checkpoint
    first = [o for o in SMALL if not o.startswith("algo.iterations")] + ["algo.iterations=2", "stop_after=1"]
    monkeypatch.setattr(sys, "argv", ["dexmots-train", *first, f"run_dir={run}"])
    train_app.main()
    full_after(20_000)  # the next checkpoint (some 100 kB) does not fit: torch's zip writer fails mid-archive
    monkeypatch.setattr(sys, "argv", ["dexmots-train", f"resume={run}", "progress=false"])
    with pytest.raises(SystemExit) as err:
        train_app.main()
    msg = _one_line(err, "dexmots-train")
    assert "no space left on device" in msg and str(run / "checkpoints" / "last.pt") in msg
    assert load_checkpoint(run / "checkpoints" / "last.pt")["iteration"] == 1  # the last good one stays
    assert [p.name for p in (run / "checkpoints").iterdir()] == ["last.pt"]  # no temp file


def _unwritable_dir(tmp_path: Path) -> Path:
    """A directory nothing can be written under: read-only, or (as root, whom permissions do not stop) a path
    under a regular file."""
    folder = tmp_path / "read_only"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        (folder / "probe").touch()
    except PermissionError:
        return folder
    (folder / "probe").unlink()
    folder.chmod(0o700)
    (tmp_path / "a_file").write_text("")
    return tmp_path / "a_file" / "dir"


def test_eval_prints_its_result_when_it_cannot_write_it(tmp_path, capsys):
    import json

    from dexmots_rl.apps import eval as eval_app

    run = tmp_path / "run"
    with initialize_config_dir(config_dir=str(train_app.CONFIG_DIR), version_base="1.3"):
        train_app.run(compose("config", overrides=[*SMALL, f"run_dir={run}"]))
    capsys.readouterr()
    out = _unwritable_dir(tmp_path) / "eval.json"
    with pytest.raises(SystemExit) as err:
        eval_app.main([str(run), "--episodes", "1", "--out", str(out)])
    msg = _one_line(err, "dexmots-eval")
    assert str(out) in msg and "--out" in msg and ".tmp" not in msg
    assert json.loads(capsys.readouterr().out)["episodes"] == 1  # the result, printed all the same


@pytest.mark.parametrize("cache", ["full", "unwritable", "a_file"])
def test_an_unusable_scene_cache_is_one_error_naming_it_and_leaves_no_partial_scene(tmp_path, monkeypatch,
                                                                                    full_after, cache):
    from dexmots_rl.envs.tasks.allegro.object_scenes import build_scene, scene_dir

    root = {"full": lambda: full_after(3_000), "unwritable": lambda: _unwritable_dir(tmp_path),
            "a_file": lambda: tmp_path / "a_file"}[cache]()
    if cache == "a_file":
        root.write_text("")
    monkeypatch.setenv("DEXMOTS_CACHE", str(root))
    with pytest.raises(OSError) as err:
        build_scene("stapler_a")
    msg = str(err.value)
    assert "DEXMOTS_CACHE" in msg and str(root) in msg and "\n" not in msg
    assert not scene_dir("stapler_a").exists()  # no half-written scene folder
    with pytest.raises(SystemExit) as cli_err:  # and a console script says it in one line
        with os_errors_as_one_line("dexmots-eval"):
            build_scene("stapler_a")
    assert "DEXMOTS_CACHE" in _one_line(cli_err, "dexmots-eval")


def test_eval_refuses_objects_of_another_class_or_topology(tmp_path, capsys):
    from dexmots_rl.apps import eval as eval_app

    run = tmp_path / "run"
    with initialize_config_dir(config_dir=str(train_app.CONFIG_DIR), version_base="1.3"):
        train_app.run(compose("config", overrides=[
            "task=stapler", "algo=ppo", "task.num_envs=2", "task.max_episode_steps=4", "algo.frames_per_batch=8",
            "algo.total_frames=8", "algo.minibatch_size=8", "algo.hidden=[8]", "eval.episodes=1", "progress=false",
            f"run_dir={run}"]))
    for objects, differs in (("drawer_a", "class"), ("scissors_a,scissors_b", "class")):
        with pytest.raises(SystemExit) as err:
            eval_app.main([str(run), "--episodes", "1", "--objects", objects])
        msg = _one_line(err, "dexmots-eval")
        assert msg.startswith("dexmots-eval: --objects: ") and f"differs in its {differs}" in msg and "stapler_a" in msg
    assert not (run / "eval.json").exists()
    from dexmots_rl.envs.tasks.allegro.object_scenes import check_evaluation_objects

    assert check_evaluation_objects({"object": "stapler_a", "objects": None}, "heldout") == ["stapler_b"]
    assert check_evaluation_objects({"object": "valve_a", "objects": "valve_a,valve_c"}, "valve_b") == ["valve_b"]


# the commands that run from a config under configs/ take hydra key=value overrides; every other takes --options
KEY_VALUE_SCRIPTS = {"dexmots-train", "dexmots-table", "dexmots-record"}
# each --options command with its required arguments (none is run: the unknown option stops it first)
OPTION_ARGS = {"dexmots-bench": ["throughput"], "dexmots-eval": ["run"], "dexmots-plot": ["curves", "runs/a"],
               "dexmots-plan": ["--task", "screw_claw", "--goal", "1", "--out", "p.pt"],
               "dexmots-pregrasp": ["--task", "screw_claw"], "dexmots-rollout": [], "dexmots-view": ["run.mcap"],
               "dexmots-sysid": ["--data", "run.mcap", "--params", "joint_damping", "--out", "knob.json"]}


def _console_scripts() -> dict:
    import tomllib

    with open(ROOT / "pyproject.toml", "rb") as f:
        return tomllib.load(f)["project"]["scripts"]


def _run_script(script: str, args: list[str], monkeypatch, capsys):
    """``script``'s entry point on the command line ``args``: (exit code, stdout, stderr)."""
    import importlib

    from hydra.core.global_hydra import GlobalHydra

    GlobalHydra.instance().clear()  # another test's compose() may have left hydra initialised
    module, _, name = _console_scripts()[script].partition(":")
    monkeypatch.setattr(sys, "argv", [script, *args])
    code = 0
    try:
        getattr(importlib.import_module(module), name)()
    except SystemExit as e:
        code = e.code
    out, err = capsys.readouterr()
    return code, out, err


def test_every_console_script_follows_one_convention():
    assert set(_console_scripts()) == KEY_VALUE_SCRIPTS | set(OPTION_ARGS)


@pytest.mark.parametrize("script", sorted(KEY_VALUE_SCRIPTS | set(OPTION_ARGS)))
def test_every_console_script_prints_its_help(script, monkeypatch, capsys):
    code, out, err = _run_script(script, ["--help"], monkeypatch, capsys)
    assert code in (0, None) and script in out, (code, out, err)


@pytest.mark.parametrize("script", sorted(OPTION_ARGS))
def test_an_unknown_option_is_one_error_naming_it(script, monkeypatch, capsys, tmp_path):
    monkeypatch.chdir(tmp_path)
    code, out, err = _run_script(script, [*OPTION_ARGS[script], "--no-such-option"], monkeypatch, capsys)
    assert code == 2 and err.strip().splitlines()[-1] == f"{script}: error: unrecognized arguments: --no-such-option"


@pytest.mark.parametrize("script", sorted(KEY_VALUE_SCRIPTS))
@pytest.mark.parametrize("key", ["no_such_key", "+no_such_key"])
def test_an_unknown_key_is_one_line_naming_it_and_the_known_ones(script, key, monkeypatch, capsys, tmp_path):
    monkeypatch.chdir(tmp_path)
    code, out, err = _run_script(script, [f"{key}=1"], monkeypatch, capsys)
    message = str(code)
    assert message.startswith(f"{script}: no_such_key: no such key") and "\n" not in message, (code, err)
    assert "seed" in message and not out and "Traceback" not in err and not list(tmp_path.iterdir())
