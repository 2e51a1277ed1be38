"""What the viewer and the RGB renderer draw: every body of a scene, as MuJoCo compiles its MJCF, as meshes.

Each recorded body (the hand's links, then the object's bodies: ``body_pose``'s order) is drawn with its
geoms in its own frame; bodies that do not move (the palm, an operable object's static base) and the table
plane are drawn once per world, in the world's frame. A body with visual-only geoms (MJCF ``group="1"``, such
as the object library's watertight meshes) is drawn with those; any other body with all its geoms (primitives
meshed with trimesh, mesh geoms from MuJoCo's compiled vertices and faces). A body welded to a moving one (no
joint between them) is drawn with it. Colours are the MJCF's ``rgba``; a geom left at MuJoCo's default grey
takes its role's colour (``ROLE_RGBA``).

Example:
    >>> from dexmots_rl.assets import asset_path
    >>> from dexmots_rl.sim import load_scene
    >>> geo = scene_geometry(load_scene(asset_path("allegro_knob.xml")))
    >>> geo.body_names[-1], geo.num_hand_links, sorted({p.role for p in geo.parts})
    ('object', 16, ['hand', 'object', 'palm'])
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

__all__ = ["MeshPart", "SceneGeometry", "scene_geometry", "recorded_body_names", "box_mesh", "ROLE_RGBA",
           "GOAL_RGBA", "STATIC"]

log = logging.getLogger(__name__)

STATIC = -1  # MeshPart.body of a part drawn in the world's frame (it never moves)
ROLE_RGBA = {"hand": (0.75, 0.38, 0.12, 1.0), "palm": (0.60, 0.30, 0.10, 1.0), "object": (0.20, 0.40, 0.85, 1.0),
             "base": (0.55, 0.55, 0.60, 1.0), "table": (0.80, 0.75, 0.65, 1.0)}
GOAL_RGBA = (0.30, 0.85, 0.40, 0.30)
_MUJOCO_DEFAULT_RGBA = (0.5, 0.5, 0.5, 1.0)
_TABLE_THICKNESS = 0.01  # m: the table plane is drawn as a slab this thick under its surface
_UNBOUNDED_PLANE = 1.0  # m: half size drawn for an infinite plane (MJCF size 0)


@dataclasses.dataclass
class MeshPart:
    """One drawn piece: a triangle mesh (``vertices`` [V, 3] in the frame of recorded body ``body``, or in the
    world's frame when ``body`` is :data:`STATIC`; ``faces`` [T, 3], counter-clockwise seen from outside), its
    colour, the MuJoCo body it comes from (``name``) and its ``role``: hand, palm, object, base (a static object
    part) or table."""

    name: str
    role: str
    body: int
    vertices: np.ndarray
    faces: np.ndarray
    rgba: tuple[float, float, float, float]


@dataclasses.dataclass
class SceneGeometry:
    """The drawn scene: ``body_names`` (recorded bodies, ``body_pose``'s order: ``num_hand_links`` hand links
    then the object's bodies), the mesh ``parts`` and the goal ghost (the object's bodies at rest, in the
    frame of its base: ``ghost_vertices`` [V, 3], ``ghost_faces`` [T, 3])."""

    body_names: list[str]
    num_hand_links: int
    parts: list[MeshPart]
    ghost_vertices: np.ndarray
    ghost_faces: np.ndarray

    def world_points(self, body_pose: np.ndarray, roles=None) -> np.ndarray:
        """Every vertex [K, 3] of the parts (of ``roles``, default all but the table) placed at ``body_pose``
        [B, 7] (one world)."""
        roles = set(roles or ("hand", "palm", "object", "base"))
        pts = [transform(p.vertices, body_pose[p.body]) if p.body != STATIC else p.vertices
               for p in self.parts if p.role in roles and len(p.vertices)]
        return np.concatenate(pts) if pts else np.zeros((0, 3))


def quat_to_mat(q) -> np.ndarray:
    """The rotation matrix of a ``wxyz`` quaternion (normalised first)."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def transform(points: np.ndarray, pose) -> np.ndarray:
    """``points`` [K, 3] of a body frame placed at ``pose`` (pos + wxyz quat)."""
    return points @ quat_to_mat(pose[3:7]).T + np.asarray(pose[:3])


def recorded_body_names(scene) -> list[str]:
    """The bodies of ``body_pose`` for a scene: the hand's links, then the object's body or bodies."""
    tree = getattr(scene, "tree", None)  # an ArticulatedScene's object tree
    if tree is not None:
        return list(scene.body_names) + list(tree.body_names)
    return list(scene.body_names)


def box_mesh(half) -> tuple[np.ndarray, np.ndarray]:
    """Vertices [8, 3] and faces [12, 3] of a box with half sizes ``half``, centred at the origin (trimesh)."""
    import trimesh

    mesh = trimesh.creation.box(extents=2 * np.asarray(half, dtype=np.float64))
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)


def _geom_mesh(m, g: int):
    """Vertices and faces of geom ``g`` in its own frame (None for a kind that is not drawn)."""
    import mujoco
    import trimesh

    kind, size = int(m.geom_type[g]), np.asarray(m.geom_size[g], dtype=np.float64)
    t = mujoco.mjtGeom
    if kind == t.mjGEOM_MESH:
        mid = int(m.geom_dataid[g])
        v0, nv, f0, nf = m.mesh_vertadr[mid], m.mesh_vertnum[mid], m.mesh_faceadr[mid], m.mesh_facenum[mid]
        return m.mesh_vert[v0:v0 + nv].astype(np.float64), m.mesh_face[f0:f0 + nf].astype(np.int64)
    if kind == t.mjGEOM_BOX:
        return box_mesh(size)
    if kind == t.mjGEOM_PLANE:
        sx, sy = (float(s) if s > 0 else _UNBOUNDED_PLANE for s in size[:2])
        v, f = box_mesh((sx, sy, 0.5 * _TABLE_THICKNESS))
        return v - [0.0, 0.0, 0.5 * _TABLE_THICKNESS], f
    if kind == t.mjGEOM_SPHERE:
        mesh = trimesh.creation.icosphere(subdivisions=2, radius=float(size[0]))
    elif kind == t.mjGEOM_ELLIPSOID:
        mesh = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
        mesh.apply_scale(size[:3])
    elif kind == t.mjGEOM_CAPSULE:
        mesh = trimesh.creation.capsule(height=2 * float(size[1]), radius=float(size[0]), count=[12, 12])
    elif kind == t.mjGEOM_CYLINDER:
        mesh = trimesh.creation.cylinder(radius=float(size[0]), height=2 * float(size[1]), sections=24)
    else:  # height fields, SDF plugins: not drawn
        log.warning("geom %d of kind %d is not drawn", g, kind)
        return None
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)


def _moves(m, b: int) -> bool:
    """Whether body ``b`` or an ancestor has a joint (else it is welded to the world)."""
    while b > 0:
        if m.body_jntnum[b] > 0:
            return True
        b = int(m.body_parentid[b])
    return False


def _compiled_model(scene, asset=None):
    """MuJoCo's model of ``scene``: its MJCF file, or (when that file is gone, as for a scene built in a
    temporary folder) the hand-and-object MJCF of ``asset`` written again."""
    import tempfile
    from pathlib import Path

    import mujoco

    if Path(scene.path).is_file():
        return mujoco.MjModel.from_xml_path(str(scene.path))
    if asset is None:
        raise ValueError(f"{scene.path}: the scene's MJCF file is gone; keep it while recording, or pass the "
                         "scene's object asset to rebuild it")
    from ..assets.hand_scene import hand_object_scene_xml

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scene.xml"
        path.write_text(hand_object_scene_xml(asset, tmp))
        return mujoco.MjModel.from_xml_path(str(path))


def scene_geometry(scene, asset=None) -> SceneGeometry:
    """The geometry of every body of ``scene`` (a :class:`~dexmots_rl.sim.SceneModel` or an
    :class:`~dexmots_rl.sim._articulated.ArticulatedScene`), read from the MJCF it was loaded from (or, when that
    file is gone, from the scene of the Allegro hand and the object ``asset``,
    :func:`~dexmots_rl.assets.hand_scene.hand_object_scene_xml`)."""
    import mujoco

    m = _compiled_model(scene, asset)
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)  # at qpos0: welded bodies' offsets and static bodies' world poses
    names = recorded_body_names(scene)
    num_links = int(scene.num_hand_dofs)
    index = {}
    for i, n in enumerate(names):
        b = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n)
        if b < 0:
            raise ValueError(f"{scene.path}: the scene has no body {n!r} (a recorded body)")
        index[b] = i
    hand_ancestors = set()
    for n in names[:num_links]:
        b = int(m.body_parentid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n)])
        while b > 0:
            hand_ancestors.add(b)
            b = int(m.body_parentid[b])
    visual = {int(m.geom_bodyid[g]) for g in range(m.ngeom) if m.geom_group[g] == 1}
    groups: dict[tuple, list] = {}
    for g in range(m.ngeom):
        body = int(m.geom_bodyid[g])
        rgba = tuple(float(c) for c in m.geom_rgba[g])
        if rgba[3] <= 0 or (body in visual and m.geom_group[g] != 1):
            continue
        anchor = body
        while anchor > 0 and anchor not in index and m.body_jntnum[anchor] == 0:
            anchor = int(m.body_parentid[anchor])
        if anchor in index:
            recorded = index[anchor]
            role = "hand" if recorded < num_links else "object"
        elif anchor > 0 or _moves(m, body):
            log.warning("body %r moves but is not recorded: not drawn", mujoco.mj_id2name(m, 1, body))
            continue
        else:
            recorded = STATIC
            role = ("table" if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE else
                    "palm" if body in hand_ancestors else "base")
        if body == 0 and role != "table":
            continue  # other world geoms (floors, markers) are not part of the scene's bodies
        mesh = _geom_mesh(m, g)
        if mesh is None:
            continue
        rot = d.geom_xmat[g].reshape(3, 3)
        verts = mesh[0] @ rot.T + d.geom_xpos[g]  # world frame at qpos0
        if recorded != STATIC:  # into the recorded body's frame
            rot_a = d.xmat[anchor].reshape(3, 3)
            verts = (verts - d.xpos[anchor]) @ rot_a
        if np.allclose(rgba, _MUJOCO_DEFAULT_RGBA, atol=1e-6):
            rgba = ROLE_RGBA[role]
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, anchor if recorded != STATIC else body) or "world"
        groups.setdefault((recorded, name, role, rgba), []).append((verts, mesh[1]))
    parts = []
    for (recorded, name, role, rgba), meshes in groups.items():
        verts, faces, offset = [], [], 0
        for v, f in meshes:
            verts.append(v)
            faces.append(f + offset)
            offset += len(v)
        parts.append(MeshPart(name, role, recorded, np.concatenate(verts), np.concatenate(faces), rgba))
    return SceneGeometry(names, num_links, parts, *_ghost(m, d, parts, names, num_links))


def _ghost(m, d, parts: list[MeshPart], names: list[str], num_links: int) -> tuple[np.ndarray, np.ndarray]:
    """The object's moving bodies at rest (qpos0), merged in the frame of its base."""
    import mujoco

    def pose(i):
        b = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, names[i])
        return np.concatenate([d.xpos[b], d.xquat[b]])

    base = pose(num_links) if len(names) > num_links else np.array([0, 0, 0, 1.0, 0, 0, 0])
    rot_b = quat_to_mat(base[3:])
    verts, faces, offset = [], [], 0
    for p in parts:
        if p.role != "object":
            continue
        v = (transform(p.vertices, pose(p.body)) - base[:3]) @ rot_b
        verts.append(v)
        faces.append(p.faces + offset)
        offset += len(v)
    if not verts:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return np.concatenate(verts), np.concatenate(faces)
