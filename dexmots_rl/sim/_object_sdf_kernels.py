"""The knob and cube scenes' object geometry as warp functions: a point's smooth signed distance and outward normal
to the object (a sphere, a cylinder, a convex polytope or a mesh's distance grid), and the box distances the palm
shares.

Built per scene structure by :func:`build_object_sdf` from the fused kernels' spec (sim/_fused_model.py). The convex
polytope's distance has a hand-written adjoint (checked against finite differences in tests/test_hand_adjoints.py):
a taped step saves its Jacobian (``Saved.sdf_jac``), so its reverse pass is one product instead of warp's replay of
the face loops followed by their op-by-op adjoint.
"""

# no `from __future__ import annotations`: warp reads the closure-typed annotations at definition time

import dataclasses

import warp as wp

from ._constants import GEOM_CYLINDER, GEOM_SDF, GEOM_SPHERE, LSE_CUTOFF
from ._fused_model import FusedSpec
from ._kernel_funcs import build_funcs

__all__ = ["ObjectSdfFuncs", "build_object_sdf"]


@dataclasses.dataclass(frozen=True)
class ObjectSdfFuncs:
    """The geometry functions :func:`build_object_sdf` builds for one scene structure (wp.func each; (d, n) packs a
    signed distance in m and an outward unit normal)."""

    object_sdf: object  # (d, n) of a point to the object, object frame (hand-written adjoint for a polytope)
    polytope_max: object  # a point's largest face-plane distance (m) to the convex object: a lower bound of its d
    smooth_box: object  # (d, n) of a point to a box (box frame), log-sum-exp smoothed at edges
    box_face_max: object  # a point's largest face distance (m) to a box: a lower bound of smooth_box's


def build_object_sdf(t: FusedSpec) -> ObjectSdfFuncs:
    """The object's distance functions for the types and scene structure in ``t``."""
    dtype, vec3, vec4, mat33, mat43, Model, Saved = t.dtype, t.vec3, t.vec4, t.mat33, t.mat43, t.Model, t.Saved
    K, shape = t.K, t.shape
    BOX = t.box  # the convex object is an axis-aligned box (Model.obj_box_center / obj_box_half)
    trilinear = build_funcs(dtype).trilinear

    @wp.func
    def grid_sdf(m: Model, p: vec3):
        """Trilinear signed distance and its normalised gradient from the grid; outside the grid the
        distance to the grid box is added (the grid is padded, so this only matters far away)."""
        g = (p - m.sdf_origin) / m.sdf_cell
        hi = vec3(dtype(m.sdf.shape[0] - 1), dtype(m.sdf.shape[1] - 1), dtype(m.sdf.shape[2] - 1))
        gc = vec3(wp.clamp(g[0], dtype(0.0), hi[0]), wp.clamp(g[1], dtype(0.0), hi[1]), wp.clamp(g[2], dtype(0.0), hi[2]))
        i = wp.min(int(gc[0]), m.sdf.shape[0] - 2)
        j = wp.min(int(gc[1]), m.sdf.shape[1] - 2)
        k = wp.min(int(gc[2]), m.sdf.shape[2] - 2)
        fx = gc[0] - dtype(i)
        fy = gc[1] - dtype(j)
        fz = gc[2] - dtype(k)
        c000 = m.sdf[i, j, k]
        c100 = m.sdf[i + 1, j, k]
        c010 = m.sdf[i, j + 1, k]
        c110 = m.sdf[i + 1, j + 1, k]
        c001 = m.sdf[i, j, k + 1]
        c101 = m.sdf[i + 1, j, k + 1]
        c011 = m.sdf[i, j + 1, k + 1]
        c111 = m.sdf[i + 1, j + 1, k + 1]
        dg = trilinear(c000, c001, c010, c011, c100, c101, c110, c111, vec3(fx, fy, fz))
        n = vec3(dg[1], dg[2], dg[3]) + (g - gc)  # outside the grid: point away from it
        return dg[0] + m.sdf_cell * wp.length(g - gc), wp.normalize(n)

    @wp.func(inline=True)
    def box_face_max(h: vec3, q: vec3):
        """The largest face distance max_i(|q_i| - h_i) of point q (box frame) to the box of half sizes h:
        a lower bound of the smooth distance, used by the culling tests of the object, palm and base boxes."""
        return wp.max(wp.max(wp.abs(q[0]) - h[0], wp.abs(q[1]) - h[1]), wp.abs(q[2]) - h[2])

    @wp.func(inline=True)  # out of line, each call copied the Model struct
    def polytope_max(m: Model, p: vec3):
        """The largest face-plane distance n_k . p - d_k of the convex object at p (object frame)."""
        if wp.static(BOX):
            return box_face_max(m.obj_box_half, p - m.obj_box_center)
        hi = dtype(-1e9)
        for k in range(K):
            pl = m.planes[k]
            hi = wp.max(hi, pl[0] * p[0] + pl[1] * p[1] + pl[2] * p[2] - pl[3])
        return hi

    @wp.func
    def face_weight(m: Model, p: vec3, k: int, hi: dtype):
        """exp((g_k - hi) / smooth) of face k, 0 for faces far below the max (weight < e^-LSE_CUTOFF)."""
        pl = m.planes[k]
        gap = pl[0] * p[0] + pl[1] * p[1] + pl[2] * p[2] - pl[3] - hi
        if gap > dtype(-LSE_CUTOFF) * m.smooth:
            return wp.exp(gap / m.smooth)
        return dtype(0.0)

    @wp.func
    def lse_weight(g: dtype, hi: dtype, s: dtype):
        """exp((g - hi) / s), 0 when g is more than LSE_CUTOFF smoothing lengths below the max hi."""
        if g - hi > dtype(-LSE_CUTOFF) * s:
            return wp.exp((g - hi) / s)
        return dtype(0.0)

    @wp.func
    def smooth_box(h: vec3, q: vec3, s: dtype):
        """Smooth signed distance and outward unit normal (box frame) of point q to the box of half sizes h,
        packed (d, n): the log-sum-exp smooth max (smoothing s) of the six face distances g = +-q_i - h_i,
        d = hi + s log sum_k exp((g_k - hi) / s) >= max_k g_k, n the normalised gradient; faces far below
        the max are dropped (lse_weight). The palm's boxes use it."""
        gx0 = q[0] - h[0]
        gx1 = -q[0] - h[0]
        gy0 = q[1] - h[1]
        gy1 = -q[1] - h[1]
        gz0 = q[2] - h[2]
        gz1 = -q[2] - h[2]
        hi = wp.max(wp.max(wp.max(gx0, gx1), wp.max(gy0, gy1)), wp.max(gz0, gz1))
        wx0 = lse_weight(gx0, hi, s)
        wx1 = lse_weight(gx1, hi, s)
        wy0 = lse_weight(gy0, hi, s)
        wy1 = lse_weight(gy1, hi, s)
        wz0 = lse_weight(gz0, hi, s)
        wz1 = lse_weight(gz1, hi, s)
        n = wp.normalize(vec3(wx0 - wx1, wy0 - wy1, wz0 - wz1))
        return vec4(hi + s * wp.log(wx0 + wx1 + wy0 + wy1 + wz0 + wz1), n[0], n[1], n[2])

    @wp.func
    def polytope_sdf(m: Model, p: vec3, saved: Saved, row: int, slot: int):
        """Convex polytope: log-sum-exp smooth max over the face planes g_k = n_k . p - d_k: distance
        hi + smooth log(sum_k w_k) and normal u / |u|, u = sum_k w_k n_k, w_k = face_weight.

        A taped step also saves the result's Jacobian for the hand-written adjoint: d = smooth log
        sum_k exp(g_k / smooth) gives dd/dp = u / sum_k w_k; the normal does not change with the common
        factor exp(-hi / smooth), so dn/dp = (I - n n^T) S / (smooth |u|) with S = sum_k w_k n_k n_k^T."""
        keep = saved.sdf_jac.shape[0] > 0
        hi = polytope_max(m, p)
        total = dtype(0.0)
        u = vec3()
        S = mat33()
        for k in range(K):
            w = face_weight(m, p, k, hi)
            nk = vec3(m.planes[k][0], m.planes[k][1], m.planes[k][2])
            total = total + w
            u = u + w * nk
            if keep:
                S = S + w * wp.outer(nk, nk)
        n = wp.normalize(u)
        if keep:
            length = wp.length(u)
            dn = mat33()
            if length > dtype(0.0):
                dn = (wp.identity(n=3, dtype=dtype) - wp.outer(n, n)) * S / (m.smooth * length)
            g = u / total
            saved.sdf_jac[row, slot] = mat43(g[0], g[1], g[2], dn[0, 0], dn[0, 1], dn[0, 2],
                                             dn[1, 0], dn[1, 1], dn[1, 2], dn[2, 0], dn[2, 1], dn[2, 2])
        return vec4(hi + m.smooth * wp.log(total), n[0], n[1], n[2])

    @wp.func_replay(polytope_sdf)
    def replay_polytope_sdf(m: Model, p: vec3, saved: Saved, row: int, slot: int):
        return saved.sdf[row, slot]

    @wp.func_grad(polytope_sdf)
    def adj_polytope_sdf(m: Model, p: vec3, saved: Saved, row: int, slot: int, adj_ret: vec4):
        # the Jacobian saved by the taped forward: no replay of the face loops, no per-face adjoints
        wp.adjoint[p] += wp.transpose(saved.sdf_jac[row, slot]) * adj_ret

    @wp.func
    def object_sdf(m: Model, p: vec3, saved: Saved, row: int, slot: int):
        """Signed distance (smoothed at edges) and outward unit normal (object frame), packed as
        (d, n). ``saved``/``row``/``slot``: where the caller saves the result for the reverse pass."""
        if wp.static(shape == GEOM_SPHERE):
            d = wp.length(p)
            n = p / wp.max(d, dtype(1e-9))
            return vec4(d - m.shape_size[0], n[0], n[1], n[2])
        if wp.static(shape == GEOM_CYLINDER):
            rho = wp.sqrt(p[0] * p[0] + p[1] * p[1] + dtype(1e-12))
            s_r = rho - m.shape_size[0]
            s_z = wp.abs(p[2]) - m.shape_size[1]
            hi = wp.max(s_r, s_z)
            w_r = wp.exp((s_r - hi) / m.smooth)
            w_z = wp.exp((s_z - hi) / m.smooth)
            n = wp.normalize(w_r * vec3(p[0] / rho, p[1] / rho, dtype(0.0)) + w_z * vec3(dtype(0.0), dtype(0.0), wp.sign(p[2])))
            return vec4(hi + m.smooth * wp.log(w_r + w_z), n[0], n[1], n[2])
        if wp.static(shape == GEOM_SDF):
            d, n = grid_sdf(m, p)
            return vec4(d, n[0], n[1], n[2])
        return polytope_sdf(m, p, saved, row, slot)

    # Replays: warp's adjoint of a function first re-runs the function's forward to get its
    # intermediates, and the adjoint of a caller re-runs its callees too, so a function nested d deep
    # ran d + 1 times in the reverse pass. A taped forward saves each call's result; the replays here, in
    # _contact_kernels.py and in _kernels.py load it, so every function body runs once more in reverse (in its own
    # adjoint).
    @wp.func_replay(object_sdf)
    def replay_object_sdf(m: Model, p: vec3, saved: Saved, row: int, slot: int):
        return saved.sdf[row, slot]


    return ObjectSdfFuncs(object_sdf=object_sdf, polytope_max=polytope_max, smooth_box=smooth_box,
                          box_face_max=box_face_max)
