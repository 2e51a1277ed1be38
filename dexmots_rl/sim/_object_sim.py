"""The articulated object on its own: many worlds of one object tree on a table, differentiable.

:class:`ObjectSimulator` steps the object of a scene (sim/_object_model.py) under gravity, its joints'
springs, dampers, friction and stops, the table's contact and an applied wrench per body (the hand's
contact, or a planner's wrench). A step is ``substeps`` launches of one fused kernel over all worlds;
with gradients on, the launches are recorded on a ``wp.Tape`` with one set of arrays per substep (a
taped launch must not overwrite what an earlier one read) and :class:`ObjectStep` replays them backwards.

Object variants (sim/_object_variants.py): given ``variants`` (trees of one topology), the model's arrays hold
every variant and world ``w`` simulates variant ``variant[w]`` (:attr:`ObjectSimulator.variant`, int32 [N],
zeros by default; read at each step).

Example:
    >>> from dexmots_rl.assets.objects import load_object
    >>> from dexmots_rl.sim._object_sim import ObjectSimulator, load_object_tree
    >>> tree, _ = load_object_tree(load_object("spray_bottle_a"))  # doctest: +SKIP
    >>> sim = ObjectSimulator(tree, num_worlds=2)  # doctest: +SKIP
"""

from __future__ import annotations

import dataclasses
import tempfile

import numpy as np
import torch
import warp as wp
from tensordict import TensorDict

from ._mjcf_shapes import AssetError
from ._constants import LIMIT_WIDTH, OBJECT_STOP_FREQUENCY, TABLE_FRICTION
from ._object_kernels import build_object_kernels
from ._object_model import MAX_SAMPLES, ObjectTree, object_tree
from ._hand_sim import check_device, warp_float

__all__ = ["TableContact", "ObjectSimulator", "ObjectStep", "load_object_tree"]


@dataclasses.dataclass(frozen=True)
class TableContact:
    """Penalty contact of the object's surface samples with the table: normal force
    ``stiffness * softplus(sharpness * penetration) / sharpness * max(1 - damping * v_normal, 0)`` per sample,
    Coulomb friction ``friction * f_n`` smoothed below ``slip_velocity`` (its viscous part is integrated
    implicitly, so a small slip velocity stays stable: the object holds on the table like static friction)."""

    stiffness: float = 2.0e4  # N/m per sample
    sharpness: float = 1.0e4  # 1/m
    damping: float = 10.0  # s/m
    friction: float = TABLE_FRICTION
    slip_velocity: float = 0.002  # m/s


def load_object_tree(asset, *, timestep: float = 1.0 / 960.0) -> tuple[ObjectTree, object]:
    """Compile ``asset`` on a table with MuJoCo; returns ``(ObjectTree, MjModel)``."""
    import mujoco

    from ..assets.objects import object_scene_xml

    with tempfile.TemporaryDirectory() as tmp:
        xml = object_scene_xml(asset, tmp, timestep=timestep)
        try:
            m = mujoco.MjModel.from_xml_string(xml)
        except Exception as exc:
            raise AssetError(f"object {asset.name!r} does not compile: {exc}") from exc
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    return object_tree(m, d), m


class ObjectSimulator:
    """Worlds of one object tree (see the module docstring). State: ``q`` [N, nq], ``qd`` [N, nv]
    (:class:`~dexmots_rl.sim._object_model.ObjectTree` documents the layout); parameters: the named
    per-joint values of :attr:`param_names`, each [N, 1]."""

    def __init__(self, tree: ObjectTree, num_worlds: int, *, device: str = "cpu", dtype: torch.dtype = torch.float32,
                 substeps: int = 16, sub_dt: float = 1.0 / 960.0, table: TableContact | None = None,
                 gravity=(0.0, 0.0, -9.81), variants: list[ObjectTree] | None = None):
        if num_worlds <= 0:
            raise ValueError(f"num_worlds must be positive, got {num_worlds}")
        self.tree, self.num_worlds, self.substeps, self.sub_dt = tree, num_worlds, substeps, sub_dt
        self.variants = list(variants) if variants else [tree]  # the object's variants (variant 0 is ``tree``)
        self.dt = sub_dt * substeps
        self.dtype = dtype
        self.torch_device = check_device(device)
        self.device = wp.device_from_torch(self.torch_device)
        self.table = table or TableContact()
        self.kernels = build_object_kernels(warp_float(dtype), tree.num_bodies, tree.free,
                                            tree.table_height is not None)
        self.model = self._make_model(np.asarray(gravity, dtype=np.float64))
        # [N] int32: the variant each world simulates (see the module docstring)
        self.variant = torch.zeros(num_worlds, dtype=torch.int32, device=self.torch_device)
        self._arrays = _ArrayPool(self.device)  # the substeps' arrays, reused once their step is done with

    @property
    def nq(self) -> int:
        return self.tree.nq

    @property
    def nv(self) -> int:
        return self.tree.nv

    @property
    def param_names(self) -> tuple[str, ...]:
        return self.tree.param_names

    def _make_model(self, gravity):
        t, k = self.tree, self.kernels
        wdt = warp_float(self.dtype)

        def arr(x, dtype):
            return wp.array(np.asarray(x, dtype=np.float64), dtype=dtype, device=self.device)

        def per_variant(field):  # [V, ...]: the field of every variant, stacked
            return np.stack([field(tree) for tree in self.variants])

        pad = (lambda a, shape: a if t.num_parts else np.zeros(shape))
        m = k.Model()
        m.parent = wp.array(t.parent.astype(np.int32), dtype=wp.int32, device=self.device)
        m.off_pos = arr(per_variant(lambda v: v.offset_pos), k.vec3)
        m.off_rot = arr(per_variant(lambda v: v.offset_rot), k.mat33)
        m.jkind = wp.array(pad(t.joint_kind, (1,)).astype(np.int32), dtype=wp.int32, device=self.device)
        m.jaxis = arr(per_variant(lambda v: pad(v.joint_axis, (1, 3))), k.vec3)
        m.janchor = arr(per_variant(lambda v: pad(v.joint_anchor, (1, 3))), k.vec3)
        rng = per_variant(lambda v: pad(v.joint_range, (1, 2)))
        m.jlower, m.jupper = arr(rng[..., 0], wdt), arr(rng[..., 1], wdt)
        # each stop as stiff as an OBJECT_STOP_FREQUENCY oscillator on the joint's own inertia (at the initial pose)
        m.limit_ke = arr(per_variant(lambda v: pad(v.joint_inertia, (1,))) * OBJECT_STOP_FREQUENCY**2, wdt)
        # a stop stiffens over LIMIT_WIDTH, or over 5 % of a short range (a pump's 12 mm stroke)
        span = rng[..., 1] - rng[..., 0] if t.num_parts else np.ones((len(self.variants), 1))
        m.limit_width = arr(np.minimum(LIMIT_WIDTH, 0.05 * span), wdt)
        m.armature = arr(per_variant(lambda v: pad(v.armature, (1,))), wdt)
        m.ancestor = arr(t.ancestor if t.num_parts else np.zeros((t.num_bodies, 1)), wdt)
        m.mass, m.com = arr(per_variant(lambda v: v.mass), wdt), arr(per_variant(lambda v: v.com), k.vec3)
        m.inertia = arr(per_variant(lambda v: v.inertia), k.mat33)
        m.sample_pos = arr(per_variant(lambda v: v.sample_pos), k.vec3)
        m.sample_radius = arr(per_variant(lambda v: v.sample_radius), wdt)
        m.gravity = k.vec3(*gravity)
        m.table_z = arr([v.table_height or 0.0 for v in self.variants], wdt)
        c = self.table
        # the table's friction is the per-world parameter "table/friction" (default_params: this law's)
        m.ke, m.beta, m.kd, m.v_slip = (wdt(v) for v in (c.stiffness, c.sharpness, c.damping, c.slip_velocity))
        return m

    # ---------------------------------------------------------------------------------------- state
    def _zeros(self, *shape):
        return torch.zeros(*shape, dtype=self.dtype, device=self.torch_device)

    def initial_state(self) -> tuple[torch.Tensor, torch.Tensor]:
        q = torch.as_tensor(self.tree.q0, dtype=self.dtype, device=self.torch_device).expand(self.num_worlds, -1)
        return q.clone(), self._zeros(self.num_worlds, self.nv)

    def default_params(self) -> TensorDict:
        values = {n: torch.full((self.num_worlds, 1), v, dtype=self.dtype, device=self.torch_device)
                  for n, v in self.tree.default_param_values(self.table.friction).items()}
        return TensorDict(values, batch_size=[self.num_worlds], device=self.torch_device)

    def pack_params(self, params) -> torch.Tensor:
        names = self.param_names
        if not names:
            return self._zeros(self.num_worlds, 4)
        missing = [n for n in names if n not in params.keys()]
        if missing:
            raise ValueError(f"params lacks {', '.join(missing)}; this object's parameters are {', '.join(names)}")
        return torch.cat([params[n].reshape(-1, 1) for n in names], -1)

    def step(self, q, qd, params, body_wrench=None):
        """One env step (``substeps`` substeps). ``body_wrench`` [N, B, 6]: force (N) and torque about each
        body's com (N m), world frame, held over the step. Returns ``(q, qd)``; differentiable."""
        if q.shape != (self.num_worlds, self.nq) or qd.shape != (self.num_worlds, self.nv):
            raise ValueError(f"q must be [{self.num_worlds}, {self.nq}] and qd [{self.num_worlds}, {self.nv}], "
                             f"got {tuple(q.shape)} and {tuple(qd.shape)}")
        if body_wrench is None:
            body_wrench = self._zeros(self.num_worlds, self.tree.num_bodies, 6)
        ext = body_wrench.reshape(self.num_worlds, -1)
        return ObjectStep.apply(self, q, qd, self.pack_params(params), ext)

    # ------------------------------------------------------------------------------------- launches
    def _run(self, q, qd, params, ext, grad: bool):
        """Launch the substeps; returns the arrays (inputs first) so a tape can replay them."""
        n, k = self.num_worlds, self.kernels
        wq = wp.from_torch(q.contiguous(), requires_grad=grad)
        wqd = wp.from_torch(qd.contiguous(), requires_grad=grad)
        wpar = wp.from_torch(params.contiguous(), requires_grad=grad)
        wext = wp.from_torch(ext.contiguous(), requires_grad=grad)
        variant = wp.from_torch(self.variant.clone())  # this step's (a later change must not reach its replay)
        nb, nparts = self.tree.num_bodies, max(self.tree.num_parts, 1)
        wdt = warp_float(self.dtype)
        states = [(wq, wqd)]

        def new(dtype, count):
            return self._arrays.take(dtype, (n, count), grad)

        for _ in range(self.substeps):
            # every substep its own arrays: a taped launch must not overwrite what an earlier one read
            q_in, qd_in = states[-1]
            frames = [new(k.vec3, nb), new(k.mat33, nb), new(k.vec3, nb), new(k.vec3, nb), new(k.vec3, nb)]
            wp.launch(k.frames, dim=n, inputs=[self.model, variant, q_in, qd_in], outputs=frames, device=self.device)
            contact = [new(k.vec3, nb), new(k.vec3, nb), new(k.mat33, nb), new(k.mat33, nb), new(k.mat33, nb)]
            if k.table:
                wp.launch(k.table_contact, dim=(n, nb), device=self.device,  # adds into the (zero) contact
                          inputs=[self.model, variant, wpar, k.table_mu_col, *frames, wdt(self.sub_dt), MAX_SAMPLES],
                          outputs=contact)
            q_out, qd_out = new(wdt, self.nq), new(wdt, self.nv)
            wp.launch(k.substep, dim=n, device=self.device,
                      inputs=[self.model, variant, q_in, qd_in, wpar, wext, *contact, wdt(self.sub_dt),
                              new(k.vec3, nb), new(k.mat33, nb), new(k.vec3, nb), new(k.vec3, nb),
                              new(k.vec3, nb), new(k.vec3, nb), new(k.vec3, nparts), new(k.vec3, nparts)],
                      outputs=[q_out, qd_out])
            states.append((q_out, qd_out))
        return wq, wqd, wpar, wext, states[-1]


class _ArrayPool:
    """Warp arrays handed out zeroed and taken back for reuse: building a warp array costs more CPU time than
    the launch that fills it (a joint plan's forward pass spent two thirds of its time creating them)."""

    def __init__(self, device):
        self.device, self.free, self.in_use = device, {}, []

    def take(self, dtype, shape: tuple, grad: bool):
        spare = self.free.get((dtype, shape, grad))
        if spare:
            a = spare.pop()
            a.zero_()
            if grad:
                a.grad.zero_()
        else:
            a = wp.zeros(shape, dtype=dtype, device=self.device, requires_grad=grad)
        self.in_use.append(a)
        return a

    def taken_since(self, mark: int) -> list:
        """The arrays taken since ``len(self.in_use)`` was ``mark`` (one step's), no longer tracked."""
        out, self.in_use = self.in_use[mark:], self.in_use[:mark]
        return out

    def give_back(self, arrays) -> None:
        for a in arrays:
            self.free.setdefault((a.dtype, a.shape, a.requires_grad), []).append(a)


class ObjectStep(torch.autograd.Function):
    """One env step of an :class:`ObjectSimulator`; inputs ``sim, q, qd, params, ext``, outputs ``(q, qd)``."""

    @staticmethod
    def forward(ctx, sim: ObjectSimulator, q, qd, params, ext):
        inputs = [t.detach().to(sim.dtype).clone() for t in (q, qd, params, ext)]
        grad = any(ctx.needs_input_grad[1:])
        ctx.sim, ctx.tape = sim, None
        mark = len(sim._arrays.in_use)
        if grad:
            tape = wp.Tape()
            with tape:
                arrays = sim._run(*inputs, grad=True)
            ctx.tape, ctx.arrays = tape, arrays
        else:
            arrays = sim._run(*inputs, grad=False)
        q_out, qd_out = arrays[-1]
        out = wp.to_torch(q_out).clone(), wp.to_torch(qd_out).clone()
        pooled = sim._arrays.taken_since(mark)
        if grad:  # back to the pool after the backward pass, which replays them
            ctx.pooled = pooled
        else:
            sim._arrays.give_back(pooled)
        return out

    @staticmethod
    def backward(ctx, grad_q, grad_qd):
        if ctx.tape is None:
            raise RuntimeError("ObjectStep supports one backward pass per forward")
        wq, wqd, wpar, wext, (q_out, qd_out) = ctx.arrays
        for arr, g in ((q_out, grad_q), (qd_out, grad_qd)):
            if g is not None:
                wp.to_torch(arr.grad).copy_(g.to(wp.to_torch(arr.grad).dtype))
        ctx.tape.backward()
        grads = [wp.to_torch(a.grad).clone() for a in (wq, wqd, wpar, wext)]
        ctx.tape.zero()
        ctx.sim._arrays.give_back(ctx.pooled)
        ctx.tape, ctx.arrays, ctx.pooled = None, None, None
        return (None, *[g if need else None for g, need in zip(grads, ctx.needs_input_grad[1:])])

