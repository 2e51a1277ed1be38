"""Warp kernels of the hand in an articulated-object scene: finger chains, and their contact with the object.

Three kernels per substep (sim/_articulated.py runs them around the object tree's, sim/_object_kernels.py):

* ``link_frames``, a thread per world and finger: every link's frame (origin, rotation) and joint axis through its
  finger chain, once per substep, into arrays the two kernels below read (their adjoints flow back through them).
* ``finger_contact``, a thread per world and finger link (on a CPU, per world): the fingers' contact with the object
  (sim/_finger_contact_kernels.py).
* ``hand_substep``, a thread per world and finger: the chain's mass matrix and bias forces, the motor's implicit
  PD drive (saturated at its effort), joint damping, friction and range stops, the contact forces, and the solve,
  whose inverse it keeps; its adjoint is ``hand_residual``'s (the solve's adjoint as a residual's gradient, O(J)).

``observe`` writes every hand link's pose and the fingertips. Hand joints are hinges; loops have compile-time
trip counts (exact adjoints); everything is generic in the float type (docs/devnotes.md: the hand's adjoint).
"""

# no `from __future__ import annotations`: warp reads the closure-typed annotations at definition time

import dataclasses
import functools

import warp as wp

from ._constants import LIMIT_WIDTH
from ._finger_contact_kernels import build_finger_contact
from ._kernel_funcs import build_funcs, constant_read_2d, unit_vector

__all__ = ["build_hand_kernels"]


@dataclasses.dataclass(frozen=True)
class HandKernels:
    """What :func:`build_hand_kernels` builds for one scene structure: the model struct type, the kernels and the
    warp types they use."""

    Model: type  # the hand's model struct (a wp.struct)
    link_frames: object  # wp.Kernel: every link's frame and joint axis
    finger_contact: object  # wp.Kernel: each finger link's contact with the object's bodies
    hand_substep: object  # wp.Kernel: each finger's implicit solve (no generated adjoint)
    hand_residual: object  # wp.Kernel: hand_substep's adjoint, as the gradient of a scalar (seeded with ones)
    observe: object  # wp.Kernel: body poses and fingertips
    geom_distance: object  # wp.func: a point's signed distance to a geom (probe kernels)
    vec3: type
    mat33: type
    vecJ: type  # a finger's joints
    matJ: type
    dtype: type


@functools.lru_cache(maxsize=None)
def build_hand_kernels(float_type, num_fingers: int, joints: int, points: int, bodies: int, geoms: int):
    """Kernels for ``num_fingers`` chains of ``joints`` hinges with ``points`` sample spheres per link, against an
    object of ``bodies`` bodies with at most ``geoms`` collision geoms each."""
    dtype = float_type
    F, J, P, B, G = int(num_fingers), int(joints), int(points), int(bodies), int(geoms)
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    vecJ = wp.types.vector(J, dtype)
    matJ = wp.types.matrix((J, J), dtype)
    mat3J = wp.types.matrix((3, J), dtype)

    @wp.struct
    class Model:
        base_pos: wp.array(dtype=vec3)  # [F] m, world: where each chain starts
        base_rot: wp.array(dtype=mat33)  # [F]
        off_pos: wp.array(dtype=vec3)  # [F*J] link frame in its parent's at q = 0
        off_rot: wp.array(dtype=mat33)  # [F*J]
        axis: wp.array(dtype=vec3)  # [F*J] hinge axis, link frame
        mass: wp.array(dtype=dtype)  # [F*J] kg
        com: wp.array(dtype=vec3)  # [F*J] m, link frame
        inertia: wp.array(dtype=mat33)  # [F*J] kg m^2 about the com, link frame
        armature: wp.array(dtype=dtype)  # [F*J] kg m^2
        damping: wp.array(dtype=dtype)  # [F*J] N m s/rad
        friction: wp.array(dtype=dtype)  # [F*J] N m
        lower: wp.array(dtype=dtype)  # [F*J] rad
        upper: wp.array(dtype=dtype)  # [F*J] rad
        limit_ke: wp.array(dtype=dtype)  # [F*J] N m/rad (0: unlimited)
        effort: wp.array(dtype=dtype)  # [F*J] N m: the drive's saturation (0: none)
        point_pos: wp.array(dtype=vec3)  # [F*J*P] m, link frame
        point_radius: wp.array(dtype=dtype)  # [F*J*P] m (0: padding)
        tip_pos: wp.array(dtype=vec3)  # [F] m, last link's frame
        # the object's geoms: V object variants (sim/_object_variants.py), world w reads variant[w]'s
        geom_kind: wp.array3d(dtype=wp.int32)  # [V, B, G] GEOM_* (GEOM_NONE: padding)
        geom_pos: wp.array3d(dtype=vec3)  # [V, B, G] m, body frame
        geom_rot: wp.array3d(dtype=mat33)  # [V, B, G] geom -> body
        geom_size: wp.array3d(dtype=vec3)  # [V, B, G] box, sdf grid: half sizes; sphere: (r); capsule, cylinder:
        # (r, half length)
        geom_bound: wp.array3d(dtype=dtype)  # [V, B, G] m: a sphere about the geom's centre holding it (a mesh:
        # huge, never skipped; ObjectGeoms.skip_bound)
        geom_grid: wp.array3d(dtype=wp.vec4i)  # [V, B, G] sdf: (first index in sdf_values, points along x, y, z)
        sdf_values: wp.array(dtype=dtype)  # every variant's sdf grids (m, negative inside), x-major, one after another
        body_bound: wp.array2d(dtype=dtype)  # [V, B] m: a sphere about the body origin holding its geoms (with margin)
        # [V, B] each object body's inverse mass (1/kg) and inverse inertia about its com (body frame): the contact
        # law's damping is implicit against the body's mobility (zero: a fixed base) plus the finger's
        body_inv_mass: wp.array2d(dtype=dtype)
        body_inv_inertia: wp.array2d(dtype=mat33)
        body_mass: wp.array2d(dtype=dtype)  # [V, B] kg: the masses the two above are of
        # the packed parameters' columns (ArticulatedScene.param_names): body b >= first_moving's mass is column
        # mass_col + b - first_moving, the fingers' friction coefficient column mu_col
        first_moving: int
        mass_col: int
        mu_col: int
        gravity: vec3
        ke: dtype  # N/m: contact stiffness
        kd: dtype  # s/m: Hunt-Crossley damping
        beta: dtype  # 1/m: softplus sharpness
        v_slip: dtype  # m/s

    funcs = build_funcs(dtype)
    axis_angle, range_stop = funcs.axis_angle, funcs.range_stop
    fixed, fixed_vec3, fixed_mat33 = funcs.fixed, funcs.fixed_vec3, funcs.fixed_mat33  # model reads, no adjoint
    joint_friction, joint_drive, write_pose = funcs.joint_friction, funcs.joint_drive, funcs.write_pose

    unit_j = unit_vector(J, dtype)

    contact = build_finger_contact(Model, dtype, J, P, B, G)

    if J == 1:  # warp's inverse starts at 2 x 2

        @wp.func
        def inverse_jj(A: matJ):
            return matJ(dtype(1.0) / A[0, 0])

        @wp.func
        def apply_inverse(A: matJ, A_inv: matJ, b: vecJ):
            return vecJ(b[0] / A[0, 0])

    else:

        @wp.func
        def inverse_jj(A: matJ):
            return wp.inverse(A)

        @wp.func
        def apply_inverse(A: matJ, A_inv: matJ, b: vecJ):
            return A_inv * b

    fixed_2d = constant_read_2d(dtype)  # the step's outputs' adjoints
    fixed_inverse = constant_read_2d(matJ)  # the forward's saved (M + D)^-1
    fixed_accel = constant_read_2d(vecJ)  # the forward's saved joint accelerations

    @wp.func
    def link_motion(acc: vec3, al: vec3, om: vec3, lever: vec3, a: vec3, qd: dtype):
        """The chain's velocity-product terms carried to the next link, whose origin is ``lever`` on from the
        last and whose joint turns at ``qd`` about ``a``: its origin's acceleration, then the link's angular
        acceleration and velocity."""
        acc_next = acc + wp.cross(al, lever) + wp.cross(om, wp.cross(om, lever))
        al_next = al + wp.cross(om, a * qd)
        return acc_next, al_next, om + a * qd

    @wp.func
    def joint_terms(m: Model, w: int, f: int, qf: vecJ, qdf: vecJ, tau: wp.array2d(dtype=dtype),
                    q_target: wp.array2d(dtype=dtype), kp: wp.array2d(dtype=dtype), kd: wp.array2d(dtype=dtype),
                    gen: wp.array2d(dtype=dtype), dt: dtype):
        """A finger's joint-space forces but the bias (feed-forward, drive, damping, friction, range stops,
        contact; N m) and the diagonal its implicit terms add to the mass matrix (armature, dt damping, the
        drive's gain)."""
        rhs = vecJ()
        diag = vecJ()
        for k in range(J):
            i = f * J + k
            qk = qf[k]
            qdk = qdf[k]
            drive, gain = joint_drive(kp[w, i], kd[w, i], q_target[w, i], qk, qdk, dt, fixed(m.effort, i))
            e = unit_j(k)
            diag = diag + (fixed(m.armature, i) + dt * fixed(m.damping, i) + gain) * e
            lim, _ = range_stop(fixed(m.limit_ke, i), fixed(m.lower, i) - qk, qk - fixed(m.upper, i),
                                dtype(LIMIT_WIDTH))
            fric = joint_friction(fixed(m.friction, i), qdk)
            rhs = rhs + (tau[w, i] + drive - fixed(m.damping, i) * qdk - fric + lim + gen[w, i]) * e
        return rhs, diag

    @wp.kernel(module="unique", enable_backward=True)
    def link_frames(
        m: Model,
        hq: wp.array2d(dtype=dtype),  # [N, F*J] rad
        link_x: wp.array2d(dtype=vec3),  # [N, F*J] out: link origins = joint origins (m, world)
        link_R: wp.array2d(dtype=mat33),  # [N, F*J] out: link rotations (link -> world)
        link_a: wp.array2d(dtype=vec3),  # [N, F*J] out: joint axes (world)
    ):
        """Every link's frame through its finger chain, once per substep for the contact and the solve."""
        w, f = wp.tid()
        R = fixed_mat33(m.base_rot, f)
        x = fixed_vec3(m.base_pos, f)
        for k in range(J):
            i = f * J + k
            x = x + R * fixed_vec3(m.off_pos, i)
            R = R * fixed_mat33(m.off_rot, i)
            link_a[w, i] = R * fixed_vec3(m.axis, i)
            R = R * axis_angle(fixed_vec3(m.axis, i), hq[w, i])
            link_x[w, i] = x
            link_R[w, i] = R

    # no generated adjoint: hand_residual's is this kernel's (the adjoint of its solve, without its mass matrix)
    @wp.kernel(module="unique", enable_backward=False)
    def hand_substep(
        m: Model,
        hq: wp.array2d(dtype=dtype),  # [N, F*J] in
        hqd: wp.array2d(dtype=dtype),  # [N, F*J] in
        tau: wp.array2d(dtype=dtype),  # [N, F*J] N m: feed-forward torque
        q_target: wp.array2d(dtype=dtype),  # [N, F*J] rad
        kp: wp.array2d(dtype=dtype),  # [N, F*J] N m/rad
        kd: wp.array2d(dtype=dtype),  # [N, F*J] N m s/rad
        gen: wp.array2d(dtype=dtype),  # [N, F*J] N m: contact torques (finger_contact)
        link_x: wp.array2d(dtype=vec3),  # [N, F*J] link_frames'
        link_R: wp.array2d(dtype=mat33),
        link_a: wp.array2d(dtype=vec3),
        dt: dtype,
        hq_out: wp.array2d(dtype=dtype),  # [N, F*J]
        hqd_out: wp.array2d(dtype=dtype),  # [N, F*J]
        solve_inv: wp.array2d(dtype=matJ),  # [N, F] out: (M + diag)^-1, for hand_residual
        accel: wp.array2d(dtype=vecJ),  # [N, F] out: the joint accelerations (rad/s^2), for hand_residual
    ):
        w, f = wp.tid()
        om = vec3()
        al = vec3()  # velocity-product angular acceleration
        acc = -m.gravity  # velocity-product acceleration of the joint origin (gravity as the base's acceleration)
        o_prev = fixed_vec3(m.base_pos, f)
        O = mat3J()
        A = mat3J()
        M = matJ()
        bias = vecJ()
        qf = vecJ()
        qdf = vecJ()
        for k in range(J):
            qf = qf + hq[w, f * J + k] * unit_j(k)
            qdf = qdf + hqd[w, f * J + k] * unit_j(k)
        for k in range(J):
            i = f * J + k
            x = link_x[w, i]
            R = link_R[w, i]
            a = link_a[w, i]
            acc, al, om = link_motion(acc, al, om, x - o_prev, a, qdf[k])
            o_prev = x
            O = O + wp.outer(x, unit_j(k))
            A = A + wp.outer(a, unit_j(k))
            # the link's com Jacobian Jv and angular Jacobian Jw over the chain's joints so far
            c = x + R * fixed_vec3(m.com, i)
            Jv = mat3J()
            for kk in range(J):
                if kk <= k:
                    ak = vec3(A[0, kk], A[1, kk], A[2, kk])
                    Jv = Jv + wp.outer(wp.cross(ak, c - vec3(O[0, kk], O[1, kk], O[2, kk])), unit_j(kk))
            Jw = A
            ml = fixed(m.mass, i)
            Iw = R * fixed_mat33(m.inertia, i) * wp.transpose(R)
            ac = acc + wp.cross(al, c - x) + wp.cross(om, wp.cross(om, c - x))
            M = M + ml * wp.transpose(Jv) * Jv + wp.transpose(Jw) * Iw * Jw
            bias = bias + wp.transpose(Jv) * (ml * ac) + wp.transpose(Jw) * (Iw * al + wp.cross(om, Iw * om))
        rhs, diag = joint_terms(m, w, f, qf, qdf, tau, q_target, kp, kd, gen, dt)
        rhs = rhs - bias
        for k in range(J):
            M[k, k] = M[k, k] + diag[k]
        M_inv = inverse_jj(M)
        qdd = apply_inverse(M, M_inv, rhs)
        solve_inv[w, f] = M_inv
        accel[w, f] = qdd
        for k in range(J):
            i = f * J + k
            v_new = qdf[k] + dt * qdd[k]
            hqd_out[w, i] = v_new
            hq_out[w, i] = qf[k] + dt * v_new

    @wp.kernel(module="unique", enable_backward=True)
    def hand_residual(
        m: Model,
        hq: wp.array2d(dtype=dtype),  # hand_substep's inputs, as it read them
        hqd: wp.array2d(dtype=dtype),
        tau: wp.array2d(dtype=dtype),
        q_target: wp.array2d(dtype=dtype),
        kp: wp.array2d(dtype=dtype),
        kd: wp.array2d(dtype=dtype),
        gen: wp.array2d(dtype=dtype),
        link_x: wp.array2d(dtype=vec3),
        link_R: wp.array2d(dtype=mat33),
        link_a: wp.array2d(dtype=vec3),
        dt: dtype,
        solve_inv: wp.array2d(dtype=matJ),  # [N, F] hand_substep's
        accel: wp.array2d(dtype=vecJ),  # [N, F] hand_substep's
        adj_hq_out: wp.array2d(dtype=dtype),  # [N, F*J] the adjoints of hand_substep's outputs
        adj_hqd_out: wp.array2d(dtype=dtype),
        residual: wp.array2d(dtype=dtype),  # [N, F] out; its adjoint launch is seeded with ones
    ):
        """hand_substep's adjoint, as the gradient of a scalar: with qdd = A^-1 b (A = M + diag, b = rhs - bias),
        the adjoint of the inputs theta is y^T (db/dtheta - dA/dtheta qdd), y = A^-T adj_qdd (one more product
        with the saved inverse), i.e. the gradient of y . (b - A qdd) at fixed y and qdd. y^T (M qdd + bias) is
        inverse dynamics contracted with y, a sum over links of the com's and the link's velocity under y
        (J_v y, J_w y, running sums) dotted with the link's force and moment at qdd: O(J) products of 3-vectors
        where the forward solve builds J x J matrices, and their adjoints as cheap. Plus the direct terms of
        q' = q + dt qd', qd' = qd + dt qdd."""
        w, f = wp.tid()
        A_inv = fixed_inverse(solve_inv, w, f)
        qdd = fixed_accel(accel, w, f)
        adj_q = vecJ()
        adj_v = vecJ()  # of qd' = qd + dt qdd
        qf = vecJ()
        qdf = vecJ()
        for k in range(J):
            i = f * J + k
            adj_q = adj_q + fixed_2d(adj_hq_out, w, i) * unit_j(k)
            adj_v = adj_v + (fixed_2d(adj_hqd_out, w, i) + dt * fixed_2d(adj_hq_out, w, i)) * unit_j(k)
            qf = qf + hq[w, i] * unit_j(k)
            qdf = qdf + hqd[w, i] * unit_j(k)
        y = wp.transpose(A_inv) * (dt * adj_v)
        rhs, diag = joint_terms(m, w, f, qf, qdf, tau, q_target, kp, kd, gen, dt)
        total = wp.dot(adj_q, qf) + wp.dot(adj_v, qdf) + wp.dot(y, rhs)
        om = vec3()
        al = vec3()
        acc = -m.gravity
        o_prev = fixed_vec3(m.base_pos, f)
        wy = vec3()  # J_w y: the angular velocity the joints get under velocities y
        wq = vec3()  # J_w qdd
        sy = vec3()  # sum of y_k a_k x o_k, so that J_v y at a point p is wy x p - sy
        sq = vec3()
        for k in range(J):
            i = f * J + k
            x = link_x[w, i]
            R = link_R[w, i]
            a = link_a[w, i]
            acc, al, om = link_motion(acc, al, om, x - o_prev, a, qdf[k])
            o_prev = x
            wy = wy + a * y[k]
            wq = wq + a * qdd[k]
            sy = sy + wp.cross(a, x) * y[k]
            sq = sq + wp.cross(a, x) * qdd[k]
            c = x + R * fixed_vec3(m.com, i)
            I = fixed_mat33(m.inertia, i)
            ac = acc + wp.cross(al, c - x) + wp.cross(om, wp.cross(om, c - x))
            force = fixed(m.mass, i) * (wp.cross(wq, c) - sq + ac)
            Iom = R * (I * (wp.transpose(R) * om))
            moment = R * (I * (wp.transpose(R) * (wq + al))) + wp.cross(om, Iom)
            total = total - wp.dot(wp.cross(wy, c) - sy, force) - wp.dot(wy, moment)
        for k in range(J):
            total = total - y[k] * diag[k] * qdd[k]
        residual[w, f] = total

    @wp.kernel(module="unique", enable_backward=True)
    def observe(
        m: Model,
        hq: wp.array2d(dtype=dtype),  # [N, F*J]
        body_x: wp.array2d(dtype=vec3),  # [N, B] object frames
        body_R: wp.array2d(dtype=mat33),
        pose: wp.array2d(dtype=dtype),  # [N, (F*J + B) * 7] out: pos + wxyz quat of every hand link, then body
        tips: wp.array2d(dtype=dtype),  # [N, F * 3] out: fingertip positions (m)
    ):
        w = wp.tid()
        for f in range(F):
            R = fixed_mat33(m.base_rot, f)
            x = fixed_vec3(m.base_pos, f)
            for k in range(J):
                i = f * J + k
                x = x + R * fixed_vec3(m.off_pos, i)
                R = R * fixed_mat33(m.off_rot, i) * axis_angle(fixed_vec3(m.axis, i), hq[w, i])
                write_pose(pose, w, i, x, R)
            tip = x + R * fixed_vec3(m.tip_pos, f)
            for c in range(3):
                tips[w, f * 3 + c] = tip[c]
        for b in range(B):
            write_pose(pose, w, F * J + b, body_x[w, b], body_R[w, b])

    return HandKernels(Model=Model, link_frames=link_frames, finger_contact=contact.finger_contact,
                       hand_substep=hand_substep, hand_residual=hand_residual, observe=observe,
                       geom_distance=contact.geom_distance, vec3=vec3, mat33=mat33, vecJ=vecJ, matJ=matJ, dtype=dtype)
