"""Contact kernels: the knob and cube scenes' finger-sphere contact law and its culling tests, as warp functions.

Built per scene structure by :func:`build_contact` from the fused kernels' spec (sim/_fused_model.py), the object's
distance functions (sim/_object_sdf_kernels.py) and the finger chain's point Jacobian (sim/_chain_kernels.py). The
contact law has a hand-written adjoint, checked against finite differences in tests/test_hand_adjoints.py: a taped
step saves what it needs (``Saved``), so its reverse pass is a few products instead of warp's replay of the law
followed by its op-by-op adjoint.
"""

# no `from __future__ import annotations`: warp reads the closure-typed annotations at definition time

import dataclasses

import warp as wp

from ._chain_kernels import ChainFuncs
from ._constants import CONTACT_CUTOFF, GEOM_CONVEX
from ._fused_model import FusedSpec
from ._kernel_funcs import build_funcs
from ._object_sdf_kernels import ObjectSdfFuncs

__all__ = ["ContactFuncs", "build_contact"]


@dataclasses.dataclass(frozen=True)
class ContactFuncs:
    """The contact functions :func:`build_contact` builds for one scene structure (wp.func each; J: joints per
    finger)."""

    contact_force: object  # one finger sphere's contact law: [7 + J] force (N), torque (N m), |fn| (N), joint forces
    point_contact: object  # the object's distance then contact_force, for one finger sphere
    sphere_near: object  # 1 when a finger sphere may reach the object, else 0 (culling, no adjoint)
    link_near: object  # 1 when some sphere of a finger link may, else 0 (culling, no adjoint)


def build_contact(t: FusedSpec, sdf: ObjectSdfFuncs, chain: ChainFuncs) -> ContactFuncs:
    """The contact functions for the types and scene structure in ``t``, on ``sdf``'s object distance and ``chain``'s
    point Jacobian."""
    dtype, vec3, vec4, mat33, vecJ, matJ3, vecC, mat43 = t.dtype, t.vec3, t.vec4, t.mat33, t.vecJ, t.matJ3, t.vecC, t.mat43
    Model, Saved, J, shape = t.Model, t.Saved, t.J, t.shape
    HINGE_OBJECT = t.hinge_object  # the object turns on a hinge (else it is a free body)
    object_sdf, polytope_max = sdf.object_sdf, sdf.polytope_max
    point_jacobian, point_jacobian_vjp = chain.point_jacobian, chain.point_jacobian_vjp
    funcs = build_funcs(dtype)
    softplus, normal_force, slip_norm = funcs.softplus, funcs.normal_force, funcs.slip_norm
    body_mobility, tangent_mobility = funcs.body_mobility, funcs.tangent_mobility

    @wp.func
    def object_mobility(m: Model, Ro: mat33, r: vec3, n: vec3):
        """The free object's inverse effective mass (1/kg) along n at r from its origin (its com), world frame."""
        return body_mobility(dtype(1.0) / m.obj_mass, m.obj_inv_inertia, Ro, r, n)

    @wp.func
    def object_slip_mobility(m: Model, Ro: mat33, r: vec3, n: vec3):
        """The free object's inverse effective mass (1/kg) over the tangent plane of n at r from its com (world)."""
        return tangent_mobility(dtype(1.0) / m.obj_mass, m.obj_inv_inertia, Ro, r, n)

    @wp.func
    def contact_force(m: Model, p: vec3, rad: dtype, sd: vec4, Ro: mat33, xo: vec3, vo: vec3, wo: vec3, base: int,
                      A: matJ3, O: matJ3, qdf: vecJ, dt: dtype, saved: Saved, row: int, slot: int):
        """The contact law of one finger sphere (centre p, radius rad) whose signed distance and normal
        (object frame) are ``sd``. Returns, packed in one vector: the force on the finger, its torque
        about xo ((contact point - xo) x force: the results of several contacts sum to their total force
        and torque in one vector addition), the normal force magnitude and the generalized force on the
        finger's joints."""
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
            spring = m.ke * sp
            # the normal damping integrated implicitly against the object's mobility there (the finger is far
            # heavier; kernel_funcs.normal_force). A free object only: the hinged knob, far less mobile, makes
            # no energy with the explicit law
            mobility = dtype(0.0)
            if wp.static(not HINGE_OBJECT):
                mobility = object_mobility(m, Ro, cp - xo, n)
            fn = normal_force(spring, vn, m.kd, dt, mobility)
            vt = v_rel - vn * n
            den = slip_norm(vt, m.v_slip)
            if wp.static(not HINGE_OBJECT):
                # the friction's drag implicit against the object's tangential mobility there (slip_norm says why)
                den = den + dt * m.mu * fn * object_slip_mobility(m, Ro, cp - xo, n)
            ft = -m.mu * fn / den * vt
            fc = fn * n + ft
            gen = Jv * fc
            if saved.law.shape[0] > 0:  # what the hand-written adjoint would recompute
                slope = dtype(1.0) / (dtype(1.0) + wp.exp(-m.beta * phi))  # softplus' = sigmoid
                saved.law[row, slot] = mat43(n[0], n[1], n[2], cp[0], cp[1], cp[2], v_rel[0], v_rel[1], v_rel[2],
                                             sp, slope, den)
        tq = wp.cross(cp - xo, fc)
        res = vecC()
        for c in range(3):
            res[c] = fc[c]
            res[3 + c] = tq[c]
        res[6] = fn
        for j in range(J):
            res[7 + j] = gen[j]
        return res

    @wp.func_replay(contact_force)
    def replay_contact_force(m: Model, p: vec3, rad: dtype, sd: vec4, Ro: mat33, xo: vec3, vo: vec3, wo: vec3,
                             base: int, A: matJ3, O: matJ3, qdf: vecJ, dt: dtype, saved: Saved, row: int, slot: int):
        return saved.contact[row, slot]

    @wp.func_grad(contact_force)
    def adj_contact_force(m: Model, p: vec3, rad: dtype, sd: vec4, Ro: mat33, xo: vec3, vo: vec3, wo: vec3,
                          base: int, A: matJ3, O: matJ3, qdf: vecJ, dt: dtype, saved: Saved, row: int, slot: int,
                          adj_ret: vecC):
        # Hand-written reverse of contact_force (the generated one re-ran the whole law and then
        # differentiated it op by op): the forward's intermediates (saved), walked back.
        # Model parameters (and the sphere radius) are constants: no adjoint.
        a_fc = vec3(adj_ret[0], adj_ret[1], adj_ret[2])
        a_tq = vec3(adj_ret[3], adj_ret[4], adj_ret[5])
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
            spring = m.ke * sp
            w = dtype(0.0)
            kd = m.kd
            if wp.static(not HINGE_OBJECT):
                if dt > dtype(0.0):
                    w = object_mobility(m, Ro, r, n)
                    kd = kd / (dtype(1.0) + dt * m.kd * spring * w)
            damp_arg = dtype(1.0) - kd * vn
            damp = wp.max(damp_arg, dtype(0.0))
            fn = spring * damp
            vt = v_rel - vn * n
            c = -m.mu / den
            fc = fn * n + c * fn * vt
            # tq = r x fc
            a_fc = a_fc + wp.cross(a_tq, r)
            a_cp = wp.cross(fc, a_tq)
            wp.adjoint[xo] += -a_cp
            a_gen = vecJ()
            for j in range(J):
                a_gen[j] = adj_ret[7 + j]
            # gen = Jv fc
            a_fc = a_fc + wp.transpose(Jv) * a_gen
            a_Jv = wp.outer(a_gen, fc)
            # fc = fn n + ft, ft = c fn vt with c = -mu / den
            a_fn = a_fn + wp.dot(a_fc, n) + c * wp.dot(vt, a_fc)
            a_n = fn * a_fc
            # den = slip_norm(vt) + dt mu fn w_t (a free object; w_t its tangential mobility)
            a_den = m.mu * fn * wp.dot(vt, a_fc) / (den * den)
            a_vt = c * fn * a_fc + (a_den / slip_norm(vt, m.v_slip)) * vt
            if wp.static(not HINGE_OBJECT):
                if dt > dtype(0.0):
                    # w_t = (3/m + |rb|^2 tr I^-1 - rb . I^-1 rb - w) / 2, rb = Ro^T r, w = 1/m + u . I^-1 u,
                    # u = Ro^T (r x n): its adjoint into Ro, r (cp, xo) and n
                    a_fn = a_fn + a_den * dt * m.mu * object_slip_mobility(m, Ro, r, n)
                    a_wt = a_den * dt * m.mu * fn
                    I_inv = m.obj_inv_inertia
                    rb = wp.transpose(Ro) * r
                    rn = wp.cross(r, n)
                    ub = wp.transpose(Ro) * rn
                    g_rn = Ro * (I_inv * ub)  # d (u . I^-1 u) / d (r x n), halved
                    inv_trace = I_inv[0, 0] + I_inv[1, 1] + I_inv[2, 2]
                    g_r = Ro * (inv_trace * rb - I_inv * rb)  # d (|rb|^2 tr I^-1 - rb . I^-1 rb) / d r, halved
                    a_r_t = a_wt * (g_r - wp.cross(n, g_rn))
                    a_n = a_n - a_wt * wp.cross(g_rn, r)
                    wp.adjoint[Ro] += a_wt * (wp.outer(r, inv_trace * rb - I_inv * rb) - wp.outer(rn, I_inv * ub))
                    a_cp = a_cp + a_r_t
                    wp.adjoint[xo] += -a_r_t
            # vt = v_rel - vn n
            a_vrel = a_vt
            a_vn = -wp.dot(a_vt, n)
            a_n = a_n - vn * a_vt
            # fn = spring max(1 - kd' vn, 0), spring = ke softplus(phi), kd' = kd / (1 + dt kd spring w):
            # d kd'/d spring = -kd'^2 dt w, d kd'/d w = -kd'^2 dt spring
            a_spring = a_fn * damp
            if damp_arg > dtype(0.0):
                a_vn = a_vn - kd * a_fn * spring
                if dt > dtype(0.0) and w > dtype(0.0):  # the implicit damping (a free object)
                    grow = a_fn * spring * vn * kd * kd * dt  # a_fn x d fn / d(spring w) / (the other factor)
                    a_spring = a_spring + grow * w
                    # w = mobility(u), u = Ro^T (r x n): its adjoint into Ro, r (cp, xo) and n
                    u = wp.transpose(Ro) * wp.cross(r, n)
                    a_u = (grow * spring * dtype(2.0)) * (m.obj_inv_inertia * u)
                    a_rn = Ro * a_u
                    wp.adjoint[Ro] += wp.outer(wp.cross(r, n), a_u)
                    a_r_w = wp.cross(n, a_rn)
                    a_n = a_n + wp.cross(a_rn, r)
                    a_cp = a_cp + a_r_w
                    wp.adjoint[xo] += -a_r_w
            a_phi = a_spring * m.ke * law[3, 1]  # softplus' = sigmoid
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
            a_A, a_O, a_jac_cp = point_jacobian_vjp(m.jtype, base, A, O, cp, a_Jv)
            a_cp = a_cp + a_jac_cp
            wp.adjoint[A] += a_A
            wp.adjoint[O] += a_O
            # cp = p - rad n, n = Ro n_o, phi = rad - d
            wp.adjoint[p] += a_cp
            a_n = a_n - rad * a_cp
            wp.adjoint[Ro] += wp.outer(a_n, n_o)
            a_no = wp.transpose(Ro) * a_n
            wp.adjoint[sd] += vec4(-a_phi, a_no[0], a_no[1], a_no[2])
        # out of the band the result is zero: no adjoint

    @wp.func
    def point_contact(m: Model, p: vec3, rad: dtype, Ro: mat33, xo: vec3, vo: vec3, wo: vec3, base: int,
                      A: matJ3, O: matJ3, qdf: vecJ, dt: dtype, saved: Saved, row: int, slot: int):
        """Relaxed penalty contact of one finger sphere (centre p, radius rad) with the object.

        Returns :func:`contact_force`'s packed result: the force on the finger, its torque about xo, the
        normal force magnitude and the generalized force on the finger's joints.
        """
        sd = object_sdf(m, wp.transpose(Ro) * (p - xo), saved, row, slot)
        if saved.sdf.shape[0] > 0:
            saved.sdf[row, slot] = sd
        return contact_force(m, p, rad, sd, Ro, xo, vo, wo, base, A, O, qdf, dt, saved, row, slot)

    @wp.func_replay(point_contact)
    def replay_point_contact(m: Model, p: vec3, rad: dtype, Ro: mat33, xo: vec3, vo: vec3, wo: vec3, base: int,
                             A: matJ3, O: matJ3, qdf: vecJ, dt: dtype, saved: Saved, row: int, slot: int):
        return saved.contact[row, slot]

    @wp.func(inline=True)  # called per sample sphere: out of line, each call copied the Model struct
    def sphere_near(m: Model, x: vec3, R: mat33, pi: int, xo: vec3, Ro: mat33):
        """1 when sample sphere pi of a link at (x, R) is close enough to the object (at xo, Ro) to need the
        contact law, else 0: inside the object's bounding sphere grown by the sphere radius and the law's
        cutoff band and, for a convex polytope, below every face plane by less than that reach. The smooth
        distance is never below the largest face distance, so a sphere this test skips gets exactly zero
        from contact_force anyway; the test only skips the work. A branch condition: its empty custom adjoint
        keeps the reverse pass from differentiating the position and distance test of every sphere."""
        rad = m.point_radius[pi]
        if rad > dtype(0.0):
            reach = rad + dtype(CONTACT_CUTOFF) / m.beta
            p = x + R * m.point_pos[pi]
            if wp.length(p - xo) < m.obj_bound + reach:
                if wp.static(shape == GEOM_CONVEX):
                    if polytope_max(m, wp.transpose(Ro) * (p - xo)) < reach:
                        return 1
                    return 0
                return 1
        return 0

    @wp.func_grad(sphere_near)
    def adj_sphere_near(m: Model, x: vec3, R: mat33, pi: int, xo: vec3, Ro: mat33, adj_ret: int):
        return

    @wp.func(inline=True)
    def link_near(m: Model, x: vec3, i: int, xo: vec3, Ro: mat33):
        """1 when some sample sphere of link i (origin x) may pass :func:`sphere_near`, else 0: a sphere's
        centre is within ``link_reach - radius`` of the link origin, so a link origin farther than the
        object's bound + the link's reach + the cutoff band has none near; for a convex polytope, neither
        has a link origin above a face plane by more than the link's reach + the band (a face distance
        changes by at most the distance moved). Skips the per-sphere tests of the links far from the object
        (most of them). A branch condition: empty adjoint."""
        reach = m.link_reach[i] + dtype(CONTACT_CUTOFF) / m.beta
        if wp.length(x - xo) < m.obj_bound + reach:
            if wp.static(shape == GEOM_CONVEX):
                if polytope_max(m, wp.transpose(Ro) * (x - xo)) < reach:
                    return 1
                return 0
            return 1
        return 0

    @wp.func_grad(link_near)
    def adj_link_near(m: Model, x: vec3, i: int, xo: vec3, Ro: mat33, adj_ret: int):
        return

    return ContactFuncs(contact_force=contact_force, point_contact=point_contact, sphere_near=sphere_near,
                        link_near=link_near)
