"""Gradient quality: autodiff through a task's simulator step against central finite differences, in float64.

Every task with bench poses runs: the knob and cube scenes (:class:`~dexmots_rl.sim.Simulator`) and the
articulated objects (``operate`` and the tool tasks, :class:`~dexmots_rl.sim.ArticulatedSimulator`, whose poses
come from the task's pre-grasps, :mod:`dexmots_rl.envs.tasks.allegro.operate_bench`). For each horizon H and
contact case, a rollout of H env steps with ``Control.tau = action * gear`` from the task's touching pose
(``contact=True``: its squeezing action plus noise) or its pose far from the object (``contact=False``: its
release action, if any, plus noise) gives a scalar loss

    pose loss:      L = 1/H * sum_t [(theta_t - theta*)^2 + sum_f |p_{f,t} - c_t|^2 + B_t] + (theta_H - theta*)^2
    velocity loss:  L = (omega_H - omega*)^2 + 0.01 * |qd_hand,H|^2 + V_H

(theta: the operated joint (the knob's angle; a tool's operated hinge or slide), theta* its goal (the knob:
``GOAL_ANGLE``); p_f: fingertips; c_t: the operated part's origin (the knob: the object's); omega: the joint's
velocity, omega* its goal speed (the knob: ``GOAL_SPEED``). A free base is held where it stands, each deviation
divided by the task's tolerance (s m, r rad): B_t = (|x_t - x_0| / s)^2 + (2 |quat_t - quat_0| / r)^2 (twice the
quaternion difference is the tilt for small turns) and V_H = (|v_H| / s)^2 + (|w_H| / r)^2 (per second), so the
gradient also flows through the base's contact with the table. Both losses are reported: a position loss weighs
early actions more than late ones simply because a torque moves every later position (~H^2 growth without any
contact), while a final-velocity loss has no such lever, so its grad_growth isolates amplification by the
dynamics. dL/da is compared on a random subset of the H x nu action entries with
``(L(a + eps e) - L(a - eps e)) / 2 eps``. Each row runs ``draws`` random action sequences; the nominal rollouts
and every perturbed one are worlds of one batched simulator (worlds are independent).

rel_err = |ad - fd| / max(|fd|, floor_rel * max|dL/da|), pooled over draws; grad_growth =
max_t |dL/da_t| / |dL/da_{H-1}|, the median over draws (``grad_growth_max``: the worst draw). The ratio
hangs on one number, the last action's effect, which is small whenever the fingers are about to leave
the knob at the last step, so a single draw says little; ``growth_per_step`` = exp(slope of
log |dL/da_t| against steps to go), median over draws, is the per-step amplification backward in time
(1.0: none; Newton's Featherstone solver measured ~10 on the claw). grad_growth_vs_free divides
grad_growth by the contact-free row's at the same H (for the pose loss that is the lever arm of early
actions on later positions, ~H^2, not an instability). The goal (grad_growth <= 10 at the longest
horizon) is judged on the velocity loss, which isolates amplification by the dynamics.
"""

from __future__ import annotations

import dataclasses
import logging
import math

import torch

from .bench_setup import bench_env

__all__ = ["GOAL_ANGLE", "GOAL_SPEED", "NOISE", "LossTarget", "growth_per_step", "loss_rollout", "grad_row", "run_grad"]

log = logging.getLogger(__name__)

GOAL_ANGLE = math.pi / 4  # within screw_claw's goal range
GOAL_SPEED = 1.0  # rad/s, for the velocity loss
LOSSES = ("pose", "velocity")
NOISE = 0.2  # amplitude of the uniform action noise
HAND_SPEED_WEIGHT = 0.01  # of |qd_hand|^2 in the velocity loss


@dataclasses.dataclass(frozen=True)
class LossTarget:
    """Where the loss reads a simulator's state: the operated joint's coordinate in ``joint_q`` and
    ``joint_qd``, its goal and goal speed, the body whose origin the fingertips are drawn to (None: the
    scene's fixed object origin ``centre``), and a free base's tolerances (None: no base term)."""

    q_index: int
    qd_index: int
    goal: float
    goal_speed: float
    part_body: int | None
    centre: tuple[float, ...] | None
    base_tolerance: tuple[float, float] | None

    @classmethod
    def of(cls, sim, poses) -> "LossTarget":
        """The target of ``poses`` (:class:`~dexmots_rl.envs.BenchPoses`) in ``sim``'s state layout."""
        nu, j = sim.nu, poses.joint
        goal = GOAL_ANGLE if poses.goal is None else poses.goal
        speed = GOAL_SPEED if poses.goal_speed is None else poses.goal_speed
        if sim.object_tree is not None:  # q: hand, then the base's pose if free, then the joints
            free = int(sim.object_tree.free)
            tolerance = poses.base_tolerance if free else None
            # body_pose: the hand's links, the base, then one body per joint
            return cls(nu + 7 * free + j, nu + 6 * free + j, goal, speed, nu + 1 + j, None, tolerance)
        centre = tuple(float(x) for x in sim.scene.object_base_pos)
        return cls(nu + j, nu + j, goal, speed, None, centre, None)


def _base_deviation(q, qd, q0, nu: int, tolerance) -> tuple[torch.Tensor, torch.Tensor]:
    """A free base's (pose term B [W], velocity term V [W]) of the module docstring."""
    shift, tilt = tolerance
    pose = ((q[:, nu:nu + 3] - q0[:, nu:nu + 3]) ** 2).sum(-1) / shift**2 \
        + (2.0 / tilt) ** 2 * ((q[:, nu + 3:nu + 7] - q0[:, nu + 3:nu + 7]) ** 2).sum(-1)
    speed = (qd[:, nu:nu + 3] ** 2).sum(-1) / shift**2 + (qd[:, nu + 3:nu + 6] ** 2).sum(-1) / tilt**2
    return pose, speed


def growth_per_step(norms: torch.Tensor) -> torch.Tensor:
    """The per-step amplification backward in time of gradient norms ``[..., H]`` (``norms[..., t]``:
    ``|dL/da_t|``): exp of the least-squares slope of their log against steps to go (1.0: none)."""
    horizon = norms.shape[-1]
    to_go = torch.arange(horizon - 1, -1, -1, dtype=torch.float64)
    x = to_go - to_go.mean()  # centred, so the least-squares slope needs no centring of the logs
    return ((norms.double().log() * x).sum(-1) / (x * x).sum().clamp_min(1e-12)).exp()


def loss_rollout(sim, q0: torch.Tensor, actions: torch.Tensor, target: LossTarget, kind: str = "pose"):
    """Roll ``actions`` [H, W, nu] out from ``q0`` [W, nq] at rest; returns (loss [W] of kind ``kind``,
    contact_force [H, W]) (the module docstring defines both losses)."""
    from ..sim import Control

    opts = dict(dtype=sim.dtype, device=sim.torch_device)
    gear = torch.as_tensor(sim.scene.actuator_gear, **opts)
    centre = None if target.centre is None else torch.as_tensor(target.centre, **opts)
    zero = torch.zeros(q0.shape[0], sim.nu, **opts)
    params = sim.default_params()
    q, qd = q0, torch.zeros(q0.shape[0], sim.nv, **opts)
    running, forces = 0.0, []
    for a in actions:
        out = sim.step(q, qd, Control(a * gear, zero, zero, zero), params)
        q, qd = out.joint_q, out.joint_qd
        angle_err = (q[:, target.q_index] - target.goal) ** 2
        part = centre if target.part_body is None else out.body_pose[:, target.part_body, :3].unsqueeze(1)
        running = running + angle_err + ((out.fingertips - part) ** 2).sum((-1, -2))
        if target.base_tolerance is not None:
            running = running + _base_deviation(q, qd, q0, sim.nu, target.base_tolerance)[0]
        forces.append(out.contact_force.detach())
    if kind == "velocity":
        loss = (qd[:, target.qd_index] - target.goal_speed) ** 2 + HAND_SPEED_WEIGHT * (qd[:, :sim.nu] ** 2).sum(-1)
        if target.base_tolerance is not None:
            loss = loss + _base_deviation(q, qd, q0, sim.nu, target.base_tolerance)[1]
        return loss, torch.stack(forces)
    return running / len(actions) + angle_err, torch.stack(forces)


def grad_row(scene, poses, horizon: int, contact: bool, eps: float, num_entries: int, floor_rel: float,
             generator: torch.Generator, device: str = "cpu", loss_kind: str = "pose", draws: int = 8,
             law=None) -> dict:
    """One row of the gradient benchmark (see the module docstring) on ``scene`` with the task's ``poses``
    (:class:`~dexmots_rl.envs.BenchPoses`), over ``draws`` random action sequences simulated side by side:
    draw d owns worlds ``d * (1 + 2k) ...`` (nominal, then +eps/-eps per checked entry). ``law``: the task's
    ContactParams (None: the defaults, the claw's)."""
    from ..sim import make_simulator

    nu = scene.num_hand_dofs
    k = min(num_entries, horizon * nu)
    per_draw = 1 + 2 * k
    sim = make_simulator(scene, num_worlds=draws * per_draw, device=device, dtype=torch.float64, contact=law)
    target = LossTarget.of(sim, poses)
    opts = dict(dtype=torch.float64, device=sim.torch_device)
    action = poses.squeeze_action if contact else poses.release_action or (0.0,) * nu
    base = torch.tensor(action, dtype=torch.float64)
    entries = torch.stack([torch.randperm(horizon * nu, generator=generator)[:k] for _ in range(draws)])  # [D, k]
    base = base + NOISE * (2 * torch.rand(draws, horizon, nu, generator=generator, dtype=torch.float64) - 1)
    delta = torch.zeros(draws, per_draw, horizon, nu, dtype=torch.float64)
    t_idx, j_idx = entries // nu, entries % nu
    d_idx, w = torch.arange(draws)[:, None].expand(-1, k), torch.arange(k)[None].expand(draws, -1)
    delta[d_idx, 1 + 2 * w, t_idx, j_idx] = eps
    delta[d_idx, 2 + 2 * w, t_idx, j_idx] = -eps
    actions = (base[:, None] + delta).reshape(-1, horizon, nu).transpose(0, 1).to(**opts).requires_grad_(True)
    q0 = torch.tensor(poses.touch_q if contact else poses.free_q, **opts).expand(sim.num_worlds, sim.nq).contiguous()

    loss, forces = loss_rollout(sim, q0, actions, target, loss_kind)
    loss.view(draws, per_draw)[:, 0].sum().backward()  # worlds are independent: one backward for all draws
    ad_full = actions.grad.detach().cpu().view(horizon, draws, per_draw, nu)[:, :, 0].transpose(0, 1)  # [D, H, nu]
    loss = loss.detach().cpu().view(draws, per_draw)
    fd = (loss[:, 1::2] - loss[:, 2::2]) / (2 * eps)  # [D, k]
    ad = ad_full[d_idx, t_idx, j_idx]
    floor = (floor_rel * ad_full.flatten(1).abs().amax(1, keepdim=True)).clamp_min(torch.finfo(torch.float64).tiny)
    rel = (ad - fd).abs() / torch.maximum(fd.abs(), floor)
    norms = ad_full.norm(dim=2)  # [D, H]
    growth = norms.amax(1) / norms[:, -1]
    contact_fraction = (forces.cpu().view(horizon, draws, per_draw)[:, :, 0] > 0).double().mean().item()
    if contact != (contact_fraction > 0):
        log.warning("H=%d contact=%s: contact force > 0 on %.0f%% of the steps", horizon, contact,
                    100 * contact_fraction)
    return {
        "loss_kind": loss_kind,
        "horizon": horizon,
        "contact": contact,
        "draws": draws,
        "median_rel_err": rel.median().item(),
        "max_rel_err": rel.max().item(),
        "grad_growth": growth.median().item(),  # median over draws
        "grad_growth_max": growth.max().item(),  # worst draw
        "growth_per_step": growth_per_step(norms).median().item(),
        "contact_fraction": contact_fraction,
        "loss": loss[:, 0].mean().item(),
        "grad_norm": ad_full.flatten(1).norm(dim=1).median().item(),
    }


def run_grad(task: str = "screw_claw", horizons=(1, 8, 32), eps: float = 1e-6, num_entries: int = 16,
             floor_rel: float = 1e-3, seed: int = 0, device: str = "cpu", draws: int = 8,
             object_name: str | None = None) -> dict:
    """All rows; returns the result dict printed by ``dexmots-bench grad``. ``object_name``: the object of a
    task that operates one (``operate``, the tool tasks; None: the task's own)."""
    env = bench_env(task, **({} if object_name is None else {"object": object_name}))
    poses, scene, law = env.bench_poses(), env.sim.scene, env.sim.contact
    target = LossTarget.of(env.sim, poses)
    generator = torch.Generator().manual_seed(seed)
    rows = []
    log.info("grad: the first row compiles the float64 kernels when not cached")
    for loss_kind in LOSSES:
        for horizon in horizons:
            for contact in (True, False):
                rows.append(grad_row(scene, poses, horizon, contact, eps, num_entries, floor_rel, generator,
                                     device, loss_kind, draws, law))
                log.info("grad: %s", rows[-1])
            # growth of a free (contact-less) rollout is the baseline: a position loss on a second-order
            # system already weighs early actions ~H^2 more than the last one
            free = rows[-1]["grad_growth"]
            for row in rows[-2:]:
                row["grad_growth_vs_free"] = row["grad_growth"] / free
    base = "B_t = (|x_t-x_0|/s)^2 + (2|quat_t-quat_0|/r)^2, " if target.base_tolerance else ""
    result = {"task": task, "precision": "float64", "eps": eps, "floor_rel": floor_rel, "num_entries": num_entries,
              "seed": seed, "draws": draws, "loss_definition": {
                  "pose": f"mean_t[(theta_t-theta*)^2 + sum_f |tip_f,t - part_t|^2{' + B_t' if base else ''}]"
                          " + (theta_H-theta*)^2" + (f"; {base.rstrip(', ')}" if base else ""),
                  "velocity": "(omega_H-omega*)^2 + 0.01 |qd_hand,H|^2"
                              + (" + (|v_H|/s)^2 + (|w_H|/r)^2" if base else "")},
              "goal_angle": target.goal, "goal_speed": target.goal_speed, "rows": rows}
    if target.part_body is not None:  # an articulated object: which one, its operated joint, its base
        result.update(object=getattr(env.config, "object", None), joint=env.sim.tree.joint_names[poses.joint],
                      free_base=bool(env.sim.tree.free), base_tolerance=target.base_tolerance)
    return result
