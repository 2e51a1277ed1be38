"""Warp kernels of the articulated object (sim/_object_model.py): one substep of the object tree per world.

One thread per world: the bodies' kinematics (base, then each part through its hinge or slide), the
table's contact on each body's surface samples (and the sum of each body's contacts,
sim/_contact_sum_kernels.py), the tree's mass matrix and bias forces (a sum over bodies of
J^T M J and J^T (inertial - applied) wrenches, with J each body's com/angular velocity Jacobian), the joint
springs, dampers, Coulomb friction and range stops, and a linearly implicit solve: joint damping, springs and
stops, and the table's tangential friction, enter the matrix (stable at any stiffness and slip velocity); the
joints' Coulomb friction is the force that stops them within the step, capped (sim/_joint_friction.py).

Generalized coordinates (per world): a free base's origin position (m) and orientation (w, x, y, z), then the
parts' joint positions (rad or m); velocities: the base origin's linear velocity and the base's angular
velocity (world frame), then the joint velocities. The solve is block elimination over [base translation (3),
base rotation (3), joints (P)], with warp's 3x3 and P x P inverses (P <= 4). Everything is generic in the
float type (float64 for gradient checks); loops have compile-time trip counts, so warp's adjoint is exact.

The model holds every object variant of a scene (sim/_object_variants.py): the arrays that may differ between
variants have a leading variant dimension, and each kernel reads the row of its world's ``variant[w]``.
"""

# no `from __future__ import annotations`: warp reads the closure-typed annotations at definition time

import dataclasses
import functools

import warp as wp

from ._contact_sum_kernels import build_sum_contacts
from ._joint_friction import build_joint_friction
from ._kernel_funcs import build_funcs, unit_vector
from ._surface_kernels import build_surface_contact

__all__ = ["build_object_kernels"]


@dataclasses.dataclass(frozen=True)
class ObjectKernels:
    """What :func:`build_object_kernels` builds for one object tree structure: the model struct type, the kernels
    and the warp types they use."""

    Model: type  # the object's model struct (a wp.struct)
    substep: object  # wp.Kernel: the tree's implicit solve
    frames: object  # wp.Kernel: every body's frame and velocity
    table_contact: object  # wp.Kernel: the table's push on each body (sim/_surface_kernels.py)
    table: bool  # the scene has a table (else table_contact is never launched)
    table_mu_col: int  # the packed parameters' column of the table's friction coefficient (ObjectTree.param_names)
    sum_contacts: object  # wp.Kernel: each body's total contact and the hand's running means
    vec3: type
    mat33: type
    dtype: type


@functools.lru_cache(maxsize=None)
def build_object_kernels(float_type, num_bodies: int, free: bool, table: bool):
    """The kernels for an object tree of ``num_bodies`` bodies (base + parts), a free or fixed base, with or
    without a table (its samples per body are a launch argument of ``table_contact``)."""
    dtype = float_type
    B = int(num_bodies)
    NP = B - 1
    FREE = bool(free)
    TABLE = bool(table) and FREE
    assert NP >= 1 or FREE, "a fixed object needs a moving part"
    NPV = max(NP, 1)  # warp types need a positive size; with NP == 0 the joint block is compiled out
    # the packed parameters' columns (ObjectTree.param_names): 4 per joint, then each moving body's mass (every
    # body from FIRST_MOVING on), then the table's friction
    MASS_COL = 4 * NP
    FIRST_MOVING = 0 if FREE else 1
    TABLE_MU_COL = MASS_COL + B - FIRST_MOVING
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    quat = wp.types.quaternion(dtype)
    vecP = wp.types.vector(NPV, dtype)
    mat3P = wp.types.matrix((3, NPV), dtype)
    matPP = wp.types.matrix((NPV, NPV), dtype)

    # the leading V of an array is the object variant (sim/_object_variants.py): a world reads variant[w]'s row;
    # the topology (parent, joint kinds, ancestor) is every variant's
    @wp.struct
    class Model:
        parent: wp.array(dtype=wp.int32)  # [B]
        off_pos: wp.array2d(dtype=vec3)  # [V, B] m, parent frame (the base: world frame, fixed base only)
        off_rot: wp.array2d(dtype=mat33)  # [V, B]
        jkind: wp.array(dtype=wp.int32)  # [NP] 0 hinge, 1 slide
        jaxis: wp.array2d(dtype=vec3)  # [V, NP] part frame, unit
        janchor: wp.array2d(dtype=vec3)  # [V, NP] m, part frame
        jlower: wp.array2d(dtype=dtype)  # [V, NP] rad or m
        jupper: wp.array2d(dtype=dtype)
        limit_ke: wp.array2d(dtype=dtype)  # [V, NP] N m/rad or N/m: the range stops' stiffness
        limit_width: wp.array2d(dtype=dtype)  # [V, NP] rad or m: depth over which a stop stiffens (smooth)
        armature: wp.array2d(dtype=dtype)  # [V, NP]
        ancestor: wp.array2d(dtype=dtype)  # [B, NP] 1 where joint k moves body b
        mass: wp.array2d(dtype=dtype)  # [V, B] kg
        com: wp.array2d(dtype=vec3)  # [V, B] m, body frame
        inertia: wp.array2d(dtype=mat33)  # [V, B] kg m^2 about the com, body frame
        sample_pos: wp.array3d(dtype=vec3)  # [V, B, S] m, body frame
        sample_radius: wp.array3d(dtype=dtype)  # [V, B, S] m (< 0: padding)
        table_z: wp.array(dtype=dtype)  # [V] m
        gravity: vec3
        ke: dtype  # N/m per sample: the table's penalty stiffness
        beta: dtype  # 1/m: softplus sharpness of the penalty
        kd: dtype  # s/m: Hunt-Crossley damping of the normal force
        mu: dtype  # Coulomb friction coefficient against the table (unread: the parameter "table/friction" is)
        v_slip: dtype  # m/s: slip velocity smoothing the friction

    funcs = build_funcs(dtype)
    axis_angle, limit_ramp, limit_slope = funcs.axis_angle, funcs.limit_ramp, funcs.limit_slope

    @wp.func
    def base_state(m: Model, q: wp.array2d(dtype=dtype), qd: wp.array2d(dtype=dtype), w: int, v: int):
        """The base's origin, rotation, origin velocity and angular velocity (world) in world w (of variant v):
        read from the state for a free base, the model's placement (at rest) for a fixed one."""
        x0 = m.off_pos[v, 0]
        R0 = m.off_rot[v, 0]
        v0 = vec3()
        w0 = vec3()
        if wp.static(FREE):
            x0 = vec3(q[w, 0], q[w, 1], q[w, 2])
            R0 = wp.quat_to_matrix(quat(q[w, 4], q[w, 5], q[w, 6], q[w, 3]))
            v0 = vec3(qd[w, 0], qd[w, 1], qd[w, 2])
            w0 = vec3(qd[w, 3], qd[w, 4], qd[w, 5])
        return x0, R0, v0, w0

    @wp.func
    def mass_scale(mass: dtype, nominal: dtype):
        """A body's mass parameter over its model mass (1 for a massless body, which stays massless)."""
        scale = dtype(1.0)
        if nominal > dtype(0.0):
            scale = mass / nominal
        return scale

    unit_p = unit_vector(NPV, dtype)
    joint_accelerations = build_joint_friction(dtype, NP, vecP, matPP, unit_p)

    @wp.kernel(module="unique", enable_backward=True)
    def substep(
        m: Model,
        variant: wp.array(dtype=wp.int32),  # [N] each world's object variant
        q: wp.array2d(dtype=dtype),  # [N, nq] in
        qd: wp.array2d(dtype=dtype),  # [N, nv] in
        params: wp.array2d(dtype=dtype),  # [N, P] packed as ObjectTree.param_names (the columns above)
        ext: wp.array2d(dtype=dtype),  # [N, 6 * B] per body: force (N) and torque about its com (N m), world
        contact_f: wp.array2d(dtype=vec3),  # [N, B] contact force on each body (N), world (table_contact)
        contact_t: wp.array2d(dtype=vec3),  # [N, B] its torque about the body's com (N m)
        contact_Kvv: wp.array2d(dtype=mat33),  # [N, B] dt x the contacts' viscous friction, at the com
        contact_Kvw: wp.array2d(dtype=mat33),
        contact_Kww: wp.array2d(dtype=mat33),
        dt: dtype,
        body_x: wp.array2d(dtype=vec3),  # [N, B] scratch (this substep's): body origins
        body_R: wp.array2d(dtype=mat33),  # [N, B] scratch: body rotations
        body_w: wp.array2d(dtype=vec3),  # [N, B] scratch: angular velocities
        body_al: wp.array2d(dtype=vec3),  # [N, B] scratch: velocity-product angular accelerations
        body_c: wp.array2d(dtype=vec3),  # [N, B] scratch: com positions
        body_ac: wp.array2d(dtype=vec3),  # [N, B] scratch: velocity-product com accelerations
        joint_a: wp.array2d(dtype=vec3),  # [N, NP] scratch: joint axes (world)
        joint_o: wp.array2d(dtype=vec3),  # [N, NP] scratch: joint anchors (world)
        q_out: wp.array2d(dtype=dtype),  # [N, nq]
        qd_out: wp.array2d(dtype=dtype),  # [N, nv]
    ):
        w = wp.tid()
        v = variant[w]
        qo = 7 * int(FREE)  # first joint coordinate
        vo = 6 * int(FREE)  # first joint velocity
        # joint state (and its velocity) as vectors, read once
        qj = vecP()
        qdj = vecP()
        for k in range(NP):
            qj = qj + q[w, qo + k] * unit_p(k)
            qdj = qdj + qd[w, vo + k] * unit_p(k)
        # the base
        x0, R0, v0, w0 = base_state(m, q, qd, w, v)
        # block sums of the mass matrix [T R P] and of the right-hand side
        M11 = mat33()
        M12 = mat33()
        M13 = mat3P()
        M22 = mat33()
        M23 = mat3P()
        M33 = matPP()
        r1 = vec3()
        r2 = vec3()
        r3 = vecP()
        for b in range(B):
            x = x0
            R = R0
            om = w0
            al = vec3()
            c = vec3()
            ac = vec3()
            if b > 0:
                p = m.parent[b]
                k = b - 1
                xp = body_x[w, p]
                Rp = body_R[w, p]
                omp = body_w[w, p]
                alp = body_al[w, p]
                cp = body_c[w, p]
                acp = body_ac[w, p]
                R = Rp * m.off_rot[v, b]
                a = R * m.jaxis[v, k]
                o = xp + Rp * m.off_pos[v, b] + R * m.janchor[v, k]
                joint_a[w, k] = a
                joint_o[w, k] = o
                a_o = acp + wp.cross(alp, o - cp) + wp.cross(omp, wp.cross(omp, o - cp))
                if m.jkind[k] == 0:
                    R = R * axis_angle(m.jaxis[v, k], qj[k])
                    x = o - R * m.janchor[v, k]
                    om = omp + a * qdj[k]
                    al = alp + wp.cross(omp, a * qdj[k])
                else:
                    x = o - R * m.janchor[v, k] + a * qj[k]
                    om = omp
                    al = alp
                c = x + R * m.com[v, b]
                if m.jkind[k] == 0:
                    ac = a_o + wp.cross(al, c - o) + wp.cross(om, wp.cross(om, c - o))
                else:
                    ac = acp + wp.cross(alp, c - cp) + wp.cross(omp, wp.cross(omp, c - cp)) + dtype(2.0) * wp.cross(omp, a * qdj[k])
            else:
                c = x + R * m.com[v, 0]
                ac = wp.cross(om, wp.cross(om, c - x0))
            body_x[w, b] = x
            body_R[w, b] = R
            body_w[w, b] = om
            body_al[w, b] = al
            body_c[w, b] = c
            body_ac[w, b] = ac
            # this body's Jacobians over the joints: com velocity Jv and angular velocity Jw
            Jv = mat3P()
            Jw = mat3P()
            for kk in range(NP):
                if m.ancestor[b, kk] > dtype(0.0):
                    ak = joint_a[w, kk]
                    if m.jkind[kk] == 0:
                        Jv = Jv + wp.outer(wp.cross(ak, c - joint_o[w, kk]), unit_p(kk))
                        Jw = Jw + wp.outer(ak, unit_p(kk))
                    else:
                        Jv = Jv + wp.outer(ak, unit_p(kk))
            # applied wrench: external (the hand, the planner) and the table
            f_app = vec3(ext[w, 6 * b + 0], ext[w, 6 * b + 1], ext[w, 6 * b + 2])
            t_app = vec3(ext[w, 6 * b + 3], ext[w, 6 * b + 4], ext[w, 6 * b + 5])
            # the body's spatial inertia at its com, plus the contacts' implicit viscous part (table_contact)
            mb = m.mass[v, b]
            Iw = R * m.inertia[v, b] * wp.transpose(R)
            if b >= FIRST_MOVING:  # the body's mass parameter; its inertia scales with it (same shape)
                scale = mass_scale(params[w, MASS_COL + b - FIRST_MOVING], mb)
                mb = mb * scale
                Iw = Iw * scale
            Kvv = mb * wp.identity(n=3, dtype=dtype) + contact_Kvv[w, b]
            Kvw = contact_Kvw[w, b]
            Kww = Iw + contact_Kww[w, b]
            f_app = f_app + contact_f[w, b]
            t_app = t_app + contact_t[w, b]
            Kwv = wp.transpose(Kvw)
            # inertial minus applied wrench, and the body's share of the matrix, block by block
            F = mb * (ac - m.gravity) - f_app
            T = Iw * al + wp.cross(om, Iw * om) - t_app
            r3 = r3 - (wp.transpose(Jv) * F + wp.transpose(Jw) * T)
            KJ_v = Kvv * Jv + Kvw * Jw  # the body's [V; w] rows times its joint columns
            KJ_w = Kwv * Jv + Kww * Jw
            M33 = M33 + wp.transpose(Jv) * KJ_v + wp.transpose(Jw) * KJ_w
            if wp.static(FREE):
                JR = -wp.skew(c - x0)  # com velocity per unit base angular velocity
                KR_v = Kvv * JR + Kvw
                KR_w = Kwv * JR + Kww
                M11 = M11 + Kvv
                M12 = M12 + KR_v
                M13 = M13 + KJ_v
                M22 = M22 + wp.transpose(JR) * KR_v + KR_w
                M23 = M23 + wp.transpose(JR) * KJ_v + KJ_w
                r1 = r1 - F
                r2 = r2 - (wp.cross(c - x0, F) + T)
        # joints: springs, dampers and range stops, linearised at the predicted position (friction: after the
        # elimination)
        friction = vecP()
        for k in range(NP):
            damp = params[w, 4 * k + 0]
            fric = params[w, 4 * k + 1]
            spring = params[w, 4 * k + 2]
            rest = params[w, 4 * k + 3]
            qp = qj[k] + dt * qdj[k]
            lo = m.jlower[v, k] - qp
            hi = qp - m.jupper[v, k]
            force = -damp * qdj[k] - spring * (qp - rest)
            width = m.limit_width[v, k]
            force = force + m.limit_ke[v, k] * (limit_ramp(lo, width) - limit_ramp(hi, width))
            stiff = spring + m.limit_ke[v, k] * (limit_slope(lo, width) + limit_slope(hi, width))
            r3 = r3 + force * unit_p(k)
            e = unit_p(k)
            friction = friction + fric * e
            M33 = M33 + (m.armature[v, k] + dt * damp + dt * dt * stiff) * wp.outer(e, e)
        # block elimination: [T R P] with T = base translation, R = base rotation, P = joints
        qdd_p = vecP()
        if wp.static(FREE):
            M11i = wp.inverse(M11)
            S22 = M22 - wp.transpose(M12) * M11i * M12
            S23 = M23 - wp.transpose(M12) * M11i * M13
            S33 = M33 - wp.transpose(M13) * M11i * M13
            s2 = r2 - wp.transpose(M12) * (M11i * r1)
            s3 = r3 - wp.transpose(M13) * (M11i * r1)
            S22i = wp.inverse(S22)
            if wp.static(NP > 0):
                T33 = S33 - wp.transpose(S23) * S22i * S23
                t3 = s3 - wp.transpose(S23) * (S22i * s2)
                qdd_p = joint_accelerations(T33, t3, qdj, friction, dt)
            a_rot = S22i * (s2 - S23 * qdd_p)
            a_lin = M11i * (r1 - M12 * a_rot - M13 * qdd_p)
            v_new = v0 + dt * a_lin
            w_new = w0 + dt * a_rot
            x_new = x0 + dt * v_new
            rq = quat(q[w, 4], q[w, 5], q[w, 6], q[w, 3])
            rq = wp.normalize(rq + quat(w_new[0], w_new[1], w_new[2], dtype(0.0)) * rq * (dtype(0.5) * dt))
            for i in range(3):
                q_out[w, i] = x_new[i]
                qd_out[w, i] = v_new[i]
                qd_out[w, 3 + i] = w_new[i]
            q_out[w, 3] = rq[3]
            q_out[w, 4] = rq[0]
            q_out[w, 5] = rq[1]
            q_out[w, 6] = rq[2]
        else:
            qdd_p = joint_accelerations(M33, r3, qdj, friction, dt)
        for k in range(NP):
            v_k = qdj[k] + dt * qdd_p[k]
            qd_out[w, vo + k] = v_k
            q_out[w, qo + k] = qj[k] + dt * v_k


    @wp.kernel(module="unique", enable_backward=True)
    def frames(
        m: Model,
        variant: wp.array(dtype=wp.int32),  # [N]
        q: wp.array2d(dtype=dtype),  # [N, nq]
        qd: wp.array2d(dtype=dtype),  # [N, nv]
        body_x: wp.array2d(dtype=vec3),  # [N, B] out: body origins (m, world)
        body_R: wp.array2d(dtype=mat33),  # [N, B] out: body rotations (body -> world)
        body_c: wp.array2d(dtype=vec3),  # [N, B] out: com positions (m)
        body_v: wp.array2d(dtype=vec3),  # [N, B] out: com velocities (m/s)
        body_w: wp.array2d(dtype=vec3),  # [N, B] out: angular velocities (rad/s)
    ):
        """Every body's pose and velocity (what the contacts read at the start of a substep)."""
        w = wp.tid()
        v = variant[w]
        qo = 7 * int(FREE)
        vo = 6 * int(FREE)
        x0, R0, v0, w0 = base_state(m, q, qd, w, v)
        body_x[w, 0] = x0
        body_R[w, 0] = R0
        body_c[w, 0] = x0 + R0 * m.com[v, 0]
        body_v[w, 0] = v0 + wp.cross(w0, R0 * m.com[v, 0])
        body_w[w, 0] = w0
        for b in range(1, B):
            k = b - 1
            p = m.parent[b]
            xp = body_x[w, p]
            Rp = body_R[w, p]
            omp = body_w[w, p]
            vo_p = body_v[w, p] + wp.cross(omp, xp - body_c[w, p])  # velocity of the parent's origin
            R = Rp * m.off_rot[v, b]
            a = R * m.jaxis[v, k]
            o = xp + Rp * m.off_pos[v, b] + R * m.janchor[v, k]
            v_o = vo_p + wp.cross(omp, o - xp)
            qk = q[w, qo + k]
            qdk = qd[w, vo + k]
            x = o - R * m.janchor[v, k]
            om = omp
            if m.jkind[k] == 0:
                R = R * axis_angle(m.jaxis[v, k], qk)
                x = o - R * m.janchor[v, k]
                om = omp + a * qdk
            else:
                x = x + a * qk
                v_o = v_o + a * qdk + wp.cross(omp, a * qk)
            c = x + R * m.com[v, b]
            if m.jkind[k] == 0:
                v_c = v_o + wp.cross(om, c - o)
            else:
                v_c = v_o + wp.cross(om, c - o - a * qk)
            body_x[w, b] = x
            body_R[w, b] = R
            body_c[w, b] = c
            body_v[w, b] = v_c
            body_w[w, b] = om

    @wp.func
    def table_top(m: Model, v: int, k: int, ps: vec3, rad: dtype):  # a surface of sim/_surface_kernels.py
        return m.table_z[v] + rad - ps[2], vec3(dtype(0.0), dtype(0.0), dtype(1.0))

    return ObjectKernels(Model=Model, substep=substep, frames=frames, table=TABLE, table_mu_col=TABLE_MU_COL,
                         table_contact=build_surface_contact(dtype, Model, 1, table_top),
                         sum_contacts=build_sum_contacts(dtype, B, Model), vec3=vec3, mat33=mat33, dtype=dtype)
