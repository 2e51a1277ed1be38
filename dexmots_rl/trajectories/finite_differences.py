"""Net wrenches from pose-only demonstrations by finite differences (the paper's route for mocap / video plans).

Given sampled poses of a rigid object (positions and wxyz unit quaternions, MuJoCo order) the net wrench that
produced them follows from Newton–Euler:

* force  ``F = m·a`` with ``a`` the second central difference of the positions,
* torque ``τ = I_w·α + ω × (I_w·ω)`` with the world-frame inertia ``I_w = R I Rᵀ`` (``I`` about the centre of
  mass in the body frame), ``ω`` the world-frame angular velocity and ``α = dω/dt``.

The result is the **net** wrench: the sum of all external forces and torques, gravity and its support included.
An object at rest on a table therefore has zero net wrench; add ``m·g`` yourself if you want the contact part.

Angular velocity uses quaternion differences. Between samples, ``ω_{t+½} = 2·log(q_{t+1} ⊗ q_t⁻¹)/dt``, picking the
shorter of ``±(q_{t+1} ⊗ q_t⁻¹)`` so a demo whose quaternions flip sign (q and −q are the same rotation) still gives
a smooth ω. At sample t, ω is the mean of the two neighbouring half-step values and ``α_t = (ω_{t+½} − ω_{t−½})/dt``;
both are second-order accurate at interior steps, like the central differences used for positions. The end steps use
one-sided differences (second-order for velocities, the neighbour's value for accelerations, i.e. first order).

Example:
    >>> import torch
    >>> T, dt = 6, 0.1
    >>> t = torch.arange(T, dtype=torch.float64) * dt
    >>> pos = torch.stack([0.5 * 2.0 * t**2, 0 * t, 0 * t], -1)       # constant 2 m/s² along x
    >>> quat = torch.tensor([1.0, 0, 0, 0], dtype=torch.float64).repeat(T, 1)
    >>> w = wrenches_from_poses(pos, quat, dt, mass=3.0, inertia=torch.eye(3, dtype=torch.float64))
    >>> [round(v, 6) for v in w[2].tolist()]
    [6.0, 0.0, 0.0, 0.0, 0.0, 0.0]
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from ..quaternions import quat_conjugate, quat_log, quat_multiply, quat_to_matrix
from .trajectory import PoseWrenchTrajectory, TrajectoryFormatError, _check_dt, validate_trajectory_fields

__all__ = [
    "angular_velocities",
    "load_pose_demo",
    "wrenches_from_poses",
]


def _first_derivative_and_second(x: torch.Tensor, dt: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Central first and second differences along dim 0, one-sided at the ends."""
    T = x.shape[0]
    if T == 1:
        return torch.zeros_like(x), torch.zeros_like(x)
    if T == 2:
        v = ((x[1] - x[0]) / dt).expand_as(x).clone()
        return v, torch.zeros_like(x)
    v = torch.empty_like(x)
    v[1:-1] = (x[2:] - x[:-2]) / (2 * dt)
    v[0] = (-3 * x[0] + 4 * x[1] - x[2]) / (2 * dt)
    v[-1] = (3 * x[-1] - 4 * x[-2] + x[-3]) / (2 * dt)
    a = torch.empty_like(x)
    a[1:-1] = (x[2:] - 2 * x[1:-1] + x[:-2]) / dt**2
    # the neighbour's second difference is the only one available at the ends
    a[0] = a[1]
    a[-1] = a[-2]
    return v, a


def angular_velocities(quat: torch.Tensor, dt: float) -> tuple[torch.Tensor, torch.Tensor]:
    """World-frame angular velocity ω [T, 3] and acceleration α [T, 3] from wxyz quaternions [T, 4]."""
    T = quat.shape[0]
    if T == 1:
        z = quat.new_zeros(1, 3)
        return z, z.clone()
    # world-frame ω left-multiplies: q_{t+1} = exp(ω dt / 2) ⊗ q_t
    half = quat_log(quat_multiply(quat[1:], quat_conjugate(quat[:-1]))) / dt  # ω at t + ½, [T-1, 3]
    if T == 2:
        return half.expand(2, 3).clone(), quat.new_zeros(2, 3)
    omega = torch.empty(T, 3, dtype=quat.dtype, device=quat.device)
    omega[1:-1] = 0.5 * (half[1:] + half[:-1])
    # linear extrapolation of the half-step values keeps the ends second order
    omega[0] = 1.5 * half[0] - 0.5 * half[1]
    omega[-1] = 1.5 * half[-1] - 0.5 * half[-2]
    alpha = torch.empty_like(omega)
    alpha[1:-1] = (half[1:] - half[:-1]) / dt
    alpha[0] = alpha[1]
    alpha[-1] = alpha[-2]
    return omega, alpha


def _as_tensor(x: Any, dtype: torch.dtype | None = None) -> torch.Tensor:
    if isinstance(x, np.ndarray) or not isinstance(x, torch.Tensor):
        x = torch.as_tensor(np.asarray(x))
    if not x.is_floating_point():
        x = x.to(torch.get_default_dtype() if dtype is None else dtype)
    return x if dtype is None else x.to(dtype)


def wrenches_from_poses(
    pos: torch.Tensor,
    quat: torch.Tensor,
    dt: float,
    mass: float,
    inertia: torch.Tensor,
) -> torch.Tensor:
    """Net world-frame wrench [T, 6] (force, torque) that moves a rigid body through the sampled poses.

    ``pos`` [T, 3] is the centre-of-mass position, ``quat`` [T, 4] unit wxyz, ``inertia`` [3, 3] the body-frame
    inertia about the centre of mass. Gravity is *not* added: this is the net wrench (all external forces summed).
    See the module docstring for the difference scheme and its accuracy.
    """
    dt = _check_dt(dt)
    pos = torch.as_tensor(pos)
    quat = torch.as_tensor(quat, dtype=pos.dtype, device=pos.device)
    inertia = torch.as_tensor(inertia, dtype=pos.dtype, device=pos.device)
    if pos.ndim != 2 or pos.shape[1] != 3:
        raise ValueError(f"pos must be [T, 3], got {tuple(pos.shape)}")
    if quat.shape != (pos.shape[0], 4):
        raise ValueError(f"quat must be [T, 4] with T={pos.shape[0]}, got {tuple(quat.shape)}")
    if inertia.shape != (3, 3):
        raise ValueError(f"inertia must be [3, 3], got {tuple(inertia.shape)}")
    _, acc = _first_derivative_and_second(pos, dt)
    force = mass * acc
    omega, alpha = angular_velocities(quat, dt)
    R = quat_to_matrix(quat)
    I_w = R @ inertia @ R.transpose(-1, -2)
    Iw_omega = (I_w @ omega.unsqueeze(-1)).squeeze(-1)
    torque = (I_w @ alpha.unsqueeze(-1)).squeeze(-1) + torch.linalg.cross(omega, Iw_omega, dim=-1)
    return torch.cat([force, torque], dim=-1)


def load_pose_demo(
    pos: Any,
    quat: Any,
    dt: float,
    mass: float,
    inertia: Any,
    joint_q: Any | None = None,
) -> PoseWrenchTrajectory:
    """Build a :class:`PoseWrenchTrajectory` from a pose-only demonstration (numpy arrays or torch tensors).

    Quaternions (wxyz) are normalised first; the wrench comes from :func:`wrenches_from_poses`. Articulation torques
    cannot be recovered without the articulation's dynamics, so ``joint_torque`` is zero.

    Example:
        >>> import numpy as np
        >>> T = 4
        >>> traj = load_pose_demo(np.zeros((T, 3)), np.tile([2.0, 0, 0, 0], (T, 1)), 0.02, 1.0, np.eye(3))
        >>> traj.quat[0].tolist(), traj.wrench.abs().max().item()
        ([1.0, 0.0, 0.0, 0.0], 0.0)
    """
    pos_t = _as_tensor(pos)
    quat_t = _as_tensor(quat, pos_t.dtype).to(pos_t.device)
    if quat_t.ndim != 2 or quat_t.shape[-1] != 4:
        raise TrajectoryFormatError(f"field 'quat' must have shape [T, 4], got {tuple(quat_t.shape)}")
    norm = torch.linalg.vector_norm(quat_t, dim=-1, keepdim=True)
    if not bool(torch.isfinite(norm).all()) or bool((norm < 1e-8).any()):
        raise TrajectoryFormatError("field 'quat' has zero-length or non-finite quaternions")
    quat_t = quat_t / norm
    jq = None if joint_q is None else _as_tensor(joint_q, pos_t.dtype).to(pos_t.device)
    if jq is not None and jq.ndim == 1:
        jq = jq.unsqueeze(-1)  # a single articulation coordinate given as [T]
    # validate shapes/finiteness before differencing so errors name the field, not a broadcast failure
    T = pos_t.shape[0] if pos_t.ndim >= 1 else 0
    jq_check = jq if jq is not None else pos_t.new_zeros(T, 0)
    validate_trajectory_fields(
        {"pos": pos_t, "quat": quat_t, "joint_q": jq_check, "wrench": pos_t.new_zeros(T, 6),
         "joint_torque": torch.zeros_like(jq_check)},
        dt,
    )
    inertia_t = _as_tensor(inertia, pos_t.dtype).to(pos_t.device)
    wrench = wrenches_from_poses(pos_t, quat_t, dt, float(mass), inertia_t)
    return PoseWrenchTrajectory(pos_t, quat_t, wrench, dt, joint_q=jq)
