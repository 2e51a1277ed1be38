"""PGDM baseline (``dexmots-train algo=pgdm``): its reward on known poses, its observation, the action-bias warm
start, a tiny run that dexmots-eval reloads on the plain task env, torchrl's ClipPPOLoss."""

from __future__ import annotations

import json
import math

import pytest
import torch
from hydra import compose, initialize_config_dir
from torchrl.envs.utils import ExplorationType, set_exploration_type

from dexmots_rl.algorithms import pgdm
from dexmots_rl.algorithms.evaluation import evaluate_policy
from dexmots_rl.algorithms.registry import policy_from_checkpoint
from dexmots_rl.apps.eval import main as eval_main
from dexmots_rl.apps.train import CONFIG_DIR, run as train
from dexmots_rl.envs import list_tasks, make_env
from dexmots_rl.quaternions import quat_multiply

TINY = ["algo=pgdm", "task.num_envs=4", "task.max_episode_steps=6", "eval.episodes=2", "progress=false",
        "checkpoint_every=1", "algo.frames_per_batch=24", "algo.total_frames=48", "algo.minibatch_size=12",
        "algo.hidden=[16]"]


def _cfg(tmp_path, *overrides):
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return compose("config", overrides=[*TINY, f"run_dir={tmp_path / 'run'}", *overrides])


def test_tracking_reward_exact_values():
    zero = torch.zeros(1, 1)
    assert pgdm.tracking_reward(zero, zero).item() == pytest.approx(10.0)
    # 1 cm and a half turn: 50 (0.01 + 0.1 * pi / pi) = 5.5
    assert pgdm.tracking_reward(zero + 0.01, zero + math.pi).item() == pytest.approx(10 * math.exp(-5.5))
    lifted = torch.ones(1, 1, dtype=torch.bool)
    assert pgdm.tracking_reward(zero, zero, lifted).item() == pytest.approx(12.5)
    assert pgdm.tracking_reward(zero, zero, ~lifted).item() == pytest.approx(10.0)


def test_hinged_part_reward_is_its_angle_error(tmp_path):
    cfg = _cfg(tmp_path)
    env = make_env(cfg.task, differentiable=False, seed=0)
    features = pgdm.PGDMFeatures(env.base_env, cfg.algo)
    td = env.reset()
    td.set(("task", "step"), torch.full_like(td["task", "step"], 10))
    ref = env.base_env.goal_window(td, td["task", "step"], False)[:, 0]  # the knob's reference angle at step 10
    td.set(("object", "q"), ref + torch.tensor([[0.0], [0.3], [-0.3], [math.pi]]))
    reward, far = features.reward_and_far(td)
    expected = [10.0, *(10 * math.exp(-50 * 0.1 * e / math.pi) for e in (0.3, 0.3, math.pi))]
    torch.testing.assert_close(reward.flatten(), torch.tensor(expected), rtol=1e-5, atol=1e-5)
    assert not far.any()  # a hinged part never ends the episode early


def test_a_sliding_part_is_tracked_in_metres_and_a_tools_base_is_tracked(tmp_path):
    """The pump's head slides: its error is a position (m), not an angle, so 5 mm off its reference costs
    10 (1 - e^-0.25), not the 0.1 / pi-weighted sliver an angle would. A free base's shift (m) and tilt (rad)
    against where it stood are the tool's pose error too (the stapler: a hinge on a free base)."""
    cfg = _cfg(tmp_path, "task=pump_dispenser")
    env = make_env(cfg.task, num_envs=2, differentiable=False, seed=0)
    features = pgdm.PGDMFeatures(env.base_env, cfg.algo)
    assert features.slides
    td = env.reset()
    ref = env.base_env.goal_window(td, td["task", "step"], False)[:, 0]
    q = td["object", "q"].clone()
    part = features.part
    q[:, part] = ref[:, 0] + torch.tensor([0.0, 0.005])
    td.set(("object", "q"), q)
    td.set(("object", "base_pose"), env.base_env._base0.expand(2, 7).clone())  # the base where it stood
    reward, _ = features.reward_and_far(td)
    torch.testing.assert_close(reward.flatten(), torch.tensor([10.0, 10 * math.exp(-50 * 0.005)]),
                               rtol=1e-4, atol=1e-4)

    cfg = _cfg(tmp_path, "task=stapler")
    env = make_env(cfg.task, num_envs=3, differentiable=False, seed=0)
    features = pgdm.PGDMFeatures(env.base_env, cfg.algo)
    assert not features.slides
    td = env.reset()
    ref = env.base_env.goal_window(td, td["task", "step"], False)[:, 0]
    q = td["object", "q"].clone()
    q[:, features.part] = ref[:, 0]
    td.set(("object", "q"), q)
    base = env.base_env._per_world("_base0", td).expand(3, 7).clone()
    base[1, 0] += 0.01  # shifted 1 cm
    half = 0.5 * 0.3  # tilted 0.3 rad about x: wxyz quaternion (cos, sin, 0, 0) composed with the start
    tilt = torch.tensor([math.cos(half), math.sin(half), 0.0, 0.0], dtype=base.dtype)
    base[2, 3:] = quat_multiply(tilt, base[2, 3:])
    td.set(("object", "base_pose"), base)
    reward, _ = features.reward_and_far(td)
    expected = [10.0, 10 * math.exp(-50 * 0.01), 10 * math.exp(-50 * 0.1 * 0.3 / math.pi)]
    torch.testing.assert_close(reward.flatten(), torch.tensor(expected), rtol=1e-4, atol=1e-4)


def test_free_object_reward_and_early_termination(tmp_path):
    cfg = _cfg(tmp_path, "task=repose_cube")
    env = make_env(cfg.task, num_envs=3, differentiable=False, seed=0)
    features = pgdm.PGDMFeatures(env.base_env, cfg.algo)
    td = env.reset()
    ref = env.base_env.goal_window(td, td["task", "step"], False)[:, 0]  # [3, 7]: pos + quat at step 0
    pose = ref.clone()
    pose[1, 0] += 0.03  # 3 cm off, same orientation
    pose[2, 2] += 0.3  # 30 cm above: lifted but the reference is not, and too far
    td.set(("object", "pose"), pose)
    reward, far = features.reward_and_far(td)
    torch.testing.assert_close(reward.flatten(), torch.tensor([10.0, 10 * math.exp(-1.5), 10 * math.exp(-15.0)]),
                               rtol=1e-4, atol=1e-5)
    assert far.flatten().tolist() == [False, False, True]


def test_observation_width_targets_and_time_features(tmp_path):
    # the layout, unmirrored (tests/test_mirror.py checks the reflection of the mirrored task's worlds)
    cfg = _cfg(tmp_path, "task.max_episode_steps=100", "task.mirror=false")
    plain = make_env(cfg.task, differentiable=False, seed=0)
    base = plain.base_env
    td = plain.reset()
    module = pgdm.policy_observation(cfg.algo, plain)
    # screw_claw: 2 x 4 hand joints + 2 fingertips x 3 + knob angle and rate + 3 targets + 2 x 4 time features
    assert module.width == 2 * 4 + 6 + 2 + 3 + 8 == 27
    obs = module(td.clone())["observation"]
    assert obs.shape == (4, 27)
    torch.testing.assert_close(obs[:, -8:-4], torch.zeros(4, 4))  # step 0: sin 0, cos 1
    torch.testing.assert_close(obs[:, -4:], torch.ones(4, 4))
    steps = torch.tensor([[50], [50], [0], [99]])
    td.set(("task", "step"), steps)
    obs = module(td.clone())["observation"]
    tau = steps.float() / 100
    freqs = torch.tensor([1.0, 4.0, 6.0, 8.0])
    torch.testing.assert_close(obs[:, -8:-4], torch.sin(tau * freqs))
    torch.testing.assert_close(obs[:, -4:], torch.cos(tau * freqs))
    torch.testing.assert_close(obs[0, -8:-4], torch.sin(0.5 * freqs))  # mid-episode
    targets = base.goal_window(td, steps + torch.tensor([1, 5, 10]), False).flatten(1)
    torch.testing.assert_close(obs[:, -11:-8], targets)
    torch.testing.assert_close(obs[:, 14:15], td["object", "q"])


def test_training_env_and_deployable_policy_see_the_same_observation(tmp_path):
    cfg = _cfg(tmp_path)
    env = make_env(cfg.task, differentiable=False, seed=3)
    env.append_transform(pgdm.PGDMObservation(cfg.algo))
    plain = make_env(cfg.task, differentiable=False, seed=3)
    module = pgdm.policy_observation(cfg.algo, make_env(cfg.task, num_envs=1, differentiable=False, seed=0))
    td, td_plain = env.reset(), plain.reset()
    action = torch.rand(4, env.action_spec.shape[-1], generator=torch.Generator().manual_seed(0)) * 2 - 1
    for _ in range(3):
        td = env.step(td.set("action", action))["next"]
        td_plain = plain.step(td_plain.set("action", action))["next"]
    torch.testing.assert_close(module(td_plain.clone())["observation"], td["observation"])
    assert td["observation"].shape[-1] == 27 and td["pgdm_reward"].shape == (4, 1)


@pytest.mark.parametrize("task", list_tasks())
def test_every_task_gets_an_observation_of_the_width_pgdm_declares(tmp_path, task):
    """On every registered task (the tools' free bases included: the part's angle and rate and the base's pose),
    the training env's transform writes an observation of the width its spec declares (what the normaliser and
    the networks are built for), and the deployable policy's module rebuilds the same one on the plain env."""
    cfg = _cfg(tmp_path, f"task={task}", "task.num_envs=2")
    env = make_env(cfg.task, differentiable=False, seed=0)
    env.append_transform(pgdm.PGDMObservation(cfg.algo))
    plain = make_env(cfg.task, differentiable=False, seed=0)
    td, td_plain = env.reset(), plain.reset()
    action = torch.zeros(2, env.action_spec.shape[-1])
    td, td_plain = env.step(td.set("action", action))["next"], plain.step(td_plain.set("action", action))["next"]
    width = env.observation_spec["observation"].shape[-1]
    assert td["observation"].shape == (2, width) and torch.isfinite(td["observation"]).all()
    module = pgdm.policy_observation(cfg.algo, plain)
    torch.testing.assert_close(module(td_plain.clone())["observation"], td["observation"])
    if ("object", "base_pose") in td_plain.keys(True, True):
        assert ("object", "base_pose") in module.in_keys


@pytest.mark.parametrize("action", ["vi", "position"])
def test_warm_start_mean_action_targets_the_start_pose(tmp_path, action):
    cfg = _cfg(tmp_path, f"task.action={action}", "task.joint_noise=0.0")
    env, _, actor = pgdm.build(cfg)[:3]
    td = env.reset()
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        out = actor(td.clone())
    base = env.base_env
    nu = base.sim.nu
    start = td["hand", "q"]  # the grasp (no joint noise): (0.5, -0.42, -0.5, 0.42)
    torch.testing.assert_close(base.actions.targets(out["action"][:, :nu]), start, atol=0.02, rtol=0)
    if action == "vi":  # the stiffness half at its default (0: the geometric mean of the range)
        torch.testing.assert_close(out["action"][:, nu:], torch.zeros(4, nu), atol=0.02, rtol=0)
    torch.testing.assert_close(out["scale"].log(), torch.full_like(out["scale"], -1.6))


def test_warm_start_off_and_torque_leave_the_mean_at_zero(tmp_path):
    for overrides in (["algo.warm_start=false"], ["task.action=torque"]):
        env, _, actor = pgdm.build(_cfg(tmp_path, *overrides))[:3]
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            action = actor(env.reset())["action"]
        assert action.abs().max() < 0.05, overrides


def test_tiny_run_writes_metrics_and_dexmots_eval_reloads_it(tmp_path):
    result = train(_cfg(tmp_path))
    run = tmp_path / "run"
    assert result["algo"] == "pgdm" and result["iterations"] == 2 and result["episodes"] == 2
    metrics = json.loads((run / "metrics.json").read_text())
    assert {"success_rate", "mean_final_error", "success_by_friction", "env_steps", "budget"} <= set(metrics)
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert all({"pgdm_reward", "reward", "episode_success"} <= set(r) for r in rows)

    policy, data = policy_from_checkpoint(run)
    assert data["algo"] == "pgdm"
    for key, value in policy.state_dict().items():
        torch.testing.assert_close(value, data["modules"]["policy"][key])
    # the plain task env as evaluate_policy builds it: the same episodes as the final evaluation
    ev = evaluate_policy(policy, data["config"]["task"], episodes=2, seed=data["config"]["eval"]["seed"])
    assert ev["mean_final_error"] == pytest.approx(metrics["mean_final_error"], rel=1e-5)
    eval_main([str(run), "--episodes", "2"])
    assert json.loads((run / "eval.json").read_text())["episodes"] == 2


def test_the_loss_is_torchrls_clip_ppo(tmp_path):
    from torchrl.objectives import ClipPPOLoss

    assert type(pgdm.build(_cfg(tmp_path))[5]) is ClipPPOLoss


@pytest.mark.parametrize("override, field", [("algo.target_offsets=[]", "algo.target_offsets"),
                                             ("algo.time_frequencies=[a]", "algo.time_frequencies"),
                                             ("algo.termination_distance=-1", "algo.termination_distance")])
def test_bad_pgdm_fields_name_the_field(tmp_path, override, field):
    with pytest.raises(ValueError, match=field):
        train(_cfg(tmp_path, override))


@pytest.mark.slow  # two training runs
def test_a_resumed_run_trains_its_checkpoints_pgdm(tmp_path):
    run = tmp_path / "run"
    assert train(_cfg(tmp_path, "stop_after=1", "algo.target_offsets=[1,2]")) == {}
    cli = [f"resume={run}", "progress=false"]  # the defaults name another method (ahac) and other offsets
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        result = train(compose("config", overrides=cli), cli)
    assert result["algo"] == "pgdm" and result["iterations"] == 2
    _, data = policy_from_checkpoint(run)
    assert list(data["config"]["algo"]["target_offsets"]) == [1, 2]
