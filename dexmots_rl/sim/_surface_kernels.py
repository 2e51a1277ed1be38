"""The push of fixed surfaces (the table's top, the palm's boxes) on each body of an articulated object: one kernel
factory for both.

A thread per world and object body tests the body's surface samples (sim/_object_model.py) against each surface:
a relaxed penalty along the surface's outward normal with Hunt-Crossley damping and smoothed Coulomb friction
(``surface_contact`` of sim/_kernel_funcs.py). Their viscous parts are handed to the object's solve as matrices
at the body's com (linearly implicit: the object holds on the table like static friction at any slip velocity, and
a stiff damper cannot overshoot and pump energy into a bounce). The surfaces only push the object; nothing pushes
back (the table and the fixed-mount hand's palm do not move).
"""

# no `from __future__ import annotations`: warp reads the closure-typed annotations at definition time

import warp as wp

from ._constants import CONTACT_CUTOFF
from ._kernel_funcs import build_funcs

__all__ = ["build_surface_contact"]


def build_surface_contact(dtype, Model, samples: int, surfaces: int, surface):
    """The kernel of ``surfaces`` fixed surfaces against bodies of ``samples`` samples each. ``Model`` (a wp.struct)
    holds ``sample_pos``/``sample_radius`` [V, B, S] and the law's ``ke``, ``beta``, ``kd``, ``mu``, ``v_slip``;
    ``surface(m, v, k, ps, rad)`` (a wp.func) returns the penetration (m) of the sample sphere at ``ps`` (world) of
    radius ``rad`` into surface k (of object variant v) and the surface's outward unit normal there. The kernel adds
    the push on each body to the contact it is given (``in_*``) into ``out_*`` (the same arrays: in place)."""
    S, K = int(samples), int(surfaces)
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    surface_contact = build_funcs(dtype).surface_contact

    @wp.kernel(module="unique", enable_backward=True)
    def push(
        m: Model,
        variant: wp.array(dtype=wp.int32),  # [N] each world's object variant
        body_x: wp.array2d(dtype=vec3),  # [N, B] object frames (object_kernels.frames)
        body_R: wp.array2d(dtype=mat33),
        body_c: wp.array2d(dtype=vec3),
        body_v: wp.array2d(dtype=vec3),
        body_w: wp.array2d(dtype=vec3),
        dt: dtype,
        in_f: wp.array2d(dtype=vec3),  # [N, B] in: force on the body (N)
        in_t: wp.array2d(dtype=vec3),  # [N, B] torque about its com (N m)
        in_Kvv: wp.array2d(dtype=mat33),  # [N, B] dt x viscous friction seen at the com
        in_Kvw: wp.array2d(dtype=mat33),
        in_Kww: wp.array2d(dtype=mat33),
        out_f: wp.array2d(dtype=vec3),  # [N, B] out: in + these surfaces' push
        out_t: wp.array2d(dtype=vec3),
        out_Kvv: wp.array2d(dtype=mat33),
        out_Kvw: wp.array2d(dtype=mat33),
        out_Kww: wp.array2d(dtype=mat33),
    ):
        w, b = wp.tid()
        v = variant[w]
        x = body_x[w, b]
        R = body_R[w, b]
        c = body_c[w, b]
        vc = body_v[w, b]
        om = body_w[w, b]
        f_sum = vec3()
        t_sum = vec3()
        Kvv = mat33()
        Kvw = mat33()
        Kww = mat33()
        for s in range(S):
            rad = m.sample_radius[v, b, s]
            if rad >= dtype(0.0):
                ps = x + R * m.sample_pos[v, b, s]
                for k in range(K):
                    pen, n = surface(m, v, k, ps, rad)
                    if pen > dtype(-CONTACT_CUTOFF) / m.beta:
                        r = ps - n * rad - c
                        f, Pc = surface_contact(pen, n, vc + wp.cross(om, r), m.ke, m.beta, m.kd, m.mu, m.v_slip, dt)
                        f_sum = f_sum + f
                        t_sum = t_sum + wp.cross(r, f)
                        # P at the contact point moved to the com (the point's velocity is V - [r]x w)
                        Sr = wp.skew(r)
                        Kvv = Kvv + Pc
                        Kvw = Kvw - Pc * Sr
                        Kww = Kww + wp.transpose(Sr) * Pc * Sr
        out_f[w, b] = in_f[w, b] + f_sum
        out_t[w, b] = in_t[w, b] + t_sum
        out_Kvv[w, b] = in_Kvv[w, b] + Kvv
        out_Kvw[w, b] = in_Kvw[w, b] + Kvw
        out_Kww[w, b] = in_Kww[w, b] + Kww

    return push
