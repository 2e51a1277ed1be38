"""What a recording draws: the hand links and the object of a :class:`~dexmots_rl.sim.SceneModel` as geometry.

The hand is drawn exactly as the simulator sees it: every link is the union of its contact spheres
(``point_pos`` / ``point_radius``, link frame), and consecutive spheres of one link with the same radius
are joined by a cylinder, which turns the sampled points of a capsule back into that capsule. The
object's moving part is a triangle mesh in its body frame (an operable object's static base: its boxes,
world frame, ``base_boxes``): the convex polytope of its planes (halfspace intersection),
an icosphere or a cylinder for the analytic shapes, and for a signed-distance object the mesh of the
MJCF the scene was compiled from.

Example:
    >>> from dexmots_rl.assets import asset_path
    >>> from dexmots_rl.sim import load_scene
    >>> geo = scene_geometry(load_scene(asset_path("claw_screw.xml")))
    >>> geo.body_names
    ['right_proximal', 'right_distal', 'left_proximal', 'left_distal', 'object']
    >>> geo.links[0].segments.shape, geo.object_faces.shape[1]
    ((3, 7), 3)
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

__all__ = ["LinkGeometry", "SceneGeometry", "scene_geometry", "link_mesh", "box_mesh", "HAND_RGBA", "OBJECT_RGBA", "GOAL_RGBA", "BASE_RGBA"]

log = logging.getLogger(__name__)

HAND_RGBA = (0.75, 0.38, 0.12, 1.0)
OBJECT_RGBA = (0.20, 0.40, 0.85, 1.0)
GOAL_RGBA = (0.30, 0.85, 0.40, 0.30)
BASE_RGBA = (0.55, 0.55, 0.60, 1.0)


@dataclasses.dataclass
class LinkGeometry:
    """One hand link in its body frame: ``spheres`` [K, 4] (centre, radius), ``segments`` [S, 7] (p0, p1, radius)."""

    spheres: np.ndarray
    segments: np.ndarray


@dataclasses.dataclass
class SceneGeometry:
    """Geometry of every body: ``links`` (hand, in ``body_names`` order) then the object mesh."""

    body_names: list[str]
    links: list[LinkGeometry]
    object_vertices: np.ndarray  # [V, 3] object frame
    object_faces: np.ndarray  # [T, 3] int, counter-clockwise seen from outside
    # the operable object's static base (world frame): per box centre (3), wxyz quat (4), half sizes (3)
    base_boxes: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 10)))

    @property
    def extent(self) -> float:
        """A length that spans the scene at its reference pose (used to space worlds apart)."""
        reach = [np.abs(g.spheres[:, :3]).max() + g.spheres[:, 3].max() for g in self.links if len(g.spheres)]
        obj = float(np.linalg.norm(self.object_vertices, axis=1).max()) if len(self.object_vertices) else 0.0
        return float(sum(reach) + 2 * obj) if reach else 2 * obj


def _link_geometry(points: np.ndarray, radii: np.ndarray) -> LinkGeometry:
    keep = radii > 0
    points, radii = points[keep], radii[keep]
    spheres = np.concatenate([points, radii[:, None]], 1) if len(points) else np.zeros((0, 4))
    segs = [np.concatenate([points[k], points[k + 1], [radii[k]]]) for k in range(len(points) - 1)
            if radii[k] == radii[k + 1] and np.linalg.norm(points[k + 1] - points[k]) > 0]
    return LinkGeometry(spheres, np.stack(segs) if segs else np.zeros((0, 7)))


def _convex_mesh(planes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    import trimesh
    from scipy.optimize import linprog
    from scipy.spatial import HalfspaceIntersection

    normals, offsets = planes[:, :3], planes[:, 3]
    if (offsets > 1e-9).all():
        inside = np.zeros(3)
    else:  # Chebyshev centre: max r s.t. n.x + r |n| <= d
        res = linprog(np.r_[0, 0, 0, -1.0], A_ub=np.c_[normals, np.linalg.norm(normals, axis=1)], b_ub=offsets,
                      bounds=[(None, None)] * 3 + [(0, None)])
        inside = res.x[:3]
    verts = HalfspaceIntersection(np.c_[normals, -offsets], inside).intersections
    hull = trimesh.convex.convex_hull(verts)
    return np.asarray(hull.vertices, dtype=np.float64), np.asarray(hull.faces, dtype=np.int64)


def _mjcf_object_mesh(path: str) -> tuple[np.ndarray, np.ndarray]:
    import mujoco

    m = mujoco.MjModel.from_xml_path(path)
    body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "object")
    g = next(g for g in range(m.ngeom) if m.geom_bodyid[g] == body)
    mid = m.geom_dataid[g]
    v0, nv, f0, nf = m.mesh_vertadr[mid], m.mesh_vertnum[mid], m.mesh_faceadr[mid], m.mesh_facenum[mid]
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, m.geom_quat[g])
    verts = m.mesh_vert[v0 : v0 + nv].astype(np.float64) @ rot.reshape(3, 3).T + m.geom_pos[g]
    return verts, m.mesh_face[f0 : f0 + nf].astype(np.int64)


def _object_mesh(scene) -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    from ..sim.mjcf_shapes import SHAPE_CONVEX, SHAPE_CYLINDER, SHAPE_SPHERE

    shape = int(scene.object_shape)
    try:
        if shape == SHAPE_CONVEX:
            return _convex_mesh(np.asarray(scene.object_planes, dtype=np.float64))
        if shape == SHAPE_SPHERE:
            mesh = trimesh.creation.icosphere(subdivisions=3, radius=float(scene.object_shape_size[0]))
        elif shape == SHAPE_CYLINDER:
            radius, half = (float(x) for x in scene.object_shape_size)
            mesh = trimesh.creation.cylinder(radius=radius, height=2 * half, sections=32)
        else:
            return _mjcf_object_mesh(scene.path)
    except Exception as exc:  # never fail a recording over the picture of the object
        log.warning("object geometry (shape %d) could not be meshed (%s); drawing its bounding sphere", shape, exc)
        mesh = trimesh.creation.icosphere(subdivisions=2, radius=float(scene.object_bound))
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)


def scene_geometry(scene) -> SceneGeometry:
    """The geometry of every body of ``scene`` (a :class:`~dexmots_rl.sim.SceneModel`); see the module docstring."""
    p = scene.points_per_link
    links = [_link_geometry(np.asarray(scene.point_pos[i * p : (i + 1) * p], dtype=np.float64),
                            np.asarray(scene.point_radius[i * p : (i + 1) * p], dtype=np.float64))
             for i in range(scene.num_hand_dofs)]
    verts, faces = _object_mesh(scene)
    return SceneGeometry(list(scene.body_names), links, verts, faces, _base_boxes(scene))


def _base_boxes(scene) -> np.ndarray:
    import mujoco

    rows = []
    for pos, rot, half in zip(scene.base_box_pos, scene.base_box_rot, scene.base_box_half):
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, np.asarray(rot, dtype=np.float64).reshape(-1))
        rows.append(np.concatenate([pos, quat, half]))
    return np.asarray(rows, dtype=np.float64).reshape(-1, 10)


def box_mesh(half) -> tuple[np.ndarray, np.ndarray]:
    """Vertices [8, 3] and faces [12, 3] of a box with half sizes ``half``, centred at the origin (trimesh)."""
    import trimesh

    mesh = trimesh.creation.box(extents=2 * np.asarray(half, dtype=np.float64))
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)


def _rotation_z_to(d: np.ndarray) -> np.ndarray:
    """A rotation matrix taking +z to the unit vector ``d``."""
    z = np.array([0.0, 0.0, 1.0])
    v, c = np.cross(z, d), float(np.dot(z, d))
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + c)


def link_mesh(link: LinkGeometry, sections: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """One triangle mesh (vertices [V, 3], faces [T, 3]) for a link: its spheres and cylinders, concatenated."""
    import trimesh

    parts = []
    for s in link.spheres:
        sphere = trimesh.creation.icosphere(subdivisions=2, radius=float(s[3]))
        sphere.apply_translation(s[:3])
        parts.append(sphere)
    for seg in link.segments:
        p0, p1, r = seg[:3], seg[3:6], float(seg[6])
        length = float(np.linalg.norm(p1 - p0))
        tf = np.eye(4)
        tf[:3, :3], tf[:3, 3] = _rotation_z_to((p1 - p0) / length), 0.5 * (p0 + p1)
        parts.append(trimesh.creation.cylinder(radius=r, height=length, sections=sections, transform=tf))
    if not parts:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    mesh = trimesh.util.concatenate(parts)
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)
