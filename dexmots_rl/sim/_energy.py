"""The object's mechanical energy from its state, in torch (an independent check of the kernels' physics).

:func:`tree_kinematics` runs the forward kinematics of an articulated object (sim/_object_model.py) from its
generalized coordinates and velocities; :func:`tree_energy` sums, over every body, the kinetic energy of its
com's translation and of its rotation about the com, plus gravity's potential, plus each part joint's rotor
inertia (armature) and spring (``0.5 k (q - rest)^2``). :func:`scene_object_energy` does the same for the
one-body object of a knob or cube scene (sim/_model.py). Neither reads a kernel: what the simulator integrates
is checked against what these compute (tests/test_articulated.py, benchmarks/energy.py).

Contact and range-stop penalties store some energy too; it is left out (it is small, and any energy a
contact injects shows up as kinetic or potential energy of the bodies).

Example:
    >>> import torch
    >>> from dexmots_rl.sim._energy import rotation_about
    >>> rotation_about(torch.tensor([0.0, 0.0, 1.0]), torch.tensor([0.0])).shape
    torch.Size([1, 3, 3])
"""

from __future__ import annotations

import torch

from ..quaternions import quat_to_matrix
from ._model import OBJECT_HINGE, SceneModel
from ._object_model import HINGE, ObjectTree

__all__ = ["rotation_about", "tree_kinematics", "tree_energy", "scene_object_energy"]


def rotation_about(axis: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """Rotation matrices [N, 3, 3] by ``angle`` [N] about the unit ``axis`` [3] (Rodrigues)."""
    a = axis.to(angle.dtype)
    skew = torch.zeros(3, 3, dtype=angle.dtype, device=angle.device)
    skew[0, 1], skew[0, 2], skew[1, 2] = -a[2], a[1], -a[0]
    skew = skew - skew.T
    c, s = torch.cos(angle)[:, None, None], torch.sin(angle)[:, None, None]
    eye = torch.eye(3, dtype=angle.dtype, device=angle.device)
    return c * eye + s * skew + (1 - c) * torch.outer(a, a)


def _mv(R: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """[N, 3, 3] x [N or 1, 3] -> [N, 3]."""
    return (R @ x.unsqueeze(-1)).squeeze(-1)


def tree_kinematics(tree: ObjectTree, q: torch.Tensor, qd: torch.Tensor):
    """Every body's origin, rotation (body -> world), com, com velocity and angular velocity (world), each
    ``[N, B, ...]``, from the object's coordinates ``q`` [N, nq] and velocities ``qd`` [N, nv] (the layout of
    :class:`~dexmots_rl.sim._object_model.ObjectTree`: a free base's position, wxyz quaternion, linear velocity of
    its origin and angular velocity, then one coordinate per part joint)."""
    n, dtype, dev = q.shape[0], q.dtype, q.device

    def t(x):
        return torch.as_tensor(x, dtype=dtype, device=dev)

    if tree.free:
        x0, R0 = q[:, :3], quat_to_matrix(q[:, 3:7])
        v0, w0 = qd[:, :3], qd[:, 3:6]  # the origin's velocity
    else:
        x0, R0 = t(tree.offset_pos[0]).expand(n, 3), t(tree.offset_rot[0]).expand(n, 3, 3)
        v0 = w0 = torch.zeros(n, 3, dtype=dtype, device=dev)
    qo, vo = 7 * tree.free, 6 * tree.free
    xs, Rs, vs, ws = [x0], [R0], [v0], [w0]  # vs: velocity of each body's origin
    for b in range(1, tree.num_bodies):
        p, k = int(tree.parent[b]), b - 1
        axis, anchor = t(tree.joint_axis[k]), t(tree.joint_anchor[k])
        xp, Rp, vp, wp_ = xs[p], Rs[p], vs[p], ws[p]
        R_zero = Rp @ t(tree.offset_rot[b])  # the part's rotation at joint 0
        a = _mv(R_zero, axis)  # the joint axis, world
        o = xp + _mv(Rp, t(tree.offset_pos[b])) + _mv(R_zero, anchor)  # the joint's anchor, fixed in the parent
        v_o = vp + torch.cross(wp_, o - xp, dim=-1)
        qk, qdk = q[:, qo + k], qd[:, vo + k]
        if int(tree.joint_kind[k]) == HINGE:
            R = R_zero @ rotation_about(axis, qk)
            x = o - _mv(R, anchor)
            w = wp_ + a * qdk[:, None]
            v = v_o + torch.cross(w, x - o, dim=-1)
        else:  # a slide along the parent-fixed axis
            R = R_zero
            x = o - _mv(R, anchor) + a * qk[:, None]
            w = wp_
            v = v_o + torch.cross(wp_, x - o, dim=-1) + a * qdk[:, None]
        xs.append(x)
        Rs.append(R)
        vs.append(v)
        ws.append(w)
    x, R, v_origin, w = (torch.stack(a, 1) for a in (xs, Rs, vs, ws))
    com_offset = _mv(R.reshape(-1, 3, 3), t(tree.com).repeat(n, 1)).view(n, -1, 3)
    return x, R, x + com_offset, v_origin + torch.cross(w, com_offset, dim=-1), w


def tree_energy(tree: ObjectTree, q: torch.Tensor, qd: torch.Tensor, stiffness: torch.Tensor | None = None,
                rest: torch.Tensor | None = None, gravity=(0.0, 0.0, -9.81)) -> torch.Tensor:
    """[N] J: kinetic energy of every body (com translation + rotation about the com) and of the part joints'
    armature, gravity's potential of every body (zero at the world origin), and the joint springs' potential.
    ``stiffness`` / ``rest`` [N, P] (default: the tree's) are the per-world joint parameters."""
    dtype, dev = q.dtype, q.device
    _, R, c, v, w = tree_kinematics(tree, q, qd)
    mass = torch.as_tensor(tree.mass, dtype=dtype, device=dev)
    inertia = R @ torch.as_tensor(tree.inertia, dtype=dtype, device=dev) @ R.transpose(-1, -2)
    kinetic = 0.5 * mass * (v * v).sum(-1) + 0.5 * (w * (inertia @ w.unsqueeze(-1)).squeeze(-1)).sum(-1)
    potential = -mass * (c @ torch.as_tensor(gravity, dtype=dtype, device=dev))
    energy = (kinetic + potential).sum(-1)
    if tree.num_parts:
        joint_q, joint_qd = q[:, 7 * tree.free:], qd[:, 6 * tree.free:]
        stiffness = torch.as_tensor(tree.joint_stiffness, dtype=dtype, device=dev) if stiffness is None else stiffness
        rest = torch.as_tensor(tree.joint_rest, dtype=dtype, device=dev) if rest is None else rest
        armature = torch.as_tensor(tree.armature, dtype=dtype, device=dev)
        energy = energy + (0.5 * armature * joint_qd**2 + 0.5 * stiffness * (joint_q - rest) ** 2).sum(-1)
    return energy


def scene_object_energy(scene: SceneModel, q: torch.Tensor, qd: torch.Tensor, stiffness: torch.Tensor | None = None,
                        rest: torch.Tensor | None = None) -> torch.Tensor:
    """[N] J: the kinetic, gravity and spring energy of a knob or cube scene's object, from its coordinates
    ``q`` [N, 1 or 7] and velocities ``qd`` [N, 1 or 6] (a free object's origin is its com; a hinge's inertia
    about its axis includes the armature). ``stiffness`` / ``rest`` [N, 1] default to the scene's."""
    dtype, dev = q.dtype, q.device

    def t(x):
        return torch.as_tensor(x, dtype=dtype, device=dev)

    mass, gravity = float(scene.object_mass), t(scene.gravity)
    if scene.object_kind == OBJECT_HINGE:
        axis, com, base_rot = t(scene.object_axis), t(scene.object_com), t(scene.object_base_rot)
        arm = torch.linalg.cross(axis, com)
        axial = float(axis @ t(scene.object_inertia) @ axis + mass * arm @ arm) + float(scene.object_armature)
        R = base_rot @ rotation_about(axis, q[:, 0])
        centre = t(scene.object_base_pos) + _mv(R, com.expand(q.shape[0], 3))
        stiffness = t(scene.object_stiffness) if stiffness is None else stiffness.reshape(-1)
        rest = t(scene.object_rest) if rest is None else rest.reshape(-1)
        return 0.5 * axial * qd[:, 0] ** 2 - mass * (centre @ gravity) + 0.5 * stiffness * (q[:, 0] - rest) ** 2
    R = quat_to_matrix(q[:, 3:7])
    inertia = R @ t(scene.object_inertia) @ R.transpose(-1, -2)
    v, w = qd[:, :3], qd[:, 3:6]
    spin = (w * (inertia @ w.unsqueeze(-1)).squeeze(-1)).sum(-1)
    return 0.5 * mass * (v * v).sum(-1) + 0.5 * spin - mass * (q[:, :3] @ gravity)
