"""Object-centric wrench planning through the simulator (paper §4): ``optimize_wrenches``.

The plan is made for the object alone. A reference of object configurations is interpolated from start to
goal (linear for positions and joint coordinates, slerp for rotations); the object is then simulated under
a sequence of external wrenches (the hand is present but has no contact: contact stiffness is zero) and
the wrenches are optimised by gradient descent through the simulator — Adam with gradient-norm clipping —
to minimise the mean tracking error ``mean_t ‖p̂_t − p̄_t‖``:

* 1-DoF articulation (the knob): ``|θ̂_t − θ̄_t|`` in rad; the variable is the torque about the hinge axis;
* free body (the cube): ``‖x̂_t − x̄_t‖ + L·angle(q̂_t, q̄_t)`` with ``L = length_scale`` metres per radian;
  the variable is the force and torque at the centre of mass (world frame).

Row ``t`` of the returned :class:`PoseWrenchTrajectory` is the *simulated* object state at time ``t·dt``
(so poses and wrenches are physically consistent) and the wrench that acted over the step that ended
there (row 0 repeats row 1): the env's ``("task", "step")`` counter indexes it directly. ``wrench`` holds
the external wrench the hand must supply (besides gravity, joint damping and friction); for a hinge
``joint_torque`` is its component about the axis.

Example:
    >>> from dexmots_rl.trajectories import optimize_wrenches
    >>> from dexmots_rl.assets import asset_path
    >>> plan = optimize_wrenches(asset_path("claw_screw.xml"), start=0.0, goal=0.5, steps=10, iterations=30,
    ...                          progress=False)
    >>> plan.trajectory.horizon, plan.final_error < plan.initial_error
    (11, True)
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import torch

from ..quaternions import quat_conjugate, quat_multiply, slerp
from .trajectory import PoseWrenchTrajectory

__all__ = ["PlanResult", "interpolate_reference", "optimize_wrenches"]

log = logging.getLogger(__name__)


@dataclasses.dataclass
class PlanResult:
    """What :func:`optimize_wrenches` returns: one trajectory per world, the loss per iteration, and the
    mean tracking error (object-configuration units, see the module docstring) before (holding the object
    still: zero wrench, plus the weight of a free body) and after."""

    trajectories: list[PoseWrenchTrajectory]
    loss_history: list[float]
    initial_error: float
    final_error: float
    reference: torch.Tensor  # [N, T+1, nq_object], the interpolated object configurations

    @property
    def trajectory(self) -> PoseWrenchTrajectory:
        return self.trajectories[0]


def interpolate_reference(start: torch.Tensor, goal: torch.Tensor, steps: int, free_body: bool) -> torch.Tensor:
    """Object configurations ``[N, steps+1, nq]`` from ``start`` to ``goal`` ``[N, nq]``: linear for joint
    coordinates and positions, slerp for a free body's quaternion (``nq = 7``: pos + wxyz quat)."""
    s = torch.linspace(0.0, 1.0, steps + 1, dtype=start.dtype, device=start.device).view(1, -1, 1)
    lin = start.unsqueeze(1) + s * (goal - start).unsqueeze(1)
    if not free_body:
        return lin
    quat = slerp(start[:, None, 3:7], goal[:, None, 3:7], s)
    return torch.cat([lin[..., :3], quat], -1)


def _scene_of(scene):
    from ..sim import SceneModel, load_scene

    if isinstance(scene, SceneModel):
        return scene
    if isinstance(scene, (str, Path)) and str(scene).endswith(".xml"):
        return load_scene(scene)
    raise ValueError(f"scene must be a SceneModel or an MJCF path, got {scene!r} (a task's scene: "
                     "dexmots_rl.envs.task_scene(name))")


def _as_batch(name: str, x, nq: int, dtype) -> torch.Tensor:
    t = torch.as_tensor(x, dtype=dtype)
    if t.dim() < 2 and t.numel() % nq == 0:
        t = t.reshape(-1, nq)
    if t.dim() != 2 or t.shape[-1] != nq:
        raise ValueError(f"{name} must hold {nq} object coordinates per world, got shape {tuple(t.shape)}")
    if not torch.isfinite(t).all():
        raise ValueError(f"{name} must be finite")
    return t


def _tracking_error(q: torch.Tensor, ref: torch.Tensor, free_body: bool, length_scale: float) -> torch.Tensor:
    """Per world and step ``[N, T]``; smooth at zero (the sqrt has a floor) so its gradient is defined."""
    if not free_body:
        return torch.sqrt((q - ref).square().sum(-1) + 1e-12)
    pos = torch.sqrt((q[..., :3] - ref[..., :3]).square().sum(-1) + 1e-12)
    rel = quat_multiply(quat_conjugate(ref[..., 3:7]), q[..., 3:7])
    angle = 2.0 * torch.atan2(torch.sqrt(rel[..., 1:].square().sum(-1) + 1e-12), rel[..., 0].abs())
    return pos + length_scale * angle


def optimize_wrenches(
    task,
    start,
    goal,
    steps: int,
    *,
    iterations: int = 200,
    lr: float = 0.5,
    max_grad_norm: float = 10.0,
    params: dict | None = None,
    substeps: int = 16,
    dt: float | None = None,
    length_scale: float = 0.1,
    dtype: torch.dtype = torch.float32,
    progress: bool = True,
) -> PlanResult:
    """Plan the wrenches that move the object alone from ``start`` to ``goal`` in ``steps`` env steps.

    Args:
        task: the scene, a :class:`~dexmots_rl.sim.SceneModel` or an MJCF path (a registered task's:
            :func:`dexmots_rl.envs.task_scene`).
        start, goal: object coordinates, ``[nq]`` or ``[N, nq]`` for N plans at once (a hinge: the angle;
            a free body: pos + wxyz quat).
        steps: env steps T of the plan (the trajectory has T + 1 rows).
        iterations: Adam iterations; ``lr`` (N, N·m per iteration, decayed linearly to 5%);
            ``max_grad_norm`` clips the gradient of each iteration.
        params: named object parameters (``{"joint_damping": [N] or scalar, ...}``, any of the scene's
            :attr:`~dexmots_rl.sim.SceneModel.param_names`) per plan; the rest are the MJCF's.
        dt: env step (default: the MJCF timestep × ``substeps``, the envs' default).
    """
    from ..sim import Control, ContactParams, Simulator

    if steps < 1 or iterations < 0:
        raise ValueError(f"steps must be >= 1 and iterations >= 0, got steps={steps}, iterations={iterations}")
    scene = _scene_of(task)
    free_body = not scene.articulated
    nq = scene.object_nq
    start = _as_batch("start", start, nq, dtype)
    goal = _as_batch("goal", goal, nq, dtype)
    if start.shape[0] != goal.shape[0]:
        start, goal = torch.broadcast_tensors(start, goal)
        start, goal = start.contiguous(), goal.contiguous()
    n = start.shape[0]
    # no contact: the hand cannot touch the object, so the object moves under the planned wrench alone
    sim = Simulator(scene, n, dtype=dtype, substeps=substeps, dt=dt, contact=ContactParams(stiffness=0.0, friction=0.0))
    named = sim.default_params()
    for name, value in (params or {}).items():
        if name not in named.keys():
            raise ValueError(f"params: {name!r} is not a parameter of this scene ({', '.join(named.keys())})")
        named.set(name, torch.as_tensor(value, dtype=dtype).reshape(-1, 1).expand(n, 1).contiguous())
    params = named
    reference = interpolate_reference(start, goal, steps, free_body)
    q0, qd0 = sim.initial_state()
    q0 = q0.clone()
    q0[:, sim.nu:] = start
    axis = torch.as_tensor(scene.object_base_rot @ scene.object_axis, dtype=dtype)
    # decision variables: the hinge torque [N, T, 1] or the free body's force + torque [N, T, 6]
    # start from holding the object still: a free body's weight is carried (a vertical hinge needs nothing)
    hold_still = torch.zeros(n, steps, 6 if free_body else 1, dtype=dtype)
    if free_body:
        hold_still[..., :3] = -scene.object_mass * torch.as_tensor(scene.gravity, dtype=dtype)
    wrench_var = hold_still.clone().requires_grad_(True)
    hold = torch.zeros(n, sim.nu, dtype=dtype)
    control_base = Control(hold, hold, hold, hold)

    def to_wrench(u: torch.Tensor) -> torch.Tensor:
        if free_body:
            return u
        return torch.cat([torch.zeros_like(u).expand(*u.shape[:-1], 3), u * axis], -1)

    def simulate(u: torch.Tensor) -> torch.Tensor:
        q, qd, qs = q0, qd0, []
        for t in range(steps):
            ctrl = dataclasses.replace(control_base, object_wrench=to_wrench(u[:, t]))
            out = sim.step(q, qd, ctrl, params)
            q, qd = out.joint_q, out.joint_qd
            qs.append(q[:, sim.nu:])
        return torch.stack(qs, 1)

    def error(u: torch.Tensor) -> torch.Tensor:
        return _tracking_error(simulate(u), reference[:, 1:], free_body, length_scale)

    opt = torch.optim.Adam([wrench_var], lr=lr)
    # linear decay to 5% of lr: late iterations refine instead of oscillating around the optimum
    decay = torch.optim.lr_scheduler.LambdaLR(opt, lambda i: 1.0 - 0.95 * i / max(iterations, 1))
    history: list[float] = []
    from ..progress import progress_bar

    bar = progress_bar(range(iterations), desc="optimize_wrenches", disable=not progress, leave=False)
    for _ in bar:
        opt.zero_grad()
        loss = error(wrench_var).mean()
        loss.backward()
        torch.nn.utils.clip_grad_norm_([wrench_var], max_grad_norm)
        opt.step()
        decay.step()
        history.append(loss.item())
        bar.set_postfix(error=f"{history[-1]:.4g}")
    with torch.no_grad():
        initial = error(hold_still).mean().item()
        final_q = simulate(wrench_var)
        final = _tracking_error(final_q, reference[:, 1:], free_body, length_scale).mean().item()
    log.info("optimize_wrenches: tracking error %.4g -> %.4g in %d iterations", initial, final, iterations)
    return PlanResult(_trajectories(scene, sim, q0, final_q, to_wrench(wrench_var.detach()), wrench_var.detach(),
                                    free_body), history, initial, final, reference.detach())


def _trajectories(scene, sim, q0, qs, wrenches, u, free_body) -> list[PoseWrenchTrajectory]:
    """Rows t = 0..T: simulated object state at time t and the wrench of the step ending there."""
    n, steps = qs.shape[:2]
    obj = torch.cat([q0[:, sim.nu:].unsqueeze(1), qs], 1)  # [N, T+1, nq]
    wrench = torch.cat([wrenches[:, :1], wrenches], 1)
    full_q = q0.unsqueeze(1).expand(n, steps + 1, sim.nq).clone()
    full_q[..., sim.nu:] = obj
    poses = sim.observe(full_q.reshape(-1, sim.nq))[0][:, -1].view(n, steps + 1, 7)
    out = []
    for w in range(n):
        if free_body:
            joint_q = joint_torque = obj.new_zeros(steps + 1, 0)
        else:
            joint_q = obj[w]
            joint_torque = torch.cat([u[w, :1], u[w]], 0)
        out.append(PoseWrenchTrajectory(poses[w, :, :3].contiguous(), _unit(poses[w, :, 3:]), wrench[w].contiguous(),
                                        dt=sim.dt, joint_q=joint_q.contiguous(), joint_torque=joint_torque.contiguous()))
    return out


def _unit(q: torch.Tensor) -> torch.Tensor:
    return (q / q.norm(dim=-1, keepdim=True)).contiguous()

