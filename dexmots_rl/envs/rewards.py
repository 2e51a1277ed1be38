"""Rewards as plain torch functions of observation tensors (differentiable, testable alone).

The paper's reward model (§5.1, Eq. 1-3)::

    r = λ_pose r_pose + λ_wrench r_wrench + λ_act r_act + λ_f r_f

* ``r_pose  = exp(-‖p - p̄‖)``   object pose error (position, orientation, articulation), :func:`pose_reward`;
* ``r_wrench = exp(-‖ω - ω̄‖)``  object wrench error (force, torque), :func:`wrench_reward`;
* ``r_act = -‖w ⊙ a‖``          action penalty, heavier on distal joints, :func:`action_penalty`;
* ``r_f = Σ_i exp(-‖x_fi - x_o‖)`` fingertips near the object centre, :func:`fingertip_reward`.

Every function maps batched inputs ``[..., D]`` to ``[..., 1]`` (one reward per world, the env's reward
shape) and is differentiable everywhere, including at zero error (norms go through
``torch.linalg.vector_norm``, whose gradient at 0 is 0 rather than NaN; angles use ``atan2``, not ``acos``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import torch

from ..quaternions import quat_angle
from .fields import rule

__all__ = [
    "RewardCoefficients",
    "action_penalty",
    "angle_tracking_reward",
    "distal_weighted_joint_weights",
    "fingertip_reward",
    "pose_reward",
    "wrench_reward",
]


def angle_tracking_reward(angle: torch.Tensor, goal: torch.Tensor, scale: float = 1.0) -> torch.Tensor:
    """``exp(-|angle - goal| / scale)`` per world: 1 on the goal, decaying with the angle error (rad).

    Example:
        >>> import torch
        >>> angle_tracking_reward(torch.tensor([[0.0]]), torch.tensor([[0.0]]))
        tensor([[1.]])
    """
    return torch.exp(-(angle - goal).abs() / scale)


def _check_last(name: str, x: torch.Tensor, size: int) -> None:
    if x.shape[-1:] != (size,):
        raise ValueError(f"{name} must have shape [..., {size}], got {tuple(x.shape)}")


def pose_reward(
    pose: torch.Tensor,
    target_pose: torch.Tensor,
    q: torch.Tensor | None = None,
    target_q: torch.Tensor | None = None,
    *,
    pos_scale: float = 1.0,
    rot_scale: float = 1.0,
    joint_scale: float = 1.0,
) -> torch.Tensor:
    """Eq. 1's ``r_pose = exp(-‖p - p̄‖)`` per world, ``[..., 1]``.

    ``pose``/``target_pose``: ``[..., 7]`` position (m) + wxyz unit quaternion; ``q``/``target_q``:
    optional articulation coordinates ``[..., K]`` (rad or m, e.g. a hinge angle). The pose error is the
    Euclidean norm of the stacked, weighted components::

        ‖p - p̄‖ = sqrt( (pos_scale ‖Δx‖)² + (rot_scale θ)² + (joint_scale ‖Δq‖)² )

    with ``θ`` the geodesic angle (:func:`quat_angle`). The paper stacks position and axis-angle error
    in one 6-vector, which is the default (all weights 1: 1 rad of orientation error counts as 1 m of
    position error); ``rot_scale`` (m/rad) re-balances them for objects much smaller or larger than 1 m.

    Example:
        >>> import torch
        >>> p = torch.tensor([[0.0, 0, 0, 1, 0, 0, 0]])
        >>> pose_reward(p, p)
        tensor([[1.]])
    """
    _check_last("pose", pose, 7)
    _check_last("target_pose", target_pose, 7)
    if (q is None) != (target_q is None):
        raise ValueError("q and target_q must be given together (articulation coordinates of the object)")
    parts = [
        pos_scale * (pose[..., :3] - target_pose[..., :3]),
        rot_scale * quat_angle(pose[..., 3:], target_pose[..., 3:]),
    ]
    if q is not None:
        if q.shape[-1:] != target_q.shape[-1:]:
            raise ValueError(f"q has shape {tuple(q.shape)} but target_q has {tuple(target_q.shape)}")
        parts.append(joint_scale * (q - target_q))
    # position/angle/joint errors may broadcast differently (e.g. one target for all worlds)
    batch = torch.broadcast_shapes(*[p.shape[:-1] for p in parts])
    err = torch.cat([p.expand(*batch, p.shape[-1]) for p in parts], dim=-1)
    return torch.exp(-torch.linalg.vector_norm(err, dim=-1, keepdim=True))


def wrench_reward(
    wrench: torch.Tensor,
    target_wrench: torch.Tensor,
    force_scale: float = 1.0,
    torque_scale: float = 1.0,
) -> torch.Tensor:
    """Eq. 1's ``r_wrench = exp(-‖ω - ω̄‖)`` per world, ``[..., 1]``.

    ``wrench``/``target_wrench``: ``[..., 6]`` force (N) then torque (N·m). The force error is divided by
    ``force_scale`` (N) and the torque error by ``torque_scale`` (N·m), so both parts are unitless
    before they are stacked: an error of one ``force_scale`` alone gives ``exp(-1)``.

    Example:
        >>> import torch
        >>> w = torch.zeros(1, 6)
        >>> round(wrench_reward(w, w + torch.tensor([2.0, 0, 0, 0, 0, 0]), force_scale=2.0).item(), 4)
        0.3679
    """
    _check_last("wrench", wrench, 6)
    _check_last("target_wrench", target_wrench, 6)
    if not (force_scale > 0 and torque_scale > 0):
        raise ValueError(f"force_scale and torque_scale must be > 0, got {force_scale}, {torque_scale}")
    d = wrench - target_wrench
    err = torch.cat([d[..., :3] / force_scale, d[..., 3:] / torque_scale], dim=-1)
    return torch.exp(-torch.linalg.vector_norm(err, dim=-1, keepdim=True))


def distal_weighted_joint_weights(
    joints_per_finger: int,
    num_fingers: int,
    proximal: float = 1.0,
    distal: float = 2.0,
    dtype: torch.dtype = torch.float32,
    device: str | torch.device = "cpu",
) -> torch.Tensor:
    """Per-joint action-penalty weights ``[num_fingers * joints_per_finger]``, a linear ramp per finger.

    Joint ``j`` of each finger (0 = proximal) gets ``proximal + (distal - proximal) j / (J - 1)``; the
    order matches the simulator's hand dofs (``finger * J + link``). The paper penalises distal joints
    more so that grasps manipulate with the distal links. With one joint per finger the ramp has a
    single point and that joint gets ``proximal``.

    Example:
        >>> distal_weighted_joint_weights(2, 2)
        tensor([1., 2., 1., 2.])
    """
    for name, v in (("joints_per_finger", joints_per_finger), ("num_fingers", num_fingers)):
        if not isinstance(v, int) or v <= 0:
            raise ValueError(f"{name} must be a positive integer, got {v!r}")
    for name, v in (("proximal", proximal), ("distal", distal)):
        if not (math.isfinite(v) and v >= 0):
            raise ValueError(f"{name} weight must be finite and >= 0, got {v!r}")
    ramp = torch.linspace(proximal, distal, joints_per_finger, dtype=dtype, device=device)
    return ramp.repeat(num_fingers)


def action_penalty(action: torch.Tensor, joint_weights: torch.Tensor | None = None) -> torch.Tensor:
    """Eq. 2's ``r_act = -‖w ⊙ a‖`` per world, ``[..., 1]`` (≤ 0); ``w = 1`` when no weights are given.

    ``joint_weights`` broadcasts against ``action`` (e.g. ``[nu]`` from
    :func:`distal_weighted_joint_weights`; for the ``"vi"`` action space pass ``[2 nu]`` weights or
    penalise only the target half).

    Example:
        >>> import torch
        >>> action_penalty(torch.tensor([[3.0, 4.0]]))
        tensor([[-5.]])
    """
    a = action if joint_weights is None else action * joint_weights
    return -torch.linalg.vector_norm(a, dim=-1, keepdim=True)


def fingertip_reward(fingertips: torch.Tensor, object_pos: torch.Tensor, scale: float = 1.0) -> torch.Tensor:
    """Eq. 2's ``r_f = Σ_i exp(-‖x_fi - x_o‖ / scale)`` per world, ``[..., 1]`` (in ``(0, F]``).

    ``fingertips``: ``[..., F, 3]`` fingertip positions (m); ``object_pos``: ``[..., 3]`` object centre;
    ``scale`` (m): the distance over which the term decays (of the order of the hand: 1 m leaves a
    centimetre-sized hand no gradient to follow).

    Example:
        >>> import torch
        >>> fingertip_reward(torch.zeros(1, 2, 3), torch.zeros(1, 3))
        tensor([[2.]])
    """
    _check_last("fingertips", fingertips, 3)
    _check_last("object_pos", object_pos, 3)
    if fingertips.dim() < 2:
        raise ValueError(f"fingertips must have shape [..., F, 3], got {tuple(fingertips.shape)}")
    dist = torch.linalg.vector_norm(fingertips - object_pos.unsqueeze(-2), dim=-1)
    return torch.exp(-dist / scale).sum(-1, keepdim=True)


@dataclass
class RewardCoefficients:
    """Eq. 3's coefficients ``λ``; each must be finite and ≥ 0 (``r_act`` is already negative).

    The paper keeps them fixed across tasks but does not list them; the defaults are ours: the
    object-centric terms dominate, the action and fingertip terms shape.

    Example:
        >>> RewardCoefficients(lambda_act=0.0).lambda_pose
        1.0
    """

    lambda_pose: float = field(default=1.0, metadata=rule(ge=0))
    lambda_wrench: float = field(default=1.0, metadata=rule(ge=0))
    lambda_act: float = field(default=0.01, metadata=rule(ge=0))
    lambda_f: float = field(default=0.1, metadata=rule(ge=0))

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ValueError(f"{f.name} must be a real number, got {v!r}")
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{f.name} must be finite and >= 0, got {v!r}")
