"""PPO / SAC baselines (``dexmots-train algo=ppo|sac``): run directory, resume, dexmots-eval reload, torchrl's losses,
the replay buffer's keys, the exported policy's normaliser."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf
from tensordict import TensorDict

from dexmots_rl.algorithms import ppo, sac
from dexmots_rl.algorithms.checkpoint import CheckpointError, load_checkpoint
from dexmots_rl.algorithms.common import (RunningObsNorm, deployable_policy, make_train_env, sync_obs_norm,
                                          tanh_gaussian_actor)
from dexmots_rl.algorithms.registry import policy_from_checkpoint
from dexmots_rl.apps.eval import main as eval_main
from dexmots_rl.apps.train import CONFIG_DIR, run as train
from dexmots_rl.envs import make_env

TINY = ["task.num_envs=4", "task.max_episode_steps=6", "eval.episodes=2", "progress=false", "checkpoint_every=1"]
ALGOS = {
    "ppo": ["algo=ppo", "algo.frames_per_batch=24", "algo.total_frames=48", "algo.minibatch_size=12",
            "algo.hidden=[16]"],
    "sac": ["algo=sac", "algo.frames_per_batch=16", "algo.total_frames=32", "algo.init_random_frames=16",
            "algo.batch_size=8", "algo.hidden=[16]", "algo.buffer_size=1000"],
}


def _cfg(algo, run_dir, *overrides):
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return compose("config", overrides=[*TINY, *ALGOS[algo], f"run_dir={run_dir}", *overrides])


@pytest.mark.parametrize("algo, goal", [("ppo", "pose"), ("ppo", "pose_wrench"), ("sac", "pose_wrench")])
def test_two_iterations_write_a_run_that_dexmots_eval_reloads(tmp_path, algo, goal):
    run = tmp_path / "run"
    result = train(_cfg(algo, run, f"task.goal={goal}"))
    assert result["algo"] == algo and result["iterations"] == 2 and result["episodes"] == 2
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert [r["iteration"] for r in rows] == [1, 2]
    assert rows[-1]["env_steps"] == result["env_steps"] == 2 * int(ALGOS[algo][1].split("=")[1])
    assert all({"wall_clock_s", "reward", "episode_success"} <= set(r) for r in rows)
    assert 0.0 <= rows[-1]["episode_success"] <= 1.0  # 6-step episodes end inside every batch
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["success_rate"] == result["success_rate"]

    policy, data = policy_from_checkpoint(run)
    assert data["algo"] == algo and data["iteration"] == 2
    for key, value in policy.state_dict().items():
        torch.testing.assert_close(value, data["modules"]["policy"][key])
    eval_main([str(run), "--episodes", "2"])  # dexmots-eval: same episodes (seed) as the final evaluation
    ev = json.loads((run / "eval.json").read_text())
    assert ev["episodes"] == 2 and ev["mean_final_error"] == pytest.approx(metrics["mean_final_error"], rel=1e-5)


def test_the_losses_are_torchrls(tmp_path):
    from torchrl.objectives import ClipPPOLoss, SACLoss

    loss = ppo.build(_cfg("ppo", tmp_path / "p"))[5]
    assert type(loss) is ClipPPOLoss
    loss = sac.build(_cfg("sac", tmp_path / "s"))[3]
    assert type(loss) is SACLoss


def test_replay_buffer_stores_only_what_sac_reads(tmp_path):
    env, vecnorm, actor, loss, updater, optimizer, buffer = sac.build(_cfg("sac", tmp_path / "s"))
    data = env.rollout(5, actor, break_when_any_done=False)  # [4 worlds, 5 steps], every key the env writes
    assert ("sim", "joint_q") in data.keys(True) and ("next", "reward_terms", "pose") in data.keys(True)
    sac.store_transitions(buffer, data)
    assert len(buffer) == 20
    stored = buffer.storage[0:len(buffer)]
    # plus "index", the buffer's own bookkeeping (TensorDictReplayBuffer writes each item's storage index)
    assert set(stored.keys(True, True)) == {*sac.TRANSITION_KEYS, "index"}
    out = loss(buffer.sample())  # and they are all the loss needs
    assert torch.isfinite(out["loss_qvalue"]) and torch.isfinite(out["loss_actor"])


def test_deployable_policy_normalises_the_plain_env_like_the_training_env():
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose("config", overrides=["task.num_envs=3", "task.max_episode_steps=6"])
    env, vecnorm = make_train_env(cfg, seed=3)
    plain = make_env(cfg.task, differentiable=False, seed=3)
    actions = torch.rand(4, 3, env.action_spec.shape[-1], generator=torch.Generator().manual_seed(0)) * 2 - 1
    td, td_plain = env.reset(), plain.reset()
    for i, a in enumerate(actions):  # same seed, same actions: the same worlds, once normalised, once raw
        if i == 2:
            vecnorm.freeze()  # statistics from the first steps, then fixed
        td = env.step(td.set("action", a))["next"]
        td_plain = plain.step(td_plain.set("action", a))["next"]
    actor = tanh_gaussian_actor(td["observation"].shape[-1], env.action_spec_unbatched, [8])
    policy = deployable_policy(actor, td["observation"].shape[-1])
    sync_obs_norm(policy, vecnorm)
    normalised = policy[0](TensorDict(observation=td_plain["observation"], batch_size=[3]))["observation"]
    torch.testing.assert_close(normalised, td["observation"], rtol=1e-4, atol=1e-4)


def test_running_obs_norm_stays_finite_on_features_that_do_not_move():
    # 1001 constant features (a resting tool base's height, its orientation, ...) for ~164k env steps: the bias
    # correction reaches 1 in float32 and torchrl's E[x²] - E[x]² turns negative on some of them (the NaNs that
    # stopped PGDM's tool runs); the normaliser must keep every feature finite and at the scale of its spread
    still = torch.linspace(-0.1, 1.0, 1001).expand(4096, -1)
    moving = torch.randn(4096, 3, generator=torch.Generator().manual_seed(0)) * 2.0 + 5.0
    norm = RunningObsNorm(in_keys=["observation"], reduce_batch_dims=True, decay=0.9999)
    for _ in range(40):
        data = TensorDict(observation=torch.cat([still, moving], -1), batch_size=[4096])
        out = norm._step(data.clone(), data.clone())["observation"]
    assert torch.isfinite(out).all()
    loc, scale = norm._get_loc_scale()
    torch.testing.assert_close(loc["observation"][:1001], still[0], rtol=1e-4, atol=1e-6)
    torch.testing.assert_close(scale["observation"][1001:], torch.full((3,), 2.0), rtol=0.05, atol=0.0)
    assert bool((scale["observation"][:1001] < 1e-2).all())  # a still feature: eps or rounding, not NaN


def test_ppo_stops_after_and_resumes_in_its_own_directory(tmp_path):
    run = tmp_path / "run"
    assert train(_cfg("ppo", run, "stop_after=1")) == {}  # two iterations in the schedule: stopped after one
    assert load_checkpoint(run / "checkpoints" / "last.pt")["iteration"] == 1 and not (run / "metrics.json").exists()
    result = train(_cfg("ppo", tmp_path / "elsewhere", f"resume={run}"))
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert [r["iteration"] for r in rows] == [1, 2] and rows[1]["env_steps"] == 2 * rows[0]["env_steps"]
    assert result["iterations"] == 2 and Path(result["run_dir"]) == run and (run / "metrics.json").is_file()
    assert Path(OmegaConf.load(run / "config.yaml").run_dir) == run and not (tmp_path / "elsewhere").exists()
    with pytest.raises(CheckpointError, match="algo.lr"):  # the checkpoint's algo section trains on
        train(_cfg("ppo", tmp_path / "again", f"resume={run}", "algo.lr=0.1"), [f"resume={run}", "algo.lr=0.1"])
