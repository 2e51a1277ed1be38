"""Collision primitives and drawable watertight meshes fitted to a part's mesh pieces.

Scanned or segmented meshes (PartNet-Mobility's OBJ pieces) are many per part and often open surfaces, so they
have neither a volume nor a signed distance. A part is approximated in two ways:

* **collision**: oriented boxes. Every piece is split into its connected components (when it has at most
  :data:`MAX_COMPONENTS_PER_PIECE`); components are grouped by a greedy agglomerative clustering that merges,
  at each step, the two groups whose common box adds the least volume, until ``max_boxes`` groups are left;
  each group gets its minimum-volume oriented bounding box. Open or hollow shapes become solid (a drawer
  is a solid block, a ring is filled): fingers collide with the boxes' outside only. Given the vertical (``up``),
  a group whose minimum box reaches below the group's lowest point (a disc or a round foot: any turn of the box
  is as small, and its corners poke out) or is hardly smaller than an upright one gets the upright box instead,
  turned about the vertical only: its bottom face lies at the group's lowest point, so an object stands on
  flat faces, as it stands on its meshes.
* **collision, alternatively**: the convex hull of all the pieces, one watertight mesh (its signed distance
  is well defined; a union of overlapping hulls would not have one).
* **drawing**: the union of the convex hulls of the same components (each hull is closed, so the union is
  watertight in trimesh's sense), which keeps the silhouette of a part made of several pieces.

Flat components (a single quad, a planar disc) are thickened to ``2 * min_half`` so every box and hull has a
volume.
"""

from __future__ import annotations

import functools

import numpy as np
import trimesh

__all__ = ["Box", "fit_boxes", "hull_mesh", "convex_hull", "components", "MAX_COMPONENTS_PER_PIECE"]

MAX_COMPONENTS_PER_PIECE = 64
_MAX_CLUSTER_SEEDS = 16  # greedy merging is quadratic: more components are first grouped by k-means on centroids
Box = tuple[np.ndarray, np.ndarray, np.ndarray]  # (half extents (3,), centre (3,), rotation (3, 3), box->frame)


def _quiet(function):
    """Flat hulls have zero volume, and trimesh divides by it for their centre of mass: no warning for that."""

    @functools.wraps(function)
    def wrapped(*args, **kwargs):
        with np.errstate(divide="ignore", invalid="ignore"):
            return function(*args, **kwargs)

    return wrapped


@_quiet
def components(pieces: list[trimesh.Trimesh]) -> list[np.ndarray]:
    """The point sets (convex-hull vertices where a hull exists) of the pieces' connected components."""
    out = []
    for piece in pieces:
        parts = piece.split(only_watertight=False) if piece.body_count <= MAX_COMPONENTS_PER_PIECE else [piece]
        for part in parts or [piece]:
            if len(part.vertices):
                out.append(_hull_points(np.asarray(part.vertices, dtype=float)))
    return out


def _hull_points(points: np.ndarray) -> np.ndarray:
    try:
        hull = trimesh.convex.convex_hull(points)
        if hull.volume > 0:
            return np.asarray(hull.vertices, dtype=float)
    except Exception:  # noqa: BLE001 - qhull rejects flat or tiny point sets; the raw points serve then
        pass
    return points


def _pca_box_volume(points: np.ndarray, min_half: float) -> float:
    """Volume of the box aligned with the points' principal axes: a cheap stand-in for the minimum box."""
    centred = points - points.mean(axis=0)
    _, vectors = np.linalg.eigh(centred.T @ centred)
    extent = np.ptp(centred @ vectors, axis=0)
    return float(np.prod(np.maximum(extent, 2.0 * min_half)))


def _oriented_box(points: np.ndarray, min_half: float) -> Box:
    if len(points) < 4 or np.linalg.matrix_rank(points - points.mean(axis=0), tol=1e-9) < 3:
        rotation = _principal_axes(points)
        local = (points - points.mean(axis=0)) @ rotation
        low, high = local.min(axis=0), local.max(axis=0)
        centre = points.mean(axis=0) + rotation @ ((low + high) / 2)
        return np.maximum((high - low) / 2, min_half), centre, rotation
    to_origin, extents = trimesh.bounds.oriented_bounds(points)
    box_to_frame = np.linalg.inv(to_origin)
    rotation = box_to_frame[:3, :3]
    if np.linalg.det(rotation) < 0:  # keep a proper rotation (a quaternion exists)
        rotation = rotation.copy()
        rotation[:, 2] *= -1
    return np.maximum(np.asarray(extents) / 2, min_half), box_to_frame[:3, 3].copy(), rotation


def _principal_axes(points: np.ndarray) -> np.ndarray:
    centred = points - points.mean(axis=0)
    _, vectors = np.linalg.eigh(centred.T @ centred)
    if np.linalg.det(vectors) < 0:
        vectors[:, 0] *= -1
    return vectors


def _seed_groups(sets: list[np.ndarray]) -> list[np.ndarray]:
    if len(sets) <= _MAX_CLUSTER_SEEDS:
        return sets
    from scipy.cluster.vq import kmeans2

    centroids = np.array([s.mean(axis=0) for s in sets])
    _, labels = kmeans2(centroids, _MAX_CLUSTER_SEEDS, seed=0, minit="++")
    return [np.concatenate([s for s, label in zip(sets, labels) if label == k]) for k in np.unique(labels)]


@_quiet
def fit_boxes(pieces: list[trimesh.Trimesh], max_boxes: int, min_half: float, up=None) -> list[Box]:
    """At most ``max_boxes`` oriented boxes covering the pieces (see the module docstring); ``up``: the
    vertical in the pieces' frame (None: boxes of any orientation)."""
    groups = _seed_groups(components(pieces))
    volumes = [_pca_box_volume(g, min_half) for g in groups]
    cost: dict[tuple[int, int], float] = {}

    def pair_cost(i: int, j: int) -> float:
        key = (min(i, j), max(i, j))
        if key not in cost:
            merged = _pca_box_volume(np.concatenate([groups[i], groups[j]]), min_half)
            cost[key] = merged - volumes[i] - volumes[j]
        return cost[key]

    alive = list(range(len(groups)))
    while len(alive) > max_boxes:
        i, j = min(((a, b) for n, a in enumerate(alive) for b in alive[n + 1:]), key=lambda ab: pair_cost(*ab))
        groups.append(_hull_points(np.concatenate([groups[i], groups[j]])))
        volumes.append(_pca_box_volume(groups[-1], min_half))
        alive = [k for k in alive if k not in (i, j)] + [len(groups) - 1]
    return [_box(groups[k], min_half, up) for k in alive]


UPRIGHT_VOLUME_RATIO = 1.05  # an upright box at most this much larger than the minimum one is preferred
POKE_TOLERANCE = 0.005  # of a group's height: a minimum box reaching lower than this below its points is refused


def _box(points: np.ndarray, min_half: float, up) -> Box:
    """The group's minimum oriented box, or its upright box (see the module docstring)."""
    best = _oriented_box(points, min_half)
    if up is None:
        return best
    up = np.asarray(up, dtype=float) / np.linalg.norm(up)
    upright = _upright_box(points, min_half, up)
    heights = points @ up
    corners = best[1] + (np.array(list(np.ndindex(2, 2, 2))) * 2 - 1) * best[0] @ best[2].T
    poke = heights.min() - (corners @ up).min()
    if poke > max(min_half, POKE_TOLERANCE * np.ptp(heights)) or \
            np.prod(upright[0]) <= UPRIGHT_VOLUME_RATIO * np.prod(best[0]):
        return upright
    return best


def _upright_box(points: np.ndarray, min_half: float, up: np.ndarray) -> Box:
    """The smallest box with one axis along ``up`` (turned about it only) holding the points."""
    side = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    side /= np.linalg.norm(side)
    frame = np.column_stack([side, np.cross(up, side), up])  # columns: two horizontal axes and up
    local = points @ frame
    try:
        to_origin, extents_2d = trimesh.bounds.oriented_bounds_2D(local[:, :2])
        turn = np.linalg.inv(to_origin)[:2, :2]
    except Exception:  # noqa: BLE001 - qhull rejects collinear plans: keep the frame's axes
        turn = np.eye(2)
    if np.linalg.det(turn) < 0:
        turn = turn @ np.diag([1.0, -1.0])
    axes = np.eye(3)
    axes[:2, :2] = turn
    rotation = frame @ axes
    box_local = points @ rotation
    low, high = box_local.min(axis=0), box_local.max(axis=0)
    return np.maximum((high - low) / 2, min_half), rotation @ ((low + high) / 2), rotation


@_quiet
def hull_mesh(pieces: list[trimesh.Trimesh], min_half: float) -> trimesh.Trimesh:
    """The union (concatenation) of the convex hulls of the pieces' components: closed, for drawing."""
    hulls = []
    for points in components(pieces):
        hull = None
        try:
            hull = trimesh.convex.convex_hull(points)
        except Exception:  # noqa: BLE001 - flat point sets have no hull; their thickened box is drawn instead
            pass
        if hull is None or not hull.is_watertight or hull.volume <= 0:
            half, centre, rotation = _oriented_box(points, min_half)
            transform = np.eye(4)
            transform[:3, :3], transform[:3, 3] = rotation, centre
            hull = trimesh.creation.box(extents=2 * half, transform=transform)
        hulls.append(hull)
    return trimesh.util.concatenate(hulls)


@_quiet
def convex_hull(pieces: list[trimesh.Trimesh], min_half: float) -> trimesh.Trimesh:
    """The convex hull of all the pieces (their thickened box when they are flat together)."""
    points = np.concatenate([np.asarray(p.vertices, dtype=float) for p in pieces])
    try:
        hull = trimesh.convex.convex_hull(points)
        if hull.is_watertight and hull.volume > 0:
            return hull
    except Exception:  # noqa: BLE001 - qhull rejects flat point sets
        pass
    half, centre, rotation = _oriented_box(points, min_half)
    transform = np.eye(4)
    transform[:3, :3], transform[:3, 3] = rotation, centre
    return trimesh.creation.box(extents=2 * half, transform=transform)
