"""Small warp functions the articulated-object kernels share, generic in the float type.

:func:`build_funcs` returns them for one float type (cached): ``fixed`` / ``fixed_vec3`` / ``fixed_mat33``
(a model array's element, read without an adjoint), ``softplus`` (the contact penalty's smooth ramp),
``normal_force`` / ``slip_norm`` / ``body_mobility`` / ``tangent_mobility`` (the one contact law's normal force with
its implicit damping, its friction's smoothing, and the mobilities the damping and the friction are integrated
against),
``axis_angle`` (a rotation matrix, with a hand-written adjoint), ``limit_ramp`` / ``limit_slope`` (a range stop's
C1 penalty and its slope), ``range_stop`` (a joint's range-stop force and stiffness), ``joint_friction`` (smoothed Coulomb friction), ``joint_drive`` (the motor's implicit PD drive, capped at its
effort), ``write_pose`` (a body's pose as 7 floats),
``box_distance`` (signed distance and outward normal of a point to a box), ``trilinear`` (a grid cell's
interpolant and its gradient) and ``grid_distance`` (signed distance and normal from a mesh's grid,
sim/_mesh_sdf.py).
"""

# no `from __future__ import annotations`: warp reads the closure-typed annotations at definition time

import dataclasses
import functools

import warp as wp

from ._constants import FRICTION_VELOCITY

__all__ = ["KernelFuncs", "build_funcs", "unit_vector", "constant_read_2d"]


@dataclasses.dataclass(frozen=True)
class KernelFuncs:
    """The functions :func:`build_funcs` builds for one float type (wp.func each; the module docstring says what
    each does)."""

    fixed: object
    fixed_vec3: object
    fixed_mat33: object
    softplus: object
    normal_force: object
    slip_norm: object
    body_mobility: object
    tangent_mobility: object
    surface_contact: object
    axis_angle: object
    limit_ramp: object
    limit_slope: object
    range_stop: object
    joint_friction: object
    joint_drive: object
    write_pose: object
    box_distance: object
    trilinear: object
    grid_distance: object


@functools.lru_cache(maxsize=None)
def unit_vector(length: int, float_type):
    """``unit(k)``, a wp.func: the k-th unit vector of ``length`` elements of ``float_type``. Differentiable code
    builds a vector element by element as a sum of these (an element assigned in place has no adjoint)."""
    dtype = float_type
    vecn = wp.types.vector(int(length), dtype)

    @wp.func
    def unit(k: int):
        e = vecn()
        e[k] = dtype(1.0)
        return e

    return unit


@functools.lru_cache(maxsize=None)
def constant_read_2d(value_type):
    """``read(a, w, i)``: element ``[w, i]`` of a 2-D array of ``value_type``, which the reverse pass treats as a
    constant (an empty adjoint, as ``fixed`` does for model arrays): what a hand-written adjoint reads from the
    forward (a saved solve) or is given (the outputs' adjoints)."""

    @wp.func
    def read(a: wp.array2d(dtype=value_type), w: int, i: int):
        return a[w, i]

    @wp.func_grad(read)
    def adj_read(a: wp.array2d(dtype=value_type), w: int, i: int, adj_ret: value_type):
        return

    return read


@functools.lru_cache(maxsize=None)
def build_funcs(float_type) -> KernelFuncs:
    dtype = float_type
    vec3 = wp.types.vector(3, dtype)
    vec4 = wp.types.vector(4, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)

    # Model arrays are constants: reading them through fixed* (empty custom adjoint) instead of indexing lets the
    # compiler drop every adjoint term that would only flow into the model (half the reverse work of a product
    # with a constant matrix), where a plain read keeps them alive for a runtime check.
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
        """log(1 + exp(beta x)) / beta, computed without overflow."""
        bx = beta * x
        return (wp.max(bx, dtype(0.0)) + wp.log(dtype(1.0) + wp.exp(-wp.abs(bx)))) / beta

    @wp.func
    def normal_force(spring: dtype, vn: dtype, kd: dtype, dt: dtype, mobility: dtype):
        """The contact law's normal force (N): the penalty ``spring`` (ke softplus(penetration)) with Hunt-Crossley
        damping, ``spring max(1 - kd' vn, 0)`` at normal velocity ``vn`` (m/s, positive separating). Against a
        body of ``mobility`` w (1/kg: its inverse effective mass along the normal at the contact point) the
        damping kd x spring is integrated implicitly, kd' = kd / (1 + dt kd spring w), so one substep never
        reverses the normal velocity: explicit, it reverses and grows it once dt kd spring w passes 2 (a light
        body pressed hard), and contact makes energy. w = 0: a body that does not move, or one whose solve takes
        the damping into its matrix (the table's and the palm's, object_kernels / palm_object_kernels)."""
        damping = kd
        if dt * mobility > dtype(0.0):
            damping = kd / (dtype(1.0) + dt * kd * spring * mobility)
        return spring * wp.max(dtype(1.0) - damping * vn, dtype(0.0))

    @wp.func
    def slip_norm(vt: vec3, v_slip: dtype):
        """sqrt(|vt|^2 + v_slip^2): the contact law's friction is -mu fn vt / slip_norm (Coulomb, smoothed).

        Near sticking that is a viscous drag of mu fn / v_slip (N s/m). Against a body of tangential ``mobility``
        w the law adds dt mu fn w to this norm (the drag c becomes c / (1 + dt c w): implicit, exactly so for
        one contact), as :func:`normal_force` does for the normal damping: explicit, a light body squeezed hard
        (a cube's corner under a fingertip, dt c w ~ 6) has its slip reversed and grown every substep."""
        return wp.sqrt(wp.dot(vt, vt) + v_slip * v_slip)

    @wp.func
    def body_mobility(inv_mass: dtype, inv_inertia: mat33, R: mat33, r: vec3, n: vec3):
        """A free rigid body's inverse effective mass (1/kg) along the unit n at r from its com (world):
        1/m + (r x n)^T I^-1 (r x n), ``inv_inertia`` I^-1 in the body frame, R body -> world. A joint or a
        heavier body attached can only lower it, so for a part of a tree it bounds the true mobility from
        above (the implicit damping is then on the safe side)."""
        u = wp.transpose(R) * wp.cross(r, n)
        return inv_mass + wp.dot(u, inv_inertia * u)

    @wp.func
    def tangent_mobility(inv_mass: dtype, inv_inertia: mat33, R: mat33, r: vec3, n: vec3):
        """The mean of a free rigid body's inverse effective mass (1/kg) over the plane normal to the unit n, at
        r from its com (world; ``inv_inertia`` in the body frame, R body -> world): (trace - along n) / 2 of the
        point's mobility matrix 1/m I + [r]x^T I^-1 [r]x, what the friction's drag is integrated against."""
        rb = wp.transpose(R) * r
        inv_trace = inv_inertia[0, 0] + inv_inertia[1, 1] + inv_inertia[2, 2]
        trace = dtype(3.0) * inv_mass + wp.dot(rb, rb) * inv_trace - wp.dot(rb, inv_inertia * rb)
        return dtype(0.5) * (trace - body_mobility(inv_mass, inv_inertia, R, r, n))

    @wp.func
    def surface_contact(pen: dtype, n: vec3, vp: vec3, ke: dtype, beta: dtype, kd: dtype, mu: dtype, v_slip: dtype,
                        dt: dtype):
        """The contact law between a body's sample sphere and a rigid surface that does not move (the table, the
        fixed palm), linearly implicit in the body's solve: penetration ``pen`` (m), the surface's outward unit
        normal n, the contact point's velocity vp. Returns the force on the body (its explicit part, with the
        penalty's stiffness kn linearised at the predicted penetration: - dt kn vn) and P, the matrix the solve
        adds at that point: dt x the viscous friction (mu fn / slip_norm on the tangent plane) plus
        dt^2 kn + dt kd spring along n. The body then holds still on the surface like static friction at any
        slip velocity, and a stiff penalty cannot overshoot and pump energy into a bounce."""
        vn = wp.dot(vp, n)
        spring = ke * softplus(pen, beta)
        damp = dtype(1.0) - kd * vn
        kn = ke / (dtype(1.0) + wp.exp(-beta * pen)) * wp.max(damp, dtype(0.0))  # softplus' = sigmoid
        fn = normal_force(spring, vn, kd, dt, dtype(0.0)) - dt * kn * vn
        vt = vp - vn * n
        drag = mu * fn / slip_norm(vt, v_slip)
        gn = dt * dt * kn
        if damp > dtype(0.0):
            gn = gn + dt * spring * kd
        nn = wp.outer(n, n)
        return fn * n - drag * vt, dt * drag * (wp.identity(n=3, dtype=dtype) - nn) + gn * nn

    @wp.func
    def axis_angle(a: vec3, t: dtype):
        """The rotation by angle t about the unit axis a."""
        c = wp.cos(t)
        s = wp.sin(t)
        return c * wp.identity(n=3, dtype=dtype) + s * wp.skew(a) + (dtype(1.0) - c) * wp.outer(a, a)

    @wp.func_grad(axis_angle)
    def adj_axis_angle(a: vec3, t: dtype, adj_ret: mat33):
        # hand-written: warp's generated adjoint differentiates the identity, skew and outer matrices
        # entry by entry; this is R = c I + s [a]x + (1 - c) a a^T contracted with adj_ret directly
        c = wp.cos(t)
        s = wp.sin(t)
        G = adj_ret
        v = vec3(G[2, 1] - G[1, 2], G[0, 2] - G[2, 0], G[1, 0] - G[0, 1])  # <G, [u]x> = v . u
        aGa = wp.dot(a, G * a)
        wp.adjoint[t] += -s * (G[0, 0] + G[1, 1] + G[2, 2]) + c * wp.dot(v, a) + s * aGa
        wp.adjoint[a] += s * v + (dtype(1.0) - c) * ((G + wp.transpose(G)) * a)

    @wp.func
    def limit_ramp(x: dtype, width: dtype):
        """A range stop's penalty depth: zero inside the range (x <= 0), quadratic over ``width``, then linear."""
        if x <= dtype(0.0):
            return dtype(0.0)
        if x < width:
            return x * x * (dtype(0.5) / width)
        return x - dtype(0.5) * width

    @wp.func
    def limit_slope(x: dtype, width: dtype):
        """d limit_ramp / dx."""
        if x <= dtype(0.0):
            return dtype(0.0)
        if x < width:
            return x * (dtype(1.0) / width)
        return dtype(1.0)

    @wp.func
    def range_stop(ke: dtype, below: dtype, above: dtype, width: dtype):
        """A joint's range stops at ``below`` = lower - q and ``above`` = q - upper past them (each <= 0 inside the
        range): the force (N m or N, pushing back into the range) and its stiffness -d force / dq, for an implicit
        update that linearises the stop."""
        force = ke * (limit_ramp(below, width) - limit_ramp(above, width))
        stiffness = ke * (limit_slope(below, width) + limit_slope(above, width))
        return force, stiffness

    @wp.func
    def joint_friction(friction: dtype, speed: dtype):
        """A joint's Coulomb friction (N m or N) at ``speed``, smoothed over FRICTION_VELOCITY (opposes it when
        subtracted)."""
        return friction * wp.tanh(speed / dtype(FRICTION_VELOCITY))

    @wp.func
    def joint_drive(kp: dtype, kd: dtype, target: dtype, q: dtype, qd: dtype, dt: dtype, effort: dtype):
        """The motor's PD drive towards ``target``, implicit in the substep's velocity update, and the gain it adds to
        the joint's diagonal (dt kd + dt^2 kp). With an ``effort`` > 0 the drive saturates smoothly there,
        effort tanh(drive / effort), and its gain is scaled by the saturation's slope: a stiff target far inside the
        object otherwise asks for kp * error, ~10x what the motor can give."""
        drive = kp * (target - q - dt * qd) - kd * qd
        gain = dt * kd + dt * dt * kp
        if effort > dtype(0.0):
            sat = wp.tanh(drive / effort)
            drive = effort * sat
            gain = gain * (dtype(1.0) - sat * sat)
        return drive, gain

    @wp.func
    def write_pose(out: wp.array2d(dtype=dtype), w: int, b: int, x: vec3, R: mat33):
        """Body b's pose into row w of ``out``: position, then the (w, x, y, z) quaternion of R, 7 columns."""
        rq = wp.quat_from_matrix(R)
        out[w, b * 7 + 0] = x[0]
        out[w, b * 7 + 1] = x[1]
        out[w, b * 7 + 2] = x[2]
        out[w, b * 7 + 3] = rq[3]
        out[w, b * 7 + 4] = rq[0]
        out[w, b * 7 + 5] = rq[1]
        out[w, b * 7 + 6] = rq[2]

    @wp.func
    def box_distance(h: vec3, p: vec3):
        """Signed distance (m, negative inside) of point p (box frame) to the box of half sizes h, and its outward
        unit normal (box frame; inside: the nearest face's), packed as (d, n)."""
        qx = wp.abs(p[0]) - h[0]
        qy = wp.abs(p[1]) - h[1]
        qz = wp.abs(p[2]) - h[2]
        out = vec3(wp.max(qx, dtype(0.0)), wp.max(qy, dtype(0.0)), wp.max(qz, dtype(0.0)))
        lo = wp.length(out)
        d = lo
        n = vec3(dtype(0.0), dtype(0.0), dtype(1.0))
        if lo > dtype(1.0e-9):
            n = vec3(out[0] * wp.sign(p[0]), out[1] * wp.sign(p[1]), out[2] * wp.sign(p[2])) / lo
        else:
            d = wp.max(qx, wp.max(qy, qz))
            if qx >= qy and qx >= qz:
                n = vec3(wp.sign(p[0]), dtype(0.0), dtype(0.0))
            elif qy >= qz:
                n = vec3(dtype(0.0), wp.sign(p[1]), dtype(0.0))
            else:
                n = vec3(dtype(0.0), dtype(0.0), wp.sign(p[2]))
        return vec4(d, n[0], n[1], n[2])

    @wp.func
    def trilinear(c000: dtype, c001: dtype, c010: dtype, c011: dtype, c100: dtype, c101: dtype, c110: dtype,
                  c111: dtype, f: vec3):
        """The trilinear interpolant of a cell's corner values c_ijk (i along x) at fractions f in [0, 1]^3, and
        its gradient in cell units, packed as (value, d/dfx, d/dfy, d/dfz)."""
        one = dtype(1.0)
        c00 = c000 * (one - f[0]) + c100 * f[0]
        c01 = c001 * (one - f[0]) + c101 * f[0]
        c10 = c010 * (one - f[0]) + c110 * f[0]
        c11 = c011 * (one - f[0]) + c111 * f[0]
        c0 = c00 * (one - f[1]) + c10 * f[1]
        c1 = c01 * (one - f[1]) + c11 * f[1]
        dx = ((c100 - c000) * (one - f[1]) + (c110 - c010) * f[1]) * (one - f[2]) \
            + ((c101 - c001) * (one - f[1]) + (c111 - c011) * f[1]) * f[2]
        return vec4(c0 * (one - f[2]) + c1 * f[2], dx, (c10 - c00) * (one - f[2]) + (c11 - c01) * f[2], c1 - c0)

    @wp.func
    def grid_distance(values: wp.array(dtype=dtype), grid: wp.vec4i, h: vec3, p: vec3):
        """Signed distance (m, negative inside) and outward unit normal of point p (grid frame: the grid's box
        is centred at the origin with half sizes h) from a signed-distance grid, packed as (d, n). ``grid``:
        (first index in ``values``, points along x, y, z); ``values`` holds the grid x-major, spacing
        2 h_x / (nx - 1). Inside the box: trilinear interpolation, n its normalised gradient. Outside: the value
        at the nearest point of the box plus the distance to it, n pointing from the surface to p (the grid is
        padded beyond a finger sphere's radius, so a touching sphere's centre is inside)."""
        nx = grid[1]
        ny = grid[2]
        nz = grid[3]
        cell = dtype(2.0) * h[0] / dtype(nx - 1)
        gx = (p[0] + h[0]) / cell
        gy = (p[1] + h[1]) / cell
        gz = (p[2] + h[2]) / cell
        cx = wp.clamp(gx, dtype(0.0), dtype(nx - 1))
        cy = wp.clamp(gy, dtype(0.0), dtype(ny - 1))
        cz = wp.clamp(gz, dtype(0.0), dtype(nz - 1))
        i = wp.min(int(cx), nx - 2)
        j = wp.min(int(cy), ny - 2)
        k = wp.min(int(cz), nz - 2)
        fx = cx - dtype(i)
        fy = cy - dtype(j)
        fz = cz - dtype(k)
        first = grid[0] + (i * ny + j) * nz + k
        sx = ny * nz
        c000 = values[first]
        c001 = values[first + 1]
        c010 = values[first + nz]
        c011 = values[first + nz + 1]
        c100 = values[first + sx]
        c101 = values[first + sx + 1]
        c110 = values[first + sx + nz]
        c111 = values[first + sx + nz + 1]
        dg = trilinear(c000, c001, c010, c011, c100, c101, c110, c111, vec3(fx, fy, fz))
        d = dg[0]
        n = wp.normalize(vec3(dg[1], dg[2], dg[3]))
        beyond = vec3(gx - cx, gy - cy, gz - cz) * cell  # p minus the nearest point of the grid's box (m)
        far2 = wp.dot(beyond, beyond)
        if far2 > dtype(0.0):
            d = dg[0] + wp.sqrt(far2)
            n = wp.normalize(n * wp.max(dg[0], dtype(0.0)) + beyond)
        return vec4(d, n[0], n[1], n[2])

    return KernelFuncs(fixed=fixed, fixed_vec3=fixed_vec3, fixed_mat33=fixed_mat33, softplus=softplus,
                       normal_force=normal_force, slip_norm=slip_norm, body_mobility=body_mobility,
                       tangent_mobility=tangent_mobility, surface_contact=surface_contact, axis_angle=axis_angle,
                       limit_ramp=limit_ramp, limit_slope=limit_slope, range_stop=range_stop,
                       joint_friction=joint_friction,
                       joint_drive=joint_drive, write_pose=write_pose, box_distance=box_distance, trilinear=trilinear,
                       grid_distance=grid_distance)
