"""Small warp functions the articulated-object kernels share, generic in the float type.

:func:`build_funcs` returns them for one float type (cached): ``softplus`` (the contact penalty's smooth ramp),
``axis_angle`` (a rotation matrix), ``limit_ramp`` / ``limit_slope`` (a range stop's C1 penalty and its slope) and
``box_distance`` (signed distance and outward normal of a point to a box).
"""

# no `from __future__ import annotations`: warp reads the closure-typed annotations at definition time

import functools
import types

import warp as wp

__all__ = ["build_funcs"]


@functools.lru_cache(maxsize=None)
def build_funcs(float_type) -> types.SimpleNamespace:
    dtype = float_type
    vec3 = wp.types.vector(3, dtype)
    vec4 = wp.types.vector(4, dtype)

    @wp.func
    def softplus(x: dtype, beta: dtype):
        """log(1 + exp(beta x)) / beta, computed without overflow."""
        bx = beta * x
        return (wp.max(bx, dtype(0.0)) + wp.log(dtype(1.0) + wp.exp(-wp.abs(bx)))) / beta

    @wp.func
    def axis_angle(a: vec3, t: dtype):
        """The rotation by angle t about the unit axis a."""
        c = wp.cos(t)
        s = wp.sin(t)
        return c * wp.identity(n=3, dtype=dtype) + s * wp.skew(a) + (dtype(1.0) - c) * wp.outer(a, a)

    @wp.func
    def limit_ramp(x: dtype, width: dtype):
        """A range stop's penalty depth: zero inside the range (x <= 0), quadratic over ``width``, then linear."""
        if x <= dtype(0.0):
            return dtype(0.0)
        if x < width:
            return x * x / (dtype(2.0) * width)
        return x - dtype(0.5) * width

    @wp.func
    def limit_slope(x: dtype, width: dtype):
        """d limit_ramp / dx."""
        if x <= dtype(0.0):
            return dtype(0.0)
        if x < width:
            return x / width
        return dtype(1.0)

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

    return types.SimpleNamespace(softplus=softplus, axis_angle=axis_angle, limit_ramp=limit_ramp,
                                 limit_slope=limit_slope, box_distance=box_distance)
