"""The torchrl env: specs, differentiable rollouts, seeding, partial resets, truncation, success, actions.

All envs here are the claw scene in float32 (one kernel specialisation); they are cheap to build once
its kernels are loaded, so tests that need a particular seed or option build their own.
"""

from __future__ import annotations

import math

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torchrl.envs.utils import check_env_specs, step_mdp

from dexmots_rl.envs import make_env
from simutil import CLAW_CONTACT_Q

N = 3


@pytest.fixture(scope="module")
def env():
    return make_env("screw_claw", num_envs=N, device="cpu", differentiable=True, seed=0, action="torque", goal="pose", initial="open")


def _policy(obs_dim: int, act_dim: int, seed: int = 0) -> TensorDictModule:
    torch.manual_seed(seed)
    net = torch.nn.Sequential(torch.nn.Linear(obs_dim, act_dim), torch.nn.Tanh())
    return TensorDictModule(net, in_keys=["observation"], out_keys=["action"])


def _run(env, actions, td=None):
    """Step ``env`` through ``actions`` [T, N, nu] from ``td`` (default: a reset); returns the T "next" tds."""
    td = env.reset() if td is None else td
    outs = []
    for a in actions:
        td = td.clone(False)
        td.set("action", a)
        td = env.step(td)
        outs.append(td["next"])
        td = step_mdp(td)
    return outs


@pytest.mark.parametrize("differentiable", [True, False])
def test_check_env_specs(differentiable):
    env = make_env("screw_claw", num_envs=N, differentiable=differentiable, seed=1, action="torque", goal="pose", initial="open")
    check_env_specs(env, seed=1)
    raw = make_env("screw_claw", num_envs=N, differentiable=differentiable, seed=1, raw=True, action="torque", goal="pose", initial="open")
    check_env_specs(raw, seed=1)


def test_observation_and_state_keys(env):
    td = env.reset()
    assert td["observation"].shape == (N, 18)
    assert td["sim", "joint_q"].shape == (N, 5) and td["sim", "joint_qd"].shape == (N, 5)
    assert set(td["sim", "params"].keys()) == {"joint_damping", "joint_friction", "joint_stiffness", "joint_rest"}
    assert td["sim", "params", "joint_friction"].shape == (N, 1)
    assert td["fingertips", "pos"].shape == (N, 2, 3)
    assert td["object", "pose"].shape == (N, 7)
    torch.testing.assert_close(td["hand", "q"], td["sim", "joint_q"][:, :4], rtol=0, atol=0)
    torch.testing.assert_close(td["object", "q"], td["sim", "joint_q"][:, 4:], rtol=0, atol=0)
    torch.testing.assert_close(td["achieved_goal"], td["object", "q"], rtol=0, atol=0)
    assert (td["task", "step"] == 0).all()
    goal = td["desired_goal"].abs()
    assert ((goal >= math.pi / 4 - 1e-6) & (goal <= math.pi / 2 + 1e-6)).all()


def test_gradients_flow_through_rollout_to_policy(env):
    """A torch loss on the rewards of a differentiable rollout reaches the policy parameters.

    The rollout starts with the fingers pressed on the knob (the env is functional: the state is whatever
    the input TensorDict says), so the knob angle - and hence the reward - depends on the actions."""
    policy = _policy(env.observation_spec["observation"].shape[-1], 4)
    td = env.reset()
    td["sim", "joint_q"] = torch.tensor(CLAW_CONTACT_Q, dtype=torch.float32).expand(N, 5).clone()
    td = env.transform(td)  # rebuild "observation" from the edited state
    rollout = env.rollout(5, policy, tensordict=td, auto_reset=False, break_when_any_done=False)
    reward = rollout["next", "reward"]
    assert reward.shape == (N, 5, 1) and reward.requires_grad
    loss = -reward.mean()
    loss.backward()
    for name, p in policy.named_parameters():
        assert p.grad is not None, name
        assert torch.isfinite(p.grad).all(), name
        assert float(p.grad.abs().max()) > 0, name


def test_non_differentiable_env_builds_no_graph():
    env = make_env("screw_claw", num_envs=N, differentiable=False, seed=0, action="torque", goal="pose", initial="open")
    policy = _policy(env.observation_spec["observation"].shape[-1], 4)
    rollout = env.rollout(3, policy, auto_reset=True, break_when_any_done=False)
    assert rollout["action"].requires_grad  # the policy output itself is in a graph ...
    for key in [("next", "reward"), ("next", "sim", "joint_q"), ("next", "observation")]:
        assert not rollout[key].requires_grad, key  # ... but nothing the env returns is


def test_same_seed_same_rollout():
    actions = 2 * torch.rand(6, N, 4, generator=torch.Generator().manual_seed(0)) - 1
    a = make_env("screw_claw", num_envs=N, differentiable=False, seed=3, action="torque", goal="pose", initial="open")
    b = make_env("screw_claw", num_envs=N, differentiable=False, seed=3, action="torque", goal="pose", initial="open")
    ra, rb = _run(a, actions), _run(b, actions)
    for ta, tb in zip(ra, rb):
        for key in ["reward", "observation", ("sim", "joint_q"), ("sim", "params", "joint_friction"), "desired_goal"]:
            assert torch.equal(ta[key], tb[key]), key
    # the actions did something (so identical outputs are not trivially identical)
    assert not torch.equal(ra[0]["sim", "joint_q"], ra[-1]["sim", "joint_q"])


def test_different_seed_different_goals():
    a = make_env("screw_claw", num_envs=N, differentiable=False, seed=3, action="torque", goal="pose", initial="open").reset()
    b = make_env("screw_claw", num_envs=N, differentiable=False, seed=4, action="torque", goal="pose", initial="open").reset()
    assert not torch.equal(a["desired_goal"], b["desired_goal"])
    assert not torch.equal(a["sim", "params", "joint_friction"], b["sim", "params", "joint_friction"])
    assert not torch.equal(a["sim", "joint_q"], b["sim", "joint_q"])


def test_partial_reset_keeps_other_worlds():
    n = 4
    env = make_env("screw_claw", num_envs=n, differentiable=False, seed=5, action="torque", goal="pose", initial="open")
    actions = 2 * torch.rand(3, n, 4, generator=torch.Generator().manual_seed(1)) - 1
    td = _run(env, actions)[-1]
    td = step_mdp(TensorDict({"next": td}, batch_size=[n]))  # the state after 3 steps, as a root td
    assert (td["task", "step"] == 3).all()
    before = td.clone()
    mask = torch.tensor([[False], [True], [False], [True]])
    td.set("_reset", mask)
    out = env.reset(td)
    keep, reset = [0, 2], [1, 3]
    keys = ["observation", ("sim", "joint_q"), ("sim", "joint_qd"), ("sim", "params", "joint_friction"), ("hand", "q"),
            ("object", "q"), ("fingertips", "pos"), "desired_goal", ("task", "step"), ("info", "sim_failures")]
    for key in keys:
        assert torch.equal(out[key][keep], before[key][keep]), key
    assert (out["task", "step"][reset] == 0).all()
    assert (out["sim", "joint_qd"][reset] == 0).all()
    assert not torch.equal(out["sim", "joint_q"][reset], before["sim", "joint_q"][reset])
    assert not torch.equal(out["desired_goal"][reset], before["desired_goal"][reset])
    assert not out["done"].any()


def test_truncation_after_max_episode_steps():
    env = make_env("screw_claw", num_envs=N, differentiable=False, seed=2, max_episode_steps=5, action="torque", goal="pose", initial="open")
    rollout = env.rollout(7, tensordict=env.reset(), auto_reset=False, break_when_any_done=False)
    steps = rollout["next", "task", "step"][..., 0]
    # torchrl resets the truncated worlds between steps 5 and 6 (a partial reset through "_reset")
    assert (steps == torch.tensor([1, 2, 3, 4, 5, 1, 2])).all(), steps
    truncated = rollout["next", "truncated"][..., 0]
    expected = torch.zeros(N, 7, dtype=torch.bool)
    expected[:, 4] = True
    assert torch.equal(truncated, expected)
    assert torch.equal(rollout["next", "done"], rollout["next", "truncated"] | rollout["next", "terminated"])
    assert not rollout["next", "terminated"].any()
    # with the default break_when_any_done, the rollout stops at the first truncation
    assert env.rollout(10).shape == (N, 5)


def test_success_flag_matches_goal_distance():
    env = make_env("screw_claw", num_envs=4, differentiable=False, seed=6, action="torque", goal="pose", initial="open")
    td = env.reset()
    # goals near and far from the knob's current angle (0): the env reads the goal from the TensorDict
    td["task", "goal"] = torch.tensor([[0.0], [0.09], [-0.3], [1.0]])
    td["action"] = torch.zeros(4, 4)
    nxt = env.step(td)["next"]
    expected = (nxt["object", "q"] - nxt["task", "goal"]).abs() < 0.1
    assert torch.equal(nxt["success"], expected)
    assert nxt["success"].any() and not nxt["success"].all()
    assert nxt["success"].squeeze(-1).tolist()[::3] == [True, False]
    # and on an ordinary random rollout
    rollout = env.rollout(4)
    expected = (rollout["next", "object", "q"] - rollout["next", "desired_goal"]).abs() < 0.1
    assert torch.equal(rollout["next", "success"], expected)


def test_position_actions_track_targets():
    env = make_env("screw_claw", num_envs=2, differentiable=False, seed=7, action="position", goal="pose", initial="open")
    base = env.base_env
    lower, upper = base.actions.lower, base.actions.upper
    # open-hand targets away from the knob, different per world
    targets = torch.tensor([[1.0, -0.3, -1.0, 0.3], [1.3, -0.7, -0.9, 0.1]])
    action = 2 * (targets - lower) / (upper - lower) - 1
    assert (action.abs() <= 1).all()
    td = env.reset()
    err0 = (td["hand", "q"] - targets).abs()
    for out in _run(env, action.expand(30, 2, 4), td):
        pass
    err = (out["hand", "q"] - targets).abs()
    assert (err < 0.5 * err0 + 1e-3).all()
    assert float(err.max()) < 0.02
    assert float(out["hand", "qd"].abs().max()) < 0.1  # settled (critically damped PD)


def test_variable_impedance_env_specs_and_gradients():
    from torchrl.envs.utils import check_env_specs

    from dexmots_rl.envs import make_env

    env = make_env("screw_claw", num_envs=2, seed=0, action="vi", goal="pose", initial="open")
    assert env.action_spec.shape[-1] == 8  # 4 joint targets + 4 stiffnesses
    check_env_specs(env)
    td = env.reset()
    action = torch.zeros(2, 8, requires_grad=True)
    out = env.step(td.set("action", action))
    (grad,) = torch.autograd.grad(out["next", "hand", "q"].sum(), action)
    assert torch.isfinite(grad).all() and grad[:, :4].abs().sum() > 0 and grad[:, 4:].abs().sum() > 0


def test_gradient_counts_are_published_per_world():
    """The backward pass's per-world counts (a capped adjoint, a non-finite gradient set to zero) ride in every
    step's TensorDict under ("info", ...) keys and in ``gradient_counts()``: consumers read keys, not the simulator."""
    env = make_env("screw_claw", num_envs=N, differentiable=True, seed=0, raw=True, adjoint_clip=10.0)
    td = env.reset()
    for key in ("clipped_adjoints", "nonfinite_gradients"):
        assert td["info", key].shape == (N, 1) and td["info", key].dtype == torch.int64 and not td["info", key].any()
    action = torch.zeros(N, env.action_spec.shape[-1], requires_grad=True)
    td.set("action", action)
    out = env.step(td)["next"]
    upstream = torch.tensor([[1.0], [float("inf")], [1.0]])  # world 1's adjoint overflows in the simulator
    with pytest.warns(RuntimeWarning, match="non-finite gradient"):
        (out["sim", "joint_q"] * upstream).sum().backward()
    assert (action.grad[1] == 0).all() and action.grad[[0, 2]].abs().max() > 0
    counts = env.gradient_counts()
    assert counts["info", "nonfinite_gradients"].squeeze(-1).tolist() == [0, 1, 0]
    nxt = out.clone().detach()
    nxt.set("action", torch.zeros(N, env.action_spec.shape[-1]))
    assert env.step(nxt)["next", "info", "nonfinite_gradients"].squeeze(-1).tolist() == [0, 1, 0]
