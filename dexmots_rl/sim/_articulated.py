"""A hand and an articulated object on a table: scene, simulator and the differentiable step.

:func:`~dexmots_rl.sim.load_scene` returns an :class:`ArticulatedScene` when body ``object`` is a tree (a base
with moving parts, sim/_object_model.py). :class:`ArticulatedSimulator` steps it with the same interface as
:class:`~dexmots_rl.sim.Simulator` (state ``joint_q``/``joint_qd`` = the hand's joints then the object's
coordinates, a :class:`~dexmots_rl.sim.Control`, named per-world parameters), so envs use either.

One substep is seven launches over all worlds, eight when the palm collides (each kernel module documents its
part): the object's frames, the hand's link frames (a thread per world and finger), the table's contact (a thread
per world and body), the palm's (the same), the fingers' contact (a thread per world and finger link), the sum of
each body's contacts, the object tree's solve and the hand's (a thread per world and finger). The launches are recorded once per trajectory of buffers and
replayed, their adjoints in reverse for the gradient (sim/_articulated_stepper.py).

A scene of K object variants (sim/_object_variants.py) steps each world's own variant: the per-world parameter
``"variant"`` (the last column of the packed parameters) picks it; K = 1 has no such parameter.
"""

from __future__ import annotations


import numpy as np
import torch
import warp as wp

from ._articulated_scene import HAND_FRICTION_PARAM, ArticulatedScene, ObjectGeoms, object_geoms
from ._articulated_stepper import ArticulatedTrajectory
from ._energy import tree_energy
from ._hand_kernels import build_hand_kernels
from ._object_model import SLIDE, TABLE_FRICTION_PARAM
from ._palm_object_kernels import build_palm_object_kernels
from ..quaternions import quat_to_matrix
from ._hand_sim import BELOW_TABLE, PAST_STOP_HINGE, PAST_STOP_SLIDE, HandSimulator, StepOutput
from ._model import ContactParams
from ._object_sim import ObjectSimulator, TableContact

__all__ = ["ArticulatedScene", "ArticulatedSimulator", "ArticulatedStepOutput", "ObjectGeoms", "object_geoms"]



def _inverse_masses(trees) -> tuple[np.ndarray, np.ndarray]:
    """[V, B] inverse masses and [V, B, 3, 3] inverse inertias (body frame) of every variant's bodies, as free
    bodies (what the contact law's implicit damping reads); zero for a fixed base, which does not move."""
    inv_mass = np.stack([np.where(t.mass > 0, 1.0 / np.maximum(t.mass, 1e-12), 0.0) for t in trees])
    inv_inertia = np.stack([np.linalg.pinv(t.inertia) for t in trees])  # a massless body: zero
    for v, tree in enumerate(trees):
        if not tree.free:
            inv_mass[v, 0], inv_inertia[v, 0] = 0.0, 0.0
    return inv_mass, inv_inertia


class ArticulatedStepOutput(StepOutput):
    """:class:`~dexmots_rl.sim.StepOutput` of an articulated object, plus ``joint_wrench`` [N, P]: the mean over
    substeps of the fingers' generalised contact force on each of the object's part joints (the order of
    ``tree.joint_names``), the component of their wrench on the bodies the joint moves that acts on the joint: the
    torque about a hinge's axis through its anchor (N m), the force along a slide's axis (N), positive when it
    pushes the joint's coordinate up (the sign of the reference's joint torque). Like ``wrench`` it counts the
    fingers' contacts: the palm's push, like the table's, is part of the scene."""

    __slots__ = ()
    names = StepOutput.names + ("joint_wrench",)


class ArticulatedSimulator(HandSimulator):
    """Many worlds of a hand and an articulated object (see the module docstring; the options are
    :class:`~dexmots_rl.sim._hand_sim.HandSimulator`'s, plus the ``table``'s contact). The object's kernels, model
    and variants are those of :attr:`object_sim`, the object alone (an
    :class:`~dexmots_rl.sim._object_sim.ObjectSimulator` of the same worlds); the hand's and the palm's are this
    simulator's own."""

    output_type = ArticulatedStepOutput

    def __init__(self, scene: ArticulatedScene, num_worlds: int, *, device: str = "cpu",
                 dtype: torch.dtype = torch.float32, substeps: int = 16, dt: float | None = None,
                 contact: ContactParams | None = None, table: TableContact | None = None,
                 adjoint_clip: float | None = None):
        if (np.asarray(scene.joint_type) != 0).any():
            raise ValueError("an articulated-object scene's hand joints must all be hinges")
        super().__init__(scene, num_worlds, device=device, dtype=dtype, substeps=substeps, dt=dt, contact=contact,
                         adjoint_clip=adjoint_clip)
        self.object_sim = ObjectSimulator(scene.tree, num_worlds, device=device, dtype=dtype, substeps=substeps,
                                          sub_dt=self.sub_dt, table=table, gravity=scene.gravity,
                                          variants=scene.variant_trees)
        self.tree, self.variants, self.table = scene.tree, self.object_sim.variants, self.object_sim.table
        self.kernels, self.model = self.object_sim.kernels, self.object_sim.model  # the object tree's
        self.nu = scene.num_hand_dofs
        self.nq, self.nv = self.nu + scene.tree.nq, self.nu + scene.tree.nv
        self.num_bodies = self.nu + scene.tree.num_bodies
        # the reverse pass's buffers, shared by every trajectory of this simulator (made at the first backward pass;
        # ArticulatedTrajectory.backward documents them)
        self._adjoint_buffers = None
        # what outside_physics compares a state with, per variant: the part joints' ranges [V, P, 2] (rad or m) and
        # how far past them a world has left the physics [P]; the table-contact samples (body frame, m) [V, B, S, 3]
        # and their radii [V, B, S] (m, -1: padding); the table's top [V] (m)
        opts = dict(dtype=dtype, device=self.torch_device)
        self._joint_range = torch.as_tensor(np.stack([t.joint_range for t in self.variants]), **opts)
        self._past_stop = torch.as_tensor([PAST_STOP_SLIDE if kind == SLIDE else PAST_STOP_HINGE
                                           for kind in scene.tree.joint_kind], **opts)
        self._sample_pos = torch.as_tensor(np.stack([t.sample_pos for t in self.variants]), **opts)
        self._sample_radius = torch.as_tensor(np.stack([t.sample_radius for t in self.variants]), **opts)
        self._table_z = torch.as_tensor([t.table_height or 0.0 for t in self.variants], **opts)
        self.hand_kernels = build_hand_kernels(self.kernels.dtype, scene.num_fingers, scene.joints_per_finger,
                                               scene.points_per_link, scene.tree.num_bodies,
                                               scene.variant_geoms[0].kind.shape[1])
        self.hand_model = self._make_hand_model()
        self.more_kernels = [self.hand_kernels]
        self.palm_kernels, self.palm_model = self._make_palm()

    @property
    def num_variants(self) -> int:
        return len(self.variants)

    def variant_of(self, params, n: int | None = None) -> torch.Tensor:
        """[n] int32: each world's object variant in ``params`` (zeros with one variant; ``n`` defaults to the
        simulator's worlds); raises ValueError naming ``variant`` when one is not a whole number in [0, K)."""
        if self.num_variants == 1:
            return torch.zeros(n or self.num_worlds, dtype=torch.int32, device=self.torch_device)
        if "variant" not in params.keys():
            raise ValueError(f"params lacks 'variant' (the world's object variant, 0..{self.num_variants - 1})")
        value = params["variant"].detach().reshape(-1)
        index = value.round()
        if bool(((index - value).abs() > 1e-6).any() | (index < 0).any() | (index >= self.num_variants).any()):
            raise ValueError(f"params 'variant' must hold whole numbers in [0, {self.num_variants}), got "
                             f"{value.min().item()}..{value.max().item()}")
        return index.to(torch.int32)

    def _make_palm(self):
        """The palm's kernel and model (None, None when the scene's palm does not collide with the object)."""
        pos, rot, half = self.scene.palm
        if len(pos) == 0:
            return None, None
        k = build_palm_object_kernels(self.kernels.dtype, self.tree.num_bodies, len(pos))
        wdt, c, arr = self.kernels.dtype, self.table, self._array
        m = k.Model()
        m.box_pos, m.box_rot, m.box_half = arr(pos, k.vec3), arr(rot, k.mat33), arr(half, k.vec3)
        m.sample_pos = arr(np.stack([v.sample_pos for v in self.variants]), k.vec3)
        m.sample_radius = arr(np.stack([v.sample_radius for v in self.variants]), wdt)
        # the table's law: both are rigid surfaces the object's samples rest on
        m.ke, m.beta, m.kd, m.mu, m.v_slip = (wdt(v) for v in (c.stiffness, c.sharpness, c.damping, c.friction,
                                                               c.slip_velocity))
        return k, m

    def _make_hand_model(self):
        k, variants, arr = self.hand_kernels, self.scene.variant_geoms, self._array
        wdt = k.dtype

        def geoms(field):  # [V, B, G]: every variant's geoms (one width: object_variants.pad_geoms)
            return np.stack([getattr(g, field) for g in variants])

        m = k.Model()
        self._fill_finger_chains(m, k, wdt)  # the fingers' friction coefficient is the parameter "hand/friction"
        m.geom_kind = wp.array(geoms("kind"), dtype=wp.int32, device=self.device)
        m.geom_pos, m.geom_rot = arr(geoms("pos"), k.vec3), arr(geoms("rot"), k.mat33)
        m.geom_size = arr(geoms("size"), k.vec3)
        m.geom_bound = arr(np.stack([g.skip_bound() for g in variants]), wdt)
        # every variant's grids one after another in one array: each variant's first indices move past the earlier
        starts = np.cumsum([0] + [len(g.sdf_values) for g in variants[:-1]])
        grid = np.stack([g.grid + np.array([start, 0, 0, 0], dtype=np.int32) * (g.grid[..., 1:2] > 0)
                         for g, start in zip(variants, starts)])
        m.geom_grid = wp.array(grid.astype(np.int32), dtype=wp.vec4i, device=self.device)
        m.sdf_values = arr(np.concatenate([g.sdf_values for g in variants]), wdt)
        m.body_bound = arr(np.stack([g.bound() for g in variants]), wdt)
        inv_mass, inv_inertia = _inverse_masses(self.variants)
        m.body_inv_mass, m.body_inv_inertia = arr(inv_mass, wdt), arr(inv_inertia, k.mat33)
        m.body_mass = arr(np.stack([t.mass for t in self.variants]), wdt)
        m.first_moving, m.mass_col = self.tree.moving_bodies.start, 4 * self.tree.num_parts
        m.mu_col = self.scene.param_names.index(HAND_FRICTION_PARAM)
        return m

    def observe(self, joint_q, joint_qd=None, params=None):
        """Body poses [N, B, 7] (hand links, then the object's bodies) and fingertips [N, F, 3]; ``params``
        (their ``"variant"``) says each world's object variant (default: 0)."""
        n, k, h, nb = joint_q.shape[0], self.kernels, self.hand_kernels, self.tree.num_bodies
        with torch.no_grad():
            q = joint_q.detach().to(self.dtype).contiguous()
            hq, oq = wp.from_torch(q[:, :self.nu].contiguous()), wp.from_torch(q[:, self.nu:].contiguous())
            oqd = wp.from_torch(self._zeros(n, self.tree.nv))
            frames = [wp.zeros((n, nb), dtype=t, device=self.device) for t in (k.vec3, k.mat33, k.vec3, k.vec3,
                                                                               k.vec3)]
            variant = (torch.zeros(n, dtype=torch.int32, device=self.torch_device) if params is None
                       else self.variant_of(params, n))
            wp.launch(k.frames, dim=n, inputs=[self.model, wp.from_torch(variant), oq, oqd], outputs=frames,
                      device=self.device)
            pose, tips = self._zeros(n, self.num_bodies * 7), self._zeros(n, self.scene.num_fingers * 3)
            wp.launch(h.observe, dim=n, inputs=[self.hand_model, hq, frames[0], frames[1]],
                      outputs=[wp.from_torch(pose), wp.from_torch(tips)], device=self.device)
        return pose.view(-1, self.num_bodies, 7), tips.view(-1, self.scene.num_fingers, 3)

    def default_param_values(self) -> dict[str, float]:
        """The scene's parameter values with this simulator's contact laws' friction coefficients."""
        values = {**self.scene.default_param_values(), HAND_FRICTION_PARAM: float(self.contact.friction)}
        if self.tree.table_contact:
            values[TABLE_FRICTION_PARAM] = float(self.table.friction)
        return values

    def check_params(self, params) -> None:
        self.variant_of(params)  # the kernels index with it

    @property
    def num_params(self) -> int:
        """Columns of :meth:`pack_params`' result."""
        return len(self.param_names) or 4

    def new_trajectory(self, save: bool) -> ArticulatedTrajectory:
        return ArticulatedTrajectory(self, save=save)

    @property
    def object_tree(self):
        return self.tree

    @property
    def object_is_free(self) -> bool:
        return bool(self.tree.free)

    def outside_physics(self, joint_q, body_pose, params=None) -> torch.Tensor:
        n, nu, tree = joint_q.shape[0], self.nu, self.tree
        variant = torch.zeros(n, dtype=torch.long, device=joint_q.device)
        if self.num_variants > 1 and params is not None and "variant" in params.keys():
            variant = params["variant"].detach().reshape(-1).round().long().clamp(0, self.num_variants - 1)
        out = torch.zeros(n, dtype=torch.bool, device=joint_q.device)
        if tree.num_parts:
            coords = joint_q[:, nu + 7 * tree.free:]
            lower, upper = self._joint_range[variant].unbind(-1)  # [N, P] each
            out |= ((coords < lower - self._past_stop) | (coords > upper + self._past_stop)).any(-1)
        if tree.table_height is not None:
            pose = body_pose[:, nu:]  # [N, B, 7] the object's bodies
            rot = quat_to_matrix(pose[..., 3:7])  # [N, B, 3, 3]
            points = pose[..., None, :3] + torch.einsum("nbij,nbsj->nbsi", rot, self._sample_pos[variant])
            bottom = points[..., 2] - self._sample_radius[variant]  # [N, B, S] each sample's lowest point (m)
            bottom = torch.where(self._sample_radius[variant] >= 0, bottom, torch.full_like(bottom, float("inf")))
            out |= bottom.amin((-1, -2)) < self._table_z[variant] - BELOW_TABLE
        return out

    def object_energy(self, joint_q, joint_qd, params=None) -> torch.Tensor:
        params = self.default_params() if params is None else params
        tree, nu = self.tree, self.nu
        stiffness = torch.cat([params[f"{j}/stiffness"] for j in tree.joint_names], -1) if tree.num_parts else None
        rest = torch.cat([params[f"{j}/rest"] for j in tree.joint_names], -1) if tree.num_parts else None
        return tree_energy(tree, joint_q[:, nu:], joint_qd[:, nu:], stiffness, rest, self.scene.gravity)
