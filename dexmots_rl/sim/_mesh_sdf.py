"""Signed-distance grids of watertight triangle meshes, built once per mesh when a scene loads.

:func:`sdf_grid` samples a mesh's exact signed distance (negative inside) on a regular grid: each grid point's
closest point on the mesh through warp's BVH query, its sign from the angle-weighted pseudo-normal there (exact for a
watertight mesh; the winding-number sign of warp 1.19 misjudges points level with a ring of vertices), so a mesh of a
few hundred triangles fills a grid of a few hundred thousand points in milliseconds on one core (trimesh's
``signed_distance`` takes about a minute for the same grid). The contact kernels interpolate the grid trilinearly
(``kernel_funcs.grid_distance`` for the articulated objects, ``contact_kernels`` for the single-body object).
"""

from __future__ import annotations

import numpy as np
import warp as wp

__all__ = ["sdf_grid", "grid_cell"]

MAX_POINTS_PER_AXIS = 96  # a grid's longest axis has at most this many points (memory: 96^3 doubles = 7 MB)
MIN_CELL = 1.0e-3  # m: finer than this resolves nothing a finger sphere (r >= 5 mm) can feel


@wp.kernel
def _signed_distances(mesh: wp.uint64, lo: wp.vec3, cell: float, ny: int, nz: int, max_dist: float,
                      out: wp.array(dtype=float)):
    t = wp.tid()
    i = t // (ny * nz)
    j = (t // nz) % ny
    k = t % nz
    p = lo + cell * wp.vec3(float(i), float(j), float(k))
    query = wp.mesh_query_point_sign_normal(mesh, p, max_dist)
    if query.result:
        closest = wp.mesh_eval_position(mesh, query.face, query.u, query.v)
        out[t] = query.sign * wp.length(p - closest)  # warp's sign: negative inside


def grid_cell(extent: np.ndarray) -> float:
    """The cell size (m) of a grid over a box of ``extent`` (m, per axis): 1 mm, or coarser so that the longest
    axis has at most :data:`MAX_POINTS_PER_AXIS` points."""
    return max(MIN_CELL, float(np.max(extent)) / (MAX_POINTS_PER_AXIS - 1))


def sdf_grid(vertices: np.ndarray, faces: np.ndarray, pad: float, cell: float | None = None
             ) -> tuple[np.ndarray, np.ndarray, float]:
    """The signed distance (m, negative inside) of the watertight mesh (``vertices`` [V, 3] m, ``faces``
    [F, 3]) on a regular grid over its bounds padded by ``pad`` (m) on every side, with spacing ``cell`` (m;
    default :func:`grid_cell`). Returns ``(values [X, Y, Z], lo, cell)``: grid point ``(i, j, k)`` is at
    ``lo + cell * (i, j, k)``; the grid reaches at least ``pad`` beyond the mesh on every side."""
    vertices = np.asarray(vertices, dtype=np.float64)
    lo, hi = vertices.min(0) - pad, vertices.max(0) + pad
    cell = grid_cell(hi - lo) if cell is None else float(cell)
    dims = np.ceil((hi - lo) / cell - 1e-9).astype(int) + 1
    # warp's mesh is float32: query about the grid's centre so the coordinates stay small
    centre = lo + 0.5 * cell * (dims - 1)
    mesh = wp.Mesh(points=wp.array((vertices - centre).astype(np.float32), dtype=wp.vec3, device="cpu"),
                   indices=wp.array(np.asarray(faces, dtype=np.int32).reshape(-1), dtype=wp.int32, device="cpu"))
    out = wp.zeros(int(np.prod(dims)), dtype=float, device="cpu")
    far = float(np.linalg.norm(hi - lo)) * 2.0 + 1.0  # every grid point finds its closest point within this
    wp.launch(_signed_distances, dim=out.shape[0], device="cpu",
              inputs=[mesh.id, wp.vec3(*(lo - centre).astype(np.float32)), float(cell), int(dims[1]), int(dims[2]),
                      far, out])
    return out.numpy().astype(np.float64).reshape(*dims), lo, cell
