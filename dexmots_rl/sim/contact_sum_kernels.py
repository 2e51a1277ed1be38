"""Warp kernel summing the contacts on an articulated object's bodies (the table's, the palm's and the hand's), and
the running means over a step's substeps of the hand's wrench on the whole object and of its normal force
(sim/object_kernels.py builds it into its kernel set).
"""

# no `from __future__ import annotations`: warp reads the closure-typed annotations at definition time

import functools

import warp as wp

__all__ = ["build_sum_contacts"]


@functools.lru_cache(maxsize=None)
def build_sum_contacts(float_type, num_bodies: int):
    """The ``sum_contacts`` kernel for objects of ``num_bodies`` bodies."""
    dtype = float_type
    B = int(num_bodies)
    vec3 = wp.types.vector(3, dtype)

    @wp.kernel(module="unique", enable_backward=True)
    def sum_contacts(
        table_f: wp.array2d(dtype=vec3),  # [N, B] table contact on each body (table_contact)
        table_t: wp.array2d(dtype=vec3),
        hand_f: wp.array2d(dtype=vec3),  # [N, B] the hand's contact on each body
        hand_t: wp.array2d(dtype=vec3),  # [N, B] its torque about the body's com
        body_x: wp.array2d(dtype=vec3),  # [N, B] frames
        body_c: wp.array2d(dtype=vec3),
        wrench: wp.array2d(dtype=dtype),  # [N, 6] running mean so far
        normal: wp.array(dtype=dtype),  # [N] running mean so far
        step_normal: wp.array(dtype=dtype),  # [N] this substep's summed normal force
        weight: dtype,  # 1 / substeps
        total_f: wp.array2d(dtype=vec3),  # [N, B] out: table + hand
        total_t: wp.array2d(dtype=vec3),
        wrench_out: wp.array2d(dtype=dtype),  # [N, 6] out: + weight x the hand's wrench on the whole object
        normal_out: wp.array(dtype=dtype),  # [N] out
    ):
        """Each body's total contact, and the running means over substeps of the hand's wrench on the whole
        object (force, torque about the base origin) and of its summed normal force."""
        w = wp.tid()
        f_sum = vec3()
        t_sum = vec3()
        for b in range(B):
            total_f[w, b] = table_f[w, b] + hand_f[w, b]
            total_t[w, b] = table_t[w, b] + hand_t[w, b]
            f_sum = f_sum + hand_f[w, b]
            t_sum = t_sum + hand_t[w, b] + wp.cross(body_c[w, b] - body_x[w, 0], hand_f[w, b])
        for c in range(3):
            wrench_out[w, c] = wrench[w, c] + weight * f_sum[c]
            wrench_out[w, 3 + c] = wrench[w, 3 + c] + weight * t_sum[c]
        normal_out[w] = normal[w] + weight * step_normal[w]

    return sum_contacts
