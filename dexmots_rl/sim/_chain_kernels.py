"""Kernel functions for the knob and cube scenes' finger chains: a point's and a link's Jacobians (with the point
Jacobian's adjoint for the hand-written adjoints), and a link's mass-matrix and bias-force contribution with its
hand-written adjoint.

Built per scene structure by :func:`build_chain` from the fused kernels' spec (sim/_fused_model.py).
"""

# no `from __future__ import annotations`: warp reads the closure-typed annotations at definition time

import dataclasses

import warp as wp

from ._fused_model import FusedSpec
from ._kernel_funcs import build_funcs, unit_vector
from ._model import HINGE

__all__ = ["ChainFuncs", "build_chain"]


@dataclasses.dataclass(frozen=True)
class ChainFuncs:
    """The link functions :func:`build_chain` builds for one scene structure (wp.func each; J: joints per finger)."""

    unit_j: object  # [J]: the unit vector of one joint of a finger
    point_jacobian: object  # [J, 3] (m/rad or 1): a point's velocity per unit velocity of each of a finger's joints
    point_jacobian_vjp: object  # point_jacobian's adjoint into its inputs (for the hand-written adjoints)
    angular_jacobian: object  # [J, 3] (1): the angular velocity (rad/s) a finger link gets per unit joint velocity
    mass_block: object  # [J, J] (kg m^2): the mass matrix M out of a finger's summed [M | bias]
    bias_column: object  # [J] (N m): the bias forces out of a finger's summed [M | bias]
    joint_forces: object  # [J] (N m): the joint forces out of a (summed) packed contact result
    link_inertia: object  # [J, J + 1]: a link's [M | bias] contribution (hand-written adjoint for hinges)


def build_chain(t: FusedSpec) -> ChainFuncs:
    """The link functions for the types and scene structure in ``t``."""
    dtype, vec3, mat33, vecJ, matJ, matJ3, matJJ1 = t.dtype, t.vec3, t.mat33, t.vecJ, t.matJ, t.matJ3, t.matJJ1
    vecC = t.vecC
    Model, Saved, J, HINGES_ONLY = t.Model, t.Saved, t.J, t.hinges_only

    funcs = build_funcs(dtype)
    fixed_vec3, fixed_mat33, fixed = funcs.fixed_vec3, funcs.fixed_mat33, funcs.fixed

    unit_j = unit_vector(J, dtype)

    @wp.func
    def jac_col(jt: wp.int32, a: vec3, o: vec3, p: vec3):
        # linear velocity of point p per unit joint velocity
        if wp.static(HINGES_ONLY):
            return wp.cross(a, p - o)
        if jt == HINGE:
            return wp.cross(a, p - o)
        return a

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
    def point_jacobian_vjp(jtype: wp.array(dtype=wp.int32), base: int, A: matJ3, O: matJ3, p: vec3, a_Jv: matJ3):
        """Adjoints of (A, O, p) from the adjoint of point_jacobian(jtype, base, A, O, p), for the
        hand-written adjoints: row j is A_j x (p - O_j) for a hinge, A_j for a slider."""
        a_A = matJ3()
        a_O = matJ3()
        a_p = vec3()
        for j in range(J):
            a_row = vec3(a_Jv[j, 0], a_Jv[j, 1], a_Jv[j, 2])
            is_hinge = True
            if wp.static(not HINGES_ONLY):
                is_hinge = jtype[base + j] == HINGE
            a_axis = a_row
            if is_hinge:
                a_axis = wp.cross(vec3(p[0] - O[j, 0], p[1] - O[j, 1], p[2] - O[j, 2]), a_row)
                a_point = wp.cross(a_row, vec3(A[j, 0], A[j, 1], A[j, 2]))
                a_p = a_p + a_point
                a_O = a_O - wp.outer(unit_j(j), a_point)
            a_A = a_A + wp.outer(unit_j(j), a_axis)
        return a_A, a_O, a_p


    @wp.func
    def jac_ang(jt: wp.int32, a: vec3):
        if jt == HINGE:
            return a
        return vec3(dtype(0.0), dtype(0.0), dtype(0.0))

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
    def mass_block(MB: matJJ1):
        """The mass matrix M of a finger's summed [M | bias]."""
        M = matJ()
        for j in range(J):
            for c in range(J):
                M[j, c] = MB[j, c]
        return M

    @wp.func
    def bias_column(MB: matJJ1):
        """The bias forces of a finger's summed [M | bias]."""
        bias = vecJ()
        for j in range(J):
            bias[j] = MB[j, J]
        return bias

    @wp.func
    def joint_forces(c: vecC):
        """The joint forces of a (summed) contact result."""
        gen = vecJ()
        for j in range(J):
            gen[j] = c[7 + j]
        return gen

    @wp.func(inline=True)  # out of line, each of the J calls per finger copied the Model struct (~10 % of a step)
    def link_inertia(m: Model, i: int, base: int, R: mat33, x: vec3, acc: vec3, al: vec3, om: vec3, A: matJ3,
                     O: matJ3, saved: Saved, row: int):
        """Link i's contribution to its finger's joint-space mass matrix and bias forces, [M | bias]:
        m Jv Jv^T + Jw Iw Jw^T and Jv m a_c + Jw (Iw al + om x Iw om), with Jv the Jacobian of its centre
        of mass cw = x + R c, Iw = R I R^T and a_c the centre's velocity-product acceleration."""
        rc = R * fixed_vec3(m.com, i)
        Iw = R * fixed_mat33(m.inertia, i) * wp.transpose(R)
        a_c = acc + wp.cross(al, rc) + wp.cross(om, wp.cross(om, rc))
        Jv = point_jacobian(m.jtype, base, A, O, x + rc)
        Jw = angular_jacobian(m.jtype, base, A)
        mass = fixed(m.mass, i)
        Mc = mass * Jv * wp.transpose(Jv) + Jw * Iw * wp.transpose(Jw)
        bc = Jv * (mass * a_c) + Jw * (Iw * al + wp.cross(om, Iw * om))
        out = matJJ1()
        for j in range(J):
            out[j, J] = bc[j]
            for c in range(J):
                out[j, c] = Mc[j, c]
        return out

    @wp.func_replay(link_inertia)
    def replay_link_inertia(m: Model, i: int, base: int, R: mat33, x: vec3, acc: vec3, al: vec3, om: vec3,
                            A: matJ3, O: matJ3, saved: Saved, row: int):
        return saved.inertia[row, i]

    if HINGES_ONLY:  # the hand-written adjoint below assumes revolute joints (Jw = A); sliders keep warp's

        @wp.func_grad(link_inertia)
        def adj_link_inertia(m: Model, i: int, base: int, R: mat33, x: vec3, acc: vec3, al: vec3, om: vec3,
                             A: matJ3, O: matJ3, saved: Saved, row: int, adj_ret: matJJ1):
            # forward intermediates (recomputed: cheaper than a replay of warp's generated adjoint)
            c, I, mass = fixed_vec3(m.com, i), fixed_mat33(m.inertia, i), fixed(m.mass, i)
            rc = R * c
            cw = x + rc
            Iw = R * I * wp.transpose(R)
            w = wp.cross(om, rc)
            a_c = acc + wp.cross(al, rc) + wp.cross(om, w)
            Jv = point_jacobian(m.jtype, base, A, O, cw)
            z = Iw * om
            h = Iw * al + wp.cross(om, z)
            a_M = matJ()  # adjoint of the mass-matrix block
            g = vecJ()  # adjoint of the bias block
            for j in range(J):
                g[j] = adj_ret[j, J]
                for k in range(J):
                    a_M[j, k] = adj_ret[j, k]
            G = a_M + wp.transpose(a_M)
            # Mc = m Jv Jv^T + A Iw A^T, bc = Jv m a_c + A h
            a_Jv = mass * (G * Jv) + wp.outer(g, mass * a_c)
            a_A = G * A * Iw + wp.outer(g, h)
            a_ac = mass * (wp.transpose(Jv) * g)
            y = wp.transpose(A) * g  # adjoint of h
            a_Iw = wp.transpose(A) * a_M * A
            # h = Iw al + om x z, z = Iw om
            a_z = wp.cross(y, om)
            a_om = wp.cross(z, y) + Iw * a_z
            a_al = Iw * y
            a_Iw = a_Iw + wp.outer(y, al) + wp.outer(a_z, om)
            # a_c = acc + al x rc + om x w, w = om x rc
            a_w = wp.cross(a_ac, om)
            a_om = a_om + wp.cross(w, a_ac) + wp.cross(rc, a_w)
            a_al = a_al + wp.cross(rc, a_ac)
            a_rc = wp.cross(a_ac, al) + wp.cross(a_w, om)
            a_A_jac, a_O, a_cw = point_jacobian_vjp(m.jtype, base, A, O, cw, a_Jv)
            a_A = a_A + a_A_jac
            # cw = x + rc, rc = R c, Iw = R I R^T
            a_rc = a_rc + a_cw
            wp.adjoint[x] += a_cw
            wp.adjoint[R] += wp.outer(a_rc, c) + (a_Iw + wp.transpose(a_Iw)) * R * I
            wp.adjoint[acc] += a_ac
            wp.adjoint[al] += a_al
            wp.adjoint[om] += a_om
            wp.adjoint[A] += a_A
            wp.adjoint[O] += a_O

    return ChainFuncs(unit_j=unit_j, point_jacobian=point_jacobian, point_jacobian_vjp=point_jacobian_vjp,
                      angular_jacobian=angular_jacobian, mass_block=mass_block, bias_column=bias_column,
                      joint_forces=joint_forces, link_inertia=link_inertia)
