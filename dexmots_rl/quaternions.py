"""Quaternion maths on torch tensors, in one place: wxyz order, ``[..., 4]``, differentiable.

Example:
    >>> import math, torch
    >>> q = torch.tensor([math.cos(0.25), 0.0, 0.0, math.sin(0.25)])        # 0.5 rad about z
    >>> round(float(quat_angle(torch.tensor([1.0, 0, 0, 0]), q)), 4)
    0.5
    >>> quat_multiply(q, quat_conjugate(q))
    tensor([1., 0., 0., 0.])
"""

from __future__ import annotations

import torch

__all__ = ["quat_angle", "quat_conjugate", "quat_log", "quat_multiply", "quat_to_matrix", "slerp"]


def quat_multiply(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product ``a ⊗ b`` of wxyz quaternions [..., 4]."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        dim=-1,
    )


def quat_conjugate(q: torch.Tensor) -> torch.Tensor:
    """Conjugate (= inverse for unit quaternions), wxyz."""
    return q * q.new_tensor([1.0, -1.0, -1.0, -1.0])


def quat_log(q: torch.Tensor) -> torch.Tensor:
    """Rotation vector ``2·log(q)`` (axis · angle) of unit wxyz quaternions, using the shorter of ±q."""
    q = torch.where(q[..., :1] < 0, -q, q)
    w, v = q[..., 0], q[..., 1:]
    s = torch.linalg.vector_norm(v, dim=-1)
    angle = 2.0 * torch.atan2(s, w)
    # angle/s → 2/w as s → 0; the guarded division keeps gradients finite at the identity
    safe_s = torch.where(s > 1e-12, s, torch.ones_like(s))
    scale = torch.where(s > 1e-12, angle / safe_s, 2.0 / w)
    return v * scale.unsqueeze(-1)


def quat_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """Rotation matrices [..., 3, 3] (body → world) of unit wxyz quaternions [..., 4]."""
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(q.shape[:-1] + (3, 3))


def quat_angle(q1: torch.Tensor, q2: torch.Tensor) -> torch.Tensor:
    """Geodesic angle (rad, in [0, π]) between wxyz quaternions ``[..., 4]``; returns ``[..., 1]``.

    Sign-invariant (``q`` and ``-q`` are the same rotation). Computed as ``2 atan2(‖v‖, |w|)`` of the
    relative rotation ``q1* ⊗ q2 = (w, v)``: unlike ``2 acos(|q1·q2|)`` its gradient stays finite at
    zero error, and it does not depend on the quaternions' norms.

    Example:
        >>> import math, torch
        >>> q = torch.tensor([[math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)]])  # 90° about z
        >>> round(quat_angle(torch.tensor([[1.0, 0, 0, 0]]), q).item(), 4)
        1.5708
    """
    for name, q in (("q1", q1), ("q2", q2)):
        if q.shape[-1:] != (4,):
            raise ValueError(f"{name} must have shape [..., 4], got {tuple(q.shape)}")
    w1, v1 = q1[..., :1], q1[..., 1:]
    w2, v2 = q2[..., :1], q2[..., 1:]
    w = w1 * w2 + (v1 * v2).sum(-1, keepdim=True)
    v = w1 * v2 - w2 * v1 - torch.linalg.cross(v1, v2, dim=-1)
    return 2.0 * torch.atan2(torch.linalg.vector_norm(v, dim=-1, keepdim=True), w.abs())


def slerp(q0: torch.Tensor, q1: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
    """Spherical interpolation of wxyz unit quaternions ``[..., 4]`` at fractions ``s [..., 1]`` (shortest arc).

    Example:
        >>> import math, torch
        >>> q1 = torch.tensor([math.cos(0.5), 0.0, 0.0, math.sin(0.5)])     # 1 rad about z
        >>> mid = slerp(torch.tensor([1.0, 0, 0, 0]), q1, torch.tensor([0.5]))
        >>> round(2 * math.acos(mid[0].item()), 4)
        0.5
    """
    dot = (q0 * q1).sum(-1, keepdim=True)
    q1 = torch.where(dot < 0, -q1, q1)
    dot = dot.abs().clamp(max=1.0)
    theta = torch.acos(dot)
    small = theta < 1e-6
    sin = torch.sin(theta).clamp(min=1e-12)
    a = torch.where(small, 1.0 - s, torch.sin((1.0 - s) * theta) / sin)
    b = torch.where(small, s, torch.sin(s * theta) / sin)
    out = a * q0 + b * q1
    return out / out.norm(dim=-1, keepdim=True)
