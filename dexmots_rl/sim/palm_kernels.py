"""Palm contact: a free object's surface samples against the hand's fixed collision boxes, as warp functions.

Built by :func:`build_palm` only for scenes that have colliding palm boxes and a free object (the kernels
of every other scene do not contain it). The hand is fixed, so the boxes are world-frame constants and
the contact only acts on the object (force + torque about its origin); nothing reacts on the fingers.

* Distance: a box's smooth signed distance is the log-sum-exp smooth max of its six face planes
  (smoothing ``palm_smoothing``): C-infinity, exact to ``smoothing * e^-(gap / smoothing)`` on a face
  away from its edges, and up to ``smoothing * log 2`` farther out than the box at an edge (rounded edges);
  the normal is the normalised gradient of the smooth max.
* Law: the fingers' relaxed penalty law (:class:`~dexmots_rl.sim.ContactParams`) with the palm's
  stiffness and sharpness: ``f_n = ke_palm softplus(beta_palm phi) / beta_palm * max(1 - kd v_n, 0)`` with
  ``phi = radius - distance``, and Coulomb friction smoothed by ``slip_velocity``.

The reverse pass is warp's generated adjoint (loops over boxes and samples have compile-time trip counts
and are unrolled; the kernel raises ``max_unroll`` to the number of samples), checked against central
finite differences in tests/test_palm.py.
"""

# no `from __future__ import annotations`: warp reads the closure-typed annotations at definition time

import types

import warp as wp

from .contact_kernels import CONTACT_CUTOFF

__all__ = ["build_palm"]


def build_palm(t) -> types.SimpleNamespace:
    """The palm-contact functions for the types and scene constants in ``t`` (attributes: dtype, vec3,
    vec4, mat33, Model, NB (palm boxes), NS (object samples), fixed_vec3, fixed_mat33, fixed, softplus,
    smooth_box, box_face_max)."""
    dtype, vec3, vec4, mat33, Model = t.dtype, t.vec3, t.vec4, t.mat33, t.Model
    NB, NS = t.NB, t.NS
    fixed_vec3, fixed_mat33, fixed, softplus = t.fixed_vec3, t.fixed_mat33, t.fixed, t.softplus
    smooth_box, box_face_max = t.smooth_box, t.box_face_max

    @wp.func
    def box_sdf(m: Model, b: int, p: vec3):
        """Smooth signed distance of world point p to palm box b and the outward unit normal (world),
        packed (d, n)."""
        R = fixed_mat33(m.palm_rot, b)
        d = smooth_box(fixed_vec3(m.palm_half, b), wp.transpose(R) * (p - fixed_vec3(m.palm_pos, b)), m.palm_smooth)
        n = R * vec3(d[1], d[2], d[3])
        return vec4(d[0], n[0], n[1], n[2])

    @wp.func
    def palm_point(m: Model, b: int, p: vec3, rad: dtype, xo: vec3, vo: vec3, wo: vec3):
        """Force of palm box b on the object sample sphere (centre p, radius rad; the object moves with
        origin velocity vo and angular velocity wo about xo), and the contact point."""
        sd = box_sdf(m, b, p)
        phi = rad - sd[0]
        fc = vec3()
        cp = p
        if phi > -dtype(CONTACT_CUTOFF) / m.palm_beta:
            n = vec3(sd[1], sd[2], sd[3])
            cp = p - n * rad
            v = vo + wp.cross(wo, cp - xo)  # the object's material point at cp (the palm is still)
            vn = wp.dot(v, n)
            fn = m.palm_ke * softplus(phi, m.palm_beta) * wp.max(dtype(1.0) - m.kd * vn, dtype(0.0))
            vt = v - vn * n
            den = wp.sqrt(wp.dot(vt, vt) + m.v_slip * m.v_slip)
            fc = fn * n - (m.mu * fn / den) * vt
        return fc, cp

    @wp.func
    def palm_near(m: Model, b: int, xo: vec3):
        """1 when the object's bounding sphere is within the contact band of palm box b, else 0 (a branch
        condition: empty adjoint)."""
        R = m.palm_rot[b]
        h = m.palm_half[b]
        q = wp.transpose(R) * (xo - m.palm_pos[b])
        out = vec3(wp.max(wp.abs(q[0]) - h[0], dtype(0.0)), wp.max(wp.abs(q[1]) - h[1], dtype(0.0)),
                   wp.max(wp.abs(q[2]) - h[2], dtype(0.0)))
        if wp.length(out) < m.obj_bound + dtype(CONTACT_CUTOFF) / m.palm_beta + m.palm_smooth:
            return 1
        return 0

    @wp.func_grad(palm_near)
    def adj_palm_near(m: Model, b: int, xo: vec3, adj_ret: int):
        return

    @wp.func(inline=True)
    def palm_sample_near(m: Model, b: int, p: vec3, rad: dtype):
        """1 when the object sample sphere (centre p, radius rad) may touch palm box b, else 0: its largest
        face distance to the box is below the radius + the law's cutoff band. The smooth distance is never
        below the largest face distance, so a sample this test skips gets exactly zero force anyway; the
        test only skips the work (the smooth distance's six exponentials). A branch condition: empty
        adjoint."""
        q = wp.transpose(m.palm_rot[b]) * (p - m.palm_pos[b])
        if box_face_max(m.palm_half[b], q) < rad + dtype(CONTACT_CUTOFF) / m.palm_beta:
            return 1
        return 0

    @wp.func_grad(palm_sample_near)
    def adj_palm_sample_near(m: Model, b: int, p: vec3, rad: dtype, adj_ret: int):
        return

    @wp.func
    def palm_wrench(m: Model, xo: vec3, Ro: mat33, vo: vec3, wo: vec3):
        """Net palm force on the object and its torque about the object origin xo (world frame)."""
        f = vec3()
        tq = vec3()
        for b in range(NB):
            if palm_near(m, b, xo) != 0:
                for s in range(NS):
                    p = xo + Ro * fixed_vec3(m.obj_point_pos, s)
                    rad = fixed(m.obj_point_radius, s)
                    if palm_sample_near(m, b, p, rad) != 0:
                        fc, cp = palm_point(m, b, p, rad, xo, vo, wo)
                        f = f + fc
                        tq = tq + wp.cross(cp - xo, fc)
        return f, tq

    return types.SimpleNamespace(box_sdf=box_sdf, palm_point=palm_point, palm_wrench=palm_wrench)
