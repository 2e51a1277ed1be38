"""The trainer under bad input: config validation first, run directories that are never trained over or shared,
resumes that repeat no log rows and keep their checkpoint's config, clean SIGINT/SIGTERM."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from dexmots_rl.algorithms.checkpoint import CheckpointError, load_checkpoint
from dexmots_rl.algorithms.rundir import RunDirectory, RunDirLock
from dexmots_rl.apps.train import CONFIG_DIR, run as train
from test_resume import _cfg as resume_cfg
from test_train import _cfg, _rows


def _source_env() -> dict:
    """Subprocesses started elsewhere import this source tree (not another checkout's editable install)."""
    root = str(Path(__file__).resolve().parents[1])
    return {**os.environ, "PYTHONPATH": os.pathsep.join([root, os.environ.get("PYTHONPATH", "")])}


def _compose(*overrides):
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return compose("config", overrides=list(overrides))


@pytest.mark.parametrize("override, key", [
    ("checkpoint_every=0", "checkpoint_every"), ("algo.critic_minibatches=0", "algo.critic_minibatches"),
    ("algo.horizon=-5", "algo.horizon"), ("eval.episodes=0", "eval.episodes"), ("algo.iterations=-3", "algo.iterations"),
    ("algo.gamma=2", "algo.gamma"), ("algo.actor_lr=-1", "algo.actor_lr"), ("algo.critic_lr=nan", "algo.critic_lr"),
    ("algo.lmbda=1.5", "algo.lmbda"), ("algo.betas=[0.9,1.0]", "algo.betas"), ("algo.hidden=[0]", "algo.hidden"),
    ("algo.critic_hidden=[]", "algo.critic_hidden"),
    ("algo.target_alpha=-0.1", "algo.target_alpha"), ("algo.grad_norm=0", "algo.grad_norm"), ("seed=-1", "seed"),
    ("stop_after=0", "stop_after"), ("eval.every=-1", "eval.every"), ("algo.adjoint_clip=0.5", "algo.adjoint_clip"),
])
def test_bad_run_config_is_refused_before_any_work(tmp_path, override, key):
    run = tmp_path / "run"
    with pytest.raises(ValueError, match=re.escape(key)):
        train(_cfg(run, "algo.iterations=1", override))
    assert not run.exists()


def test_ahac_horizon_bounds_are_validated(tmp_path):
    with pytest.raises(ValueError, match="algo.horizon"):
        train(_cfg(tmp_path / "run", "algo=ahac", "algo.horizon=100"))


def test_default_run_dir_is_unique_per_run():
    cfg = _compose()
    assert re.search(r"runs/screw_claw_ahac_seed0_\d{8}-\d{6}$", cfg.run_dir), cfg.run_dir


def test_existing_run_dir_is_refused_without_overwrite(tmp_path):
    run = tmp_path / "run"
    train(_cfg(run, "algo.iterations=1"))
    before = (run / "checkpoints" / "last.pt").read_bytes()
    with pytest.raises(ValueError, match="overwrite=true"):
        train(_cfg(run, "algo.iterations=1"))
    assert (run / "checkpoints" / "last.pt").read_bytes() == before
    train(_cfg(run, "algo.iterations=2", "overwrite=true"))
    assert [r["iteration"] for r in _rows(run)] == [1, 2]  # the old run's rows are gone, not appended to


def test_a_run_failing_before_its_first_write_leaves_no_directory(tmp_path, monkeypatch):
    import dexmots_rl.algorithms.shac as shac

    def broken_build(cfg, rank=0):
        raise RuntimeError("no env today")

    monkeypatch.setattr(shac, "build", broken_build)
    run = tmp_path / "new_run"
    with pytest.raises(RuntimeError, match="no env today"):
        train(_cfg(run, "algo.iterations=1"))
    assert not run.exists()
    mine = tmp_path / "existing"  # a directory the user made is theirs: it stays, unlocked
    mine.mkdir()
    with pytest.raises(RuntimeError, match="no env today"):
        train(_cfg(mine, "algo.iterations=1"))
    assert mine.is_dir()
    RunDirLock(mine).close()


def test_locked_run_dir_fails_clearly(tmp_path):
    run = tmp_path / "run"
    with RunDirLock(run):
        with pytest.raises(ValueError, match="in use by another trainer"):
            train(_cfg(run, "algo.iterations=1"))
    train(_cfg(run, "algo.iterations=1"))  # released: usable again


def _append_crash_rows(run: Path, iteration: int) -> None:
    """What a trainer killed after logging ``iteration`` but before checkpointing it leaves behind."""
    with open(run / "metrics.jsonl", "a") as f:
        f.write(json.dumps({"iteration": iteration, "reward": 0.0}) + "\n" + '{"iteration": ')  # + a torn line
    for csv in (run / "logs").rglob("*.csv"):
        with open(csv, "a") as f:
            f.write(f"{iteration},0.0\n")


def test_resume_after_a_crash_repeats_no_log_rows_and_cleans_temp_files(tmp_path):
    run = tmp_path / "run"
    train(_cfg(run, "algo.iterations=3", "stop_after=2"))
    _append_crash_rows(run, 3)
    stale = run / "checkpoints" / ".last.pt.k1ll3d.tmp"
    stale.write_bytes(b"")
    train(_cfg(tmp_path / "ignored", "algo.iterations=3", f"resume={run}"))
    assert [r["iteration"] for r in _rows(run)] == [1, 2, 3]
    for csv in (run / "logs").rglob("*.csv"):
        steps = [int(line.split(",")[0]) for line in csv.read_text().splitlines()]
        assert steps == sorted(set(steps)), csv
    assert not stale.exists()


def test_a_resumed_run_names_its_own_directory(tmp_path):
    run = tmp_path / "run"
    train(_cfg(run, "algo.iterations=2", "stop_after=1"))
    result = train(_cfg(tmp_path / "elsewhere", "algo.iterations=2", f"resume={run}"))
    assert Path(OmegaConf.load(run / "config.yaml").run_dir) == run  # the config names the run it describes
    assert Path(load_checkpoint(run / "checkpoints" / "last.pt")["config"]["run_dir"]) == run
    assert Path(result["run_dir"]) == run and not (tmp_path / "elsewhere").exists()


def test_resume_uses_the_checkpoints_config_and_refuses_conflicting_overrides(tmp_path):
    run = tmp_path / "run"
    train(_cfg(run, "algo.iterations=1"))  # TINY: 4 worlds, horizon 4, shac
    cli = [f"resume={run}", "algo.iterations=2", "eval.episodes=2", "progress=false"]
    result = train(_compose(*cli), cli)  # the defaults (ahac, 32 steps...) are not what it resumes with
    assert result["algo"] == "shac" and result["env_steps"] == 2 * 4 * 4
    assert load_checkpoint(run / "checkpoints" / "last.pt")["config"]["task"]["num_envs"] == 4
    for extra, key in (("task.num_envs=8", "task.num_envs"), ("algo.gamma=0.5", "algo.gamma"), ("algo=ahac", "algo.name")):
        with pytest.raises(CheckpointError, match=re.escape(key)):
            train(_compose(*cli, extra), [*cli, extra])


def test_cli_resume_conflict_is_one_line_and_hydra_rewrites_nothing(tmp_path):
    run = tmp_path / "run"
    train(_cfg(run, "algo.iterations=1"))
    before = {p: p.read_bytes() for p in run.rglob("*") if p.is_file()}
    proc = subprocess.run([sys.executable, "-m", "dexmots_rl.apps.train", f"resume={run}", "task.num_envs=8"],
                          capture_output=True, text=True, timeout=300, cwd=tmp_path, env=_source_env())
    assert proc.returncode != 0
    lines = proc.stderr.strip().splitlines()
    assert lines[-1].startswith("dexmots-train:") and "task.num_envs" in lines[-1] and "Traceback" not in proc.stderr
    assert not (run / ".hydra").exists() and not list(tmp_path.glob("*.log"))
    assert {p: p.read_bytes() for p in run.rglob("*") if p.is_file()} == before


def _signal_cfg(algo, run):
    if algo == "shac":
        return _cfg(run, "algo.iterations=5", "checkpoint_every=100")
    return resume_cfg(algo, run, "checkpoint_every=100")  # four iterations


# every learning method ends its iterations with the same loop, which takes the signal
@pytest.mark.parametrize("algo, sig", [("shac", signal.SIGTERM), ("shac", signal.SIGINT), ("ppo", signal.SIGINT),
                                       ("sac", signal.SIGTERM)])
def test_signal_saves_a_checkpoint_and_returns_cleanly(tmp_path, monkeypatch, algo, sig):
    log_row = RunDirectory.log

    def log_and_signal(self, row):
        log_row(self, row)
        if row["iteration"] == 1:
            os.kill(os.getpid(), sig)

    monkeypatch.setattr(RunDirectory, "log", log_and_signal)
    run = tmp_path / "run"

    def outer(signum, frame):  # the caller's own handler (the default one is SIG_IGN under `nohup ... &`)
        raise AssertionError("the trainer's handler should have taken the signal")

    previous = signal.signal(sig, outer)
    try:
        result = train(_signal_cfg(algo, run))
        assert signal.getsignal(sig) is outer  # handlers restored
    finally:
        signal.signal(sig, previous)
    # the signal came after iteration 1's check (while logging it): iteration 2 is finished and saved
    assert result["interrupted"] == sig.name and result["iteration"] == 2
    assert load_checkpoint(run / "checkpoints" / "last.pt")["iteration"] == 2
    assert not (run / "metrics.json").exists()
