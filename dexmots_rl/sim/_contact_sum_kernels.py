"""Warp kernel summing the contacts on an articulated object's bodies (the table's, the palm's and the hand's), and
the running means over a step's substeps of the hand's wrench on the whole object, of its normal force and of its
generalised force on each of the object's joints (sim/_object_kernels.py builds it into its kernel set).
"""

# no `from __future__ import annotations`: warp reads the closure-typed annotations at definition time

import functools

import warp as wp

__all__ = ["build_sum_contacts"]


@functools.lru_cache(maxsize=None)
def build_sum_contacts(float_type, num_bodies: int, Model):
    """The ``sum_contacts`` kernel for objects of ``num_bodies`` bodies; ``Model`` is the object kernels' model
    struct (the joints' kinds, axes, anchors and which bodies each joint moves)."""
    dtype = float_type
    B = int(num_bodies)
    NP = B - 1  # part joints: joint k moves body k + 1 and its descendants
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)

    @wp.kernel(module="unique", enable_backward=True)
    def sum_contacts(
        m: Model,
        variant: wp.array(dtype=wp.int32),  # [N] each world's object variant
        table_f: wp.array2d(dtype=vec3),  # [N, B] table contact on each body (table_contact)
        table_t: wp.array2d(dtype=vec3),
        hand_f: wp.array2d(dtype=vec3),  # [N, B] the hand's contact on each body
        hand_t: wp.array2d(dtype=vec3),  # [N, B] its torque about the body's com
        body_x: wp.array2d(dtype=vec3),  # [N, B] frames
        body_R: wp.array2d(dtype=mat33),
        body_c: wp.array2d(dtype=vec3),
        wrench: wp.array2d(dtype=dtype),  # [N, 6] running mean so far
        normal: wp.array(dtype=dtype),  # [N] running mean so far
        joint_wrench: wp.array2d(dtype=dtype),  # [N, max(P, 1)] running mean so far
        step_normal: wp.array(dtype=dtype),  # [N] this substep's summed normal force
        weight: dtype,  # 1 / substeps
        total_f: wp.array2d(dtype=vec3),  # [N, B] out: table + hand
        total_t: wp.array2d(dtype=vec3),
        wrench_out: wp.array2d(dtype=dtype),  # [N, 6] out: + weight x the hand's wrench on the whole object
        normal_out: wp.array(dtype=dtype),  # [N] out
        joint_wrench_out: wp.array2d(dtype=dtype),  # [N, max(P, 1)] out: + weight x the hand's force on each joint
    ):
        """Each body's total contact, and the running means over substeps of the hand's wrench on the whole
        object (force, torque about the base origin), of its summed normal force and of its generalised force
        on each part joint: ``J_k^T`` of the hand's wrenches on the bodies joint k moves, i.e. about a hinge's
        axis through its anchor (N m), along a slide's axis (N), positive when it pushes the joint's coordinate
        up."""
        w = wp.tid()
        v = variant[w]
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
        for k in range(NP):
            # the joint's axis and anchor in the world: a hinge turns its part about the axis, so the axis in
            # the part frame maps to the world by the part's rotation, and the anchor stays where the part's
            # frame puts it (a slide's anchor moves with its part, but a slide only reads the axis)
            R = body_R[w, k + 1]
            a = R * m.jaxis[v, k]
            o = body_x[w, k + 1] + R * m.janchor[v, k]
            force = dtype(0.0)
            for b in range(B):
                if m.ancestor[b, k] > dtype(0.0):
                    if m.jkind[k] == 0:
                        force = force + wp.dot(a, hand_t[w, b] + wp.cross(body_c[w, b] - o, hand_f[w, b]))
                    else:
                        force = force + wp.dot(a, hand_f[w, b])
            joint_wrench_out[w, k] = joint_wrench[w, k] + weight * force

    return sum_contacts
