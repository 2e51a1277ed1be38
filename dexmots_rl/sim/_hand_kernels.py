"""Warp kernels of the hand in an articulated-object scene: finger chains, and their contact with the object.

Two kernels per substep (sim/_articulated.py runs them around the object tree's, sim/_object_kernels.py):

* ``finger_contact``, a thread per world and finger link: the link's frame through its finger chain (once for its
  sample spheres), then for each of the link's spheres its pose and velocity, its signed distance to each object body (the nearest of the body's geoms: box, sphere, capsule,
  cylinder, or a mesh's signed-distance grid), and a relaxed penalty contact with Coulomb friction
  (:class:`~dexmots_rl.sim.ContactParams`' law) per body it touches. The force goes to the finger's joints (J^T f) and, opposite, to the object body (force
  and torque about its com) with atomic adds, so contacts of one world sum in any order.
* ``hand_substep``, a thread per world and finger: the chain's mass matrix and bias forces (a sum over links
  of J^T M J and J^T (inertial) wrenches), the motor's PD drive (implicit, smoothly saturated at its effort),
  joint damping, friction and range stops, the contact forces, and the solve.

``observe`` writes every hand link's pose and the fingertips. Hand joints are hinges; loops have compile-time
trip counts (exact adjoints); everything is generic in the float type.
"""

# no `from __future__ import annotations`: warp reads the closure-typed annotations at definition time

import dataclasses
import functools

import warp as wp

from ._constants import (CONTACT_CUTOFF, GEOM_BOX, GEOM_CAPSULE, GEOM_CYLINDER, GEOM_NONE, GEOM_SDF,
                        GEOM_SPHERE, LIMIT_WIDTH)
from ._kernel_funcs import build_funcs

__all__ = ["build_hand_kernels", "SDF_PAD"]

GEOM_SKIP_MARGIN = 1.0e-5  # m: a geom is skipped only when its bound lies this much beyond the nearest so far
# m: a mesh's grid reaches this far beyond it, more than a finger sphere's radius (the Allegro's largest is
# 14 mm), so the centre of a sphere that touches the mesh is inside the grid, where the distance is interpolated
SDF_PAD = 0.02


@dataclasses.dataclass(frozen=True)
class HandKernels:
    """What :func:`build_hand_kernels` builds for one scene structure: the model struct type, the kernels and the
    warp types they use."""

    Model: type  # the hand's model struct (a wp.struct)
    finger_contact: object  # wp.Kernel: each finger link's contact with the object's bodies
    hand_substep: object  # wp.Kernel: each finger's implicit solve
    observe: object  # wp.Kernel: body poses and fingertips
    geom_distance: object  # wp.func: a point's signed distance to a geom (probe kernels)
    vec3: type
    mat33: type
    dtype: type


@functools.lru_cache(maxsize=None)
def build_hand_kernels(float_type, num_fingers: int, joints: int, points: int, bodies: int, geoms: int):
    """Kernels for ``num_fingers`` chains of ``joints`` hinges with ``points`` sample spheres per link, against an
    object of ``bodies`` bodies with at most ``geoms`` collision geoms each."""
    dtype = float_type
    F, J, P, B, G = int(num_fingers), int(joints), int(points), int(bodies), int(geoms)
    vec3 = wp.types.vector(3, dtype)
    vec4 = wp.types.vector(4, dtype)
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
        # law's damping is implicit against the body's mobility (zero: a fixed base)
        body_inv_mass: wp.array2d(dtype=dtype)
        body_inv_inertia: wp.array2d(dtype=mat33)
        gravity: vec3
        ke: dtype  # N/m: contact stiffness
        kd: dtype  # s/m: Hunt-Crossley damping
        beta: dtype  # 1/m: softplus sharpness
        mu: dtype  # friction coefficient
        v_slip: dtype  # m/s

    funcs = build_funcs(dtype)
    softplus, axis_angle, limit_ramp, box_distance = funcs.softplus, funcs.axis_angle, funcs.limit_ramp, \
        funcs.box_distance
    joint_friction, write_pose = funcs.joint_friction, funcs.write_pose
    normal_force, slip_norm, body_mobility = funcs.normal_force, funcs.slip_norm, funcs.body_mobility
    grid_distance = funcs.grid_distance

    @wp.func
    def unit_j(k: int):
        e = vecJ()
        e[k] = dtype(1.0)
        return e

    if J == 1:  # warp's inverse starts at 2 x 2

        @wp.func
        def solve_jj(A: matJ, b: vecJ):
            return vecJ(b[0] / A[0, 0])

    else:

        @wp.func
        def solve_jj(A: matJ, b: vecJ):
            return wp.inverse(A) * b

    @wp.func
    def geom_distance(kind: int, size: vec3, grid: wp.vec4i, values: wp.array(dtype=dtype), p: vec3):
        """Signed distance (m, negative inside) and outward unit normal of point p (geom frame), packed."""
        d = dtype(1.0e6)
        n = vec3(dtype(0.0), dtype(0.0), dtype(1.0))
        if kind == GEOM_SDF:
            dn = grid_distance(values, grid, size, p)
            d = dn[0]
            n = vec3(dn[1], dn[2], dn[3])
        elif kind == GEOM_SPHERE:
            r = wp.length(p)
            d = r - size[0]
            n = p / wp.max(r, dtype(1.0e-9))
        elif kind == GEOM_CAPSULE:
            s = vec3(dtype(0.0), dtype(0.0), wp.clamp(p[2], -size[1], size[1]))
            r = wp.length(p - s)
            d = r - size[0]
            n = (p - s) / wp.max(r, dtype(1.0e-9))
        elif kind == GEOM_BOX:
            dn = box_distance(size, p)
            d = dn[0]
            n = vec3(dn[1], dn[2], dn[3])
        elif kind == GEOM_CYLINDER:
            rho = wp.sqrt(p[0] * p[0] + p[1] * p[1] + dtype(1.0e-12))
            radial = vec3(p[0] / rho, p[1] / rho, dtype(0.0))
            qr = rho - size[0]
            qz = wp.abs(p[2]) - size[1]
            axial = vec3(dtype(0.0), dtype(0.0), wp.sign(p[2]))
            if qr > dtype(0.0) and qz > dtype(0.0):
                lo = wp.sqrt(qr * qr + qz * qz)
                d = lo
                n = (qr * radial + qz * axial) / lo
            elif qr > qz:
                d = qr
                n = radial
            else:
                d = qz
                n = axial
        return vec4(d, n[0], n[1], n[2])

    @wp.func
    def nearest_geom(m: Model, v: int, b: int, pl: vec3, reach: dtype):
        """Index of body b's geom (of variant v) nearest to point pl (body frame): the first of the smallest
        signed distances below ``reach`` (m; a sphere farther than that from every geom feels nothing); -1 if none."""
        best_d = reach
        best_g = int(-1)
        for g in range(G):
            kind = m.geom_kind[v, b, g]
            offset = pl - m.geom_pos[v, b, g]
            # a geom whose bounding sphere lies farther than the best so far cannot be nearer (its distance is at
            # least |offset| - bound; the margin keeps float rounding from changing which geom wins)
            if kind != GEOM_NONE and wp.length(offset) - m.geom_bound[v, b, g] < best_d + dtype(GEOM_SKIP_MARGIN):
                Rg = m.geom_rot[v, b, g]
                pg = wp.transpose(Rg) * offset
                size = m.geom_size[v, b, g]
                d = best_d
                if kind == GEOM_SDF:
                    # the mesh lies in the grid's box shrunk by the pad: the distance to that box is a lower
                    # bound of the mesh's, and a grid lookup is only needed where it is below the best so far
                    pad = dtype(SDF_PAD)
                    if box_distance(size - vec3(pad, pad, pad), pg)[0] < best_d:
                        d = geom_distance(kind, size, m.geom_grid[v, b, g], m.sdf_values, pg)[0]
                else:
                    d = geom_distance(kind, size, m.geom_grid[v, b, g], m.sdf_values, pg)[0]
                if d < best_d:
                    best_d = d
                    best_g = g
        return best_g

    @wp.func_grad(nearest_geom)
    def adj_nearest_geom(m: Model, v: int, b: int, pl: vec3, reach: dtype, adj_ret: int):
        pass  # an index: nothing to differentiate (the reverse pass skips the G distances' adjoints)

    @wp.kernel(module="unique", enable_backward=True)
    def finger_contact(
        m: Model,
        variant: wp.array(dtype=wp.int32),  # [N] each world's object variant
        hq: wp.array2d(dtype=dtype),  # [N, F*J] rad
        hqd: wp.array2d(dtype=dtype),  # [N, F*J] rad/s
        body_x: wp.array2d(dtype=vec3),  # [N, B] object frames (object_kernels.frames)
        body_R: wp.array2d(dtype=mat33),
        body_c: wp.array2d(dtype=vec3),
        body_v: wp.array2d(dtype=vec3),
        body_w: wp.array2d(dtype=vec3),
        gen: wp.array2d(dtype=dtype),  # [N, F*J] out (atomic): contact torque on each hand joint (N m)
        contact_f: wp.array2d(dtype=vec3),  # [N, B] out (atomic): contact force on each object body (N)
        contact_t: wp.array2d(dtype=vec3),  # [N, B] out (atomic): its torque about the body's com (N m)
        normal_sum: wp.array(dtype=dtype),  # [N] out (atomic): the summed normal force magnitudes (N)
        touching: wp.array2d(dtype=wp.int32),  # [N, S] out: 1 where the sphere is within the cutoff of a body
        only_touching: int,  # 1: skip a sphere whose ``touching`` is 0 (the adjoint launch: such a sphere
        # contributed nothing, so its adjoint is zero)
        points_per_link: int,  # P, a launch argument so the loop over a link's spheres stays a loop (unrolled, the
        # kernel's body would be copied P times)
        dt: dtype,  # s: the substep (the law's damping is implicit over it)
    ):
        w, link = wp.tid()  # link: f * J + k
        if only_touching != 0:  # the adjoint launch: a link none of whose spheres touched has a zero adjoint
            touched = int(0)
            for sp in range(P):
                touched = touched + touching[w, link * P + sp]
            if touched == 0:
                return
        f = link / J
        k_link = link - f * J
        # the chain up to the link, once for all its spheres: joint origins and axes, the link's frame
        R = m.base_rot[f]
        x = m.base_pos[f]
        O = mat3J()  # joint origins (columns)
        A = mat3J()  # joint axes (columns)
        qdf = vecJ()
        for k in range(J):
            if k <= k_link:
                i = f * J + k
                x = x + R * m.off_pos[i]
                R = R * m.off_rot[i]
                a = R * m.axis[i]
                O = O + wp.outer(x, unit_j(k))
                A = A + wp.outer(a, unit_j(k))
                R = R * axis_angle(m.axis[i], hq[w, i])
                qdf = qdf + hqd[w, i] * unit_j(k)
        v = variant[w]
        # each sphere adds its own contact (atomics, in sphere order as a thread per sphere did): nothing is
        # carried from one sphere to the next but the chain above, so the loop's adjoint is exact
        for sp in range(points_per_link):
            s = link * points_per_link + sp
            rad = m.point_radius[s]
            skip = rad <= dtype(0.0)
            if only_touching != 0:
                if touching[w, s] == 0:
                    skip = True
            if not skip:
                p = x + R * m.point_pos[s]
                # the sphere centre's Jacobian over the finger's joints and its velocity
                Jp = mat3J()
                for k in range(J):
                    if k <= k_link:
                        col = wp.cross(vec3(A[0, k], A[1, k], A[2, k]), p - vec3(O[0, k], O[1, k], O[2, k]))
                        Jp = Jp + wp.outer(col, unit_j(k))
                vp = Jp * qdf
                gen_f = vecJ()
                for b in range(B):
                    xb = body_x[w, b]
                    # no geom of body b within the cutoff: skip its distances (their result would go unused)
                    if wp.length(p - xb) < m.body_bound[v, b] + rad + dtype(CONTACT_CUTOFF) / m.beta:
                        Rb = body_R[w, b]
                        pl = wp.transpose(Rb) * (p - xb)
                        best = vec4(dtype(1.0e6), dtype(0.0), dtype(0.0), dtype(1.0))
                        # found without an adjoint; only the nearest geom's distance has one, and only within the
                        # cutoff
                        g = nearest_geom(m, v, b, pl, rad + dtype(CONTACT_CUTOFF) / m.beta)
                        if g >= 0:
                            Rg = m.geom_rot[v, b, g]
                            dn = geom_distance(m.geom_kind[v, b, g], m.geom_size[v, b, g], m.geom_grid[v, b, g],
                                               m.sdf_values, wp.transpose(Rg) * (pl - m.geom_pos[v, b, g]))
                            nb = Rg * vec3(dn[1], dn[2], dn[3])
                            best = vec4(dn[0], nb[0], nb[1], nb[2])
                        pen = rad - best[0]
                        if pen > dtype(-CONTACT_CUTOFF) / m.beta:
                            touching[w, s] = 1
                            n = Rb * vec3(best[1], best[2], best[3])  # world, out of the body
                            cp = p - n * rad
                            r = cp - body_c[w, b]
                            v_rel = vp - body_v[w, b] - wp.cross(body_w[w, b], r)
                            vn = wp.dot(v_rel, n)
                            # the one contact law (kernel_funcs.normal_force): its damping implicit against the
                            # body's mobility at the contact (the finger is far heavier)
                            mobility = body_mobility(m.body_inv_mass[v, b], m.body_inv_inertia[v, b], Rb, r, n)
                            fn = normal_force(m.ke * softplus(pen, m.beta), vn, m.kd, dt, mobility)
                            vt = v_rel - vn * n
                            ft = -m.mu * fn / slip_norm(vt, m.v_slip) * vt
                            fc = fn * n + ft  # on the finger
                            gen_f = gen_f + wp.transpose(Jp) * fc
                            wp.atomic_add(contact_f, w, b, -fc)
                            wp.atomic_add(contact_t, w, b, wp.cross(r, -fc))
                            wp.atomic_add(normal_sum, w, fn)
                for k in range(J):
                    if k <= k_link:
                        wp.atomic_add(gen, w, f * J + k, gen_f[k])

    @wp.kernel(module="unique", enable_backward=True)
    def hand_substep(
        m: Model,
        hq: wp.array2d(dtype=dtype),  # [N, F*J] in
        hqd: wp.array2d(dtype=dtype),  # [N, F*J] in
        tau: wp.array2d(dtype=dtype),  # [N, F*J] N m: feed-forward torque
        q_target: wp.array2d(dtype=dtype),  # [N, F*J] rad
        kp: wp.array2d(dtype=dtype),  # [N, F*J] N m/rad
        kd: wp.array2d(dtype=dtype),  # [N, F*J] N m s/rad
        gen: wp.array2d(dtype=dtype),  # [N, F*J] N m: contact torques (finger_contact)
        dt: dtype,
        hq_out: wp.array2d(dtype=dtype),  # [N, F*J]
        hqd_out: wp.array2d(dtype=dtype),  # [N, F*J]
    ):
        w, f = wp.tid()
        R = m.base_rot[f]
        x = m.base_pos[f]
        om = vec3()
        al = vec3()  # velocity-product angular acceleration
        acc = -m.gravity  # velocity-product acceleration of the joint origin (gravity as the base's acceleration)
        o_prev = x
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
            x = x + R * m.off_pos[i]
            R = R * m.off_rot[i]
            a = R * m.axis[i]
            lever = x - o_prev
            acc = acc + wp.cross(al, lever) + wp.cross(om, wp.cross(om, lever))
            R = R * axis_angle(m.axis[i], qf[k])
            al = al + wp.cross(om, a * qdf[k])
            om = om + a * qdf[k]
            o_prev = x
            O = O + wp.outer(x, unit_j(k))
            A = A + wp.outer(a, unit_j(k))
            # the link's com Jacobian Jv and angular Jacobian Jw over the chain's joints so far
            c = x + R * m.com[i]
            Jv = mat3J()
            for kk in range(J):
                if kk <= k:
                    ak = vec3(A[0, kk], A[1, kk], A[2, kk])
                    Jv = Jv + wp.outer(wp.cross(ak, c - vec3(O[0, kk], O[1, kk], O[2, kk])), unit_j(kk))
            Jw = A
            ml = m.mass[i]
            Iw = R * m.inertia[i] * wp.transpose(R)
            ac = acc + wp.cross(al, c - x) + wp.cross(om, wp.cross(om, c - x))
            M = M + ml * wp.transpose(Jv) * Jv + wp.transpose(Jw) * Iw * Jw
            bias = bias + wp.transpose(Jv) * (ml * ac) + wp.transpose(Jw) * (Iw * al + wp.cross(om, Iw * om))
        rhs = vecJ()
        diag = matJ()
        for k in range(J):
            i = f * J + k
            qk = qf[k]
            qdk = qdf[k]
            drive = kp[w, i] * (q_target[w, i] - qk - dt * qdk) - kd[w, i] * qdk
            gain = dt * kd[w, i] + dt * dt * kp[w, i]
            effort = m.effort[i]
            if effort > dtype(0.0):
                sat = wp.tanh(drive / effort)
                drive = effort * sat
                gain = gain * (dtype(1.0) - sat * sat)
            e = unit_j(k)
            diag = diag + (m.armature[i] + dt * m.damping[i] + gain) * wp.outer(e, e)
            width = dtype(LIMIT_WIDTH)
            lim = m.limit_ke[i] * (limit_ramp(m.lower[i] - qk, width) - limit_ramp(qk - m.upper[i], width))
            fric = joint_friction(m.friction[i], qdk)
            rhs = rhs + (tau[w, i] + drive - m.damping[i] * qdk - fric + lim + gen[w, i]) * e
        rhs = rhs - bias
        qdd = solve_jj(M + diag, rhs)
        for k in range(J):
            i = f * J + k
            v_new = qdf[k] + dt * qdd[k]
            hqd_out[w, i] = v_new
            hq_out[w, i] = qf[k] + dt * v_new

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
            R = m.base_rot[f]
            x = m.base_pos[f]
            for k in range(J):
                i = f * J + k
                x = x + R * m.off_pos[i]
                R = R * m.off_rot[i] * axis_angle(m.axis[i], hq[w, i])
                write_pose(pose, w, i, x, R)
            tip = x + R * m.tip_pos[f]
            for c in range(3):
                tips[w, f * 3 + c] = tip[c]
        for b in range(B):
            write_pose(pose, w, F * J + b, body_x[w, b], body_R[w, b])

    return HandKernels(Model=Model, finger_contact=finger_contact, hand_substep=hand_substep, observe=observe,
                       geom_distance=geom_distance, vec3=vec3, mat33=mat33, dtype=dtype)
