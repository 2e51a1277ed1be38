"""Warp kernel of the fingers' contact with an articulated object's bodies (built into sim/_hand_kernels.py's set).

``finger_contact``, a thread per world and finger link on a GPU, per world on a CPU (its links in turn: a thread's
entry zeroes all its locals, the adjoint launch's twice over, which cost more than the work of the 7 links in
10 that touch nothing): the link's frame and its chain's joints (read from the
arrays ``link_frames`` wrote once per substep), then for each of the link's spheres its pose and velocity, its
signed distance to each object body (the nearest of the body's geoms: box, sphere, capsule, cylinder, or a mesh's
signed-distance grid), and a relaxed penalty contact with Coulomb friction (:class:`~dexmots_rl.sim.ContactParams`'
law) per body it touches. The force goes to the finger's joints (J^T f) and, opposite, to the object body (force and
torque about its com) with atomic adds, so contacts of one world sum in any order.
"""

# no `from __future__ import annotations`: warp reads the closure-typed annotations at definition time

import dataclasses

import warp as wp

from ._constants import (CONTACT_CUTOFF, GEOM_BOX, GEOM_CAPSULE, GEOM_CYLINDER, GEOM_NONE, GEOM_SDF,
                         GEOM_SPHERE, SDF_PAD)
from ._kernel_funcs import build_funcs

__all__ = ["FingerContactFuncs", "build_finger_contact"]

GEOM_SKIP_MARGIN = 1.0e-5  # m: a geom is skipped only when its bound lies this much beyond the nearest so far


def build_finger_contact(Model, dtype, joints: int, points: int, bodies: int, geoms: int) -> "FingerContactFuncs":
    """``geom_distance`` (a point's signed distance to a geom) and the ``finger_contact`` kernel, for the hand
    model struct ``Model`` (sim/_hand_kernels.py), chains of ``joints`` hinges with ``points`` spheres per link,
    against an object of ``bodies`` bodies with at most ``geoms`` geoms each."""
    J, P, B, G = int(joints), int(points), int(bodies), int(geoms)
    vec3 = wp.types.vector(3, dtype)
    vec4 = wp.types.vector(4, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    funcs = build_funcs(dtype)
    softplus, box_distance, grid_distance = funcs.softplus, funcs.box_distance, funcs.grid_distance
    fixed, fixed_vec3 = funcs.fixed, funcs.fixed_vec3  # model reads without an adjoint
    normal_force, slip_norm, body_mobility = funcs.normal_force, funcs.slip_norm, funcs.body_mobility

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

    # The contact of one sphere and of one link, each a function whose replay does nothing: warp's adjoint of a
    # loop replays its body's forward before each iteration's adjoint, and of a loop in a loop the inner body
    # again, so in the kernel's adjoint a sphere's forward work ran three times (the kernel's forward section,
    # the link loop's replay, the sphere loop's). They return nothing (their results are atomic adds), so an
    # empty replay leaves the adjoint exact; each function's own adjoint recomputes its forward once.
    @wp.func(inline=True)
    def sphere_contact(m: Model, w: int, v: int, s: int, f: int, k_link: int, x: vec3, R: mat33, vx: vec3,
                       om: vec3, rad: dtype, params: wp.array2d(dtype=dtype), link_x: wp.array2d(dtype=vec3),
                       link_a: wp.array2d(dtype=vec3), body_x: wp.array2d(dtype=vec3),
                       body_R: wp.array2d(dtype=mat33), body_c: wp.array2d(dtype=vec3),
                       body_v: wp.array2d(dtype=vec3), body_w: wp.array2d(dtype=vec3), gen: wp.array2d(dtype=dtype),
                       contact_f: wp.array2d(dtype=vec3), contact_t: wp.array2d(dtype=vec3),
                       normal_sum: wp.array(dtype=dtype), touching: wp.array2d(dtype=wp.int32), dt: dtype):
        """Sphere s (radius rad) of finger f's link k_link (origin x, rotation R, velocity vx, angular velocity
        om): its contact with each object body, into the finger's joint torques and the bodies' wrenches."""
        p = x + R * fixed_vec3(m.point_pos, s)
        vp = vx + wp.cross(om, p - x)  # the sphere centre's velocity
        f_sum = vec3()  # the bodies' force on the sphere
        hit = int(0)
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
                    # the finger's mobility at the sphere along n (1/kg): the chain's hinges with only
                    # their rotor inertia and the damping's implicit share, which bounds it from above
                    # (the links' inertia and the drive only lower it), so the implicit damping below
                    # stays on the safe side (a hinge with neither gives no bound: left out)
                    finger_n = dtype(0.0)
                    for k in range(J):
                        i = f * J + k
                        rotor = fixed(m.armature, i) + dt * fixed(m.damping, i)
                        if k <= k_link and rotor > dtype(0.0):
                            lever = wp.cross(link_a[w, i], p - link_x[w, i])
                            finger_n = finger_n + wp.dot(lever, n) * wp.dot(lever, n) / rotor
                    cp = p - n * rad
                    r = cp - body_c[w, b]
                    v_rel = vp - body_v[w, b] - wp.cross(body_w[w, b], r)
                    vn = wp.dot(v_rel, n)
                    # the one contact law (kernel_funcs.normal_force): its damping implicit against the
                    # mobility of the two sides at the contact, the body's (a moving body's model
                    # mobility times its model mass over its mass parameter) plus the finger's. Against
                    # the body's alone, a finger pressed into a body far heavier than it (the open
                    # hand's fingers sunk in a 3 kg safe) had its velocity reversed and grown every
                    # substep, and the contact made energy. The friction stays explicit: implicit
                    # against these (upper-bound) mobilities it slipped, and the scissors and the jar's
                    # lid no longer followed the fingers.
                    lighter = dtype(1.0)
                    if b >= m.first_moving and m.body_mass[v, b] > dtype(0.0):
                        lighter = m.body_mass[v, b] / params[w, m.mass_col + b - m.first_moving]
                    mobility = finger_n + lighter * body_mobility(m.body_inv_mass[v, b],
                                                                  m.body_inv_inertia[v, b], Rb, r, n)
                    fn = normal_force(m.ke * softplus(pen, m.beta), vn, m.kd, dt, mobility)
                    vt = v_rel - vn * n
                    ft = -params[w, m.mu_col] * fn / slip_norm(vt, m.v_slip) * vt
                    fc = fn * n + ft  # on the finger
                    f_sum = f_sum + fc
                    hit = 1
                    wp.atomic_add(contact_f, w, b, -fc)
                    wp.atomic_add(contact_t, w, b, wp.cross(r, -fc))
                    wp.atomic_add(normal_sum, w, fn)
        if hit != 0:  # J^T f at the sphere centre: joint k's torque a_k . ((p - o_k) x f)
            for k in range(J):
                if k <= k_link:
                    i = f * J + k
                    wp.atomic_add(gen, w, i, wp.dot(link_a[w, i], wp.cross(p - link_x[w, i], f_sum)))

    @wp.func_replay(sphere_contact)
    def replay_sphere_contact(m: Model, w: int, v: int, s: int, f: int, k_link: int, x: vec3, R: mat33, vx: vec3,
                              om: vec3, rad: dtype, params: wp.array2d(dtype=dtype), link_x: wp.array2d(dtype=vec3),
                              link_a: wp.array2d(dtype=vec3), body_x: wp.array2d(dtype=vec3),
                              body_R: wp.array2d(dtype=mat33), body_c: wp.array2d(dtype=vec3),
                              body_v: wp.array2d(dtype=vec3), body_w: wp.array2d(dtype=vec3),
                              gen: wp.array2d(dtype=dtype),
                              contact_f: wp.array2d(dtype=vec3), contact_t: wp.array2d(dtype=vec3),
                              normal_sum: wp.array(dtype=dtype), touching: wp.array2d(dtype=wp.int32), dt: dtype):
        return

    @wp.func(inline=True)
    def link_contact(m: Model, w: int, v: int, link: int, params: wp.array2d(dtype=dtype),
                     hqd: wp.array2d(dtype=dtype), link_x: wp.array2d(dtype=vec3), link_R: wp.array2d(dtype=mat33),
                     link_a: wp.array2d(dtype=vec3), body_x: wp.array2d(dtype=vec3), body_R: wp.array2d(dtype=mat33),
                     body_c: wp.array2d(dtype=vec3), body_v: wp.array2d(dtype=vec3), body_w: wp.array2d(dtype=vec3),
                     gen: wp.array2d(dtype=dtype), contact_f: wp.array2d(dtype=vec3),
                     contact_t: wp.array2d(dtype=vec3), normal_sum: wp.array(dtype=dtype),
                     touching: wp.array2d(dtype=wp.int32), only_touching: int, points_per_link: int, dt: dtype):
        """Each sphere of one finger link's contact (link = f * J + k)."""
        f = link / J
        k_link = link - f * J
        x = link_x[w, link]
        R = link_R[w, link]
        # the link's velocity over its chain's joints (link_frames' origins and axes): its origin's and its
        # angular velocity, so a sphere's is one cross product away
        vx = vec3()
        om = vec3()
        for k in range(J):
            if k <= k_link:
                i = f * J + k
                a = link_a[w, i]
                vx = vx + wp.cross(a, x - link_x[w, i]) * hqd[w, i]
                om = om + a * hqd[w, i]
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
                sphere_contact(m, w, v, s, f, k_link, x, R, vx, om, rad, params, link_x, link_a, body_x, body_R,
                               body_c, body_v, body_w, gen, contact_f, contact_t, normal_sum, touching, dt)

    @wp.func_replay(link_contact)
    def replay_link_contact(m: Model, w: int, v: int, link: int, params: wp.array2d(dtype=dtype),
                            hqd: wp.array2d(dtype=dtype), link_x: wp.array2d(dtype=vec3),
                            link_R: wp.array2d(dtype=mat33), link_a: wp.array2d(dtype=vec3),
                            body_x: wp.array2d(dtype=vec3), body_R: wp.array2d(dtype=mat33),
                            body_c: wp.array2d(dtype=vec3), body_v: wp.array2d(dtype=vec3),
                            body_w: wp.array2d(dtype=vec3),
                            gen: wp.array2d(dtype=dtype), contact_f: wp.array2d(dtype=vec3),
                            contact_t: wp.array2d(dtype=vec3), normal_sum: wp.array(dtype=dtype),
                            touching: wp.array2d(dtype=wp.int32), only_touching: int, points_per_link: int, dt: dtype):
        return

    @wp.kernel(module="unique", enable_backward=True)
    def finger_contact(
        m: Model,
        variant: wp.array(dtype=wp.int32),  # [N] each world's object variant
        params: wp.array2d(dtype=dtype),  # [N, P] the packed parameters (the bodies' masses, the friction)
        hqd: wp.array2d(dtype=dtype),  # [N, F*J] rad/s
        link_x: wp.array2d(dtype=vec3),  # [N, F*J] link origins = joint origins (m, world; link_frames)
        link_R: wp.array2d(dtype=mat33),  # [N, F*J] link rotations (link -> world)
        link_a: wp.array2d(dtype=vec3),  # [N, F*J] joint axes (world)
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
        links_per_thread: int,  # links one thread takes in turn (CPU: all of a world's, so that a thread's entry,
        # which zeroes the adjoint launch's locals, is paid once per world; GPU: 1, a thread per link)
        dt: dtype,  # s: the substep (the law's damping is implicit over it)
    ):
        w, group = wp.tid()  # links group * links_per_thread on, one after another
        v = variant[w]
        for j in range(links_per_thread):
            link = group * links_per_thread + j  # f * J + k
            if only_touching != 0:  # the adjoint launch: a link none of whose spheres touched has a zero adjoint
                touched = int(0)
                for sp in range(P):
                    touched = touched + touching[w, link * P + sp]
                if touched == 0:
                    continue
            link_contact(m, w, v, link, params, hqd, link_x, link_R, link_a, body_x, body_R, body_c, body_v, body_w,
                         gen, contact_f, contact_t, normal_sum, touching, only_touching, points_per_link, dt)

    return FingerContactFuncs(geom_distance=geom_distance, finger_contact=finger_contact)


@dataclasses.dataclass(frozen=True)
class FingerContactFuncs:
    """What :func:`build_finger_contact` builds for one hand and object structure."""

    geom_distance: object  # wp.func (m): a point's signed distance to one geom of a body (probe kernels)
    finger_contact: object  # wp.kernel: every finger sphere's contact force into joint torques and body wrenches
