"""Resume of every learning method (``resume=<run_dir>``): a run stopped by ``stop_after`` and resumed ends exactly as
the same run uninterrupted: the same ``metrics.jsonl`` rows, final evaluation and weights, bit for bit (CPU)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir

from dexmots_rl import envs  # noqa: F401  (registers the tasks with hydra)
from dexmots_rl.algorithms.checkpoint import load_checkpoint
from dexmots_rl.apps.train import CONFIG_DIR, run as train

# 8-step episodes over 6-step (PPO, PGDM) or 4-step (SAC) batches: episodes run across the interruption
TINY = ["task.num_envs=4", "task.max_episode_steps=8", "eval.episodes=2", "progress=false", "checkpoint_every=1"]
ALGOS = {
    "ppo": ["algo=ppo", "algo.frames_per_batch=24", "algo.total_frames=96", "algo.minibatch_size=12",
            "algo.hidden=[16]"],
    "pgdm": ["algo=pgdm", "algo.frames_per_batch=24", "algo.total_frames=96", "algo.minibatch_size=12",
             "algo.hidden=[16]"],
    # random actions for the first 2 batches: the interruption falls inside them
    # a periodic evaluation falls on the interruption (the uninterrupted run evaluates there too)
    "ahac": ["algo=ahac", "algo.iterations=4", "algo.horizon=8", "algo.horizon_min=4", "algo.horizon_max=8",
             "algo.critic_iterations=2", "algo.critic_minibatches=2", "algo.hidden=[16]", "eval.every=2",
             "eval.curve_episodes=1"],
    "sac": ["algo=sac", "algo.frames_per_batch=16", "algo.total_frames=64", "algo.init_random_frames=32",
            "algo.batch_size=8", "algo.hidden=[16]", "algo.buffer_size=40"],  # the buffer wraps around
}
TIMINGS = ("wall_clock_s", "cpu_s", "train_wall_clock_s", "train_cpu_s", "collect_cpu_s", "collect_wall_s", "learn_cpu_s",
           "learn_wall_s", "run_dir", "provenance")


def _cfg(algo, run_dir, *overrides):
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return compose("config", overrides=[*TINY, *ALGOS[algo], f"run_dir={run_dir}", *overrides])


def _rows(run_dir: Path) -> list[dict]:
    rows = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    return [{k: v for k, v in r.items() if k not in TIMINGS} for r in rows]


def _assert_same_tensors(a, b, where=""):
    if isinstance(a, dict):
        assert set(a) == set(b), where
        for key in a:
            _assert_same_tensors(a[key], b[key], f"{where}.{key}")
    elif isinstance(a, torch.Tensor):
        assert torch.equal(a, b), where
    else:
        assert a == b, where


# SAC stopped inside its random frames, and after them (its buffer full and wrapped around)
@pytest.mark.parametrize("algo, stop_after, task", [("ppo", 2, "screw_claw"), ("pgdm", 2, "stapler"),
                                                    ("sac", 1, "screw_claw"), ("sac", 3, "screw_claw"),
                                                    ("ahac", 2, "screw_claw")])
def test_a_resumed_run_equals_the_uninterrupted_run(tmp_path, algo, stop_after, task):
    train(_cfg(algo, tmp_path / "straight", f"task={task}"))
    assert train(_cfg(algo, tmp_path / "split", f"task={task}", f"stop_after={stop_after}")) == {}
    train(_cfg(algo, tmp_path / "elsewhere", f"task={task}", f"resume={tmp_path / 'split'}"))
    assert _rows(tmp_path / "split") == _rows(tmp_path / "straight")
    one, other = (json.loads((tmp_path / run / "metrics.json").read_text()) for run in ("straight", "split"))
    assert {k: v for k, v in one.items() if k not in TIMINGS} == {k: v for k, v in other.items() if k not in TIMINGS}
    one, other = (load_checkpoint(tmp_path / run / "checkpoints" / "last.pt") for run in ("straight", "split"))
    _assert_same_tensors(one["modules"], other["modules"], "modules")
    _assert_same_tensors(one["optimizers"], other["optimizers"], "optimizers")


@pytest.mark.parametrize("algo, missing", [("ppo", "env_state"), ("sac", "replay_buffer")])
def test_a_checkpoint_from_before_saved_episodes_resumes_or_says_why_not(tmp_path, caplog, algo, missing):
    from dexmots_rl.algorithms.checkpoint import CheckpointError, save_checkpoint

    run = tmp_path / "run"
    assert train(_cfg(algo, run, "stop_after=1")) == {}
    path = run / "checkpoints" / "last.pt"
    save_checkpoint(path, {k: v for k, v in load_checkpoint(path).items()
                           if k not in (missing, "format", "version", "sha256")})
    if algo == "sac":  # without its transitions SAC cannot go on as it would have
        with pytest.raises(CheckpointError, match="no replay buffer"):
            train(_cfg(algo, tmp_path / "elsewhere", f"resume={run}"))
        return
    result = train(_cfg(algo, tmp_path / "elsewhere", f"resume={run}"))  # the same networks, fresh episodes
    assert result["iterations"] == 4 and "start afresh" in caplog.text
