"""The scene of a hand and an articulated object: the hand's fields, the object tree and its collision geoms.

:func:`~dexmots_rl.sim.load_scene` builds an :class:`ArticulatedScene` when body ``object`` of an MJCF is a tree
(a base with moving parts, :mod:`._object_model`); :class:`~dexmots_rl.sim._articulated.ArticulatedSimulator`
simulates it. :func:`~dexmots_rl.sim._object_variants.load_variants` builds one from several MJCF files of the
same hand with objects of one topology (the object's variants; each world simulates one).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._constants import (GEOM_BOX, GEOM_CAPSULE, GEOM_CYLINDER, GEOM_NONE, GEOM_SDF, GEOM_SPHERE, HAND_FRICTION,
                         SDF_PAD)
from ._mesh_sdf import sdf_grid
from ._mjcf_shapes import AssetError, _quat_to_mat
from ._object_model import ObjectTree

__all__ = ["ArticulatedScene", "ObjectGeoms", "object_geoms", "with_mount", "HAND_FRICTION_PARAM"]

HAND_FRICTION_PARAM = "hand/friction"  # the fingers' Coulomb coefficient on the object


@dataclasses.dataclass
class ObjectGeoms:
    """The object's collision geoms for finger contact, per body (``[B, G]``, G the most any body has):
    kind (GEOM_*; GEOM_NONE pads), centre (m) and rotation in the body frame, sizes (m: box half sizes; sphere
    radius; capsule and cylinder radius and half length). A mesh geom (GEOM_SDF) collides through the signed
    distance of its watertight mesh sampled on a grid (sim/_mesh_sdf.py): its frame is centred on the grid's box,
    its size the box's half sizes, ``grid`` [B, G, 4] (first index in ``sdf_values``, points along x, y, z),
    ``sdf_values`` every grid (m, negative inside) flattened x-major, one after another."""

    kind: np.ndarray
    pos: np.ndarray
    rot: np.ndarray
    size: np.ndarray
    grid: np.ndarray
    sdf_values: np.ndarray

    def geom_radius(self) -> np.ndarray:
        """[B, G] the radius (m) of a sphere about each geom's centre that holds it."""
        radius = np.linalg.norm(self.size, axis=-1)  # box, grid: half diagonal; cylinder: (r, half length)
        radius = np.where(self.kind == GEOM_SPHERE, self.size[..., 0], radius)
        radius = np.where(self.kind == GEOM_CAPSULE, self.size[..., 0] + self.size[..., 1], radius)
        # the mesh lies in the grid's box shrunk by the pad, whose half diagonal is at most this
        return np.where(self.kind == GEOM_SDF, radius - SDF_PAD, radius)

    def skip_bound(self) -> np.ndarray:
        """[B, G] per geom, the radius (m) the finger contact's nearest-geom search may skip it by: a primitive's
        exact signed distance is at least the distance to its centre minus :meth:`geom_radius`; a mesh's
        sampled one is only near its true distance, so a mesh is never skipped this way (a huge radius)."""
        return np.where(self.kind == GEOM_SDF, 1.0e6, self.geom_radius())

    def bound(self, margin: float = 1.0e-3) -> np.ndarray:
        """Per body, the radius (m) of a sphere about the body origin that holds all its geoms, plus ``margin``
        (rounding); -1 for a body without geoms. The finger contact skips a body whose sphere is out of reach."""
        reach = np.linalg.norm(self.pos, axis=-1) + self.geom_radius()
        reach = np.where(self.kind == GEOM_NONE, -np.inf, reach).max(axis=1)
        return np.where(np.isfinite(reach), reach * (1.0 + margin) + margin, -1.0)


def object_geoms(m) -> ObjectGeoms:
    """Read the collision geoms of body ``object`` and its descendants from a compiled model."""
    import mujoco

    root = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "object")
    bodies = [root] + [b for b in range(root + 1, m.nbody) if _descends(m, b, root)]
    per_body, grids, grid_values, used = [], [], [], 0
    for b in bodies:
        geoms = []
        for g in range(m.ngeom):
            if m.geom_bodyid[g] != b or not (m.geom_contype[g] or m.geom_conaffinity[g]):
                continue
            kind, size = int(m.geom_type[g]), np.asarray(m.geom_size[g], dtype=np.float64)
            pos, rot = m.geom_pos[g].copy(), _quat_to_mat(m.geom_quat[g])
            if kind == mujoco.mjtGeom.mjGEOM_BOX:
                geoms.append((GEOM_BOX, pos, rot, size[:3]))
            elif kind == mujoco.mjtGeom.mjGEOM_SPHERE:
                geoms.append((GEOM_SPHERE, pos, rot, np.array([size[0], 0.0, 0.0])))
            elif kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
                geoms.append((GEOM_CAPSULE, pos, rot, np.array([size[0], size[1], 0.0])))
            elif kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
                geoms.append((GEOM_CYLINDER, pos, rot, np.array([size[0], size[1], 0.0])))
            elif kind == mujoco.mjtGeom.mjGEOM_MESH:
                values, lo, cell = sdf_grid(*_watertight_mesh(m, g), pad=SDF_PAD)
                half = 0.5 * cell * (np.array(values.shape) - 1)
                grids.append((used, *values.shape))
                grid_values.append(values.reshape(-1))
                used += values.size
                geoms.append((GEOM_SDF, pos + rot @ (lo + half), rot, half))
        per_body.append(geoms)
    # padded to at least 4 geoms per body: most objects then share one compiled contact kernel
    width = max(4, max(len(g) for g in per_body))
    kind = np.full((len(bodies), width), GEOM_NONE, dtype=np.int32)
    pos, size = np.zeros((len(bodies), width, 3)), np.zeros((len(bodies), width, 3))
    rot = np.tile(np.eye(3), (len(bodies), width, 1, 1))
    grid = np.zeros((len(bodies), width, 4), dtype=np.int32)
    for b, geoms in enumerate(per_body):
        for g, (k, p, r, s) in enumerate(geoms):
            kind[b, g], pos[b, g], rot[b, g], size[b, g] = k, p, r, s
            if k == GEOM_SDF:
                grid[b, g] = grids.pop(0)
    # a scene without a mesh still binds one value (warp's kernels take no empty array)
    values = np.concatenate(grid_values) if grid_values else np.zeros(1)
    return ObjectGeoms(kind, pos, rot, size, grid, values)


def with_mount(geoms: ObjectGeoms) -> ObjectGeoms:
    """``geoms`` of one body behind a first body without geoms: the fixed mount of a single hinged body
    (:func:`~dexmots_rl.sim._object_model.single_body_tree`)."""
    width = geoms.kind.shape[1]
    return ObjectGeoms(kind=np.concatenate([np.full((1, width), GEOM_NONE, dtype=np.int32), geoms.kind]),
                       pos=np.concatenate([np.zeros((1, width, 3)), geoms.pos]),
                       rot=np.concatenate([np.tile(np.eye(3), (1, width, 1, 1)), geoms.rot]),
                       size=np.concatenate([np.zeros((1, width, 3)), geoms.size]),
                       grid=np.concatenate([np.zeros((1, width, 4), dtype=np.int32), geoms.grid]),
                       sdf_values=geoms.sdf_values)


def _watertight_mesh(m, g: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (geom frame) and faces of mesh geom ``g``; an error naming the geom if it is not watertight."""
    import mujoco
    import trimesh

    mid = m.geom_dataid[g]
    verts = m.mesh_vert[m.mesh_vertadr[mid]: m.mesh_vertadr[mid] + m.mesh_vertnum[mid]].astype(np.float64)
    faces = m.mesh_face[m.mesh_faceadr[mid]: m.mesh_faceadr[mid] + m.mesh_facenum[mid]]
    mesh = trimesh.Trimesh(verts, faces, process=True)
    if not mesh.is_watertight:
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g)
        raise AssetError(f"geom {name!r}: its mesh is not watertight, so its signed distance is undefined")
    return mesh.vertices, mesh.faces


def _descends(m, b: int, root: int) -> bool:
    while b > 0:
        if b == root:
            return True
        b = int(m.body_parentid[b])
    return False


@dataclasses.dataclass
class ArticulatedScene:
    """A fixed-mount hand (``hand``: the hand fields of :class:`~dexmots_rl.sim.SceneModel`, by name) and an
    articulated object (``tree``, ``geoms``); ``palm``: (centres [K, 3], rotations [K, 3, 3], half sizes [K, 3]),
    world frame, of the palm's boxes that collide with the object (none: the palm is drawn only).

    ``variant_trees``, ``variant_geoms``, ``variant_paths``: the object's variants (K of one topology, from one
    file each; :mod:`._object_variants`); ``tree``, ``geoms`` and ``path`` are variant 0's. One file: K = 1."""

    path: str
    hand: dict
    tree: ObjectTree
    geoms: ObjectGeoms
    palm: tuple
    variant_trees: list = dataclasses.field(default_factory=list)
    variant_geoms: list = dataclasses.field(default_factory=list)
    variant_paths: list = dataclasses.field(default_factory=list)

    def __post_init__(self):
        self.variant_trees = self.variant_trees or [self.tree]
        self.variant_geoms = self.variant_geoms or [self.geoms]
        self.variant_paths = self.variant_paths or [self.path]

    def __getattr__(self, name):  # the hand's fields read like SceneModel's (scene.num_fingers, ...)
        hand = self.__dict__.get("hand")
        if hand is not None and name in hand:
            return hand[name]
        raise AttributeError(name)

    articulated = True

    @property
    def num_hand_dofs(self) -> int:
        return self.hand["num_fingers"] * self.hand["joints_per_finger"]

    @property
    def object_nq(self) -> int:
        return self.tree.nq

    @property
    def object_nv(self) -> int:
        return self.tree.nv

    @property
    def num_variants(self) -> int:
        return len(self.variant_trees)

    @property
    def param_names(self) -> tuple[str, ...]:
        """The object tree's named parameters (its joints', its moving bodies' masses, the table's friction), the
        fingers' friction coefficient ``"hand/friction"``, then ``"variant"`` (the world's object variant) with
        K > 1."""
        return self.tree.param_names + (HAND_FRICTION_PARAM,) + (("variant",) if self.num_variants > 1 else ())

    def default_param_values(self) -> dict[str, float]:
        return {**self.tree.default_param_values(), HAND_FRICTION_PARAM: HAND_FRICTION,
                **({"variant": 0.0} if self.num_variants > 1 else {})}

    @property
    def variant_q0(self) -> np.ndarray:
        """[K, nq] each variant's initial object coordinates."""
        return np.stack([t.q0 for t in self.variant_trees])

    @property
    def object_q0(self) -> np.ndarray:
        return self.tree.q0
