"""Planning the operated joint of an articulated object through the simulator: ``optimize_joint_torques``.

The articulated counterpart of :func:`~dexmots_rl.trajectories.optimize_wrenches` (paper §4), for the
objects of :mod:`dexmots_rl.assets.objects`: the object alone (:class:`~dexmots_rl.sim.ObjectSimulator`) with its
base held where it stands (a free base is planned as fixed: the hand holds it), its other joints free under
their springs, damping and friction, and one generalised force on the operated joint: a torque about a hinge's
axis (a couple on the part and its parent) or a force along a slide. The force sequence is optimised by Adam
through the simulator to track a linear ramp of the joint from ``start`` to ``goal`` (then held), so the plan's
force includes what the spring, damping, friction, the range stops and the part's inertia need.

Row ``t`` of the returned :class:`PoseWrenchTrajectory` holds the simulated joint at time ``t·dt`` and the
force of the step that ended there (row 0 repeats row 1), ``joint_q`` / ``joint_torque`` of the operated
joint, the base's pose (held) and a zero net wrench on the base; tasks read it with ``references=``.

Example:
    >>> from dexmots_rl.trajectories.joint_planner import optimize_joint_torques
    >>> plan = optimize_joint_torques("drawer_a", "drawer", start=0.0, goal=0.05, steps=10, iterations=5,
    ...                               progress=False)
    >>> plan.trajectory.horizon, plan.final_error < plan.initial_error
    (11, True)
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import torch

from .planner import PlanResult, _as_batch, _tracking_error, interpolate_reference
from .trajectory import PoseWrenchTrajectory

__all__ = ["held_tree", "optimize_joint_torques"]

log = logging.getLogger(__name__)


def held_tree(tree):
    """``tree`` with its base fixed where it starts (a free base's initial pose becomes the fixed offset)."""
    if not tree.free:
        return tree
    return dataclasses.replace(tree, free=False, q0=np.asarray(tree.q0[7:], dtype=np.float64))


def _tree_of(obj):
    from ..sim import load_object_tree

    if hasattr(obj, "tree"):  # an ArticulatedScene (a task's scene)
        return obj.tree
    if hasattr(obj, "joint_names"):  # an ObjectTree
        return obj
    from ..assets.objects import load_object

    return load_object_tree(load_object(obj) if isinstance(obj, str) else obj)[0]


def optimize_joint_torques(obj, joint: str, start, goal, steps: int, *, iterations: int = 200, lr: float | None = None,
                           max_grad_norm: float = 10.0, params: dict | None = None, substeps: int = 16,
                           dtype: torch.dtype = torch.float32, progress: bool = True) -> PlanResult:
    """Plan the force on joint ``joint`` of ``obj`` (a library name, an :class:`ObjectAsset`, an
    :class:`ObjectTree` or a task's articulated scene) that moves it from ``start`` to ``goal`` (each a float
    or ``[N]`` for N plans at once) in ``steps`` env steps; ``lr`` in N m (or N) per iteration, decayed
    linearly to 5 % (default: a tenth of the largest quasi-static force, at least 1e-3); ``params``: named
    joint parameters (``"<joint>/damping"``, ...) per plan."""
    from .joint_law import part_torque
    from ..sim import ObjectSimulator

    if steps < 1 or iterations < 0:
        raise ValueError(f"steps must be >= 1 and iterations >= 0, got steps={steps}, iterations={iterations}")
    tree = held_tree(_tree_of(obj))
    if joint not in tree.joint_names:
        raise ValueError(f"joint {joint!r} is not a joint of the object; its joints: {tree.joint_names}")
    j = tree.joint_names.index(joint)
    start = _as_batch("start", start, 1, dtype)
    goal = _as_batch("goal", goal, 1, dtype)
    _check_in_range(tree, j, start=start, goal=goal)
    start, goal = (t.contiguous() for t in torch.broadcast_tensors(start, goal))
    n, body = start.shape[0], j + 1
    sim = ObjectSimulator(tree, n, dtype=dtype, substeps=substeps)
    named = sim.default_params()
    for name, value in (params or {}).items():
        if name not in named.keys():
            raise ValueError(f"params: {name!r} is not a parameter of this object ({', '.join(named.keys())})")
        named.set(name, torch.as_tensor(value, dtype=dtype).reshape(-1, 1).expand(n, 1).contiguous())
    # the joint's axis in the world: fixed while the parts between it and the held base do not move
    rot = np.eye(3)
    chain, k = [], body
    while k >= 0:
        chain.append(k)
        k = int(tree.parent[k])
    for k in reversed(chain):
        rot = rot @ tree.offset_rot[k]
    axis = torch.as_tensor(rot @ tree.joint_axis[j], dtype=dtype)
    parent = int(tree.parent[body])
    slide = _is_slide(tree, j)
    q0, qd0 = sim.initial_state()
    q0[:, j] = start[:, 0]
    reference = interpolate_reference(start, goal, steps, free_body=False)

    def body_wrench(u: torch.Tensor) -> torch.Tensor:
        """[N, B, 6]: the joint's force as a couple (hinge) or an axial force (slide) on the part, the reaction on
        its parent (a slide's reaction acts at the parent's com: exact for a held base, whose motion is zero)."""
        wrench = torch.zeros(n, tree.num_bodies, 6, dtype=dtype)
        lane = slice(0, 3) if slide else slice(3, 6)
        wrench[:, body, lane] = u * axis
        wrench[:, parent, lane] = -u * axis
        return wrench

    def simulate(u: torch.Tensor) -> torch.Tensor:
        q, qd, qs = q0, qd0, []
        for t in range(steps):
            q, qd = sim.step(q, qd, named, body_wrench(u[:, t]))
            qs.append(q[:, j:j + 1])
        return torch.stack(qs, 1)

    def error(u: torch.Tensor) -> torch.Tensor:
        return _tracking_error(simulate(u), reference[:, 1:], False, 1.0)

    hold = torch.zeros(n, steps, 1, dtype=dtype)
    values = named.to_dict()
    nominal = [values[f"{joint}/{p}"].reshape(n, 1, 1) for p in ("damping", "friction", "stiffness", "rest")]
    speed = (reference[:, 1:] - reference[:, :-1]) / sim.dt
    guess = part_torque(speed, reference[:, 1:], nominal).detach()
    lr = lr if lr is not None else max(0.1 * float(guess.abs().max()), 1e-3)
    force = guess.clone().requires_grad_(True)
    opt = torch.optim.Adam([force], lr=lr)
    decay = torch.optim.lr_scheduler.LambdaLR(opt, lambda i: 1.0 - 0.95 * i / max(iterations, 1))
    history: list[float] = []
    from ..progress import progress_bar

    bar = progress_bar(range(iterations), desc="optimize_joint_torques", disable=not progress, leave=False)
    for _ in bar:
        opt.zero_grad()
        loss = error(force).mean()
        loss.backward()
        torch.nn.utils.clip_grad_norm_([force], max_grad_norm)
        opt.step()
        decay.step()
        history.append(loss.item())
        bar.set_postfix(error=f"{history[-1]:.4g}")
    with torch.no_grad():
        initial = error(hold).mean().item()
        final_q = simulate(force)
        final = _tracking_error(final_q, reference[:, 1:], False, 1.0).mean().item()
    log.info("optimize_joint_torques: tracking error %.4g -> %.4g in %d iterations", initial, final, iterations)
    base = torch.as_tensor(tree.offset_pos[0], dtype=dtype)
    quat = torch.as_tensor(_quat(tree.offset_rot[0]), dtype=dtype)
    plans = []
    for w in range(n):
        joint_q = torch.cat([start[w:w + 1], final_q[w]], 0)
        torque = torch.cat([force[w, :1], force[w]], 0).detach()
        rows = steps + 1
        plans.append(PoseWrenchTrajectory(base.expand(rows, 3).contiguous(), quat.expand(rows, 4).contiguous(),
                                          torch.zeros(rows, 6, dtype=dtype), dt=sim.dt,
                                          joint_q=joint_q.contiguous(), joint_torque=torque.contiguous()))
    return PlanResult(plans, history, initial, final, reference.detach())


def _is_slide(tree, j: int) -> bool:
    from ..sim import SLIDE

    return int(tree.joint_kind[j]) == SLIDE


def _check_in_range(tree, j: int, **positions: torch.Tensor) -> None:
    """``ValueError`` naming the first of ``positions`` outside joint ``j``'s range (a range of [0, 0] is
    MuJoCo's unlimited joint): no force can hold a joint past its stops."""
    lo, hi = (float(v) for v in tree.joint_range[j])
    if lo >= hi:
        return
    unit = "m" if _is_slide(tree, j) else "rad"
    for name, values in positions.items():
        outside = [float(v) for v in values.flatten() if not lo <= float(v) <= hi]
        if outside:
            raise ValueError(f"{name} {outside[0]:g} is outside the range of joint {tree.joint_names[j]!r}: "
                             f"[{lo:g}, {hi:g}] {unit}")


def _quat(rot) -> np.ndarray:
    import mujoco

    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.asarray(rot, dtype=np.float64).ravel())
    return quat
