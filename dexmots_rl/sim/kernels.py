"""The physics core: warp kernels for one substep of every world, and for observations.

One thread per world runs the whole substep: forward kinematics and the recursive Newton-Euler bias
forces of every finger chain, relaxed penalty contact of every finger sample point against the object,
the implicit (damping/PD) joint-space solve per finger, and the object's update. Loops over fingers,
links and points have compile-time trip counts (the kernels are built per scene) and are unrolled, which
is what keeps warp's adjoint exact (a non-unrolled loop that carries state is silently differentiated
wrong). Everything is generic in the float type so gradient checks can run in float64.
"""

# no `from __future__ import annotations`: warp reads the closure-typed annotations at definition time

import functools
import os

import warp as wp

from .model import HINGE, OBJECT_HINGE, SHAPE_CYLINDER, SHAPE_SDF, SHAPE_SPHERE

__all__ = ["build_kernels"]

# clang optimisation level for the CPU build: -O2 runs 2.5x faster than -O1 at the same compile time
# (~85 s for the claw substep kernel with its adjoint, 2 cores); -O0 compiles in 14 s but runs 18x slower.
# Override with DEXMOTS_WARP_OPT=0..3 (e.g. 0 while iterating on kernel code).
OPT_LEVEL = int(os.environ.get("DEXMOTS_WARP_OPT", "2"))
FAST_MATH = os.environ.get("DEXMOTS_WARP_FAST_MATH", "0") == "1"
LSE_CUTOFF = 12.0  # smooth-max terms this many smoothing lengths below the max are dropped
CONTACT_CUTOFF = 12.0  # skip a sample point when its penetration is below -CONTACT_CUTOFF / sharpness
LIMIT_WIDTH = 0.02  # rad (or m): joint-limit springs stiffen smoothly over this depth
LIMIT_CURVE = 0.5 / LIMIT_WIDTH  # warp folds constant expressions in float32, so precompute them
LIMIT_OFFSET = 0.5 * LIMIT_WIDTH
FRICTION_VELOCITY = 0.05  # rad/s (or m/s), smoothing of joint Coulomb friction


@functools.lru_cache(maxsize=None)
def build_kernels(float_type, num_fingers: int, joints: int, points: int, planes: int, object_kind: int, shape: int,
                  hinges_only: bool = False):
    """Return a namespace with the struct type and kernels specialised for one scene structure.

    ``hinges_only``: every hand joint is revolute, so joint-type branches are resolved at build time
    (fewer instructions forward and, above all, in the generated adjoint)."""
    F, J, P, K = num_fingers, joints, points, planes
    OBJ_HINGE = object_kind == OBJECT_HINGE
    HINGES_ONLY = bool(hinges_only)
    dtype = float_type
    vec3 = wp.types.vector(3, dtype)
    vec4 = wp.types.vector(4, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    vecJ = wp.types.vector(J, dtype)
    matJ = wp.types.matrix((J, J), dtype)
    quat = wp.types.quaternion(dtype)
    matJ3 = wp.types.matrix((J, 3), dtype)
    vec7 = wp.types.vector(7, dtype)  # a finger's saved result: force, torque on the object, normal force
    vecC = wp.types.vector(7 + J, dtype)  # a contact's saved result: force, point, normal force, joint forces
    mat43 = wp.types.matrix((4, 3), dtype)  # Jacobian of (signed distance, normal) w.r.t. the query point

    @wp.struct
    class Model:
        base_pos: wp.array(dtype=vec3)
        base_rot: wp.array(dtype=mat33)
        off_pos: wp.array(dtype=vec3)
        off_rot: wp.array(dtype=mat33)
        axis: wp.array(dtype=vec3)
        jtype: wp.array(dtype=wp.int32)
        mass: wp.array(dtype=dtype)
        com: wp.array(dtype=vec3)
        inertia: wp.array(dtype=mat33)
        armature: wp.array(dtype=dtype)
        damping: wp.array(dtype=dtype)
        friction: wp.array(dtype=dtype)
        lower: wp.array(dtype=dtype)
        upper: wp.array(dtype=dtype)
        limit_ke: wp.array(dtype=dtype)
        effort: wp.array(dtype=dtype)  # PD drive saturation per dof (0: none)
        point_pos: wp.array(dtype=vec3)
        point_radius: wp.array(dtype=dtype)
        tip_pos: wp.array(dtype=vec3)
        obj_base_pos: vec3
        obj_base_rot: mat33
        obj_axis: vec3
        obj_mass: dtype
        obj_com: vec3
        obj_inertia: mat33
        obj_axial_inertia: dtype  # hinge: inertia about the axis (constant, the body turns about it) + armature
        obj_bound: dtype  # radius of a sphere about the object origin that encloses its geometry
        planes: wp.array(dtype=vec4)
        sdf: wp.array3d(dtype=dtype)  # signed distance grid for non-convex meshes
        sdf_origin: vec3
        sdf_cell: dtype
        shape_size: vec3
        gravity: vec3
        # contact: stiffness, damping, sharpness, friction, slip velocity, surface smoothing
        ke: dtype
        kd: dtype
        beta: dtype
        mu: dtype
        v_slip: dtype
        smooth: dtype

    @wp.struct
    class Saved:
        """Per-call results a taped step keeps for the reverse pass (rows: a substep's output rows;
        columns: finger, or sample sphere). Arrays with no rows when the step is not taped."""

        finger: wp.array2d(dtype=vec7)  # finger_step: force, torque on the object, normal force
        contact: wp.array2d(dtype=vecC)  # point_contact: force, point, normal force, joint forces
        sdf: wp.array2d(dtype=vec4)  # object_sdf: distance, normal
        sdf_jac: wp.array2d(dtype=mat43)  # polytope_sdf: d(distance, normal)/d(point), for its adjoint
        law: wp.array2d(dtype=mat43)  # contact_force: n, cp, v_rel and (softplus, its slope, slip norm)

    # Model arrays are constants: reading them through these (empty custom adjoint) instead of indexing
    # lets the compiler drop every adjoint term that would only flow into the model (half the reverse
    # work of a product with a constant matrix), where a plain read keeps them alive for a runtime check.
    @wp.func
    def fixed_vec3(a: wp.array(dtype=vec3), i: int):
        return a[i]

    @wp.func_grad(fixed_vec3)
    def adj_fixed_vec3(a: wp.array(dtype=vec3), i: int, adj_ret: vec3):
        return

    @wp.func
    def fixed_mat33(a: wp.array(dtype=mat33), i: int):
        return a[i]

    @wp.func_grad(fixed_mat33)
    def adj_fixed_mat33(a: wp.array(dtype=mat33), i: int, adj_ret: mat33):
        return

    @wp.func
    def fixed(a: wp.array(dtype=dtype), i: int):
        return a[i]

    @wp.func_grad(fixed)
    def adj_fixed(a: wp.array(dtype=dtype), i: int, adj_ret: dtype):
        return

    @wp.func
    def softplus(x: dtype, beta: dtype):
        bx = beta * x
        return (wp.max(bx, dtype(0.0)) + wp.log(dtype(1.0) + wp.exp(-wp.abs(bx)))) / beta

    @wp.func
    def limit_ramp(x: dtype):
        # C1 penalty ramp: zero inside the limit, quadratic over LIMIT_WIDTH, then linear
        if x <= dtype(0.0):
            return dtype(0.0)
        if x < dtype(LIMIT_WIDTH):
            return x * x * dtype(LIMIT_CURVE)
        return x - dtype(LIMIT_OFFSET)

    @wp.func
    def axis_angle(a: vec3, t: dtype):
        c = wp.cos(t)
        s = wp.sin(t)
        return c * wp.identity(n=3, dtype=dtype) + s * wp.skew(a) + (dtype(1.0) - c) * wp.outer(a, a)

    @wp.func
    def unit_j(j: int):
        e = vecJ()
        e[j] = dtype(1.0)
        return e

    @wp.func
    def jac_col(jt: wp.int32, a: vec3, o: vec3, p: vec3):
        # linear velocity of point p per unit joint velocity
        if wp.static(HINGES_ONLY):
            return wp.cross(a, p - o)
        if jt == HINGE:
            return wp.cross(a, p - o)
        return a

    @wp.func
    def jac_ang(jt: wp.int32, a: vec3):
        if jt == HINGE:
            return a
        return vec3(dtype(0.0), dtype(0.0), dtype(0.0))

    @wp.func
    def grid_sdf(m: Model, p: vec3):
        """Trilinear signed distance and its normalised gradient from the grid; outside the grid the
        distance to the grid box is added (the grid is padded, so this only matters far away)."""
        g = (p - m.sdf_origin) / m.sdf_cell
        hi = vec3(dtype(m.sdf.shape[0] - 1), dtype(m.sdf.shape[1] - 1), dtype(m.sdf.shape[2] - 1))
        gc = vec3(wp.clamp(g[0], dtype(0.0), hi[0]), wp.clamp(g[1], dtype(0.0), hi[1]), wp.clamp(g[2], dtype(0.0), hi[2]))
        i = wp.min(int(gc[0]), m.sdf.shape[0] - 2)
        j = wp.min(int(gc[1]), m.sdf.shape[1] - 2)
        k = wp.min(int(gc[2]), m.sdf.shape[2] - 2)
        fx = gc[0] - dtype(i)
        fy = gc[1] - dtype(j)
        fz = gc[2] - dtype(k)
        c000 = m.sdf[i, j, k]
        c100 = m.sdf[i + 1, j, k]
        c010 = m.sdf[i, j + 1, k]
        c110 = m.sdf[i + 1, j + 1, k]
        c001 = m.sdf[i, j, k + 1]
        c101 = m.sdf[i + 1, j, k + 1]
        c011 = m.sdf[i, j + 1, k + 1]
        c111 = m.sdf[i + 1, j + 1, k + 1]
        one = dtype(1.0)
        c00 = c000 * (one - fx) + c100 * fx
        c10 = c010 * (one - fx) + c110 * fx
        c01 = c001 * (one - fx) + c101 * fx
        c11 = c011 * (one - fx) + c111 * fx
        c0 = c00 * (one - fy) + c10 * fy
        c1 = c01 * (one - fy) + c11 * fy
        d = c0 * (one - fz) + c1 * fz
        gx = ((c100 - c000) * (one - fy) + (c110 - c010) * fy) * (one - fz) + ((c101 - c001) * (one - fy) + (c111 - c011) * fy) * fz
        gy = (c10 - c00) * (one - fz) + (c11 - c01) * fz
        gz = c1 - c0
        n = vec3(gx, gy, gz) + (g - gc)  # outside the grid: point away from it
        return d + m.sdf_cell * wp.length(g - gc), wp.normalize(n)

    @wp.func
    def polytope_max(m: Model, p: vec3):
        hi = dtype(-1e9)
        for k in range(K):
            pl = m.planes[k]
            hi = wp.max(hi, pl[0] * p[0] + pl[1] * p[1] + pl[2] * p[2] - pl[3])
        return hi

    @wp.func
    def face_weight(m: Model, p: vec3, k: int, hi: dtype):
        """exp((g_k - hi) / smooth) of face k, 0 for faces far below the max (weight < e^-LSE_CUTOFF)."""
        pl = m.planes[k]
        gap = pl[0] * p[0] + pl[1] * p[1] + pl[2] * p[2] - pl[3] - hi
        if gap > dtype(-LSE_CUTOFF) * m.smooth:
            return wp.exp(gap / m.smooth)
        return dtype(0.0)

    @wp.func
    def polytope_sdf(m: Model, p: vec3, saved: Saved, row: int, slot: int):
        """Convex polytope: log-sum-exp smooth max over the face planes g_k = n_k . p - d_k: distance
        hi + smooth log(sum_k w_k) and normal u / |u|, u = sum_k w_k n_k, w_k = face_weight.

        A taped step also saves the result's Jacobian for the hand-written adjoint: d = smooth log
        sum_k exp(g_k / smooth) gives dd/dp = u / sum_k w_k; the normal does not change with the common
        factor exp(-hi / smooth), so dn/dp = (I - n n^T) S / (smooth |u|) with S = sum_k w_k n_k n_k^T."""
        keep = saved.sdf_jac.shape[0] > 0
        hi = polytope_max(m, p)
        total = dtype(0.0)
        u = vec3()
        S = mat33()
        for k in range(K):
            w = face_weight(m, p, k, hi)
            nk = vec3(m.planes[k][0], m.planes[k][1], m.planes[k][2])
            total = total + w
            u = u + w * nk
            if keep:
                S = S + w * wp.outer(nk, nk)
        n = wp.normalize(u)
        if keep:
            length = wp.length(u)
            dn = mat33()
            if length > dtype(0.0):
                dn = (wp.identity(n=3, dtype=dtype) - wp.outer(n, n)) * S / (m.smooth * length)
            g = u / total
            saved.sdf_jac[row, slot] = mat43(g[0], g[1], g[2], dn[0, 0], dn[0, 1], dn[0, 2],
                                             dn[1, 0], dn[1, 1], dn[1, 2], dn[2, 0], dn[2, 1], dn[2, 2])
        return vec4(hi + m.smooth * wp.log(total), n[0], n[1], n[2])

    @wp.func_replay(polytope_sdf)
    def replay_polytope_sdf(m: Model, p: vec3, saved: Saved, row: int, slot: int):
        return saved.sdf[row, slot]

    @wp.func_grad(polytope_sdf)
    def adj_polytope_sdf(m: Model, p: vec3, saved: Saved, row: int, slot: int, adj_ret: vec4):
        # the Jacobian saved by the taped forward: no replay of the face loops, no per-face adjoints
        wp.adjoint[p] += wp.transpose(saved.sdf_jac[row, slot]) * adj_ret

    @wp.func
    def object_sdf(m: Model, p: vec3, saved: Saved, row: int, slot: int):
        """Signed distance (smoothed at edges) and outward unit normal (object frame), packed as
        (d, n). ``saved``/``row``/``slot``: where the caller saves the result for the reverse pass."""
        if wp.static(shape == SHAPE_SPHERE):
            d = wp.length(p)
            n = p / wp.max(d, dtype(1e-9))
            return vec4(d - m.shape_size[0], n[0], n[1], n[2])
        if wp.static(shape == SHAPE_CYLINDER):
            rho = wp.sqrt(p[0] * p[0] + p[1] * p[1] + dtype(1e-12))
            s_r = rho - m.shape_size[0]
            s_z = wp.abs(p[2]) - m.shape_size[1]
            hi = wp.max(s_r, s_z)
            w_r = wp.exp((s_r - hi) / m.smooth)
            w_z = wp.exp((s_z - hi) / m.smooth)
            n = wp.normalize(w_r * vec3(p[0] / rho, p[1] / rho, dtype(0.0)) + w_z * vec3(dtype(0.0), dtype(0.0), wp.sign(p[2])))
            return vec4(hi + m.smooth * wp.log(w_r + w_z), n[0], n[1], n[2])
        if wp.static(shape == SHAPE_SDF):
            d, n = grid_sdf(m, p)
            return vec4(d, n[0], n[1], n[2])
        return polytope_sdf(m, p, saved, row, slot)

    # Replays: warp's adjoint of a function first re-runs the function's forward to get its
    # intermediates, and the adjoint of a caller re-runs its callees too, so a function nested d deep
    # ran d + 1 times in the reverse pass. A taped forward saves each call's result; the replays below
    # load it, so every function body runs once more in reverse (in its own adjoint) and no more.
    @wp.func_replay(object_sdf)
    def replay_object_sdf(m: Model, p: vec3, saved: Saved, row: int, slot: int):
        return saved.sdf[row, slot]

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
        return pos, wp.quat_to_matrix(rq), vec3(qd[w, o], qd[w, o + 1], qd[w, o + 2]), vec3(qd[w, o + 3], qd[w, o + 4], qd[w, o + 5])

    @wp.func
    def point_jacobian(jtype: wp.array(dtype=wp.int32), base: int, A: matJ3, O: matJ3, p: vec3):
        """Row j: velocity of point p per unit velocity of joint j (zero rows for joints not yet set)."""
        Jv = matJ3()
        for j in range(J):
            v = jac_col(jtype[base + j], A[j], O[j], p)
            for c in range(3):
                Jv[j, c] = v[c]
        return Jv

    @wp.func
    def angular_jacobian(jtype: wp.array(dtype=wp.int32), base: int, A: matJ3):
        if wp.static(HINGES_ONLY):
            return A  # a hinge turns its link about its axis; A's rows of later joints are still zero
        Jw = matJ3()
        for j in range(J):
            v = jac_ang(jtype[base + j], A[j])
            for c in range(3):
                Jw[j, c] = v[c]
        return Jw

    @wp.func
    def contact_force(m: Model, p: vec3, rad: dtype, sd: vec4, Ro: mat33, xo: vec3, vo: vec3, wo: vec3, base: int,
                      A: matJ3, O: matJ3, qdf: vecJ, saved: Saved, row: int, slot: int):
        """The contact law of one finger sphere (centre p, radius rad) whose signed distance and normal
        (object frame) are ``sd``; packed result as :func:`point_contact`'s."""
        phi = rad - sd[0]
        fc = vec3()
        fn = dtype(0.0)
        cp = p
        gen = vecJ()
        if phi > -dtype(CONTACT_CUTOFF) / m.beta:
            n = Ro * vec3(sd[1], sd[2], sd[3])
            cp = p - n * rad
            Jv = point_jacobian(m.jtype, base, A, O, cp)
            v_rel = wp.transpose(Jv) * qdf - vo - wp.cross(wo, cp - xo)
            vn = wp.dot(v_rel, n)
            sp = softplus(phi, m.beta)
            fn = m.ke * sp * wp.max(dtype(1.0) - m.kd * vn, dtype(0.0))
            vt = v_rel - vn * n
            den = wp.sqrt(wp.dot(vt, vt) + m.v_slip * m.v_slip)
            ft = -m.mu * fn / den * vt
            fc = fn * n + ft
            gen = Jv * fc
            if saved.law.shape[0] > 0:  # what the hand-written adjoint would recompute
                slope = dtype(1.0) / (dtype(1.0) + wp.exp(-m.beta * phi))  # softplus' = sigmoid
                saved.law[row, slot] = mat43(n[0], n[1], n[2], cp[0], cp[1], cp[2], v_rel[0], v_rel[1], v_rel[2],
                                             sp, slope, den)
        res = vecC()
        for c in range(3):
            res[c] = fc[c]
            res[3 + c] = cp[c]
        res[6] = fn
        for j in range(J):
            res[7 + j] = gen[j]
        return res

    @wp.func_replay(contact_force)
    def replay_contact_force(m: Model, p: vec3, rad: dtype, sd: vec4, Ro: mat33, xo: vec3, vo: vec3, wo: vec3,
                             base: int, A: matJ3, O: matJ3, qdf: vecJ, saved: Saved, row: int, slot: int):
        return saved.contact[row, slot]

    @wp.func_grad(contact_force)
    def adj_contact_force(m: Model, p: vec3, rad: dtype, sd: vec4, Ro: mat33, xo: vec3, vo: vec3, wo: vec3,
                          base: int, A: matJ3, O: matJ3, qdf: vecJ, saved: Saved, row: int, slot: int,
                          adj_ret: vecC):
        # Hand-written reverse of contact_force (the generated one re-ran the whole law and then
        # differentiated it op by op): the forward's intermediates (saved), walked back.
        # Model parameters (and the sphere radius) are constants: no adjoint.
        a_fc = vec3(adj_ret[0], adj_ret[1], adj_ret[2])
        a_cp = vec3(adj_ret[3], adj_ret[4], adj_ret[5])
        a_fn = adj_ret[6]
        phi = rad - sd[0]
        if phi > -dtype(CONTACT_CUTOFF) / m.beta:
            n_o = vec3(sd[1], sd[2], sd[3])
            law = saved.law[row, slot]  # saved by the taped forward
            n = vec3(law[0, 0], law[0, 1], law[0, 2])
            cp = vec3(law[1, 0], law[1, 1], law[1, 2])
            v_rel = vec3(law[2, 0], law[2, 1], law[2, 2])
            sp = law[3, 0]
            den = law[3, 2]
            Jv = point_jacobian(m.jtype, base, A, O, cp)
            r = cp - xo
            vn = wp.dot(v_rel, n)
            damp_arg = dtype(1.0) - m.kd * vn
            damp = wp.max(damp_arg, dtype(0.0))
            fn = m.ke * sp * damp
            vt = v_rel - vn * n
            c = -m.mu / den
            fc = fn * n + c * fn * vt
            a_gen = vecJ()
            for j in range(J):
                a_gen[j] = adj_ret[7 + j]
            # gen = Jv fc
            a_fc = a_fc + wp.transpose(Jv) * a_gen
            a_Jv = wp.outer(a_gen, fc)
            # fc = fn n + ft, ft = c(vt) fn vt with c = -mu / sqrt(|vt|^2 + v_slip^2)
            a_fn = a_fn + wp.dot(a_fc, n) + c * wp.dot(vt, a_fc)
            a_n = fn * a_fc
            a_vt = c * fn * a_fc + (m.mu * fn * wp.dot(vt, a_fc) / (den * den * den)) * vt
            # vt = v_rel - vn n
            a_vrel = a_vt
            a_vn = -wp.dot(a_vt, n)
            a_n = a_n - vn * a_vt
            # fn = ke softplus(phi) max(1 - kd vn, 0)
            if damp_arg > dtype(0.0):
                a_vn = a_vn - m.kd * a_fn * m.ke * sp
            a_phi = a_fn * m.ke * damp * law[3, 1]  # softplus' = sigmoid
            # vn = v_rel . n
            a_vrel = a_vrel + a_vn * n
            a_n = a_n + a_vn * v_rel
            # v_rel = Jv^T qdf - vo - wo x r, r = cp - xo
            wp.adjoint[qdf] += Jv * a_vrel
            a_Jv = a_Jv + wp.outer(qdf, a_vrel)
            wp.adjoint[vo] += -a_vrel
            wp.adjoint[wo] += wp.cross(a_vrel, r)
            a_r = wp.cross(wo, a_vrel)
            a_cp = a_cp + a_r
            wp.adjoint[xo] += -a_r
            # Jv row j: A_j x (cp - O_j) for a hinge, A_j for a slider
            a_A = matJ3()
            a_O = matJ3()
            for j in range(J):
                a_row = vec3(a_Jv[j, 0], a_Jv[j, 1], a_Jv[j, 2])
                axis = vec3(A[j, 0], A[j, 1], A[j, 2])
                is_hinge = True
                if wp.static(not HINGES_ONLY):
                    is_hinge = m.jtype[base + j] == HINGE
                if is_hinge:
                    a_axis = wp.cross(vec3(cp[0] - O[j, 0], cp[1] - O[j, 1], cp[2] - O[j, 2]), a_row)
                    a_point = wp.cross(a_row, axis)
                    a_cp = a_cp + a_point
                    a_O = a_O - wp.outer(unit_j(j), a_point)
                else:
                    a_axis = a_row
                a_A = a_A + wp.outer(unit_j(j), a_axis)
            wp.adjoint[A] += a_A
            wp.adjoint[O] += a_O
            # cp = p - rad n, n = Ro n_o, phi = rad - d
            wp.adjoint[p] += a_cp
            a_n = a_n - rad * a_cp
            wp.adjoint[Ro] += wp.outer(a_n, n_o)
            a_no = wp.transpose(Ro) * a_n
            wp.adjoint[sd] += vec4(-a_phi, a_no[0], a_no[1], a_no[2])
        else:
            wp.adjoint[p] += a_cp  # out of the band: the result is (0, p, 0, 0)

    @wp.func
    def point_contact(m: Model, p: vec3, rad: dtype, Ro: mat33, xo: vec3, vo: vec3, wo: vec3, base: int,
                      A: matJ3, O: matJ3, qdf: vecJ, saved: Saved, row: int, slot: int):
        """Relaxed penalty contact of one finger sphere (centre p, radius rad) with the object.

        Returns, packed in one vector: the force on the finger, the contact point, the normal force
        magnitude and the generalized force on the finger's joints.
        """
        sd = object_sdf(m, wp.transpose(Ro) * (p - xo), saved, row, slot)
        if saved.sdf.shape[0] > 0:
            saved.sdf[row, slot] = sd
        return contact_force(m, p, rad, sd, Ro, xo, vo, wo, base, A, O, qdf, saved, row, slot)

    @wp.func_replay(point_contact)
    def replay_point_contact(m: Model, p: vec3, rad: dtype, Ro: mat33, xo: vec3, vo: vec3, wo: vec3, base: int,
                             A: matJ3, O: matJ3, qdf: vecJ, saved: Saved, row: int, slot: int):
        return saved.contact[row, slot]

    @wp.func
    def sphere_near(m: Model, x: vec3, R: mat33, pi: int, xo: vec3):
        """1 when sample sphere pi of a link at (x, R) is close enough to the object to need the contact
        law, else 0. A branch condition: its empty custom adjoint keeps the reverse pass from
        differentiating the position and distance test of every sphere."""
        rad = m.point_radius[pi]
        if rad > dtype(0.0):
            if wp.length(x + R * m.point_pos[pi] - xo) < m.obj_bound + dtype(CONTACT_CUTOFF) / m.beta + rad:
                return 1
        return 0

    @wp.func_grad(sphere_near)
    def adj_sphere_near(m: Model, x: vec3, R: mat33, pi: int, xo: vec3, adj_ret: int):
        return

    @wp.func
    def finger_step(
        m: Model,
        f: int,
        w: int,
        r: int,
        ro: int,
        q: wp.array2d(dtype=dtype),
        qd: wp.array2d(dtype=dtype),
        tau: wp.array2d(dtype=dtype),
        q_target: wp.array2d(dtype=dtype),
        kp: wp.array2d(dtype=dtype),
        kd: wp.array2d(dtype=dtype),
        dt: dtype,
        Ro: mat33,
        xo: vec3,
        vo: vec3,
        wo: vec3,
        saved: Saved,
    ):
        """Advance finger f of world w (state row r of q/qd, written to row ro) by one substep; returns the
        contact force and torque (about xo) it puts on the object and its summed normal force, packed.
        A function rather than inline code keeps each compiled frame small: warp value-initialises every
        local of a frame on entry. ``saved*`` (rows: ``ro``; empty when untaped): results kept for the
        reverse pass."""
        f_obj = vec3()
        t_obj = vec3()
        cforce = dtype(0.0)
        R = fixed_mat33(m.base_rot, f)
        x = fixed_vec3(m.base_pos, f)
        om = vec3()  # angular velocity of the parent link
        al = vec3()  # its angular acceleration (velocity-product part, qdd = 0)
        acc = -m.gravity  # acceleration of the parent's joint origin (gravity as base acceleration)
        o_prev = x
        O = matJ3()  # joint origins, one row per link
        A = matJ3()  # joint axes (world)
        M = matJ()
        bias = vecJ()
        gen = vecJ()  # contact generalized forces
        qdf = vecJ()
        for k in range(J):
            qdf[k] = qd[r, f * J + k]
        for k in range(J):
            i = f * J + k
            jt = m.jtype[i]
            x = x + R * fixed_vec3(m.off_pos, i)
            R = R * fixed_mat33(m.off_rot, i)
            a = R * fixed_vec3(m.axis, i)
            qk = q[r, i]
            qdk = qd[r, i]
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
            ek = vecJ()
            ek[k] = dtype(1.0)
            O = O + wp.outer(ek, x)
            A = A + wp.outer(ek, a)
            # link inertia: mass matrix and bias-force contributions through the Jacobian
            cw = x + R * fixed_vec3(m.com, i)
            Iw = R * fixed_mat33(m.inertia, i) * wp.transpose(R)
            rc = cw - x
            a_c = acc + wp.cross(al, rc) + wp.cross(om, wp.cross(om, rc))
            Jv = point_jacobian(m.jtype, f * J, A, O, cw)
            Jw = angular_jacobian(m.jtype, f * J, A)
            M = M + fixed(m.mass, i) * Jv * wp.transpose(Jv) + Jw * Iw * wp.transpose(Jw)
            bias = bias + Jv * (fixed(m.mass, i) * a_c) + Jw * (Iw * al + wp.cross(om, Iw * om))
            # contact of this link's sample spheres: a distance test each, the work only near the object
            # (kept one call deep: the adjoint replays every nesting level of functions)
            for sp in range(P):
                pi = i * P + sp
                if sphere_near(m, x, R, pi, xo) != 0:
                    p = x + R * fixed_vec3(m.point_pos, pi)
                    res = point_contact(m, p, m.point_radius[pi], Ro, xo, vo, wo, f * J, A, O, qdf, saved, ro, pi)
                    if saved.contact.shape[0] > 0:
                        saved.contact[ro, pi] = res
                    fc = vec3(res[0], res[1], res[2])
                    cforce = cforce + res[6]
                    f_obj = f_obj - fc
                    t_obj = t_obj - wp.cross(vec3(res[3], res[4], res[5]) - xo, fc)
                    for j in range(J):
                        gen = gen + unit_j(j) * res[7 + j]
        # implicit joint-space solve: (M + dt (D + Kd) + dt^2 Kp) qdd = rhs
        rhs = vecJ()
        diag = matJ()
        for k in range(J):
            i = f * J + k
            qk = q[r, i]
            qdk = qd[r, i]
            # implicit PD drive, saturated smoothly at the motor's effort e: e tanh(drive / e), and its
            # implicit gain scaled by the saturation's slope (a stiff target far inside the object
            # otherwise asks for kp * error, ~10x what the motor can give)
            drive = kp[w, i] * (q_target[w, i] - qk - dt * qdk) - kd[w, i] * qdk
            gain = dt * kd[w, i] + dt * dt * kp[w, i]
            effort = fixed(m.effort, i)
            if effort > dtype(0.0):
                sat = wp.tanh(drive / effort)
                drive = effort * sat
                gain = gain * (dtype(1.0) - sat * sat)
            diag[k, k] = fixed(m.armature, i) + dt * fixed(m.damping, i) + gain
            lim = fixed(m.limit_ke, i) * (
                limit_ramp(fixed(m.lower, i) - qk) - limit_ramp(qk - fixed(m.upper, i))
            )
            fric = fixed(m.friction, i) * wp.tanh(qdk / dtype(FRICTION_VELOCITY))
            rhs[k] = tau[w, i] + drive - fixed(m.damping, i) * qdk - fric + lim + gen[k] - bias[k]
        if wp.static(J == 1):
            qdd = vecJ(rhs[0] / (M[0, 0] + diag[0, 0]))
        else:
            qdd = wp.inverse(M + diag) * rhs
        for k in range(J):
            i = f * J + k
            v_new = qd[r, i] + dt * qdd[k]
            qd[ro, i] = v_new
            q[ro, i] = q[r, i] + dt * v_new
        return vec7(f_obj[0], f_obj[1], f_obj[2], t_obj[0], t_obj[1], t_obj[2], cforce)

    @wp.func_replay(finger_step)
    def replay_finger_step(
        m: Model,
        f: int,
        w: int,
        r: int,
        ro: int,
        q: wp.array2d(dtype=dtype),
        qd: wp.array2d(dtype=dtype),
        tau: wp.array2d(dtype=dtype),
        q_target: wp.array2d(dtype=dtype),
        kp: wp.array2d(dtype=dtype),
        kd: wp.array2d(dtype=dtype),
        dt: dtype,
        Ro: mat33,
        xo: vec3,
        vo: vec3,
        wo: vec3,
        saved: Saved,
    ):
        return saved.finger[ro, f]

    @wp.kernel(module="unique", module_options={"optimization_level": OPT_LEVEL, "fast_math": FAST_MATH})
    def substep(
        m: Model,
        q: wp.array2d(dtype=dtype),
        qd: wp.array2d(dtype=dtype),
        tau: wp.array2d(dtype=dtype),
        q_target: wp.array2d(dtype=dtype),
        kp: wp.array2d(dtype=dtype),
        kd: wp.array2d(dtype=dtype),
        params: wp.array2d(dtype=dtype),
        ext: wp.array2d(dtype=dtype),
        wrench: wp.array2d(dtype=dtype),
        cforce: wp.array(dtype=dtype),
        saved: Saved,
        w0: int,
        in_base: int,
        out_base: int,
        dt: dtype,
        inv_substeps: dtype,
    ):
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
        if wp.static(OBJ_HINGE):
            a = m.obj_base_rot * m.obj_axis
            damp = params[w, 0]
            th_d = qd[r, o]
            torque = wp.dot(a, t_obj + ext_t + wp.cross(Ro * m.obj_com, m.obj_mass * m.gravity))
            torque = torque - damp * th_d - params[w, 1] * wp.tanh(th_d / dtype(FRICTION_VELOCITY))
            v_new = th_d + dt * torque / (m.obj_axial_inertia + dt * damp)
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
            wrench[ro, c] = wrench[r, c] + inv_substeps * f_obj[c]
            wrench[ro, 3 + c] = wrench[r, 3 + c] + inv_substeps * t_obj[c]
        cforce[ro] = cforce[r] + inv_substeps * c_sum

    @wp.func
    def write_pose(out: wp.array2d(dtype=dtype), w: int, b: int, x: vec3, R: mat33):
        rq = wp.quat_from_matrix(R)
        out[w, b * 7 + 0] = x[0]
        out[w, b * 7 + 1] = x[1]
        out[w, b * 7 + 2] = x[2]
        out[w, b * 7 + 3] = rq[3]
        out[w, b * 7 + 4] = rq[0]
        out[w, b * 7 + 5] = rq[1]
        out[w, b * 7 + 6] = rq[2]

    @wp.kernel(module="unique", module_options={"optimization_level": OPT_LEVEL, "fast_math": FAST_MATH})
    def observe(
        m: Model,
        q: wp.array2d(dtype=dtype),
        qd: wp.array2d(dtype=dtype),
        body_pose: wp.array2d(dtype=dtype),
        tips: wp.array2d(dtype=dtype),
        w0: int,
    ):
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

    class Kernels:
        pass

    ns = Kernels()
    ns.Model, ns.Saved, ns.substep, ns.observe = Model, Saved, substep, observe
    ns.object_sdf, ns.contact_force = object_sdf, contact_force  # for probe kernels (tests of the hand adjoints)
    ns.vec3, ns.vec4, ns.mat33, ns.vec7, ns.vecC, ns.vecJ, ns.matJ3, ns.mat43 = vec3, vec4, mat33, vec7, vecC, vecJ, matJ3, mat43
    return ns
