"""The paper's reward model (Eq. 1-3): hand-computed values, symmetries, gradients, validation."""

from __future__ import annotations

import math

import pytest
import torch

from dexmots_rl.quaternions import quat_angle
from dexmots_rl.envs.rewards import (
    RewardCoefficients,
    action_penalty,
    angle_tracking_reward,
    distal_weighted_joint_weights,
    fingertip_reward,
    pose_reward,
    wrench_reward,
)

ID = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=torch.float64)


def quat_axis_angle(axis, angle) -> torch.Tensor:
    axis = torch.as_tensor(axis, dtype=torch.float64)
    axis = axis / axis.norm()
    return torch.cat([torch.tensor([math.cos(angle / 2)], dtype=torch.float64), math.sin(angle / 2) * axis])


def pose(pos, quat) -> torch.Tensor:
    return torch.cat([torch.as_tensor(pos, dtype=torch.float64), quat]).unsqueeze(0)


def test_quat_angle_values_and_sign_invariance():
    q90 = quat_axis_angle([0, 0, 1], math.pi / 2)
    q_tilt = quat_axis_angle([1, 2, 3], 0.7)
    assert quat_angle(ID[None], q90[None]).item() == pytest.approx(math.pi / 2, abs=1e-12)
    assert quat_angle(ID[None], -q90[None]).item() == pytest.approx(math.pi / 2, abs=1e-12)
    assert quat_angle(q_tilt[None], q_tilt[None]).item() == pytest.approx(0.0, abs=1e-12)
    assert quat_angle(q_tilt[None], -q_tilt[None]).item() == pytest.approx(0.0, abs=1e-12)
    # relative rotation: a 0.7 rad turn composed on top of an arbitrary orientation is still 0.7 rad
    w1, v1 = q_tilt[0], q_tilt[1:]
    r = quat_axis_angle([0, 1, 0], 0.3)
    w2, v2 = r[0], r[1:]
    prod = torch.cat([(w1 * w2 - v1 @ v2)[None], w1 * v2 + w2 * v1 + torch.linalg.cross(v1, v2)])
    assert quat_angle(q_tilt[None], prod[None]).item() == pytest.approx(0.3, abs=1e-12)
    # 180° is the largest distance
    assert quat_angle(ID[None], quat_axis_angle([1, 0, 0], math.pi)[None]).item() == pytest.approx(math.pi)


def test_pose_reward_hand_computed():
    p0 = pose([0, 0, 0], ID)
    assert pose_reward(p0, p0).item() == pytest.approx(1.0)
    # position error only: (0.3, 0.4, 0) -> 0.5 m
    assert pose_reward(pose([0.3, 0.4, 0], ID), p0).item() == pytest.approx(math.exp(-0.5))
    # 90° rotation only
    q90 = quat_axis_angle([0, 0, 1], math.pi / 2)
    assert pose_reward(pose([0, 0, 0], q90), p0).item() == pytest.approx(math.exp(-math.pi / 2))
    # both, with a rotation weight: sqrt(0.5^2 + (0.2 * pi/2)^2)
    got = pose_reward(pose([0.3, 0.4, 0], q90), p0, rot_scale=0.2).item()
    assert got == pytest.approx(math.exp(-math.hypot(0.5, 0.2 * math.pi / 2)))
    # articulation error joins the same norm
    q, qt = torch.tensor([[0.1]], dtype=torch.float64), torch.tensor([[0.4]], dtype=torch.float64)
    got = pose_reward(pose([0.3, 0.4, 0], ID), p0, q, qt).item()
    assert got == pytest.approx(math.exp(-math.hypot(0.5, 0.3)))
    assert pose_reward(pose([0.3, 0.4, 0], ID), p0, q, qt, joint_scale=2.0).item() == pytest.approx(
        math.exp(-math.hypot(0.5, 0.6)))


def test_pose_reward_quaternion_sign_and_batch_shape():
    q = quat_axis_angle([1, -1, 2], 1.1)
    a, b = pose([0.1, 0, 0.2], q), pose([0.1, 0, 0.2], -q)
    target = pose([0, 0, 0], quat_axis_angle([0, 1, 0], 0.4))
    assert torch.allclose(pose_reward(a, target), pose_reward(b, target))
    assert pose_reward(a, b).item() == pytest.approx(1.0)
    batch = torch.cat([a, b, target]).reshape(3, 7)
    out = pose_reward(batch, target)  # one target broadcast over the worlds
    assert out.shape == (3, 1)
    assert out[2].item() == pytest.approx(1.0)


def test_wrench_reward_scales_parts_separately():
    w0 = torch.zeros(1, 6, dtype=torch.float64)
    w = torch.tensor([[6.0, 8.0, 0.0, 0.0, 0.0, 0.3]], dtype=torch.float64)  # 10 N, 0.3 N·m
    assert wrench_reward(w0, w0).item() == pytest.approx(1.0)
    assert wrench_reward(w, w0).item() == pytest.approx(math.exp(-math.hypot(10.0, 0.3)))
    got = wrench_reward(w, w0, force_scale=10.0, torque_scale=0.1).item()
    assert got == pytest.approx(math.exp(-math.hypot(1.0, 3.0)))
    assert wrench_reward(w, w0).shape == (1, 1)
    with pytest.raises(ValueError, match="force_scale"):
        wrench_reward(w, w0, force_scale=0.0)


def test_joint_weights_ramp_proximal_to_distal():
    w = distal_weighted_joint_weights(4, 3, proximal=1.0, distal=2.5)
    assert w.shape == (12,)
    per_finger = w.reshape(3, 4)
    assert torch.allclose(per_finger[0], torch.tensor([1.0, 1.5, 2.0, 2.5]))
    assert (per_finger[:, 1:] > per_finger[:, :-1]).all()  # strictly more penalty towards the tip
    assert torch.equal(per_finger[0], per_finger[2])
    assert torch.equal(distal_weighted_joint_weights(2, 2), torch.tensor([1.0, 2.0, 1.0, 2.0]))
    assert torch.equal(distal_weighted_joint_weights(1, 2), torch.tensor([1.0, 1.0]))
    with pytest.raises(ValueError, match="joints_per_finger"):
        distal_weighted_joint_weights(0, 2)
    with pytest.raises(ValueError, match="distal"):
        distal_weighted_joint_weights(2, 2, distal=float("nan"))


def test_action_penalty_weighted_norm():
    a = torch.tensor([[1.0, 1.0, -1.0, 0.5]], dtype=torch.float64)
    w = distal_weighted_joint_weights(2, 2, dtype=torch.float64)  # [1, 2, 1, 2]
    assert action_penalty(a).item() == pytest.approx(-math.sqrt(3.25))
    assert action_penalty(a, w).item() == pytest.approx(-math.sqrt(1 + 4 + 1 + 1))
    assert action_penalty(torch.zeros(5, 4)).shape == (5, 1)
    # the same action on a distal joint costs more than on a proximal one
    prox = torch.tensor([[0.5, 0.0, 0.0, 0.0]])
    dist = torch.tensor([[0.0, 0.5, 0.0, 0.0]])
    assert action_penalty(dist, w.float()) < action_penalty(prox, w.float())


def test_fingertip_reward_sum_over_fingers():
    tips = torch.tensor([[[0.3, 0.4, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]], dtype=torch.float64)
    obj = torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64)
    expected = math.exp(-math.hypot(0.7, 0.4)) + 2.0
    assert fingertip_reward(tips, obj).item() == pytest.approx(expected)
    assert fingertip_reward(tips.expand(4, 3, 3), obj.expand(4, 3)).shape == (4, 1)


def _inputs(requires_grad=True):
    g = torch.Generator().manual_seed(0)
    q = torch.randn(3, 4, generator=g, dtype=torch.float64)
    x = {
        "pose": torch.cat([torch.randn(3, 3, generator=g, dtype=torch.float64), q / q.norm(dim=-1, keepdim=True)], -1),
        "target_pose": pose([0.1, 0.2, 0.3], quat_axis_angle([0, 0, 1], 0.5)).expand(3, 7),
        "wrench": torch.randn(3, 6, generator=g, dtype=torch.float64),
        "target_wrench": torch.randn(3, 6, generator=g, dtype=torch.float64),
        "action": torch.rand(3, 4, generator=g, dtype=torch.float64) * 2 - 1,
        "fingertips": torch.randn(3, 2, 3, generator=g, dtype=torch.float64),
        "q": torch.randn(3, 1, generator=g, dtype=torch.float64),
        "target_q": torch.zeros(3, 1, dtype=torch.float64),
    }
    for k in ("pose", "wrench", "action", "fingertips", "q"):
        x[k].requires_grad_(requires_grad)
    return x


def test_gradients_flow_and_are_finite():
    x = _inputs()
    # every term of Eq. 3, summed as a task's reward sums them
    total = (pose_reward(x["pose"], x["target_pose"], x["q"], x["target_q"])
             + wrench_reward(x["wrench"], x["target_wrench"], 2.0, 0.5)
             + action_penalty(x["action"], distal_weighted_joint_weights(2, 2, dtype=torch.float64))
             + fingertip_reward(x["fingertips"], x["pose"][..., :3]))
    grads = torch.autograd.grad(total.sum(), [x[k] for k in ("pose", "wrench", "action", "fingertips", "q")])
    for g in grads:
        assert torch.isfinite(g).all() and g.abs().sum() > 0
    # each term alone, and gradcheck against finite differences in float64
    assert torch.autograd.gradcheck(lambda p: pose_reward(p, x["target_pose"]), (x["pose"].detach().requires_grad_(),))
    assert torch.autograd.gradcheck(lambda w: wrench_reward(w, x["target_wrench"], 2.0, 0.5),
                                    (x["wrench"].detach().requires_grad_(),))
    assert torch.autograd.gradcheck(lambda t: fingertip_reward(t, x["pose"][:, :3].detach()),
                                    (x["fingertips"].detach().requires_grad_(),))
    # the pose term pulls the position towards the target: gradient ascent reduces the error
    p = x["pose"].detach().requires_grad_()
    (g,) = torch.autograd.grad(pose_reward(p, x["target_pose"]).sum(), p)
    err = (p[:, :3] - x["target_pose"][:, :3]).detach()
    assert ((g[:, :3] * err).sum(-1) < 0).all()


def test_gradients_finite_at_zero_error():
    p = pose([0.1, 0.2, 0.3], quat_axis_angle([0, 1, 0], 0.4)).requires_grad_()
    w = torch.zeros(1, 6, dtype=torch.float64, requires_grad=True)
    a = torch.zeros(1, 4, dtype=torch.float64, requires_grad=True)
    out = pose_reward(p, p.detach()) + wrench_reward(w, w.detach()) + action_penalty(a)
    for g in torch.autograd.grad(out.sum(), [p, w, a]):
        assert torch.isfinite(g).all()


@pytest.mark.parametrize("field", ["lambda_pose", "lambda_wrench", "lambda_act", "lambda_f"])
@pytest.mark.parametrize("bad", [-0.1, float("nan"), float("inf"), "1.0"])
def test_coefficient_validation_names_field(field, bad):
    with pytest.raises(ValueError, match=field):
        RewardCoefficients(**{field: bad})


def test_coefficient_defaults_valid_and_zero_allowed():
    c = RewardCoefficients()
    assert c.lambda_pose > 0 and c.lambda_wrench > 0 and c.lambda_act > 0 and c.lambda_f > 0
    RewardCoefficients(lambda_wrench=0.0)  # pose-only goal conditioning


def test_shape_errors_name_the_argument():
    with pytest.raises(ValueError, match="target_pose"):
        pose_reward(torch.zeros(2, 7), torch.zeros(2, 6))
    with pytest.raises(ValueError, match="wrench"):
        wrench_reward(torch.zeros(2, 3), torch.zeros(2, 6))
    with pytest.raises(ValueError, match="fingertips"):
        fingertip_reward(torch.zeros(2, 2), torch.zeros(2, 3))
    with pytest.raises(ValueError, match="target_q"):
        pose_reward(torch.zeros(2, 7), torch.zeros(2, 7), q=torch.zeros(2, 1))


def test_angle_tracking_reward_unchanged():
    assert angle_tracking_reward(torch.tensor([[0.5]]), torch.tensor([[0.0]]), 0.5).item() == pytest.approx(
        math.exp(-1.0))
