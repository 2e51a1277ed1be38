"""Warp kernel of the palm's contact with an articulated object's bodies.

The hand is fixed-mount, so its palm is a few boxes fixed in the world (body ``hand``'s colliding box geoms),
surfaces that push each body's samples like the table's top does (sim/_surface_kernels.py); the hand feels nothing
back (it is fixed).
"""

# no `from __future__ import annotations`: warp reads the closure-typed annotations at definition time

import dataclasses
import functools

import warp as wp

from ._kernel_funcs import build_funcs
from ._surface_kernels import build_surface_contact

__all__ = ["build_palm_object_kernels"]


@dataclasses.dataclass(frozen=True)
class PalmObjectKernels:
    """What :func:`build_palm_object_kernels` builds: the palm's model struct type, its kernel and warp types."""

    Model: type  # the palm's model struct (a wp.struct)
    palm_contact: object  # wp.Kernel: the palm boxes' push on each object body
    vec3: type
    mat33: type


@functools.lru_cache(maxsize=None)
def build_palm_object_kernels(float_type, num_bodies: int, boxes: int):
    """The palm kernel for ``boxes`` palm boxes against ``num_bodies`` bodies."""
    dtype = float_type
    NB = int(boxes)
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

    box_distance = build_funcs(dtype).box_distance

    @wp.func
    def palm_box(m: Model, v: int, k: int, ps: vec3, rad: dtype):
        """A sample sphere's penetration into palm box k and the box's outward normal there (world; the surface of
        sim/_surface_kernels.py)."""
        Rb = m.box_rot[k]
        dn = box_distance(m.box_half[k], wp.transpose(Rb) * (ps - m.box_pos[k]))
        return rad - dn[0], Rb * vec3(dn[1], dn[2], dn[3])

    return PalmObjectKernels(Model=Model, palm_contact=build_surface_contact(dtype, Model, NB, palm_box),
                             vec3=vec3, mat33=mat33)
