"""Launching one env step (all substeps) over blocks of worlds, forward and reverse.

Every array of a :class:`Trajectory` holds the whole env step: row ``s * N + w`` is world ``w`` after
``s`` substeps. Each row is written exactly once, so one set of warp arrays serves every substep, the
adjoint launches can run over the same arrays in reverse substep order, and nothing is allocated per
substep. Worlds are split into one block per CPU core; each block's launches run in their own thread
(a warp CPU launch runs on one core and releases the GIL). The reverse pass is driven by hand (adjoint
launches) rather than by ``wp.Tape``: same kernels, same adjoints, a fraction of the Python overhead.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import torch
import warp as wp

__all__ = ["Trajectory", "run_blocks", "world_blocks"]

MIN_WORLDS_PER_THREAD = 32  # below this a second CPU thread costs more than it saves
_POOL: ThreadPoolExecutor | None = None


def world_blocks(num_worlds: int, device) -> list[tuple[int, int]]:
    threads = (os.cpu_count() or 1) if device.is_cpu else 1
    blocks = max(1, min(threads, num_worlds // MIN_WORLDS_PER_THREAD))
    bounds = [round(i * num_worlds / blocks) for i in range(blocks + 1)]
    return list(zip(bounds[:-1], bounds[1:]))


def run_blocks(fn, blocks):
    global _POOL
    if len(blocks) == 1:
        fn(*blocks[0])
        return
    if _POOL is None or _POOL._max_workers < len(blocks):
        _POOL = ThreadPoolExecutor(len(blocks))
    for future in [_POOL.submit(fn, lo, hi) for lo, hi in blocks]:
        future.result()


class Trajectory:
    """Buffers and launches for one env step of ``sim.num_worlds`` worlds."""

    def __init__(self, sim, save: bool = True):
        n, s_count, z = sim.num_worlds, sim.substeps, sim._zeros
        self.sim, self.n = sim, n
        rows = (s_count + 1) * n
        # per-call results the reverse pass replays instead of recomputing (see kernels.py); row = output
        # row of the substep. Left empty for gradient-free steps.
        k, scene = sim.kernels, sim.scene
        points = scene.num_hand_dofs * scene.points_per_link
        saved_rows = rows if save else 0
        self.saved = k.Saved()
        self.saved.finger = wp.empty((saved_rows, scene.num_fingers), dtype=k.vec7, device=sim.device)
        self.saved.contact = wp.empty((saved_rows, points), dtype=k.vecC, device=sim.device)
        self.saved.sdf = wp.empty((saved_rows, points), dtype=k.vec4, device=sim.device)
        self.saved.hit = wp.empty((saved_rows, points), dtype=wp.int32, device=sim.device)
        # state trajectories and the per-step inputs: tau, q_target, kp, kd, params, object_wrench
        self.q, self.qd, self.wrench, self.cforce = z(rows, sim.nq), z(rows, sim.nv), z(rows, 6), z(rows)
        self.controls = [z(n, sim.nu), z(n, sim.nu), z(n, sim.nu), z(n, sim.nu), z(n, 2), z(n, 6)]
        self.pose, self.tips = z(n, sim.num_bodies * 7), z(n, sim.scene.num_fingers * 3)
        self.blocks = world_blocks(n, sim.device)
        self._wrap()

    def _wrap(self):
        last = self.sim.substeps * self.n
        self.w_traj = [wp.from_torch(t) for t in (self.q, self.qd)]
        self.w_acc = [wp.from_torch(t) for t in (self.wrench, self.cforce)]
        self.w_controls = [wp.from_torch(t) for t in self.controls]
        self.w_final = [wp.from_torch(self.q[last:]), wp.from_torch(self.qd[last:])]
        self.w_obs = [wp.from_torch(self.pose), wp.from_torch(self.tips)]

    def load(self, q, qd, controls) -> None:
        n = self.n
        with torch.no_grad():
            self.q[:n].copy_(q)
            self.qd[:n].copy_(qd)
            for buf, t in zip(self.controls, controls):
                buf.copy_(t)

    def _substep_args(self, s: int, lo: int):
        sim = self.sim
        return [sim.model, *self.w_traj, *self.w_controls, *self.w_acc, self.saved, lo, s * self.n,
                (s + 1) * self.n, sim.sub_dt, 1.0 / sim.substeps]

    def launches(self, lo: int, hi: int, record: bool = False):
        """The forward launches of block [lo, hi); recorded (not run) when ``record``."""
        sim, out = self.sim, []
        for s in range(sim.substeps):
            out.append(wp.launch(sim.kernels.substep, dim=hi - lo, inputs=self._substep_args(s, lo),
                                 device=sim.device, record_cmd=record))
        out.append(wp.launch(sim.kernels.observe, dim=hi - lo, inputs=[sim.model, *self.w_final, *self.w_obs, lo],
                             device=sim.device, record_cmd=record))
        return out

    def forward(self) -> None:
        run_blocks(lambda lo, hi: self.launches(lo, hi), self.blocks)

    def outputs(self) -> list[torch.Tensor]:
        last, sim = self.sim.substeps * self.n, self.sim
        return [self.q[last:].clone(), self.qd[last:].clone(), self.wrench[last:].clone(), self.cforce[last:].clone(),
                self.pose.clone().view(-1, sim.num_bodies, 7), self.tips.clone().view(-1, sim.scene.num_fingers, 3)]

    def backward(self, grad_outputs) -> list[torch.Tensor]:
        """Reverse pass: adjoints of (q, qd, wrench, contact_force, pose, tips) -> adjoints of
        (joint_q, joint_qd, tau, q_target, kp, kd, params, object_wrench)."""
        sim, n, last = self.sim, self.n, self.sim.substeps * self.n
        adj = [torch.zeros_like(t) for t in (self.q, self.qd, self.wrench, self.cforce)]
        adj_controls = [torch.zeros_like(t) for t in self.controls]
        adj_obs = [torch.zeros_like(self.pose), torch.zeros_like(self.tips)]
        for target, g in zip(adj + adj_obs, grad_outputs):
            if g is not None:
                rows = target[last:] if target.shape[0] != n else target
                rows.copy_(g.reshape(rows.shape))
        w_adj = [wp.from_torch(t) for t in adj]
        w_adj_controls = [wp.from_torch(t) for t in adj_controls]
        w_adj_final = [wp.from_torch(adj[0][last:]), wp.from_torch(adj[1][last:])]
        w_adj_obs = [wp.from_torch(t) for t in adj_obs]
        adj_model = sim.adjoint_model()

        def reverse(lo, hi):
            wp.launch(sim.kernels.observe, dim=hi - lo, device=sim.device, adjoint=True,
                      inputs=[sim.model, *self.w_final, *self.w_obs, lo],
                      adj_inputs=[adj_model, *w_adj_final, *w_adj_obs, 0])
            for s in reversed(range(sim.substeps)):
                wp.launch(sim.kernels.substep, dim=hi - lo, device=sim.device, adjoint=True,
                          inputs=self._substep_args(s, lo),
                          adj_inputs=[adj_model, *w_adj[:2], *w_adj_controls, *w_adj[2:],
                                      sim.kernels.Saved(), 0, 0, 0, 0.0, 0.0])

        run_blocks(reverse, self.blocks)
        # a world that blew up must not poison the others' gradients (the env resets it)
        grads = [adj[0][:n], adj[1][:n], *adj_controls]
        return [torch.nan_to_num(g, nan=0.0, posinf=0.0, neginf=0.0) for g in grads]
