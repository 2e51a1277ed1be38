"""A hand and an articulated object on a table: scene, simulator and the differentiable step.

:func:`~dexmots_rl.sim.load_scene` returns an :class:`ArticulatedScene` when body ``object`` is a tree (a base
with moving parts, sim/object_model.py). :class:`ArticulatedSimulator` steps it with the same interface as
:class:`~dexmots_rl.sim.Simulator` (state ``joint_q``/``joint_qd`` = the hand's joints then the object's
coordinates, a :class:`~dexmots_rl.sim.Control`, named per-world parameters), so envs use either.

One substep is five launches over all worlds (each kernel module documents its part): the object's frames, the
table's contact (a thread per world and body), the fingers' contact (a thread per world and finger sphere),
the object tree's solve and the hand's (a thread per world and finger). With gradients on, the launches are
recorded on a ``wp.Tape``, each substep writing arrays of its own.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
import warp as wp

from .articulated_scene import ArticulatedScene, ObjectGeoms, object_geoms
from .hand_kernels import build_hand_kernels
from .object_model import MAX_SAMPLES
from .palm_object_kernels import build_palm_object_kernels
from .model import ContactParams
from .object_sim import ObjectSimulator, TableContact

__all__ = ["ArticulatedScene", "ArticulatedSimulator", "ArticulatedStep", "ObjectGeoms", "object_geoms"]

LIMIT_FREQUENCY = 60.0  # rad/s: the hand's range stops, as in the knob and cube scenes


class ArticulatedSimulator(ObjectSimulator):
    """Many worlds of a hand and an articulated object (see the module docstring); the object's arrays and
    parameters are :class:`~dexmots_rl.sim.object_sim.ObjectSimulator`'s."""

    def __init__(self, scene: ArticulatedScene, num_worlds: int, device: str = "cpu",
                 dtype: torch.dtype = torch.float32, substeps: int = 16, dt: float | None = None,
                 contact: ContactParams | None = None, table: TableContact | None = None,
                 adjoint_clip: float | None = None):
        if adjoint_clip is not None and not adjoint_clip >= 1.0:
            raise ValueError(f"adjoint_clip must be None or >= 1 (a multiple of the median world), got {adjoint_clip}")
        sub_dt = scene.timestep if dt is None else dt / substeps
        super().__init__(scene.tree, num_worlds, device=device, dtype=dtype, substeps=substeps, sub_dt=sub_dt,
                         table=table, gravity=scene.gravity)
        self.scene = scene
        self.contact = contact or ContactParams()
        # Simulator's outlier-world gradient clip (a training option), applied in ArticulatedStep.backward
        self.adjoint_clip = adjoint_clip
        self._clipped = torch.zeros((), dtype=torch.int64, device=self.torch_device)
        if (np.asarray(scene.joint_type) != 0).any():
            raise ValueError("an articulated-object scene's hand joints must all be hinges")
        self.nu = scene.num_hand_dofs
        self.num_bodies = self.nu + scene.tree.num_bodies
        self.hand_kernels = build_hand_kernels(self.kernels.dtype, scene.num_fingers, scene.joints_per_finger,
                                               scene.points_per_link, scene.tree.num_bodies, scene.geoms.kind.shape[1])
        self.hand_model = self._make_hand_model()
        self.palm_kernels, self.palm_model = self._make_palm()

    @property
    def clipped_adjoints(self) -> int:
        """Worlds x steps whose adjoint ``adjoint_clip`` scaled down (as :class:`~dexmots_rl.sim.Simulator`)."""
        return int(self._clipped)

    @property
    def nq(self) -> int:
        return self.nu + self.tree.nq

    @property
    def nv(self) -> int:
        return self.nu + self.tree.nv

    def _make_palm(self):
        """The palm's kernel and model (None, None when the scene's palm does not collide with the object)."""
        pos, rot, half = self.scene.palm
        if len(pos) == 0:
            return None, None
        k = build_palm_object_kernels(self.kernels.dtype, self.tree.num_bodies, MAX_SAMPLES, len(pos))
        wdt, c, t = self.kernels.dtype, self.table, self.tree

        def arr(x, dtype):
            return wp.array(np.asarray(x, dtype=np.float64), dtype=dtype, device=self.device)

        m = k.Model()
        m.box_pos, m.box_rot, m.box_half = arr(pos, k.vec3), arr(rot, k.mat33), arr(half, k.vec3)
        m.sample_pos, m.sample_radius = arr(t.sample_pos, k.vec3), arr(t.sample_radius, wdt)
        # the table's law: both are rigid surfaces the object's samples rest on
        m.ke, m.beta, m.kd, m.mu, m.v_slip = (wdt(v) for v in (c.stiffness, c.sharpness, c.damping, c.friction,
                                                               c.slip_velocity))
        return k, m

    def _make_hand_model(self):
        s, k, c, geoms = self.scene, self.hand_kernels, self.contact, self.scene.geoms
        wdt = k.dtype

        def arr(x, dtype):
            return wp.array(np.asarray(x, dtype=np.float64), dtype=dtype, device=self.device)

        m = k.Model()
        m.base_pos, m.base_rot = arr(s.finger_base_pos, k.vec3), arr(s.finger_base_rot, k.mat33)
        m.off_pos, m.off_rot = arr(s.link_offset_pos, k.vec3), arr(s.link_offset_rot, k.mat33)
        m.axis = arr(s.joint_axis, k.vec3)
        m.mass, m.com, m.inertia = arr(s.link_mass, wdt), arr(s.link_com, k.vec3), arr(s.link_inertia, k.mat33)
        m.armature, m.damping, m.friction = arr(s.dof_armature, wdt), arr(s.dof_damping, wdt), arr(s.dof_friction, wdt)
        m.lower, m.upper = arr(s.dof_lower, wdt), arr(s.dof_upper, wdt)
        m.limit_ke = arr(s.dof_inertia0 * LIMIT_FREQUENCY**2 * s.dof_limited, wdt)
        m.effort = arr(s.actuator_effort, wdt)
        m.point_pos, m.point_radius = arr(s.point_pos, k.vec3), arr(s.point_radius, wdt)
        m.tip_pos = arr(s.tip_pos, k.vec3)
        m.geom_kind = wp.array(geoms.kind, dtype=wp.int32, device=self.device)
        m.geom_pos, m.geom_rot, m.geom_size = arr(geoms.pos, k.vec3), arr(geoms.rot, k.mat33), arr(geoms.size, k.vec3)
        m.gravity = k.vec3(*s.gravity)
        m.ke, m.kd, m.beta = wdt(c.stiffness), wdt(c.damping), wdt(c.sharpness)
        m.mu, m.v_slip = wdt(c.friction), wdt(c.slip_velocity)
        return m

    # ---------------------------------------------------------------------------------------- state
    def initial_state(self) -> tuple[torch.Tensor, torch.Tensor]:
        q = self._zeros(self.num_worlds, self.nq)
        q[:, self.nu:] = torch.as_tensor(self.tree.q0, dtype=self.dtype)
        return q, self._zeros(self.num_worlds, self.nv)

    def zero_control(self):
        from .simulator import Control

        z = self._zeros(self.num_worlds, self.nu)
        return Control(z, z, z, z)

    def step(self, joint_q, joint_qd, control, params):
        """One env step; returns a :class:`~dexmots_rl.sim.StepOutput` (the hand's contact wrench on the object
        is summed over its bodies, torque about the base origin)."""
        from .simulator import StepOutput

        n = joint_q.shape[0]
        if n != self.num_worlds:
            raise ValueError(f"joint_q has {n} worlds, the simulator was built for {self.num_worlds}")
        ext = control.object_wrench
        ext = self._zeros(n, 6) if ext is None else ext
        return StepOutput(ArticulatedStep.apply(self, joint_q, joint_qd, control.tau, control.q_target, control.kp,
                                                control.kd, self.pack_params(params), ext))

    def observe(self, joint_q, joint_qd=None):
        """Body poses [N, B, 7] (hand links, then the object's bodies) and fingertips [N, F, 3]."""
        with torch.no_grad():
            _, out = self._run_full([joint_q.detach().to(self.dtype)] + [self._zeros(joint_q.shape[0], self.nv)]
                                 + [self._zeros(joint_q.shape[0], self.nu)] * 4
                                 + [self._zeros(joint_q.shape[0], max(4, 4 * self.tree.num_parts)),
                                    self._zeros(joint_q.shape[0], 6)], grad=False, substeps=0)
        return wp.to_torch(out[-2]).view(-1, self.num_bodies, 7).clone(), \
            wp.to_torch(out[-1]).view(-1, self.scene.num_fingers, 3).clone()

    def _run_full(self, inputs, grad: bool, substeps: int | None = None):
        """Launch one env step from torch inputs; returns the warp input arrays then the outputs (joint_q,
        joint_qd, wrench, contact force, body poses, fingertips)."""
        n, k, h = self.num_worlds, self.kernels, self.hand_kernels
        wdt = k.dtype
        nb, nu = self.tree.num_bodies, self.nu
        warp_in = [wp.from_torch(t.contiguous(), requires_grad=grad) for t in inputs]
        q_all, qd_all, tau, q_target, kp, kd, params, ext = warp_in

        def new(dtype, *shape):
            return wp.zeros((n, *shape), dtype=dtype, device=self.device, requires_grad=grad)

        # the input state split into hand and object (differentiable copies)
        hq, hqd, oq, oqd = new(wdt, nu), new(wdt, nu), new(wdt, self.tree.nq), new(wdt, self.tree.nv)
        wp.launch(_split, dim=(n, self.nq), inputs=[q_all, nu], outputs=[hq, oq], device=self.device)
        wp.launch(_split, dim=(n, self.nv), inputs=[qd_all, nu], outputs=[hqd, oqd], device=self.device)
        # the planner's wrench acts on the base (torque about its com)
        body_ext = new(wdt, 6 * nb)
        wp.launch(_pad_columns, dim=(n, 6), inputs=[ext], outputs=[body_ext], device=self.device)
        wrench, normal = new(wdt, 6), wp.zeros(n, dtype=wdt, device=self.device, requires_grad=grad)
        dt = wdt(self.sub_dt)
        steps = self.substeps if substeps is None else substeps
        for _ in range(steps):
            frames = [new(k.vec3, nb), new(k.mat33, nb), new(k.vec3, nb), new(k.vec3, nb), new(k.vec3, nb)]
            wp.launch(k.frames, dim=n, inputs=[self.model, oq, oqd], outputs=frames, device=self.device)
            contact = [new(k.vec3, nb), new(k.vec3, nb), new(k.mat33, nb), new(k.mat33, nb), new(k.mat33, nb)]
            if k.table:
                wp.launch(k.table_contact, dim=(n, nb), inputs=[self.model, *frames, dt], outputs=contact,
                          device=self.device)
            if self.palm_kernels is not None:
                with_palm = [new(k.vec3, nb), new(k.vec3, nb), new(k.mat33, nb), new(k.mat33, nb), new(k.mat33, nb)]
                wp.launch(self.palm_kernels.palm_contact, dim=(n, nb), inputs=[self.palm_model, *frames, dt, *contact],
                          outputs=with_palm, device=self.device)
                contact = with_palm
            gen = new(wdt, nu)
            step_normal = wp.zeros(n, dtype=wdt, device=self.device, requires_grad=grad)
            hand_f, hand_t = new(k.vec3, nb), new(k.vec3, nb)
            wp.launch(h.finger_contact, dim=(n, len(self.scene.point_radius)),
                      inputs=[self.hand_model, hq, hqd, *frames],
                      outputs=[gen, hand_f, hand_t, step_normal], device=self.device)
            total_f, total_t = new(k.vec3, nb), new(k.vec3, nb)
            step_wrench, next_wrench, next_normal = new(wdt, 6), new(wdt, 6), wp.zeros(n, dtype=wdt, device=self.device,
                                                                                          requires_grad=grad)
            wp.launch(k.sum_contacts, dim=n, inputs=[contact[0], contact[1], hand_f, hand_t, frames[0], frames[2],
                                                    wrench, normal, step_normal, wdt(1.0 / steps)],
                      outputs=[total_f, total_t, next_wrench, next_normal], device=self.device)
            wrench, normal = next_wrench, next_normal
            oq_next, oqd_next = new(wdt, self.tree.nq), new(wdt, self.tree.nv)
            nparts = max(self.tree.num_parts, 1)
            wp.launch(k.substep, dim=n, device=self.device,
                      inputs=[self.model, oq, oqd, params, body_ext, total_f, total_t, *contact[2:], dt,
                              new(k.vec3, nb), new(k.mat33, nb), new(k.vec3, nb), new(k.vec3, nb),
                              new(k.vec3, nb), new(k.vec3, nb), new(k.vec3, nparts), new(k.vec3, nparts)],
                      outputs=[oq_next, oqd_next])
            hq_next, hqd_next = new(wdt, nu), new(wdt, nu)
            wp.launch(h.hand_substep, dim=(n, self.scene.num_fingers),
                      inputs=[self.hand_model, hq, hqd, tau, q_target, kp, kd, gen, dt],
                      outputs=[hq_next, hqd_next], device=self.device)
            hq, hqd, oq, oqd = hq_next, hqd_next, oq_next, oqd_next
            del step_wrench
        q_out, qd_out = new(wdt, self.nq), new(wdt, self.nv)
        wp.launch(_join, dim=(n, self.nq), inputs=[hq, oq, nu], outputs=[q_out], device=self.device)
        wp.launch(_join, dim=(n, self.nv), inputs=[hqd, oqd, nu], outputs=[qd_out], device=self.device)
        frames = [new(k.vec3, nb), new(k.mat33, nb), new(k.vec3, nb), new(k.vec3, nb), new(k.vec3, nb)]
        wp.launch(k.frames, dim=n, inputs=[self.model, oq, oqd], outputs=frames, device=self.device)
        pose, tips = new(wdt, self.num_bodies * 7), new(wdt, self.scene.num_fingers * 3)
        wp.launch(h.observe, dim=n, inputs=[self.hand_model, hq, frames[0], frames[1]], outputs=[pose, tips],
                  device=self.device)
        return warp_in, [q_out, qd_out, wrench, normal, pose, tips]


@wp.kernel(enable_backward=True)
def _split(src: wp.array2d(dtype=Any), nu: int, hand: wp.array2d(dtype=Any), obj: wp.array2d(dtype=Any)):
    """Columns [0, nu) of src to ``hand``, the rest to ``obj`` (a thread per world and column)."""
    w, i = wp.tid()
    if i < nu:
        hand[w, i] = src[w, i]
    else:
        obj[w, i - nu] = src[w, i]


@wp.kernel(enable_backward=True)
def _join(hand: wp.array2d(dtype=Any), obj: wp.array2d(dtype=Any), nu: int, out: wp.array2d(dtype=Any)):
    w, i = wp.tid()
    if i < nu:
        out[w, i] = hand[w, i]
    else:
        out[w, i] = obj[w, i - nu]


@wp.kernel(enable_backward=True)
def _pad_columns(src: wp.array2d(dtype=Any), out: wp.array2d(dtype=Any)):
    """The first columns of ``out`` from ``src`` (the planner's wrench on the base; the parts get none)."""
    w, i = wp.tid()
    out[w, i] = src[w, i]


class ArticulatedStep(torch.autograd.Function):
    """One env step of an :class:`ArticulatedSimulator`. Inputs ``sim, joint_q, joint_qd, tau, q_target, kp, kd,
    params, object_wrench``; outputs as :class:`~dexmots_rl.sim.StepOutput`. Launches are taped only when an
    input needs a gradient."""

    @staticmethod
    def forward(ctx, sim: ArticulatedSimulator, *inputs):
        inputs = [t.detach().to(sim.dtype).clone() for t in inputs]
        grad = any(ctx.needs_input_grad[1:])
        ctx.tape, ctx.sim = None, sim
        if grad:
            tape = wp.Tape()
            with tape:
                warp_in, warp_out = sim._run_full(inputs, grad=True)
            ctx.tape, ctx.warp_in, ctx.warp_out = tape, warp_in, warp_out
        else:
            warp_in, warp_out = sim._run_full(inputs, grad=False)
        return tuple(wp.to_torch(a).clone() for a in warp_out[:4]) + (
            wp.to_torch(warp_out[4]).view(-1, sim.num_bodies, 7).clone(),
            wp.to_torch(warp_out[5]).view(-1, sim.scene.num_fingers, 3).clone())

    @staticmethod
    def backward(ctx, *grad_outputs):
        if ctx.tape is None:
            raise RuntimeError("ArticulatedStep supports one backward pass per forward")
        for arr, g in zip(ctx.warp_out, grad_outputs):
            if g is not None:
                wp.to_torch(arr.grad).view(g.shape).copy_(g)
        ctx.tape.backward()
        grads = [wp.to_torch(a.grad).clone() for a in ctx.warp_in]
        ctx.tape.zero()
        ctx.tape = ctx.warp_in = ctx.warp_out = None
        if ctx.sim.adjoint_clip is not None:
            from .simulator import _clip_outlier_worlds

            grads = _clip_outlier_worlds(ctx.sim, grads)
        return (None, *[g if need else None for g, need in zip(grads, ctx.needs_input_grad[1:])])
