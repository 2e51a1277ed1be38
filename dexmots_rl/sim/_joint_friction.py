"""The object tree's joint Coulomb friction, solved with the tree's linearly implicit step (sim/_object_kernels.py).

A friction law written as a force of the joint's present speed (f tanh(qd / v), smoothed below a slip speed v)
cannot hold a part still: under a steady load below the friction the part creeps at the speed where the smoothed
law balances the load (a lid loaded at 2/3 of its friction crept 0.3 rad in 10 s and its swing pushed the base),
and made stiff enough to creep less, the explicit law chatters. Here the friction is the force that stops the
joint within the step, capped at the friction: from the joints' velocities u the step would give without it and
the joints' mobility W (the inverse of the solve's joint block after the base's elimination, so the base's
recoil and the joints' damping, springs and stops are in it), joint k's friction is

    f_k = F_k sat((f_k - v_k / (dt W_kk)) / F_k),   v = u + dt W f,

by Gauss-Seidel over the joints (one sweep per joint; exact for one joint). sat is the identity up to
1 - STICTION_BLEND and 1 beyond 1 + STICTION_BLEND, a quadratic between (C1, like the range stops' ramp): a load
below (1 - STICTION_BLEND) F holds the joint exactly still, a larger one slides it with the full friction, and the
derivative is the law's own (warp differentiates the sweeps; held, the step's velocity does not depend on the
load, as for a stuck part it should not).
"""

# no `from __future__ import annotations`: warp reads the closure-typed annotations at definition time

import warp as wp

__all__ = ["STICTION_BLEND", "build_joint_friction"]

STICTION_BLEND = 0.1  # of the friction: the stopping force blends into sliding between (1 -/+ this) x F


def build_joint_friction(dtype, num_joints: int, vecP, matPP, unit_p):
    """``joint_accelerations(A, r, qd, friction, dt)``: the joints' accelerations (a vecP) from their block A of
    the solve (matPP, the base eliminated) and its right-hand side r, with the friction (magnitudes, a vecP) of
    joints moving at qd added; ``unit_p(k)`` is the k-th unit vecP."""
    NP = int(num_joints)
    knee = 1.0 - STICTION_BLEND
    curve = 0.25 / STICTION_BLEND

    @wp.func
    def slide_share(x: dtype):
        """sat(x) for x >= 1 - STICTION_BLEND."""
        if x < dtype(1.0 + STICTION_BLEND):
            return x - (x - dtype(knee)) * (x - dtype(knee)) * dtype(curve)
        return dtype(1.0)

    @wp.func
    def sat(x: dtype):
        """The share of the friction a stopping force of x times it takes: x when held, +-1 when sliding."""
        if x > dtype(knee):
            return slide_share(x)
        if x < -dtype(knee):
            return -slide_share(-x)
        return x

    if NP <= 1:  # warp's inverse starts at 2 x 2

        @wp.func
        def invert(A: matPP):
            return matPP(dtype(1.0) / A[0, 0])

    else:

        @wp.func
        def invert(A: matPP):
            return wp.inverse(A)

    @wp.func
    def friction_force(W: matPP, u: vecP, friction: vecP, dt: dtype):
        """The friction's forces for the mobility W and the frictionless step's joint velocities u."""
        f = vecP()
        for sweep in range(NP):
            for k in range(NP):
                v = u + dt * (W * f)
                fk = dtype(0.0)
                if friction[k] > dtype(0.0):
                    stop = f[k] - v[k] / (dt * W[k, k])
                    fk = friction[k] * sat(stop / friction[k])
                f = f + (fk - f[k]) * unit_p(k)
        return f

    @wp.func
    def joint_accelerations(A: matPP, r: vecP, qd: vecP, friction: vecP, dt: dtype):
        W = invert(A)
        qdd = W * r
        return qdd + W * friction_force(W, qd + dt * qdd, friction, dt)

    return joint_accelerations
