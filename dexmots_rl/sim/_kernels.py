"""The physics core: warp kernels for one substep of every world, and for observations.

One thread per world runs the whole substep: forward kinematics and the recursive Newton-Euler bias
forces of every finger chain, relaxed penalty contact of every finger sample point against the object,
the implicit (damping/PD) joint-space solve per finger, and the object's update. Loops over fingers,
links and points have compile-time trip counts (the kernels are built per scene) and are unrolled, which
is what keeps warp's adjoint exact (a non-unrolled loop that carries state is silently differentiated
wrong). Everything is generic in the float type so gradient checks can run in float64.

The reverse pass is warp's generated adjoint, made cheap in three ways (docs/devnotes.md): a taped
step saves each function call's result (``Saved``) and ``wp.func_replay`` loads it instead of re-running
the call at every nesting level; model constants are read through loads with an empty adjoint, so the
compiler drops the adjoint terms that would only flow into the model; the convex object's distance
(_object_sdf_kernels.py), the contact law (_contact_kernels.py) and a link's inertia block (_chain_kernels.py) have
hand-written adjoints.
"""

# no `from __future__ import annotations`: warp reads the closure-typed annotations at definition time

import dataclasses
import functools
import os

import warp as wp

from ._chain_kernels import build_chain
from ._contact_kernels import build_contact
from ._palm_kernels import build_palm
from ._constants import LIMIT_WIDTH
from ._fused_model import fused_spec
from ._kernel_funcs import build_funcs
from ._model import HINGE, OBJECT_HINGE, OBJECT_PARAMS
from ._object_sdf_kernels import build_object_sdf

__all__ = ["build_kernels"]

# clang optimisation level for the CPU build: -O2 runs 2.5x faster than -O1 at about the same compile time
# (docs/results.md, compile times); -O0 compiles faster but runs 18x slower.
# Override with DEXMOTS_WARP_OPT=0..3 (e.g. 0 while iterating on kernel code).
OPT_LEVEL = int(os.environ.get("DEXMOTS_WARP_OPT", "2"))
# CUDA builds only: warp 1.19 does not pass fast_math to its CPU compiler (a CPU run with it set measured the
# same within noise)
FAST_MATH = os.environ.get("DEXMOTS_WARP_FAST_MATH", "0") == "1"
# columns of the packed per-world parameter array, by name (model.OBJECT_PARAMS)
P_DAMPING, P_FRICTION, P_STIFFNESS, P_REST = (OBJECT_PARAMS.index(n) for n in
                                              ("joint_damping", "joint_friction", "joint_stiffness", "joint_rest"))


@dataclasses.dataclass(frozen=True)
class Kernels:
    """What :func:`build_kernels` builds for one scene structure: the model and saved-results struct types, the
    substep and observation kernels, functions probe kernels call (tests) and the warp types they all use."""

    Model: type  # the scene's model struct (a wp.struct)
    Saved: type  # the per-call results a taped step keeps for the reverse pass (a wp.struct)
    substep: object  # wp.Kernel: one substep of every world
    observe: object  # wp.Kernel: body poses and fingertips
    object_sdf: object  # wp.func: a point's signed distance to the object (probe kernels)
    contact_force: object  # wp.func: the contact law (probe kernels)
    link_inertia: object  # wp.func: a link's mass-matrix and bias contribution (probe kernels)
    palm: object  # the palm-contact functions (probe kernels), None without palm contact
    vec3: type
    vec4: type
    mat33: type
    vec7: type
    vecC: type
    vecJ: type
    matJ3: type
    mat43: type
    matJJ1: type


@functools.lru_cache(maxsize=None)
def build_kernels(float_type, num_fingers: int, joints: int, points: int, planes: int, object_kind: int, shape: int,
                  hinges_only: bool = False, palm_boxes: int = 0, palm_points: int = 0,
                  object_limited: bool = False, box_object: bool = False):
    """Return a namespace with the struct type and kernels specialised for one scene structure.

    ``hinges_only``: every hand joint is revolute, so joint-type branches are resolved at build time
    (fewer instructions forward and, above all, in the generated adjoint). ``palm_boxes``,
    ``palm_points``: palm collision boxes and object surface samples (_palm_kernels.py; free objects only);
    with none, the palm's fields and code are left out entirely.
    ``object_limited``: the hinge object has a range, held by an implicit limit spring (else compiled out).
    ``box_object``: the convex object's faces are the six of an axis-aligned box (object frame), so the
    largest face distance is ``max(|p - c| - h)`` (exact; three planes' work instead of six)."""
    spec = fused_spec(float_type, joints, planes, shape, hinges_only, object_kind == OBJECT_HINGE, object_limited,
                      box_object, palm_boxes, palm_points)
    F, J, P = num_fingers, joints, points
    OBJ_HINGE, PALM, HINGES_ONLY = spec.hinge_object, spec.palm, spec.hinges_only
    OBJ_LIMITED = bool(object_limited) and OBJ_HINGE
    module_options = {"optimization_level": OPT_LEVEL, "fast_math": FAST_MATH}
    if PALM and palm_points > 16:
        module_options["max_unroll"] = palm_points  # the sample loop must unroll for an exact adjoint
    dtype, vec3, mat33, quat, Model, Saved = spec.dtype, spec.vec3, spec.mat33, spec.quat, spec.Model, spec.Saved
    vecJ, matJ, matJ3, vec7, vecC, matJJ1 = spec.vecJ, spec.matJ, spec.matJ3, spec.vec7, spec.vecC, spec.matJJ1

    sdf = build_object_sdf(spec)
    chain = build_chain(spec)
    contact = build_contact(spec, sdf, chain)
    point_contact, sphere_near, link_near = contact.point_contact, contact.sphere_near, contact.link_near
    unit_j, mass_block, bias_column, link_inertia = chain.unit_j, chain.mass_block, chain.bias_column, chain.link_inertia
    joint_forces = chain.joint_forces
    palm = build_palm(spec, sdf) if PALM else None
    palm_wrench = palm.palm_wrench if PALM else None

    funcs = build_funcs(dtype)
    fixed_vec3, fixed_mat33, fixed = funcs.fixed_vec3, funcs.fixed_mat33, funcs.fixed
    axis_angle, range_stop = funcs.axis_angle, funcs.range_stop
    joint_friction, joint_drive, write_pose = funcs.joint_friction, funcs.joint_drive, funcs.write_pose

    @wp.func
    def object_frame(m: Model, q: wp.array2d(dtype=dtype), qd: wp.array2d(dtype=dtype), w: int):
        # w: the row of q/qd holding this world's state
        """Object pose (origin, rotation), velocity of the origin and angular velocity, world frame."""
        if wp.static(OBJ_HINGE):
            th = q[w, F * J]
            a = m.obj_base_rot * m.obj_axis
            return m.obj_base_pos, m.obj_base_rot * axis_angle(m.obj_axis, th), vec3(), a * qd[w, F * J]
        o = F * J
        rq = quat(q[w, o + 4], q[w, o + 5], q[w, o + 6], q[w, o + 3])
        pos = vec3(q[w, o], q[w, o + 1], q[w, o + 2])
        v = vec3(qd[w, o], qd[w, o + 1], qd[w, o + 2])
        return pos, wp.quat_to_matrix(rq), v, vec3(qd[w, o + 3], qd[w, o + 4], qd[w, o + 5])

    @wp.func
    def finger_step(m: Model, f: int, w: int, r: int, ro: int, q: wp.array2d(dtype=dtype),
                    qd: wp.array2d(dtype=dtype), tau: wp.array2d(dtype=dtype), q_target: wp.array2d(dtype=dtype),
                    kp: wp.array2d(dtype=dtype), kd: wp.array2d(dtype=dtype), dt: dtype, Ro: mat33, xo: vec3, vo: vec3,
                    wo: vec3, saved: Saved):
        """Advance finger f of world w (state row r of q/qd, written to row ro) by one substep; returns the
        contact force and torque (about xo) it puts on the object and its summed normal force, packed.
        A function rather than inline code keeps each compiled frame small: warp value-initialises every
        local of a frame on entry. ``saved*`` (rows: ``ro``; empty when untaped): results kept for the
        reverse pass."""
        contacts = vecC()  # the object contacts' results summed: force, torque about xo, normal force, joint forces
        R = fixed_mat33(m.base_rot, f)
        x = fixed_vec3(m.base_pos, f)
        om = vec3()  # angular velocity of the parent link
        al = vec3()  # its angular acceleration (velocity-product part, qdd = 0)
        acc = -m.gravity  # acceleration of the parent's joint origin (gravity as base acceleration)
        o_prev = x
        O = matJ3()  # joint origins, one row per link
        A = matJ3()  # joint axes (world)
        MB = matJJ1()  # the finger's [M | bias], summed over its links
        # the finger's joint state read once: every array read has its own atomic adjoint in the reverse pass
        qf = vecJ()
        qdf = vecJ()
        for k in range(J):
            qf[k] = q[r, f * J + k]
            qdf[k] = qd[r, f * J + k]
        for k in range(J):
            i = f * J + k
            jt = m.jtype[i]
            x = x + R * fixed_vec3(m.off_pos, i)
            R = R * fixed_mat33(m.off_rot, i)
            a = R * fixed_vec3(m.axis, i)
            qk = qf[k]
            qdk = qdf[k]
            if wp.static(not HINGES_ONLY):
                if jt != HINGE:
                    x = x + a * qk
            lever = x - o_prev
            acc = acc + wp.cross(al, lever) + wp.cross(om, wp.cross(om, lever))
            if wp.static(HINGES_ONLY):
                R = R * axis_angle(fixed_vec3(m.axis, i), qk)
                al = al + wp.cross(om, a * qdk)
                om = om + a * qdk
            else:
                if jt == HINGE:
                    R = R * axis_angle(fixed_vec3(m.axis, i), qk)
                    al = al + wp.cross(om, a * qdk)
                    om = om + a * qdk
                else:
                    acc = acc + dtype(2.0) * wp.cross(om, a * qdk)
            o_prev = x
            # O and A were already read for earlier links: overwriting their components would break
            # the adjoint, so add the new row as a whole matrix instead
            O = O + wp.outer(unit_j(k), x)
            A = A + wp.outer(unit_j(k), a)
            # link inertia: mass matrix and bias-force contributions through the Jacobian
            Mb = link_inertia(m, i, f * J, R, x, acc, al, om, A, O, saved, ro)
            if saved.inertia.shape[0] > 0:
                saved.inertia[ro, i] = Mb
            MB = MB + Mb
            # contact of this link's sample spheres: a distance test each (skipped for the whole link when
            # none can reach the object), the work only near the object
            if link_near(m, x, i, xo, Ro) != 0:
                for sp in range(P):
                    pi = i * P + sp
                    if sphere_near(m, x, R, pi, xo, Ro) != 0:
                        p = x + R * fixed_vec3(m.point_pos, pi)
                        res = point_contact(m, p, m.point_radius[pi], Ro, xo, vo, wo, f * J, A, O, qdf, dt, saved, ro,
                                            pi)
                        if saved.contact.shape[0] > 0:
                            saved.contact[ro, pi] = res
                        # summed as whole vectors: a per-component sum unrolls J adjoint updates per sphere
                        contacts = contacts + res
        f_obj = -vec3(contacts[0], contacts[1], contacts[2])
        t_obj = -vec3(contacts[3], contacts[4], contacts[5])
        cforce = contacts[6]
        gen = joint_forces(contacts)
        # implicit joint-space solve: (M + dt (D + Kd) + dt^2 Kp) qdd = rhs
        M = mass_block(MB)
        bias = bias_column(MB)
        rhs = vecJ()
        diag = matJ()
        for k in range(J):
            i = f * J + k
            qk = qf[k]
            qdk = qdf[k]
            drive, gain = joint_drive(kp[w, i], kd[w, i], q_target[w, i], qk, qdk, dt, fixed(m.effort, i))
            diag[k, k] = fixed(m.armature, i) + dt * fixed(m.damping, i) + gain
            lim, _ = range_stop(fixed(m.limit_ke, i), fixed(m.lower, i) - qk, qk - fixed(m.upper, i),
                                dtype(LIMIT_WIDTH))
            fric = joint_friction(fixed(m.friction, i), qdk)
            rhs[k] = tau[w, i] + drive - fixed(m.damping, i) * qdk - fric + lim + gen[k] - bias[k]
        if wp.static(J == 1):
            qdd = vecJ(rhs[0] / (M[0, 0] + diag[0, 0]))
        else:
            qdd = wp.inverse(M + diag) * rhs
        for k in range(J):
            i = f * J + k
            v_new = qdf[k] + dt * qdd[k]
            qd[ro, i] = v_new
            q[ro, i] = qf[k] + dt * v_new
        return vec7(f_obj[0], f_obj[1], f_obj[2], t_obj[0], t_obj[1], t_obj[2], cforce)

    # the kernel's reverse pass reads the finger's result back instead of re-running it (see contact_kernels);
    # warp requires a replay to repeat the forward's signature
    @wp.func_replay(finger_step)
    def replay_finger_step(m: Model, f: int, w: int, r: int, ro: int, q: wp.array2d(dtype=dtype),
                           qd: wp.array2d(dtype=dtype), tau: wp.array2d(dtype=dtype),
                           q_target: wp.array2d(dtype=dtype), kp: wp.array2d(dtype=dtype),
                           kd: wp.array2d(dtype=dtype), dt: dtype, Ro: mat33, xo: vec3, vo: vec3, wo: vec3,
                           saved: Saved):
        return saved.finger[ro, f]

    @wp.kernel(module="unique", module_options=module_options)
    def substep(m: Model, q: wp.array2d(dtype=dtype), qd: wp.array2d(dtype=dtype), tau: wp.array2d(dtype=dtype),
                q_target: wp.array2d(dtype=dtype), kp: wp.array2d(dtype=dtype), kd: wp.array2d(dtype=dtype),
                params: wp.array2d(dtype=dtype), ext: wp.array2d(dtype=dtype), wrench: wp.array2d(dtype=dtype),
                cforce: wp.array(dtype=dtype), saved: Saved, w0: int, in_base: int, out_base: int, dt: dtype,
                inv_substeps: dtype):
        """One substep of worlds w0 + tid. q, qd, wrench, cforce hold a whole trajectory: the state of
        world w is read from row in_base + w and written to row out_base + w (every row written once,
        so warp's adjoint stays exact and one set of arrays serves all substeps of an env step)."""
        w = w0 + wp.tid()
        r = in_base + w
        ro = out_base + w
        xo, Ro, vo, wo = object_frame(m, q, qd, r)
        f_obj = vec3()
        t_obj = vec3()  # about the object origin xo
        c_sum = dtype(0.0)
        for f in range(F):
            res = finger_step(m, f, w, r, ro, q, qd, tau, q_target, kp, kd, dt, Ro, xo, vo, wo, saved)
            if saved.finger.shape[0] > 0:
                saved.finger[ro, f] = res
            f_obj = f_obj + vec3(res[0], res[1], res[2])
            t_obj = t_obj + vec3(res[3], res[4], res[5])
            c_sum = c_sum + res[6]
        o = F * J
        # external wrench on the object (world frame, torque about the object origin): the wrench planner
        # drives the object alone with it
        ext_f = vec3(ext[w, 0], ext[w, 1], ext[w, 2])
        ext_t = vec3(ext[w, 3], ext[w, 4], ext[w, 5])
        hand_f = f_obj
        hand_t = t_obj
        if wp.static(PALM):
            # the palm's push on the object: part of the hand's wrench reported below (what the wrench
            # planner's external wrench stands for: all of the hand's push besides gravity), not of the
            # fingers' contact force sum (AHAC's contact budget)
            palm_f, palm_t = palm_wrench(m, xo, Ro, vo, wo, dt)
            ext_f = ext_f + palm_f
            ext_t = ext_t + palm_t
            hand_f = hand_f + palm_f
            hand_t = hand_t + palm_t
        if wp.static(OBJ_HINGE):
            a = m.obj_base_rot * m.obj_axis
            damp = params[w, P_DAMPING]
            spring = params[w, P_STIFFNESS]
            th = q[r, o]
            th_d = qd[r, o]
            torque = wp.dot(a, t_obj + ext_t + wp.cross(Ro * m.obj_com, m.obj_mass * m.gravity))
            torque = torque - damp * th_d - joint_friction(params[w, P_FRICTION], th_d)
            # the spring is integrated implicitly like the damping (stable at any stiffness)
            torque = torque - spring * (th + dt * th_d - params[w, P_REST])
            stiff = spring
            if wp.static(OBJ_LIMITED):
                # the range's limit spring, linearised at the predicted angle like the joint spring: implicit,
                # so it can be stiff enough that a finger cannot push the part through its stop
                th_p = th + dt * th_d
                stop, stop_stiffness = range_stop(m.obj_limit_ke, m.obj_lower - th_p, th_p - m.obj_upper,
                                                  dtype(LIMIT_WIDTH))
                torque = torque + stop
                stiff = stiff + stop_stiffness
            v_new = th_d + dt * torque / (m.obj_axial_inertia + dt * damp + dt * dt * stiff)
            qd[ro, o] = v_new
            q[ro, o] = q[r, o] + dt * v_new
        else:
            # free body: origin at the centre of mass, velocities in the world frame
            Iw = Ro * m.obj_inertia * wp.transpose(Ro)
            v_new = vo + dt * ((f_obj + ext_f) / m.obj_mass + m.gravity)
            w_new = wo + dt * (wp.inverse(Iw) * (t_obj + ext_t - wp.cross(wo, Iw * wo)))
            x_new = xo + dt * v_new
            rq = quat(q[r, o + 4], q[r, o + 5], q[r, o + 6], q[r, o + 3])
            rq = wp.normalize(rq + quat(w_new[0], w_new[1], w_new[2], dtype(0.0)) * rq * (dtype(0.5) * dt))
            for c in range(3):
                q[ro, o + c] = x_new[c]
                qd[ro, o + c] = v_new[c]
                qd[ro, o + 3 + c] = w_new[c]
            q[ro, o + 3] = rq[3]
            q[ro, o + 4] = rq[0]
            q[ro, o + 5] = rq[1]
            q[ro, o + 6] = rq[2]
        for c in range(3):
            wrench[ro, c] = wrench[r, c] + inv_substeps * hand_f[c]
            wrench[ro, 3 + c] = wrench[r, 3 + c] + inv_substeps * hand_t[c]
        cforce[ro] = cforce[r] + inv_substeps * c_sum

    @wp.kernel(module="unique", module_options=module_options)
    def observe(m: Model, q: wp.array2d(dtype=dtype), qd: wp.array2d(dtype=dtype), body_pose: wp.array2d(dtype=dtype),
                tips: wp.array2d(dtype=dtype), w0: int):
        """Poses (pos + wxyz quat) of every hand link and the object, and fingertip positions."""
        w = w0 + wp.tid()
        for f in range(F):
            R = m.base_rot[f]
            x = m.base_pos[f]
            for k in range(J):
                i = f * J + k
                x = x + R * m.off_pos[i]
                R = R * m.off_rot[i]
                if m.jtype[i] == HINGE:
                    R = R * axis_angle(m.axis[i], q[w, i])
                else:
                    x = x + (R * m.axis[i]) * q[w, i]
                write_pose(body_pose, w, i, x, R)
            tip = x + R * m.tip_pos[f]
            for c in range(3):
                tips[w, f * 3 + c] = tip[c]
        xo, Ro, vo, wo = object_frame(m, q, qd, w)
        write_pose(body_pose, w, F * J, xo, Ro)

    return Kernels(Model=Model, Saved=Saved, substep=substep, observe=observe, object_sdf=sdf.object_sdf,
                   contact_force=contact.contact_force, link_inertia=link_inertia, palm=palm, vec3=vec3, vec4=spec.vec4,
                   mat33=mat33, vec7=vec7, vecC=vecC, vecJ=vecJ, matJ3=matJ3, mat43=spec.mat43, matJJ1=matJJ1)
