"""Watertight solids for the procedural objects: primitives, revolved profiles, extruded outlines, booleans.

The solids are built with ``manifold3d`` (every operation keeps a closed, self-intersection-free 2-manifold,
so a union of pieces is one watertight solid, not overlapping shells) and converted to ``trimesh.Trimesh``
at the end with :func:`to_trimesh`. Lengths in metres; all shapes are in the caller's part frame.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Iterable, Sequence

import numpy as np
import trimesh

if TYPE_CHECKING:  # manifold3d is imported only when a solid is built
    from manifold3d import Manifold as Solid

__all__ = [
    "box", "rounded_box", "cylinder", "sphere", "capsule", "polyline_tube", "revolve", "extrude",
    "ring", "union", "difference", "to_trimesh", "rotation_between", "arc", "SEGMENTS",
]

SEGMENTS = 32  # facets around a round solid: smooth enough to read as round, few enough for fast SDF grids


def _manifold():
    """The manifold3d module, imported when a solid is first built (the object description and a URDF
    object load without it)."""
    try:
        import manifold3d
    except ImportError as error:
        raise ImportError("building the procedural objects needs manifold3d (pip install manifold3d)") from error
    return manifold3d


def box(size: Sequence[float], center: Sequence[float] = (0.0, 0.0, 0.0)) -> Solid:
    """An axis-aligned box of full extents ``size`` centred at ``center``."""
    return _manifold().Manifold.cube(tuple(float(s) for s in size), center=True).translate(tuple(center))


def rounded_box(size: Sequence[float], radius: float, center: Sequence[float] = (0.0, 0.0, 0.0)) -> Solid:
    """A box of full extents ``size`` with edges rounded by ``radius`` (the hull of eight spheres)."""
    half = np.asarray(size, dtype=float) / 2.0 - radius
    if np.any(half <= 0):
        raise ValueError(f"rounded_box: radius {radius} too large for size {tuple(size)}")
    corners = [_manifold().Manifold.sphere(radius, SEGMENTS // 2).translate(tuple(np.asarray(center) + half * np.array(s)))
               for s in np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).T.reshape(-1, 3)]
    return _manifold().Manifold.batch_hull(corners)


def rotation_between(a: Sequence[float], b: Sequence[float]) -> np.ndarray:
    """The 3x3 rotation that turns direction ``a`` into direction ``b``."""
    a = np.asarray(a, dtype=float) / np.linalg.norm(a)
    b = np.asarray(b, dtype=float) / np.linalg.norm(b)
    v, c = np.cross(a, b), float(np.dot(a, b))
    if c < -1.0 + 1e-9:  # opposite: half a turn about any axis normal to a
        normal = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        normal /= np.linalg.norm(normal)
        return 2.0 * np.outer(normal, normal) - np.eye(3)
    skew = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + skew + skew @ skew / (1.0 + c)


def _place(solid: Solid, rotation: np.ndarray, translation: Sequence[float]) -> Solid:
    matrix = np.hstack([rotation, np.asarray(translation, dtype=float).reshape(3, 1)])
    return solid.transform(matrix)


def cylinder(radius: float, p0: Sequence[float], p1: Sequence[float], radius_top: float | None = None) -> Solid:
    """A cylinder (or a cone frustum when ``radius_top`` is given) from point ``p0`` to point ``p1``."""
    p0, p1 = np.asarray(p0, dtype=float), np.asarray(p1, dtype=float)
    length = float(np.linalg.norm(p1 - p0))
    top = radius if radius_top is None else radius_top
    solid = _manifold().Manifold.cylinder(length, radius, top, SEGMENTS)
    return _place(solid, rotation_between((0, 0, 1), p1 - p0), p0)


def sphere(radius: float, center: Sequence[float] = (0.0, 0.0, 0.0)) -> Solid:
    return _manifold().Manifold.sphere(radius, SEGMENTS).translate(tuple(center))


def capsule(radius: float, p0: Sequence[float], p1: Sequence[float]) -> Solid:
    """A capsule of ``radius`` around the segment p0-p1 (the hull of two spheres)."""
    return _manifold().Manifold.batch_hull([sphere(radius, p0), sphere(radius, p1)])


def polyline_tube(radius: float, points: Iterable[Sequence[float]]) -> Solid:
    """A chain of capsules through ``points`` (a bent rod: a handle, a lever, a spout)."""
    points = [np.asarray(p, dtype=float) for p in points]
    return union(capsule(radius, a, b) for a, b in zip(points[:-1], points[1:]))


def revolve(profile: Sequence[Sequence[float]], segments: int = SEGMENTS) -> Solid:
    """The solid of revolution about z of a profile of (radius, z) points (counter-clockwise, radius >= 0)."""
    section = _manifold().CrossSection([[(float(r), float(z)) for r, z in profile]])
    return _manifold().Manifold.revolve(section, segments)


def extrude(outline: Sequence[Sequence[float]], thickness: float, plane: str = "xy") -> Solid:
    """A polygon ``outline`` (2D points) extruded by ``thickness``, centred on its plane.

    ``plane="xy"``: the outline in (x, y), thickness along z; ``"xz"``: the outline in (x, z) (a side
    profile), thickness along y."""
    section = _manifold().CrossSection([[(float(u), float(v)) for u, v in outline]])
    solid = section.extrude(thickness).translate((0.0, 0.0, -thickness / 2.0))
    if plane == "xy":
        return solid
    if plane == "xz":  # (u, v, w) -> (u, -w, v): the profile stands up, thickness along y
        return _place(solid, np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]), (0.0, 0.0, 0.0))
    raise ValueError(f"extrude: plane must be 'xy' or 'xz', got {plane!r}")


def ring(inner_radius: float, outer_radius: float, thickness: float,
         center: Sequence[float] = (0.0, 0.0, 0.0)) -> Solid:
    """A flat ring (an annulus extruded along z by ``thickness``, centred at ``center``)."""
    outer = _manifold().CrossSection.circle(outer_radius, SEGMENTS)
    inner = _manifold().CrossSection.circle(inner_radius, SEGMENTS)
    return (outer - inner).extrude(thickness).translate((center[0], center[1], center[2] - thickness / 2.0))


def union(solids: Iterable[Solid]) -> Solid:
    manifold3d = _manifold()
    return manifold3d.Manifold.batch_boolean(list(solids), manifold3d.OpType.Add)


def difference(solid: Solid, *cutters: Solid) -> Solid:
    return solid - union(cutters) if cutters else solid


def to_trimesh(solid: Solid) -> trimesh.Trimesh:
    """The solid as a watertight ``trimesh.Trimesh`` (raises if the boolean left it empty)."""
    mesh = solid.to_mesh()
    if len(mesh.tri_verts) == 0:
        raise ValueError("the solid is empty")
    out = trimesh.Trimesh(np.asarray(mesh.vert_properties)[:, :3].astype(np.float64),
                          np.asarray(mesh.tri_verts, dtype=np.int64), process=False)  # merging could pinch it
    if not out.is_watertight:  # manifold3d guarantees closed output; a failure here is a bug worth raising
        raise ValueError("the solid's mesh is not watertight")
    return out


def arc(radius: float, start: float, stop: float, count: int, center=(0.0, 0.0)) -> list[tuple[float, float]]:
    """Points on a circular arc (angles in rad), for outlines."""
    return [(center[0] + radius * math.cos(a), center[1] + radius * math.sin(a))
            for a in np.linspace(start, stop, count)]
