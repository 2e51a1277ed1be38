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


def build_surface_contact(dtype, Model, surfaces: int, surface):
    """The kernel of ``surfaces`` fixed surfaces against the bodies' samples. ``Model`` (a wp.struct) holds
    ``sample_pos``/``sample_radius`` [V, B, S] and the law's ``ke``, ``beta``, ``kd``, ``mu``, ``v_slip`` (the
    friction coefficient is the launch's ``params[w, mu_col]`` instead when ``mu_col`` >= 0: the table's);
    ``surface(m, v, k, ps, rad)`` (a wp.func) returns the penetration (m) of the sample sphere at ``ps`` (world) of
    radius ``rad`` into surface k (of object variant v) and the surface's outward unit normal there. The kernel adds
    (atomically) the push on each body to the contact arrays it is given, so the table's and the palm's kernels
    add into the same ones."""
    K = int(surfaces)
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    surface_contact = build_funcs(dtype).surface_contact

    @wp.kernel(module="unique", enable_backward=True)
    def push(
        m: Model,
        variant: wp.array(dtype=wp.int32),  # [N] each world's object variant
        params: wp.array2d(dtype=dtype),  # [N, P] the packed parameters
        mu_col: int,  # the column of the friction coefficient in params; -1: the model's mu
        body_x: wp.array2d(dtype=vec3),  # [N, B] object frames (object_kernels.frames)
        body_R: wp.array2d(dtype=mat33),
        body_c: wp.array2d(dtype=vec3),
        body_v: wp.array2d(dtype=vec3),
        body_w: wp.array2d(dtype=vec3),
        dt: dtype,
        num_samples: int,  # S, a launch argument so the loop over samples stays a loop (see below)
        contact_f: wp.array2d(dtype=vec3),  # [N, B] out (atomic): force on the body (N)
        contact_t: wp.array2d(dtype=vec3),  # [N, B] out (atomic): torque about its com (N m)
        contact_Kvv: wp.array2d(dtype=mat33),  # [N, B] out (atomic): dt x viscous friction seen at the com
        contact_Kvw: wp.array2d(dtype=mat33),
        contact_Kww: wp.array2d(dtype=mat33),
    ):
        w, b = wp.tid()
        v = variant[w]
        x = body_x[w, b]
        R = body_R[w, b]
        c = body_c[w, b]
        vc = body_v[w, b]
        om = body_w[w, b]
        mu = m.mu
        if mu_col >= 0:
            mu = params[w, mu_col]
        # each sample adds its own contact (atomics, in sample order): nothing is carried from one sample to the
        # next, so the loop's adjoint is exact and visits each sample once (unrolled, the adjoint zeroed every
        # sample's adjoint variables first: most of its time)
        for s in range(num_samples):
            rad = m.sample_radius[v, b, s]
            if rad >= dtype(0.0):
                ps = x + R * m.sample_pos[v, b, s]
                for k in range(K):
                    pen, n = surface(m, v, k, ps, rad)
                    if pen > dtype(-CONTACT_CUTOFF) / m.beta:
                        r = ps - n * rad - c
                        f, Pc = surface_contact(pen, n, vc + wp.cross(om, r), m.ke, m.beta, m.kd, mu, m.v_slip, dt)
                        # P at the contact point moved to the com (the point's velocity is V - [r]x w)
                        Sr = wp.skew(r)
                        wp.atomic_add(contact_f, w, b, f)
                        wp.atomic_add(contact_t, w, b, wp.cross(r, f))
                        wp.atomic_add(contact_Kvv, w, b, Pc)
                        wp.atomic_add(contact_Kvw, w, b, -(Pc * Sr))
                        wp.atomic_add(contact_Kww, w, b, wp.transpose(Sr) * Pc * Sr)

    return push
