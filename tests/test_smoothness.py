"""PolicySmoothnessLoss (CAPS): what each term measures, the episode-boundary mask, gradients reach the
policy only, and the training option (``algo.smooth_temporal`` / ``smooth_spatial``)."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from test_train import _cfg, _rows

from dexmots_rl.algorithms.validation import validate_run_config
from dexmots_rl.apps.train import run as train
from dexmots_rl.objectives import PolicySmoothnessLoss


def _rollout(obs, done=None):
    n, t = obs.shape[:2]
    done = torch.zeros(n, t, 1, dtype=torch.bool) if done is None else done
    return TensorDict(observation=obs, next=TensorDict(done=done, batch_size=[n, t]), batch_size=[n, t])


def _identity_policy():
    net = torch.nn.Linear(1, 1, bias=False)
    with torch.no_grad():
        net.weight.fill_(1.0)
    return net, TensorDictModule(net, in_keys=["observation"], out_keys=["loc"])


def test_temporal_term_is_the_mean_squared_jump_of_the_squashed_action():
    _, policy = _identity_policy()
    obs = torch.tensor([[0.0, 0.5, 0.5, -0.5]]).unsqueeze(-1)
    out = PolicySmoothnessLoss(policy, spatial_sigma=0.0)(_rollout(obs))
    a = torch.tanh(obs[0, :, 0])
    expected = (a[1:] - a[:-1]).square().mean()
    torch.testing.assert_close(out["loss_smooth_temporal"], expected)
    assert out["loss_smooth_spatial"] == 0


def test_pairs_across_a_reset_and_non_finite_worlds_are_left_out():
    _, policy = _identity_policy()
    obs = torch.tensor([[0.0, 0.0, 3.0], [1.0, float("nan"), 1.0]]).unsqueeze(-1)
    done = torch.tensor([[False, True, False], [False, False, False]]).unsqueeze(-1)
    out = PolicySmoothnessLoss(policy, spatial_sigma=0.1)(_rollout(obs, done))
    assert out["loss_smooth_temporal"] == 0  # the only jump (0 -> 3) crosses the reset; world 1 has a NaN
    assert torch.isfinite(out["loss_smooth_spatial"]) and out["loss_smooth_spatial"] > 0


def test_gradient_reaches_the_policy_and_not_the_observations():
    net, policy = _identity_policy()
    obs = torch.randn(3, 5, 1, requires_grad=True)
    out = PolicySmoothnessLoss(policy, spatial_sigma=0.05)(_rollout(obs))
    (out["loss_smooth_temporal"] + out["loss_smooth_spatial"]).backward()
    assert net.weight.grad is not None and net.weight.grad.abs() > 0
    assert obs.grad is None
    loss = PolicySmoothnessLoss(policy)
    loss.set_keys(observation="state")
    assert loss.in_keys[0] == "state"
    with pytest.raises(ValueError, match="spatial_sigma"):
        PolicySmoothnessLoss(policy, spatial_sigma=-1.0)


def test_training_with_the_penalty_logs_both_terms(tmp_path):
    train(_cfg(tmp_path / "run", "algo.iterations=2", "algo.smooth_temporal=0.1", "algo.smooth_spatial=0.1"))
    rows = _rows(tmp_path / "run")
    assert all(r["smooth_temporal"] >= 0 and r["smooth_spatial"] > 0 for r in rows)
    with pytest.raises(ValueError, match=r"algo\.smooth_temporal"):
        validate_run_config(_cfg(tmp_path / "bad", "algo.smooth_temporal=-0.1"))


def test_adaptive_scale_follows_the_clipped_adjoint_share():
    from types import SimpleNamespace

    from dexmots_rl.algorithms.shac import _smooth_scale

    fixed = SimpleNamespace(smooth_clip_target=None, smooth_dual_lr=10.0)
    assert _smooth_scale(fixed, 0.0, 0.5) == 1.0
    algo = SimpleNamespace(smooth_clip_target=0.005, smooth_dual_lr=10.0)
    assert _smooth_scale(algo, 0.0, 0.001) == 0.0  # a healthy run: the penalty stays off
    up = _smooth_scale(algo, 0.0, 0.05)
    assert up == pytest.approx(0.45)
    assert _smooth_scale(algo, up, 0.5) == 1.0  # clamped
    assert _smooth_scale(algo, up, 0.0) == pytest.approx(0.4)


def test_training_with_an_adaptive_penalty_logs_its_scale(tmp_path):
    train(_cfg(tmp_path / "run", "algo.iterations=2", "algo.smooth_temporal=0.1", "algo.smooth_clip_target=0.0"))
    rows = _rows(tmp_path / "run")
    assert all(0.0 <= r["smooth_scale"] <= 1.0 for r in rows)
    assert all(("smooth_temporal" in r) == (r["smooth_scale"] > 0) for r in rows)
