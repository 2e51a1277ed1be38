"""Gradient quality: autodiff through ``Simulator.step`` against central finite differences, in float64.

For each horizon H and contact case, a rollout of H env steps with ``Control.tau = action * gear`` from
the task's touching pose (``contact=True``: squeezing action plus noise) or its open pose far from the
object (``contact=False``: noise only) gives a scalar loss

    pose loss:      L = 1/H * sum_t [(theta_t - theta*)^2 + sum_f |p_{f,t} - c|^2] + (theta_H - theta*)^2
    velocity loss:  L = (omega_H - omega*)^2 + 0.01 * |qd_hand,H|^2

(theta: object angle, theta* = ``GOAL_ANGLE``; p_f: fingertips; c: the object's origin; omega: object
angular velocity, omega* = ``GOAL_SPEED``). Both are reported: a position loss weighs early actions more
than late ones simply because a torque moves every later position (~H^2 growth without any contact),
while a final-velocity loss has no such lever, so its grad_growth isolates amplification by the dynamics. dL/da is
compared on a random subset of the H x nu action entries with ``(L(a + eps e) - L(a - eps e)) / 2 eps``.
Each row runs ``draws`` random action sequences; the nominal rollouts and every perturbed one are
worlds of one batched simulator (worlds are independent).

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

import logging
import math

import torch

from ..envs import task_contact
from .bench_setup import bench_task, load_task_scene

__all__ = ["GOAL_ANGLE", "NOISE", "hinge_loss_rollout", "grad_row", "run_grad"]

log = logging.getLogger(__name__)

GOAL_ANGLE = math.pi / 4  # within screw_claw's goal range
GOAL_SPEED = 1.0  # rad/s, for the velocity loss
LOSSES = ("pose", "velocity")
NOISE = 0.2  # amplitude of the uniform action noise


def hinge_loss_rollout(sim, q0: torch.Tensor, actions: torch.Tensor, goal: float, kind: str = "pose"):
    """Roll ``actions`` [H, W, nu] out from ``q0`` [W, nq] of a scene whose object is on one hinge (its
    angle is ``q[:, nu]``); returns (loss [W], contact_force [H, W])."""
    from ..sim import Control

    opts = dict(dtype=sim.dtype, device=sim.torch_device)
    gear = torch.as_tensor(sim.scene.actuator_gear, **opts)
    centre = torch.as_tensor(sim.scene.object_base_pos, **opts)
    zero = torch.zeros(q0.shape[0], sim.nu, **opts)
    params = sim.default_params()
    q, qd = q0, torch.zeros(q0.shape[0], sim.nv, **opts)
    running, forces = 0.0, []
    for a in actions:
        out = sim.step(q, qd, Control(a * gear, zero, zero, zero), params)
        q, qd = out.joint_q, out.joint_qd
        angle_err = (q[:, sim.nu] - goal) ** 2
        running = running + angle_err + ((out.fingertips - centre) ** 2).sum((-1, -2))
        forces.append(out.contact_force.detach())
    if kind == "velocity":
        return (qd[:, sim.nu] - GOAL_SPEED) ** 2 + 0.01 * (qd[:, : sim.nu] ** 2).sum(-1), torch.stack(forces)
    return running / len(actions) + angle_err, torch.stack(forces)


def grad_row(scene, task, horizon: int, contact: bool, eps: float, num_entries: int, floor_rel: float,
             generator: torch.Generator, device: str = "cpu", loss_kind: str = "pose", draws: int = 8,
             law=None) -> dict:
    """One row of the gradient benchmark (see the module docstring), over ``draws`` random action
    sequences simulated side by side: draw d owns worlds ``d * (1 + 2k) ...`` (nominal, then +eps/-eps
    per checked entry). ``law``: the task's ContactParams (None: the defaults, the claw's)."""
    from ..sim import Simulator

    nu = scene.num_hand_dofs
    k = min(num_entries, horizon * nu)
    per_draw = 1 + 2 * k
    sim = Simulator(scene, draws * per_draw, device=device, dtype=torch.float64, contact=law)
    opts = dict(dtype=torch.float64, device=sim.torch_device)
    base = torch.tensor(task.squeeze_action if contact else (0.0,) * nu, dtype=torch.float64)
    entries = torch.stack([torch.randperm(horizon * nu, generator=generator)[:k] for _ in range(draws)])  # [D, k]
    base = base + NOISE * (2 * torch.rand(draws, horizon, nu, generator=generator, dtype=torch.float64) - 1)
    delta = torch.zeros(draws, per_draw, horizon, nu, dtype=torch.float64)
    t_idx, j_idx = entries // nu, entries % nu
    d_idx, w = torch.arange(draws)[:, None].expand(-1, k), torch.arange(k)[None].expand(draws, -1)
    delta[d_idx, 1 + 2 * w, t_idx, j_idx] = eps
    delta[d_idx, 2 + 2 * w, t_idx, j_idx] = -eps
    actions = (base[:, None] + delta).reshape(-1, horizon, nu).transpose(0, 1).to(**opts).requires_grad_(True)
    q0 = torch.tensor(task.touch_q if contact else task.free_q, **opts).expand(sim.num_worlds, sim.nq).contiguous()

    loss, forces = hinge_loss_rollout(sim, q0, actions, GOAL_ANGLE, loss_kind)
    loss.view(draws, per_draw)[:, 0].sum().backward()  # worlds are independent: one backward for all draws
    ad_full = actions.grad.detach().cpu().view(horizon, draws, per_draw, nu)[:, :, 0].transpose(0, 1)  # [D, H, nu]
    loss = loss.detach().cpu().view(draws, per_draw)
    fd = (loss[:, 1::2] - loss[:, 2::2]) / (2 * eps)  # [D, k]
    ad = ad_full[d_idx, t_idx, j_idx]
    floor = (floor_rel * ad_full.flatten(1).abs().amax(1, keepdim=True)).clamp_min(torch.finfo(torch.float64).tiny)
    rel = (ad - fd).abs() / torch.maximum(fd.abs(), floor)
    norms = ad_full.norm(dim=2)  # [D, H]
    growth = norms.amax(1) / norms[:, -1]
    # per-step amplification backward in time: slope of log|dL/da_t| against steps-to-go (1.0: none)
    to_go = torch.arange(horizon - 1, -1, -1, dtype=torch.float64)
    x = to_go - to_go.mean()  # centred, so the least-squares slope needs no centring of log|dL/da_t|
    slope = (norms.log() * x).sum(1) / (x * x).sum().clamp_min(1e-12)
    contact_fraction = (forces.view(horizon, draws, per_draw)[:, :, 0] > 0).double().mean().item()
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
        "growth_per_step": slope.exp().median().item(),
        "contact_fraction": contact_fraction,
        "loss": loss[:, 0].mean().item(),
        "grad_norm": ad_full.flatten(1).norm(dim=1).median().item(),
    }


def run_grad(task: str = "screw_claw", horizons=(1, 8, 32), eps: float = 1e-6, num_entries: int = 16,
             floor_rel: float = 1e-3, seed: int = 0, device: str = "cpu", draws: int = 8) -> dict:
    """All rows; returns the result dict printed by ``dexmots-bench grad``."""
    setup = bench_task(task)
    scene, _ = load_task_scene(task)
    law = task_contact(task)  # the contact law the task's env simulates with
    generator = torch.Generator().manual_seed(seed)
    rows = []
    log.info("grad: the first row compiles the float64 kernels when not cached")
    for loss_kind in LOSSES:
        for horizon in horizons:
            for contact in (True, False):
                rows.append(grad_row(scene, setup, horizon, contact, eps, num_entries, floor_rel, generator,
                                     device, loss_kind, draws, law))
                log.info("grad: %s", rows[-1])
            # growth of a free (contact-less) rollout is the baseline: a position loss on a second-order
            # system already weighs early actions ~H^2 more than the last one
            free = rows[-1]["grad_growth"]
            for row in rows[-2:]:
                row["grad_growth_vs_free"] = row["grad_growth"] / free
    return {"task": task, "precision": "float64", "eps": eps, "floor_rel": floor_rel, "num_entries": num_entries,
            "seed": seed, "draws": draws, "loss_definition": {
                "pose": "mean_t[(theta_t-theta*)^2 + sum_f |tip_f,t - object|^2] + (theta_H-theta*)^2",
                "velocity": "(omega_H-omega*)^2 + 0.01 |qd_hand,H|^2"},
            "goal_angle": GOAL_ANGLE, "goal_speed": GOAL_SPEED, "rows": rows}
