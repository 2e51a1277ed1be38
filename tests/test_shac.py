"""SHACLoss: keys, gradient isolation, target-critic updates, TD(lambda) targets, the SHAC return
accounting across episode ends, and a short training run on the pure-torch toy env (no warp)."""

from __future__ import annotations

import doctest
import warnings

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import HardUpdate, SoftUpdate
from torchrl.objectives.utils import ValueEstimators
from torchrl.objectives.value import TDLambdaEstimator

import dexmots_rl.objectives.shac as shac_module
from dexmots_rl.objectives import SHACLoss, next_rollout_start
from toy_envs import PointMassEnv

GAMMA, LMBDA = 0.9, 0.8


@pytest.fixture(autouse=True)
def _quiet_target_warnings():
    # torchrl warns when target params exist without an updater, and for SoftUpdate eps < 0.5 (DiffRL's
    # alpha = 0.2); both are expected in these tests
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        yield


def make_actor(obs_dim: int = 4, act_dim: int = 2, env=None) -> ProbabilisticActor:
    net = nn.Sequential(MLP(in_features=obs_dim, out_features=2 * act_dim, num_cells=[32], activation_class=nn.Tanh),
                        NormalParamExtractor())
    return ProbabilisticActor(TensorDictModule(net, ["observation"], ["loc", "scale"]), in_keys=["loc", "scale"],
                              distribution_class=TanhNormal, spec=None if env is None else env.action_spec)


def make_critic(obs_dim: int = 4) -> ValueOperator:
    return ValueOperator(MLP(in_features=obs_dim, out_features=1, num_cells=[32], activation_class=nn.Tanh),
                         in_keys=["observation"])


def make_loss(**kwargs) -> SHACLoss:
    return SHACLoss(actor_network=make_actor(), critic_network=make_critic(), gamma=GAMMA, lmbda=LMBDA, **kwargs)


def differentiable_rollout(loss: SHACLoss, env: PointMassEnv, horizon: int, td=None):
    with set_exploration_type(ExplorationType.RANDOM):
        return env.rollout(horizon, loss.actor_network, auto_reset=False, break_when_any_done=False,
                           tensordict=env.reset() if td is None else td)


def tiny_rollout(requires_grad: bool = True) -> TensorDict:
    """3 worlds x 6 steps: world 0 runs through, world 1 terminates at t=2, world 2 is truncated at t=3
    (its ("next", obs) there is the pre-reset observation) and terminates at the last step."""
    torch.manual_seed(3)
    n, t = 3, 6
    done = torch.zeros(n, t, 1, dtype=torch.bool)
    terminated = torch.zeros(n, t, 1, dtype=torch.bool)
    terminated[1, 2] = True
    done[1, 2] = True
    done[2, 3] = True  # truncation: done but not terminated
    terminated[2, 5] = done[2, 5] = True
    return TensorDict(
        {
            "observation": torch.randn(n, t, 4),
            "action": torch.randn(n, t, 2),
            "next": {
                "observation": torch.randn(n, t, 4, requires_grad=requires_grad),
                "reward": torch.randn(n, t, 1, requires_grad=requires_grad),
                "other_reward": torch.randn(n, t, 1),
                "done": done,
                "terminated": terminated,
                "truncated": done & ~terminated,
            },
        },
        batch_size=[n, t],
        names=[None, "time"],
    )


def handwritten_shac(reward, next_value, done, terminated, gamma):
    """DiffRL shac.py's loop: accumulate gamma^k r, close a segment at done steps and at the horizon end."""
    n, horizon = reward.shape[:2]
    loss = reward.new_zeros(())
    rew_acc = reward.new_zeros(n)
    disc = torch.ones(n)
    for t in range(horizon):
        rew_acc = rew_acc + disc * reward[:, t, 0]
        v = torch.where(terminated[:, t, 0], torch.zeros(n), next_value[:, t, 0])
        ends = done[:, t, 0] if t < horizon - 1 else torch.ones(n, dtype=torch.bool)
        for w in range(n):
            if ends[w]:
                loss = loss - (rew_acc[w] + gamma * disc[w] * v[w])
        disc = torch.where(done[:, t, 0], torch.ones(n), disc * gamma)
        rew_acc = torch.where(done[:, t, 0], torch.zeros(n), rew_acc)
    return loss / (n * horizon)


def handwritten_td_lambda(reward, next_value, done, terminated, gamma, lmbda):
    """G_t = r_t + gamma (1 - term_t) [(1 - lambda) V'(s'_t) + lambda G_{t+1}], cut at done steps."""
    n, horizon = reward.shape[:2]
    out = torch.zeros(n, horizon, 1)
    for w in range(n):
        g_next = None
        for t in reversed(range(horizon)):
            r, v = reward[w, t, 0], next_value[w, t, 0] * (~terminated[w, t, 0])
            if t == horizon - 1 or done[w, t, 0]:
                g = r + gamma * v
            else:
                g = r + gamma * ((1 - lmbda) * v + lmbda * g_next * (~terminated[w, t, 0]))
            out[w, t, 0] = g
            g_next = g
    return out


def target_value(loss: SHACLoss, obs: torch.Tensor) -> torch.Tensor:
    with loss.target_critic_network_params.to_module(loss.critic_network):
        return loss.critic_network(TensorDict({"observation": obs}, obs.shape[:-1]))["state_value"]


# ------------------------------------------------------------------------------------------- keys
def test_default_keys_and_estimator():
    loss = make_loss()
    assert loss.tensor_keys.reward == "reward" and loss.tensor_keys.value == "state_value"
    assert SHACLoss.default_keys().value_target == "value_target"
    assert isinstance(loss.value_estimator, TDLambdaEstimator)
    assert float(loss.value_estimator.gamma) == pytest.approx(GAMMA)
    assert float(loss.value_estimator.lmbda) == pytest.approx(LMBDA)
    assert ("next", "reward") in loss.in_keys and loss.out_keys == ["loss_actor", "loss_critic"]


def test_set_keys_changes_reward_read():
    td = tiny_rollout(requires_grad=False)
    loss = make_loss()
    base_actor, base_targets = loss.actor_loss(td), loss.critic_targets(td)["value_target"]
    loss.set_keys(reward="other_reward")
    assert loss.value_estimator.tensor_keys.reward == "other_reward"
    other_actor, other_targets = loss.actor_loss(td), loss.critic_targets(td)["value_target"]
    assert not torch.allclose(base_actor, other_actor)
    assert not torch.allclose(base_targets, other_targets)
    nv = target_value(loss, td["next", "observation"])
    expected = handwritten_shac(td["next", "other_reward"], nv, td["next", "done"], td["next", "terminated"], GAMMA)
    torch.testing.assert_close(other_actor, expected)
    loss.set_keys(reward=None)  # back to the default
    assert loss.tensor_keys.reward == "reward"
    with pytest.raises(ValueError):
        loss.set_keys(not_a_key="x")


def test_make_value_estimator_updates_discount_and_rejects_gae():
    loss = make_loss()
    loss.make_value_estimator(ValueEstimators.TDLambda, gamma=0.5, lmbda=0.3)
    assert float(loss.gamma) == pytest.approx(0.5) and float(loss.lmbda) == pytest.approx(0.3)
    assert float(loss.value_estimator.gamma) == pytest.approx(0.5)
    loss.make_value_estimator(ValueEstimators.TD0)
    td = tiny_rollout(requires_grad=False)
    nv = target_value(loss, td["next", "observation"]) * ~td["next", "terminated"]
    torch.testing.assert_close(loss.critic_targets(td)["value_target"], td["next", "reward"] + 0.5 * nv)
    with pytest.raises(NotImplementedError):
        loss.make_value_estimator(ValueEstimators.GAE)


# ----------------------------------------------------------------------------- the two losses
def test_actor_loss_matches_handwritten_shac_sum():
    td = tiny_rollout()
    loss = make_loss()
    got = loss.actor_loss(td)
    nv = target_value(loss, td["next", "observation"])
    expected = handwritten_shac(td["next", "reward"], nv, td["next", "done"], td["next", "terminated"], GAMMA)
    torch.testing.assert_close(got, expected)
    leaves = [td["next", "reward"], td["next", "observation"]]
    for g_got, g_exp in zip(torch.autograd.grad(got, leaves), torch.autograd.grad(expected, leaves)):
        torch.testing.assert_close(g_got, g_exp)
    # the terminated world gets no bootstrap, the truncated one bootstraps its pre-reset next observation
    g_obs = torch.autograd.grad(loss.actor_loss(td), td["next", "observation"])[0].abs().sum(-1)
    assert g_obs[1, 2] == 0 and g_obs[2, 5] == 0 and g_obs[2, 3] > 0 and g_obs[0, 5] > 0
    assert g_obs[0, :5].sum() == 0  # mid-segment next observations are not bootstrapped


def test_td_lambda_targets_match_recursion():
    td = tiny_rollout(requires_grad=False)
    loss = make_loss()
    data = loss.critic_targets(td)
    nv = target_value(loss, td["next", "observation"])
    expected = handwritten_td_lambda(td["next", "reward"], nv, td["next", "done"], td["next", "terminated"],
                                     GAMMA, LMBDA)
    torch.testing.assert_close(data["value_target"], expected)
    assert "value_target" not in td.keys()  # the input rollout is not modified
    assert not data["value_target"].requires_grad


def test_nonfinite_world_does_not_poison_the_batch():
    td = tiny_rollout()
    with torch.no_grad():
        td["next", "reward"][1, 1] = float("nan")
        td["next", "observation"][2, 3] = float("inf")
    loss = make_loss()
    out = loss(td)
    assert torch.isfinite(out["loss_actor"]) and torch.isfinite(out["loss_critic"])
    grads = torch.autograd.grad(out["loss_actor"], [td["next", "reward"], td["next", "observation"]])
    assert all(torch.isfinite(g).all() for g in grads)
    assert grads[0][1, 1] == 0 and grads[1][2, 3].abs().sum() == 0
    targets = loss.critic_targets(td)["value_target"]
    assert torch.isfinite(targets).all() and targets[1, 0] != 0  # the NaN did not spread back in time
    assert torch.isnan(td["next", "reward"][1, 1])  # the input rollout is left as it was


def test_forward_reuses_existing_targets_and_matches_parts():
    td = tiny_rollout()
    loss = make_loss()
    out = loss(td)
    assert set(out.keys()) == {"loss_actor", "loss_critic"}
    torch.testing.assert_close(out["loss_actor"], loss.actor_loss(td))
    data = loss.critic_targets(td)
    torch.testing.assert_close(out["loss_critic"], loss.critic_loss(data))
    data["value_target"] = torch.zeros_like(data["value_target"])
    torch.testing.assert_close(loss(data)["loss_critic"], loss.critic_loss(data))


def test_critic_loss_computes_missing_targets_like_torchrl_losses():
    # a rollout without TD(lambda) targets gets them computed, as torchrl's losses do (not a KeyError)
    td = tiny_rollout()
    loss = make_loss()
    expected = loss.critic_loss(loss.critic_targets(td))
    torch.testing.assert_close(loss.critic_loss(td), expected)
    assert "value_target" not in td.keys()  # computed on a detached copy, the input is left alone


# ---------------------------------------------------------------------------- gradient isolation
def _grad_norms(params):
    return [None if p.grad is None else float(p.grad.norm()) for p in params]


def test_actor_loss_gives_no_critic_gradients_and_critic_loss_no_actor_gradients():
    torch.manual_seed(0)
    env = PointMassEnv(num_envs=4, max_episode_steps=5)
    loss = make_loss()
    rollout = differentiable_rollout(loss, env, 8)
    actor_params = list(loss.actor_network_params.values(True, True))
    critic_params = list(loss.critic_network_params.values(True, True))
    target_params = list(loss.target_critic_network_params.values(True, True))
    assert not any(p.requires_grad for p in target_params)

    loss.actor_loss(rollout).backward(retain_graph=True)
    assert all(g is not None and g > 0 for g in _grad_norms(actor_params))
    assert all(g is None or g == 0 for g in _grad_norms(critic_params))

    loss.zero_grad(set_to_none=True)
    loss.critic_loss(loss.critic_targets(rollout)).backward()
    assert all(g is not None and g > 0 for g in _grad_norms(critic_params))
    assert all(g is None for g in _grad_norms(actor_params))

    loss.zero_grad(set_to_none=True)
    loss(rollout)["loss_critic"].backward()  # forward's critic part is on the detached rollout too
    assert all(g is None for g in _grad_norms(actor_params))


@pytest.mark.parametrize("updater_cls", [SoftUpdate, HardUpdate])
def test_target_params_move_only_through_the_updater(updater_cls):
    torch.manual_seed(0)
    env = PointMassEnv(num_envs=4, max_episode_steps=5)
    loss = make_loss()
    updater = SoftUpdate(loss, tau=0.8) if updater_cls is SoftUpdate else HardUpdate(
        loss, value_network_update_interval=0)
    target0 = loss.target_critic_network_params.clone()
    critic0 = loss.critic_network_params.detach().clone()
    opt = torch.optim.SGD(loss.parameters(), lr=0.1)
    rollout = differentiable_rollout(loss, env, 6)
    out = loss(rollout)
    (out["loss_actor"] + out["loss_critic"]).backward()
    opt.step()
    critic1 = loss.critic_network_params.detach().clone()
    assert not torch.allclose(critic1["module", "0", "weight"], critic0["module", "0", "weight"])
    assert (loss.target_critic_network_params == target0).all()
    updater.step()
    moved = loss.target_critic_network_params
    for key, target in moved.items(True, True):
        expected = target0[key].lerp(critic1[key], 0.8) if updater_cls is SoftUpdate else critic1[key]
        torch.testing.assert_close(target, expected)


# --------------------------------------------------------------------------------- on the toy env
def test_rollout_next_observation_is_pre_reset_at_episode_ends():
    # the measured torchrl behaviour the bootstrap relies on: with auto_reset=False the root of step t+1
    # is already reset, ("next", obs) of step t is not
    env = PointMassEnv(num_envs=2, max_episode_steps=3)
    loss = make_loss()
    rollout = differentiable_rollout(loss, env, 5)
    assert rollout["next", "truncated"][:, 2].all()
    assert (rollout["step_count"][:, 3] == 0).all()
    assert not torch.allclose(rollout["next", "observation"][:, 2], rollout["observation"][:, 3])
    torch.testing.assert_close(rollout["next", "observation"][:, 1], rollout["observation"][:, 2])


def test_actor_loss_on_env_rollout_with_termination_and_truncation():
    env = PointMassEnv(num_envs=3, max_episode_steps=4, terminate_radius=1.5, wall_radius=10.0)
    td = env.reset()
    with torch.no_grad():  # world 0 flies out of the arena during its first step
        td["pos"][0] = torch.tensor([1.45, 0.0])
        td["vel"][0] = torch.tensor([3.0, 0.0])
        td["observation"] = torch.cat([td["pos"] - td["goal"], td["vel"]], -1)
    loss = make_loss()
    rollout = differentiable_rollout(loss, env, 7, td)
    assert rollout["next", "terminated"][0, 0] and rollout["next", "truncated"][1:, 3].all()
    got = loss.actor_loss(rollout)
    nv = target_value(loss, rollout["next", "observation"])
    expected = handwritten_shac(rollout["next", "reward"], nv, rollout["next", "done"],
                                rollout["next", "terminated"], GAMMA)
    torch.testing.assert_close(got, expected)


def _evaluate(actor, env, steps) -> float:
    env.set_seed(123)
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        rollout = env.rollout(steps, actor, auto_reset=False, break_when_any_done=False, tensordict=env.reset())
    return float(rollout["next", "reward"].sum(-2).mean())


@pytest.mark.slow  # a training run
def test_shac_training_raises_toy_env_return():
    torch.manual_seed(0)
    episode = 32
    env = PointMassEnv(num_envs=32, max_episode_steps=episode, seed=1)
    eval_env = PointMassEnv(num_envs=32, max_episode_steps=episode, seed=2)
    actor, critic = make_actor(env=env), make_critic()
    loss = SHACLoss(actor_network=actor, critic_network=critic)  # DiffRL defaults: gamma 0.99, lambda 0.95
    updater = SoftUpdate(loss, tau=0.8)
    actor_opt = torch.optim.Adam(actor.parameters(), lr=1e-2, betas=(0.7, 0.95))
    critic_opt = torch.optim.Adam(critic.parameters(), lr=1e-2, betas=(0.7, 0.95))
    before = _evaluate(actor, eval_env, episode)
    td = env.reset()
    for _ in range(30):
        rollout = differentiable_rollout(loss, env, 16, td)
        out = loss(rollout)
        actor_opt.zero_grad()
        out["loss_actor"].backward()
        nn.utils.clip_grad_norm_(actor.parameters(), 1.0)
        actor_opt.step()
        data = loss.critic_targets(rollout).reshape(-1)
        for _ in range(4):
            for batch in data[torch.randperm(data.numel())].split(data.numel() // 4):
                critic_opt.zero_grad()
                loss.critic_loss(batch).backward()
                critic_opt.step()
        updater.step()
        td = next_rollout_start(env, rollout)
        assert not td["observation"].requires_grad
    after = _evaluate(actor, eval_env, episode)
    assert after > before + 0.5 * abs(before), (before, after)


def test_docstring_example_runs():
    result = doctest.testmod(shac_module, optionflags=doctest.ELLIPSIS)
    assert result.attempted > 0 and result.failed == 0


def test_fit_critic_matches_the_minibatch_loop_over_critic_loss():
    torch.manual_seed(0)
    env = PointMassEnv(num_envs=6, max_episode_steps=5)
    loss = make_loss()
    with torch.no_grad():
        rollout = differentiable_rollout(loss, env, 7)
        rollout["next", "observation"][2, 3] = float("nan")  # a blown-up world: value 0, no gradient
        rollout["observation"][4, 1] = float("inf")
    data = loss.critic_targets(rollout).reshape(-1)
    start = {k: v.clone() for k, v in loss.critic_network_params.items(True, True)}

    def loop():
        opt, losses = torch.optim.Adam(loss.critic_network.parameters(), lr=1e-2), []
        for _ in range(3):
            for batch in data[torch.randperm(data.numel())].split(data.numel() // 4):
                opt.zero_grad()
                value_loss = loss.critic_loss(batch)
                value_loss.backward()
                opt.step()
                losses.append(value_loss.detach())
        return torch.stack(losses), {k: v.clone() for k, v in loss.critic_network_params.items(True, True)}

    torch.manual_seed(1)
    expected_losses, expected = loop()
    loss.critic_network_params.update_(start)
    torch.manual_seed(1)
    calls = []
    opt = torch.optim.Adam(loss.critic_network.parameters(), lr=1e-2)
    losses = loss.fit_critic(data, opt, 3, 4, on_gradients=lambda: calls.append(1))
    assert len(calls) == len(losses) == len(expected_losses) == 3 * 4 + 3  # 42 = 4 x 10 + a remainder of 2
    torch.testing.assert_close(losses, expected_losses)
    for key, value in loss.critic_network_params.items(True, True):
        torch.testing.assert_close(value, expected[key])
    assert any((value != start[key]).any() for key, value in expected.items())  # the critic did move
    with pytest.raises(ValueError, match="flat batch"):
        loss.fit_critic(loss.critic_targets(rollout), opt, 1, 1)
