"""Reading geometry out of a compiled MuJoCo model: link contact spheres, the object's collision shape
(convex planes, sphere, cylinder or a signed-distance grid, sim/_mesh_sdf.py), palm and object-base
boxes, the object's surface samples. :func:`dexmots_rl.sim._model.load_scene` assembles the scene from these.
"""

from __future__ import annotations

import numpy as np

from ._constants import GEOM_CONVEX, GEOM_CYLINDER, GEOM_SDF, GEOM_SPHERE

__all__ = ["AssetError", "MAX_PLANES"]

MAX_PALM_BOXES = 4  # colliding box geoms on body "hand" (palm contact, free objects only)
MAX_OBJECT_POINTS = 32  # object surface samples for palm contact
CYLINDER_RIM_POINTS = 8  # samples per cap rim of a cylinder object (palm contact)
MAX_PLANES = 32  # convex objects with more faces than this (or non-convex meshes) use a signed-distance grid
SDF_RESOLUTION = 40  # grid points along the longest padded axis


class AssetError(ValueError):
    """An asset file is missing, does not parse, or does not follow the scene conventions."""


def _quat_to_mat(q: np.ndarray) -> np.ndarray:
    import mujoco

    out = np.zeros(9)
    mujoco.mju_quat2Mat(out, np.asarray(q, dtype=np.float64))
    return out.reshape(3, 3)


def _body_inertia(m, b: int) -> tuple[float, np.ndarray, np.ndarray]:
    rot = _quat_to_mat(m.body_iquat[b])
    return float(m.body_mass[b]), m.body_ipos[b].copy(), rot @ np.diag(m.body_inertia[b]) @ rot.T


def _link_points(m, b: int, per_capsule: int) -> list[tuple[np.ndarray, float]]:
    """Contact sample spheres for the capsule/sphere geoms of body ``b`` (in the body frame)."""
    import mujoco

    points = []
    for g in range(m.ngeom):
        if m.geom_bodyid[g] != b:
            continue
        rot, pos = _quat_to_mat(m.geom_quat[g]), m.geom_pos[g]
        gtype, size = int(m.geom_type[g]), m.geom_size[g]
        if gtype == int(mujoco.mjtGeom.mjGEOM_SPHERE):
            points.append((pos.copy(), float(size[0])))
        elif gtype == int(mujoco.mjtGeom.mjGEOM_CAPSULE):
            for s in np.linspace(-1.0, 1.0, per_capsule):
                points.append((pos + rot[:, 2] * size[1] * s, float(size[0])))
        else:
            raise AssetError(
                f"geom {mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g)!r} on a finger link: only "
                "capsules and spheres are supported on the hand"
            )
    return points


def _sdf_grid(mesh, pad: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Signed distance (negative inside) sampled on a regular grid around ``mesh`` (trimesh), its longest axis
    :data:`SDF_RESOLUTION` points."""
    from ._mesh_sdf import sdf_grid

    cell = float((np.ptp(mesh.bounds, 0) + 2 * pad).max() / (SDF_RESOLUTION - 1))
    return sdf_grid(mesh.vertices, mesh.faces, pad, cell)


def _object_shape(m, b: int) -> tuple[int, np.ndarray, np.ndarray, float, tuple]:
    import mujoco
    import trimesh

    geoms = [g for g in range(m.ngeom) if m.geom_bodyid[g] == b]
    if len(geoms) != 1:
        raise AssetError(f"body 'object' must have exactly one geom, found {len(geoms)}")
    g = geoms[0]
    gtype, size = int(m.geom_type[g]), m.geom_size[g]
    rot, pos = _quat_to_mat(m.geom_quat[g]), m.geom_pos[g]
    none = np.zeros((0, 4))
    no_sdf = (np.zeros((1, 1, 1)), np.zeros(3), 1.0)
    if gtype == int(mujoco.mjtGeom.mjGEOM_SPHERE):
        return GEOM_SPHERE, none, np.array([size[0], 0.0]), float(size[0] + np.linalg.norm(pos)), no_sdf
    if gtype == int(mujoco.mjtGeom.mjGEOM_CYLINDER):
        if np.abs(pos).max() > 1e-9 or np.abs(rot - np.eye(3)).max() > 1e-9:
            raise AssetError("object cylinder geom must sit at the object body frame")
        return GEOM_CYLINDER, none, np.array([size[0], size[1]]), float(np.hypot(size[0], size[1])), no_sdf
    mesh = None
    if gtype == int(mujoco.mjtGeom.mjGEOM_BOX):
        corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * size
    elif gtype == int(mujoco.mjtGeom.mjGEOM_MESH):
        mid = m.geom_dataid[g]
        start, count = m.mesh_vertadr[mid], m.mesh_vertnum[mid]
        corners = m.mesh_vert[start : start + count].astype(np.float64)
        fstart, fcount = m.mesh_faceadr[mid], m.mesh_facenum[mid]
        mesh = trimesh.Trimesh(corners @ rot.T + pos, m.mesh_face[fstart : fstart + fcount], process=True)
    else:
        raise AssetError(f"object geom type {int(gtype)} is not supported (box, mesh, sphere, cylinder)")
    corners = corners @ rot.T + pos
    hull = trimesh.convex.convex_hull(corners)
    normals = np.asarray(hull.facets_normal) if len(hull.facets) else np.zeros((0, 3))
    origins = np.asarray(hull.facets_origin) if len(hull.facets) else np.zeros((0, 3))
    # faces that are not part of a multi-triangle facet are facets of their own
    lone = np.setdiff1d(np.arange(len(hull.faces)), np.concatenate(hull.facets) if len(hull.facets) else [])
    normals = np.concatenate([normals, hull.face_normals[lone]])
    origins = np.concatenate([origins, hull.triangles_center[lone]])
    offsets = np.einsum("ij,ij->i", normals, origins)
    planes = np.unique(np.round(np.concatenate([normals, offsets[:, None]], 1), 9), axis=0)
    bound = float(np.linalg.norm(corners, axis=1).max())
    convex = mesh is None or (mesh.is_watertight and abs(mesh.volume - hull.volume) <= 1e-3 * hull.volume)
    if convex and len(planes) <= MAX_PLANES:
        return GEOM_CONVEX, planes, np.zeros(2), bound, no_sdf
    if not mesh.is_watertight:
        raise AssetError("object mesh is neither convex (<= 32 faces) nor watertight; cannot build its SDF")
    return GEOM_SDF, none, np.zeros(2), bound, _sdf_grid(mesh, pad=0.25 * float(np.ptp(mesh.bounds, 0).max()))


def _palm_boxes(m, d, hand: int, obj_geom: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World pose and half sizes of the box geoms on body ``hand`` that collide with ``obj_geom``."""
    import mujoco

    og_type, og_aff = int(m.geom_contype[obj_geom]), int(m.geom_conaffinity[obj_geom])
    pos, rot, half = [], [], []
    for g in range(m.ngeom):
        if m.geom_bodyid[g] != hand:
            continue
        if not (int(m.geom_contype[g]) & og_aff or og_type & int(m.geom_conaffinity[g])):
            continue  # visual only (for this object)
        if int(m.geom_type[g]) != int(mujoco.mjtGeom.mjGEOM_BOX):
            gname = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g)
            raise AssetError(f"geom {gname!r} on body 'hand' collides with the object: only boxes are supported "
                             "as palm collision geometry (or set contype/conaffinity to 0)")
        pos.append(d.geom_xpos[g].copy())
        rot.append(d.geom_xmat[g].reshape(3, 3).copy())
        half.append(m.geom_size[g].copy())
    if len(pos) > MAX_PALM_BOXES:
        raise AssetError(f"body 'hand' has {len(pos)} colliding palm boxes; at most {MAX_PALM_BOXES} are supported")
    if not pos:
        return np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3))
    return np.stack(pos), np.stack(rot), np.stack(half)


def _object_points(m, g: int) -> tuple[np.ndarray, np.ndarray]:
    """Surface samples of the object geom ``g`` for palm contact, in the object body frame (see
    :attr:`SceneModel.object_point_pos`)."""
    import mujoco
    import trimesh

    gtype, size = int(m.geom_type[g]), m.geom_size[g]
    rot, pos = _quat_to_mat(m.geom_quat[g]), m.geom_pos[g]
    if gtype == int(mujoco.mjtGeom.mjGEOM_SPHERE):
        return pos[None].copy(), np.array([float(size[0])])
    if gtype == int(mujoco.mjtGeom.mjGEOM_BOX):
        # every point of {-1, 0, 1}^3 but the centre: corners, edge midpoints, face centres
        grid = np.array([[x, y, z] for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1) if (x, y, z) != (0, 0, 0)])
        local = grid * size[:3]
    elif gtype == int(mujoco.mjtGeom.mjGEOM_CYLINDER):
        ang = 2 * np.pi * np.arange(CYLINDER_RIM_POINTS) / CYLINDER_RIM_POINTS
        rim = np.stack([size[0] * np.cos(ang), size[0] * np.sin(ang), np.zeros_like(ang)], 1)
        local = np.concatenate([rim + [0, 0, size[1]], rim - [0, 0, size[1]], [[0, 0, size[1]], [0, 0, -size[1]]]])
    elif gtype == int(mujoco.mjtGeom.mjGEOM_MESH):
        mid = m.geom_dataid[g]
        verts = m.mesh_vert[m.mesh_vertadr[mid] : m.mesh_vertadr[mid] + m.mesh_vertnum[mid]].astype(np.float64)
        local = trimesh.convex.convex_hull(verts).vertices
        if len(local) > MAX_OBJECT_POINTS:
            raise AssetError(f"object mesh hull has {len(local)} vertices; palm contact samples at most "
                             f"{MAX_OBJECT_POINTS}")
    else:
        raise AssetError(f"object geom type {gtype} has no palm-contact samples")
    return local @ rot.T + pos, np.zeros(len(local))
