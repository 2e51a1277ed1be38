"""Goal conditioning transforms, per-world references, reward terms and randomisation (screw_claw)."""

from __future__ import annotations

import math

import pytest
import torch
from tensordict.nn import TensorDictModule
from torchrl.envs.utils import check_env_specs

from dexmots_rl.envs import make_env
from dexmots_rl.trajectories import PoseWrenchTrajectory
from simutil import CLAW_CONTACT_Q

N, H = 3, 4


@pytest.mark.parametrize("goal, width, error_width", [("pose", 1, 1), ("pose_traj", H, H), ("pose_wrench", 2 * H, H)])
def test_goal_modes_have_documented_shapes_and_pass_spec_checks(goal, width, error_width):
    env = make_env("screw_claw", num_envs=N, goal=goal, goal_horizon=H, seed=0, action="torque", initial="open")
    check_env_specs(env, seed=0)
    td = env.reset()
    assert td["desired_goal"].shape == (N, width)
    assert td["goal_error"].shape == (N, error_width)
    assert td["observation"].shape == (N, 16 + width + error_width)
    assert td["task", "goal"].shape == (N, 1)  # the env's own goal is untouched


def test_pose_traj_goal_is_the_reference_window_from_the_step_counter():
    env = make_env("screw_claw", num_envs=N, goal="pose_wrench", goal_horizon=H, seed=1, action="torque", initial="open")
    base = env.base_env
    td = env.rollout(3)
    nxt = td["next"][:, -1]
    k = int(nxt["task", "step"][0])
    assert k == 3
    goal = nxt["task", "goal"]
    steps = k + torch.arange(1, H + 1)
    angles = goal * (steps / base.ramp_steps).clamp(max=1.0)
    got = nxt["desired_goal"].view(N, H, 2)
    torch.testing.assert_close(got[..., 0], angles)
    # nominal knob (MJCF damping 0.5, friction 0.5) turning at goal / (ramp_steps dt)
    speed = goal / (base.ramp_steps * base.sim.dt)
    torque = 0.5 * speed + 0.5 * torch.tanh(speed / 0.05)
    torch.testing.assert_close(got[..., 1], torque.expand(N, H))
    # the goal-relative input: reference angles minus the knob's angle after the step
    torch.testing.assert_close(nxt["goal_error"], angles - nxt["object", "q"])


def test_episode_reference_torque_uses_each_worlds_drawn_knob():
    env = make_env("screw_claw", num_envs=N, goal="pose_wrench", goal_horizon=H, seed=1, reference_torque="episode", action="torque", initial="open")
    base = env.base_env
    nxt = env.rollout(2)["next"][:, -1]
    damping = nxt["sim", "params", "joint_damping"].squeeze(-1)
    friction = nxt["sim", "params", "joint_friction"].squeeze(-1)
    assert damping.unique().numel() == N and friction.unique().numel() == N  # drawn per world
    speed = nxt["task", "goal"] / (base.ramp_steps * base.sim.dt)
    torque = damping[:, None] * speed + friction[:, None] * torch.tanh(speed / 0.05)
    torch.testing.assert_close(nxt["desired_goal"].view(N, H, 2)[..., 1], torque.expand(N, H))
    with pytest.raises(ValueError, match="reference_torque"):
        make_env("screw_claw", num_envs=1, reference_torque="measured", action="torque", goal="pose", initial="open")


def test_free_body_goal_error_is_position_difference_and_relative_rotation():
    from dexmots_rl.envs.transforms import _coordinate_error

    half = torch.tensor(0.3)
    goal = torch.tensor([[1.0, 2.0, 3.0, torch.cos(half), 0.0, 0.0, torch.sin(half)]])
    achieved = torch.tensor([[0.5, 2.0, 2.0, 1.0, 0.0, 0.0, 0.0]])
    error = _coordinate_error(goal, achieved)
    torch.testing.assert_close(error[0, :3], torch.tensor([0.5, 0.0, 1.0]))
    torch.testing.assert_close(error[0, 3:], goal[0, 3:])  # from the identity, the relative rotation is the goal's
    same = _coordinate_error(goal, goal)
    torch.testing.assert_close(same[0], torch.tensor([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]))


def test_reward_terms_match_hand_computed_values():
    env = make_env("screw_claw", num_envs=N, seed=2, reward={"lambda_pose": 1.0, "lambda_wrench": 0.5,
                                                             "lambda_act": 0.1, "lambda_f": 0.2}, action="torque", goal="pose", initial="open")
    td = env.reset()
    td["action"] = torch.tensor([[0.5, -0.5, 0.2, 0.1]]).expand(N, 4)
    nxt = env.step(td)["next"]
    base = env.base_env
    ref_angle = nxt["task", "goal"] * (1 / base.ramp_steps)
    pose = torch.exp(-(nxt["object", "q"] - ref_angle).abs() / base.pose_scale)
    torch.testing.assert_close(nxt["reward_terms", "pose"], pose)
    weights = torch.tensor([1.0, 2.0, 1.0, 2.0])  # distal joints weigh double
    action = -(td["action"] * weights).norm(dim=-1, keepdim=True)
    torch.testing.assert_close(nxt["reward_terms", "action"], action)
    tips = nxt["fingertips", "pos"] - nxt["object", "pose"][:, None, :3]
    torch.testing.assert_close(nxt["reward_terms", "fingertip"], torch.exp(-tips.norm(dim=-1)).sum(-1, keepdim=True))
    terms = nxt["reward_terms"]
    total = terms["pose"] + 0.5 * terms["wrench"] + 0.1 * terms["action"] + 0.2 * terms["fingertip"]
    torch.testing.assert_close(nxt["reward"], total)


def test_pose_wrench_rollout_keeps_gradients_to_the_policy():
    env = make_env("screw_claw", num_envs=N, goal="pose_wrench", goal_horizon=H, seed=3, action="torque", initial="open")
    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Linear(env.observation_spec["observation"].shape[-1], 4), torch.nn.Tanh())
    policy = TensorDictModule(net, in_keys=["observation"], out_keys=["action"])
    td = env.reset()
    td["sim", "joint_q"] = torch.tensor(CLAW_CONTACT_Q, dtype=torch.float32).expand(N, 5).clone()
    td = env.transform(td)
    rollout = env.rollout(4, policy, tensordict=td, auto_reset=False, break_when_any_done=False)
    (-rollout["next", "reward"].mean()).backward()
    grads = [p.grad for p in net.parameters()]
    assert all(g is not None and torch.isfinite(g).all() and g.abs().max() > 0 for g in grads)


def _plan(final: float, steps: int = 5) -> PoseWrenchTrajectory:
    angle = torch.linspace(0.0, final, steps).unsqueeze(-1)
    quat = torch.cat([torch.cos(angle / 2), torch.zeros(steps, 2), torch.sin(angle / 2)], -1)
    wrench = torch.zeros(steps, 6)
    wrench[:, 5] = 1.0 + final
    return PoseWrenchTrajectory(torch.zeros(steps, 3), quat, wrench, dt=1 / 60, joint_q=angle,
                                joint_torque=wrench[:, 5:])


def test_reference_bank_picks_a_plan_per_world():
    plans = [_plan(0.8), _plan(-1.2, steps=3)]
    env = make_env("screw_claw", num_envs=8, goal="pose_wrench", goal_horizon=2, seed=4, references=plans, action="torque", initial="open")
    td = env.reset()
    index = td["task", "ref_index"].squeeze(-1)
    assert set(index.tolist()) == {0, 1}
    finals = torch.tensor([0.8, -1.2])[index]
    torch.testing.assert_close(td["task", "goal"].squeeze(-1), finals)
    window = td["desired_goal"].view(8, 2, 2)
    # steps 1 and 2 of each world's plan (the short plan holds its last row)
    expected = torch.stack([torch.tensor([[0.2, 0.4], [-0.6, -1.2]])[i] for i in index.tolist()])
    torch.testing.assert_close(window[..., 0], expected)
    torch.testing.assert_close(window[..., 1], (1.0 + finals).unsqueeze(-1).expand(8, 2))


def test_randomisation_is_seeded_and_within_ranges():
    kw = dict(num_envs=16, damping_range=(0.1, 0.2), friction_range=(0.3, 0.9), differentiable=False)
    a = make_env("screw_claw", seed=5, **kw).reset()["sim", "params"]
    b = make_env("screw_claw", seed=5, **kw).reset()["sim", "params"]
    c = make_env("screw_claw", seed=6, **kw).reset()["sim", "params"]
    assert (a == b).all() and not (a == c).all()
    damping, friction = a["joint_damping"], a["joint_friction"]
    assert ((damping >= 0.1) & (damping <= 0.2)).all() and ((friction >= 0.3) & (friction <= 0.9)).all()
    assert friction.std() > 0.05


@pytest.mark.parametrize("kwargs, field", [
    (dict(goal="pose_pose"), "goal"),
    (dict(goal_horizon=0), "goal_horizon"),
    (dict(obs="depth"), "obs"),
    (dict(friction_range=(1.0, 0.5)), "friction_range"),
    (dict(reward={"lambda_pose": -1.0}), "lambda_pose"),
    (dict(reward={"lambda_typo": 1.0}), "lambda_typo"),
    (dict(references="/no/such/plan.pt"), "plan.pt"),
])
def test_bad_goal_options_name_the_field(kwargs, field):
    with pytest.raises((ValueError, TypeError, FileNotFoundError), match=field):
        make_env("screw_claw", num_envs=1, seed=0, **kwargs)


def test_goal_magnitudes_unchanged_by_transforms():
    td = make_env("screw_claw", num_envs=32, seed=7, goal="pose_traj", goal_horizon=2, action="torque", initial="open").reset()
    goal = td["task", "goal"].abs()
    assert ((goal >= math.pi / 4 - 1e-6) & (goal <= math.pi / 2 + 1e-6)).all()
