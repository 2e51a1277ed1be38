"""dexmots-train / dexmots-eval: run directory, checkpoints, resume determinism, bad input, torchrun."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir

from dexmots_rl.algorithms.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from dexmots_rl.algorithms.evaluation import evaluate_policy
from dexmots_rl.algorithms.registry import policy_from_checkpoint
from dexmots_rl.apps.eval import main as eval_main
from dexmots_rl.apps.train import CONFIG_DIR, run as train

TINY = ["task.num_envs=4", "algo.horizon=4", "algo.critic_iterations=2", "algo.critic_minibatches=2",
        "algo.hidden=[16]", "eval.episodes=3", "task.max_episode_steps=6", "progress=false", "checkpoint_every=1"]


TINY_SHAC = ["algo=shac", *TINY]  # TINY's horizon is SHAC's (AHAC, the default, starts above it)


def _cfg(run_dir, *overrides):
    base = TINY if any(o.startswith("algo=") for o in overrides) else TINY_SHAC
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return compose("config", overrides=[*base, f"run_dir={run_dir}", *overrides])


def _rows(run_dir):
    rows = [json.loads(line) for line in (Path(run_dir) / "metrics.jsonl").read_text().splitlines()]
    return [{k: v for k, v in r.items() if k not in ("wall_clock_s", "cpu_s")} for r in rows]  # timings differ


def test_train_writes_run_directory(tmp_path):
    result = train(_cfg(tmp_path / "run", "algo.iterations=2"))
    run = tmp_path / "run"
    assert (run / "config.yaml").is_file() and (run / "checkpoints" / "last.pt").is_file()
    assert json.loads((run / "metrics.json").read_text())["success_rate"] == result["success_rate"]
    assert result["env_steps"] == 2 * 4 * 4 and result["iterations"] == 2
    assert {"success_rate", "mean_final_error", "mean_time_to_success_s"} <= set(result)
    rows = _rows(run)
    assert [r["iteration"] for r in rows] == [1, 2]
    assert all(r["reward_pose"] > 0 for r in rows)
    assert any(p.name == "reward.csv" for p in run.rglob("*.csv"))  # torchrl CSV logger output


def test_critic_widths_apart_from_the_actor(tmp_path):
    train(_cfg(tmp_path / "run", "algo.iterations=1", "algo.critic_hidden=[8,8]"))
    actor, data = policy_from_checkpoint(tmp_path / "run")  # the actor alone is rebuilt from algo.hidden
    widths = lambda state: [v.shape[0] for k, v in state.items() if k.endswith("weight") and v.dim() == 2]
    assert widths(data["modules"]["critic"]) == [8, 8, 1]
    assert widths(actor.state_dict())[:1] == [16]


def test_resume_reproduces_the_uninterrupted_run(tmp_path):
    train(_cfg(tmp_path / "straight", "algo.iterations=4"))
    assert train(_cfg(tmp_path / "split", "algo.iterations=4", "stop_after=2")) == {}  # no final eval yet
    train(_cfg(tmp_path / "elsewhere", "algo.iterations=4", f"resume={tmp_path / 'split'}"))
    straight, split = _rows(tmp_path / "straight"), _rows(tmp_path / "split")
    assert [r["iteration"] for r in split] == [1, 2, 3, 4]
    assert split == straight


def test_checkpoint_round_trip_and_eval(tmp_path):
    train(_cfg(tmp_path / "run", "algo.iterations=1"))
    actor, data = policy_from_checkpoint(tmp_path / "run")
    assert data["task"] == "screw_claw" and data["iteration"] == 1
    saved = data["modules"]["actor"]
    for key, value in actor.state_dict().items():
        torch.testing.assert_close(value, saved[key])
    ev = evaluate_policy(actor, data["config"]["task"], episodes=8, seed=0)
    assert ev["episodes"] == 8 and 0.0 <= ev["success_rate"] <= 1.0
    groups = ev["success_by_friction"]  # quartiles of the episodes' drawn knob friction
    assert [g["episodes"] for g in groups] == [2, 2, 2, 2]
    assert all(0.2 <= g["low"] <= g["high"] <= 1.0 for g in groups)
    assert all(a["high"] <= b["low"] for a, b in zip(groups, groups[1:]))
    assert sum(g["success_rate"] for g in groups) / 4 == pytest.approx(ev["success_rate"])
    goals = ev["success_by_goal"]  # quartiles of the signed goal angle: a one-direction policy shows as two halves
    assert all(0.78 <= abs(g[end]) <= 1.58 for g in goals for end in ("low", "high"))
    assert all(a["high"] <= b["low"] for a, b in zip(goals, goals[1:]))
    eval_main([str(tmp_path / "run"), "--episodes", "2"])
    assert json.loads((tmp_path / "run" / "eval.json").read_text())["episodes"] == 2


def test_bad_checkpoints_fail_clearly_and_overwrite_nothing(tmp_path):
    path = tmp_path / "ckpt.pt"
    save_checkpoint(path, {"task": "screw_claw", "algo": "shac", "iteration": 1})
    good = path.read_bytes()
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(good[: len(good) // 2])
    with pytest.raises(CheckpointError, match="truncated"):
        load_checkpoint(truncated)
    old = tmp_path / "old.pt"
    torch.save({"format": "dexmots-checkpoint", "version": 0}, old)
    with pytest.raises(CheckpointError, match="version"):
        load_checkpoint(old)
    with pytest.raises(CheckpointError, match="cube"):
        load_checkpoint(path, task="cube")
    with pytest.raises(CheckpointError, match="does not exist"):
        load_checkpoint(tmp_path / "missing.pt")
    assert path.read_bytes() == good


def test_resume_from_another_task_or_algo_is_refused(tmp_path):
    run = tmp_path / "run"
    train(_cfg(run, "algo.iterations=1"))
    before = (run / "checkpoints" / "last.pt").read_bytes()
    with pytest.raises(CheckpointError, match="algo"):
        train(_cfg(tmp_path / "other", "algo=ahac", "algo.iterations=2", f"resume={run}"))
    data = torch.load(run / "checkpoints" / "last.pt", weights_only=True)
    data["task"] = "cube"
    save_checkpoint(run / "checkpoints" / "last.pt", {k: v for k, v in data.items() if k not in ("format", "version")})
    with pytest.raises(CheckpointError, match="cube"):
        train(_cfg(tmp_path / "other", "algo.iterations=2", f"resume={run}"))
    assert (run / "checkpoints" / "last.pt").read_bytes() != before  # only our edit changed it


def test_ahac_runs_and_records_its_horizon(tmp_path):
    result = train(_cfg(tmp_path / "run", "algo=ahac", "algo.iterations=2", "algo.horizon=6", "algo.horizon_min=2",
                        "algo.horizon_max=6"))
    assert result["algo"] == "ahac"
    assert all(2 <= r["horizon"] <= 6 for r in _rows(tmp_path / "run"))


# each case starts a process (seconds of CPU in imports alone): one in the fast set, the others in the slow one
@pytest.mark.parametrize("override, field", [("task.goal=pose_pose", "goal"),
                                             pytest.param("task.action=velocity", "action", marks=pytest.mark.slow),
                                             pytest.param("algo.init_stiffness=1.0", "init_stiffness",
                                                          marks=pytest.mark.slow),
                                             pytest.param("task.reward.lambda_act=-1", "lambda_act",
                                                          marks=pytest.mark.slow)])
def test_cli_rejects_bad_config_with_one_line(tmp_path, override, field):
    proc = subprocess.run([sys.executable, "-m", "dexmots_rl.apps.train", *TINY_SHAC,
                           f"run_dir={tmp_path}/r", "algo.iterations=1", override], capture_output=True, text=True, timeout=300)
    assert proc.returncode != 0
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("dexmots-train:") and field in last


@pytest.mark.slow  # two fresh processes
def test_torchrun_two_processes(tmp_path):
    torchrun = Path(sys.executable).parent / "torchrun"
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    proc = subprocess.run([str(torchrun), "--standalone", "--nproc_per_node", "2", "-m", "dexmots_rl.apps.train",
                           *TINY_SHAC, f"run_dir={tmp_path}/r", "algo.iterations=2"], capture_output=True, text=True,
                          timeout=600, env=env)
    assert proc.returncode == 0, proc.stderr[-2000:]
    result = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert result["env_steps"] == 2 * 2 * 4 * 4  # iterations x ranks x worlds x horizon


def test_training_evaluation_records_a_live_mcap(tmp_path):
    from dexmots_rl.viz import read_recording

    train(_cfg(tmp_path / "run", "algo.iterations=2", "eval.every=1", "eval.record=true"))
    rec = read_recording(tmp_path / "run" / "eval.mcap")
    assert rec.frames.batch_size[1] == 3  # eval.episodes=3 worlds (fewer than record_worlds)
    assert int(rec.episode.max()) == 1  # two evaluations: after iteration 1 and the final one


def test_every_algorithm_config_has_a_registered_method_and_back():
    from dexmots_rl.algorithms.registry import ALGORITHMS, algorithm

    configs = {p.stem for p in (Path(CONFIG_DIR) / "algo").glob("*.yaml")}
    assert {a.config for a in ALGORITHMS.values()} == configs
    for name in configs:
        with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
            assert compose("config", overrides=[f"algo={name}"]).algo.name == name
        assert algorithm(name).config == name
    with pytest.raises(ValueError, match="known: ahac, mpc, pgdm, ppo, sac, shac"):
        algorithm("dreamer")


@pytest.mark.parametrize("name", sorted(p.stem for p in (Path(CONFIG_DIR) / "algo").glob("*.yaml")))
def test_every_method_runs_torch_on_one_thread_by_default(name, monkeypatch):
    """More torch threads wait on each other on a busy machine (docs/results.md, threads): every method's
    composed config asks for one, and the trainer sets it before the method starts."""
    from dexmots_rl.algorithms import registry

    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose("config", overrides=[f"algo={name}"])
    assert cfg.torch_threads == 1
    seen = []
    monkeypatch.setattr(registry, "train", lambda cfg, overrides=None: seen.append(torch.get_num_threads()) or {})
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        train(cfg)
    finally:
        torch.set_num_threads(before)
    assert seen == [1]


def test_init_stiffness_starts_the_vi_policy_stiff_and_leaves_its_targets(tmp_path):
    from tensordict import TensorDict

    from dexmots_rl.algorithms.shac import build

    locs = []
    for stiffness in (0.0, 0.8):
        env, actor, *_ = build(_cfg(tmp_path / "run", f"algo.init_stiffness={stiffness}"))
        nu = env.base_env.actions.nu
        with torch.no_grad():
            locs.append(actor.module[0](TensorDict(observation=env.reset()["observation"], batch_size=[4]))["loc"])
    shift = locs[1] - locs[0]  # the same seed gives the same weights: only the output bias differs
    torch.testing.assert_close(shift[:, :nu], torch.zeros_like(shift[:, :nu]))
    torch.testing.assert_close(shift[:, nu:], torch.full_like(shift[:, nu:], math.atanh(0.8)))


def test_algo_num_envs_sets_the_training_worlds_and_null_keeps_the_tasks(tmp_path):
    from dexmots_rl.algorithms.shac import build

    assert build(_cfg(tmp_path / "run"))[0].batch_size == (4,)  # TINY's task.num_envs
    assert build(_cfg(tmp_path / "run", "algo.num_envs=2"))[0].batch_size == (2,)


def test_the_kernels_are_loaded_before_the_training_clock_starts(tmp_path, monkeypatch):
    """A cold warp cache's compile (a minute or two of CPU on the Allegro scenes) is not charged to the budget."""
    import time

    import dexmots_rl.algorithms.loop as loop_module

    loaded = []

    def slow_load(env):  # stands in for a cold compile: 2 s of this process's CPU
        end = time.process_time() + 2.0
        while time.process_time() < end:
            pass
        loaded.append(env)

    monkeypatch.setattr(loop_module, "load_kernels", slow_load)
    train(_cfg(tmp_path / "run", "algo.iterations=1"))
    first = json.loads((tmp_path / "run" / "metrics.jsonl").read_text().splitlines()[0])
    assert len(loaded) == 1 and first["cpu_s"] < 2.0


def test_load_kernels_compiles_the_envs_simulator_and_leaves_other_envs_alone():
    from dexmots_rl.algorithms.loop import load_kernels
    from dexmots_rl.envs import make_env

    load_kernels(object())  # no simulator: nothing to do
    env = make_env("screw_claw", num_envs=1)
    load_kernels(env)  # the kernel cache is warm from the tests before: a file check
    assert env.rollout(2)["next", "reward"].shape == (1, 2, 1)
