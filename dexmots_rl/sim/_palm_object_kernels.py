"""Warp kernel of the palm's contact with an articulated object's bodies.

The hand is fixed-mount, so its palm is a few boxes fixed in the world (body ``hand``'s colliding box geoms).
A thread per world and object body tests the body's surface samples (sim/_object_model.py) against each box: a
relaxed penalty along the box's outward normal with Hunt-Crossley damping and smoothed Coulomb friction, its
stiffness, damping and friction handed to the object's solve as matrices at the body's com (linearly implicit,
as the table's contact). Like the table, the palm only pushes the object; the hand feels nothing back (it is
fixed).
"""

# no `from __future__ import annotations`: warp reads the closure-typed annotations at definition time

import dataclasses
import functools

import warp as wp

from ._constants import CONTACT_CUTOFF
from ._kernel_funcs import build_funcs

__all__ = ["build_palm_object_kernels"]


@dataclasses.dataclass(frozen=True)
class PalmObjectKernels:
    """What :func:`build_palm_object_kernels` builds: the palm's model struct type, its kernel and warp types."""

    Model: type  # the palm's model struct (a wp.struct)
    palm_contact: object  # wp.Kernel: the palm boxes' push on each object body
    vec3: type
    mat33: type


@functools.lru_cache(maxsize=None)
def build_palm_object_kernels(float_type, num_bodies: int, samples: int, boxes: int):
    """The palm kernel for ``boxes`` palm boxes against ``num_bodies`` bodies of ``samples`` samples each."""
    dtype = float_type
    S, NB = int(samples), int(boxes)
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)

    @wp.struct
    class Model:
        box_pos: wp.array(dtype=vec3)  # [NB] m, world: box centres
        box_rot: wp.array(dtype=mat33)  # [NB] box -> world
        box_half: wp.array(dtype=vec3)  # [NB] m: half sizes
        sample_pos: wp.array3d(dtype=vec3)  # [V, B, S] m, body frame, per object variant
        sample_radius: wp.array3d(dtype=dtype)  # [V, B, S] m (< 0: padding)
        ke: dtype  # N/m per sample
        beta: dtype  # 1/m
        kd: dtype  # s/m
        mu: dtype
        v_slip: dtype  # m/s

    funcs = build_funcs(dtype)
    surface_contact, box_distance = funcs.surface_contact, funcs.box_distance

    @wp.kernel(module="unique", enable_backward=True)
    def palm_contact(
        m: Model,
        variant: wp.array(dtype=wp.int32),  # [N] each world's object variant
        body_x: wp.array2d(dtype=vec3),  # [N, B] object frames (object_kernels.frames)
        body_R: wp.array2d(dtype=mat33),
        body_c: wp.array2d(dtype=vec3),
        body_v: wp.array2d(dtype=vec3),
        body_w: wp.array2d(dtype=vec3),
        dt: dtype,
        contact_f: wp.array2d(dtype=vec3),  # [N, B] in: the table's contact (table_contact)
        contact_t: wp.array2d(dtype=vec3),
        contact_Kvv: wp.array2d(dtype=mat33),
        contact_Kvw: wp.array2d(dtype=mat33),
        contact_Kww: wp.array2d(dtype=mat33),
        out_f: wp.array2d(dtype=vec3),  # [N, B] out: table + palm
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
                for k in range(NB):
                    Rb = m.box_rot[k]
                    dn = box_distance(m.box_half[k], wp.transpose(Rb) * (ps - m.box_pos[k]))
                    nl = vec3(dn[1], dn[2], dn[3])
                    pen = rad - dn[0]
                    if pen > dtype(-CONTACT_CUTOFF) / m.beta:
                        n = Rb * nl  # world, out of the palm: the push on the object
                        r = ps - n * rad - c
                        f, Pc = surface_contact(pen, n, vc + wp.cross(om, r), m.ke, m.beta, m.kd, m.mu, m.v_slip, dt)
                        f_sum = f_sum + f
                        t_sum = t_sum + wp.cross(r, f)
                        Sr = wp.skew(r)
                        Kvv = Kvv + Pc
                        Kvw = Kvw - Pc * Sr
                        Kww = Kww + wp.transpose(Sr) * Pc * Sr
        out_f[w, b] = contact_f[w, b] + f_sum
        out_t[w, b] = contact_t[w, b] + t_sum
        out_Kvv[w, b] = contact_Kvv[w, b] + Kvv
        out_Kvw[w, b] = contact_Kvw[w, b] + Kvw
        out_Kww[w, b] = contact_Kww[w, b] + Kww

    return PalmObjectKernels(Model=Model, palm_contact=palm_contact, vec3=vec3, mat33=mat33)
