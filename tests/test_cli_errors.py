"""A GPU the machine lacks and a full disk are one line from every console script that meets them, and a
training run refuses the device before it creates (and locks) its run directory."""

from __future__ import annotations

import builtins
import errno
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir

from dexmots_rl.apps import bench, rollout
from dexmots_rl.apps import train as train_app

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
