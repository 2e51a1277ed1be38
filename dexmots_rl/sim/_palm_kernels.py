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
  ``phi = radius - distance``, and Coulomb friction smoothed by ``slip_velocity``; the damping of all samples
  together, and their friction, are scaled down as dampers integrated implicitly (:func:`palm_wrench` says why).

The reverse pass is warp's generated adjoint (loops over boxes and samples have compile-time trip counts
and are unrolled; the kernel raises ``max_unroll`` to the number of samples), checked against central
finite differences in tests/test_palm.py.
"""

# no `from __future__ import annotations`: warp reads the closure-typed annotations at definition time

import dataclasses

import warp as wp

from ._constants import CONTACT_CUTOFF
from ._fused_model import FusedSpec
from ._kernel_funcs import build_funcs
from ._object_sdf_kernels import ObjectSdfFuncs

__all__ = ["PalmFuncs", "build_palm"]


@dataclasses.dataclass(frozen=True)
class PalmFuncs:
    """The palm-contact functions :func:`build_palm` builds (wp.func each)."""

    box_sdf: object  # a point's smooth signed distance to a palm box, and the normal
    palm_point: object  # one object sample's push from the palm boxes
    palm_wrench: object  # the palm's whole push on the object (force, torque about its origin)


def build_palm(t: FusedSpec, sdf: ObjectSdfFuncs) -> PalmFuncs:
    """The palm-contact functions for the types and scene structure in ``t``, with ``sdf``'s box distances."""
    dtype, vec3, vec4, mat33, Model = t.dtype, t.vec3, t.vec4, t.mat33, t.Model
    NB, NS = t.NB, t.NS
    smooth_box, box_face_max = sdf.smooth_box, sdf.box_face_max
    funcs = build_funcs(dtype)
    fixed_vec3, fixed_mat33, fixed, softplus = funcs.fixed_vec3, funcs.fixed_mat33, funcs.fixed, funcs.softplus
    box_distance, normal_force, slip_norm = funcs.box_distance, funcs.normal_force, funcs.slip_norm
    body_mobility, tangent_mobility = funcs.body_mobility, funcs.tangent_mobility

    @wp.func
    def box_sdf(m: Model, b: int, p: vec3):
        """Smooth signed distance of world point p to palm box b and the outward unit normal (world),
        packed (d, n)."""
        R = fixed_mat33(m.palm_rot, b)
        d = smooth_box(fixed_vec3(m.palm_half, b), wp.transpose(R) * (p - fixed_vec3(m.palm_pos, b)), m.palm_smooth)
        n = R * vec3(d[1], d[2], d[3])
        return vec4(d[0], n[0], n[1], n[2])

    @wp.func
    def palm_point(m: Model, b: int, p: vec3, rad: dtype, xo: vec3, vo: vec3, wo: vec3, inv_inertia: mat33):
        """Palm box b against the object sample sphere (centre p, radius rad; the object moves with origin
        velocity vo and angular velocity wo about xo, its com; ``inv_inertia``: its inverse inertia, world
        frame): the force's elastic part, its normal damping, its friction and the contact point, and the
        rates (1/s) of the damping and of the friction near sticking: their coefficients times the object's
        mobility (inverse effective mass) along them."""
        sd = box_sdf(m, b, p)
        phi = rad - sd[0]
        elastic = vec3()
        damping = vec3()
        friction = vec3()
        rate_n = dtype(0.0)
        rate_t = dtype(0.0)
        cp = p
        if phi > -dtype(CONTACT_CUTOFF) / m.palm_beta:
            n = vec3(sd[1], sd[2], sd[3])
            cp = p - n * rad
            r = cp - xo
            v = vo + wp.cross(wo, r)  # the object's material point at cp (the palm is still)
            vn = wp.dot(v, n)
            spring = m.palm_ke * softplus(phi, m.palm_beta)
            fn = normal_force(spring, vn, m.kd, dtype(0.0), dtype(0.0))  # explicit here: palm_wrench scales it
            vt = v - vn * n
            drag = m.mu * fn / slip_norm(vt, m.v_slip)  # friction's viscous coefficient
            elastic = spring * n
            damping = (fn - spring) * n
            friction = -drag * vt
            # the object's mobility along n, and its mean over the tangent plane (inv_inertia is world-frame)
            inv_mass = dtype(1.0) / m.obj_mass
            world = wp.identity(n=3, dtype=dtype)
            rate_n = m.kd * spring * body_mobility(inv_mass, inv_inertia, world, r, n)
            rate_t = drag * tangent_mobility(inv_mass, inv_inertia, world, r, n)
        return elastic, damping, friction, cp, rate_n, rate_t

    @wp.func
    def palm_near(m: Model, b: int, xo: vec3):
        """1 when the object's bounding sphere is within the contact band of palm box b, else 0 (a branch
        condition: empty adjoint)."""
        q = wp.transpose(m.palm_rot[b]) * (xo - m.palm_pos[b])
        if box_distance(m.palm_half[b], q)[0] < m.obj_bound + dtype(CONTACT_CUTOFF) / m.palm_beta + m.palm_smooth:
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
    def palm_wrench(m: Model, xo: vec3, Ro: mat33, vo: vec3, wo: vec3, dt: dtype):
        """Net palm force on the object and its torque about the object origin xo (world frame) over a
        substep of dt.

        Explicit, the samples' damping (or their friction near sticking) reverses and grows the object's
        velocity each substep once its rate summed over the samples passes 2 / dt, or less beside the
        palm's stiffness (a finger pressing a cube's edge into the palm; each sample alone stays below), and
        contact makes energy. So each of the two is scaled by 1 / (1 + dt x its summed rate), as a damper
        integrated implicitly (exactly so for one sample): one substep then never reverses the velocity.
        """
        elastic_f = vec3()
        elastic_t = vec3()
        damping_f = vec3()
        damping_t = vec3()
        friction_f = vec3()
        friction_t = vec3()
        rate_n = dtype(0.0)
        rate_t = dtype(0.0)
        inv_inertia = Ro * m.obj_inv_inertia * wp.transpose(Ro)
        for b in range(NB):
            if palm_near(m, b, xo) != 0:
                for s in range(NS):
                    p = xo + Ro * fixed_vec3(m.obj_point_pos, s)
                    rad = fixed(m.obj_point_radius, s)
                    if palm_sample_near(m, b, p, rad) != 0:
                        fe, fd, ff, cp, kn, kt = palm_point(m, b, p, rad, xo, vo, wo, inv_inertia)
                        r = cp - xo
                        elastic_f = elastic_f + fe
                        elastic_t = elastic_t + wp.cross(r, fe)
                        damping_f = damping_f + fd
                        damping_t = damping_t + wp.cross(r, fd)
                        friction_f = friction_f + ff
                        friction_t = friction_t + wp.cross(r, ff)
                        rate_n = rate_n + kn
                        rate_t = rate_t + kt
        scale_n = dtype(1.0) / (dtype(1.0) + dt * rate_n)
        scale_t = dtype(1.0) / (dtype(1.0) + dt * rate_t)
        return (elastic_f + scale_n * damping_f + scale_t * friction_f,
                elastic_t + scale_n * damping_t + scale_t * friction_t)

    return PalmFuncs(box_sdf=box_sdf, palm_point=palm_point, palm_wrench=palm_wrench)
