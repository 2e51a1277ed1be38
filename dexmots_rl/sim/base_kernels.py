"""Contact of the finger spheres with the static base of an operable object (body ``object_base``).

An operable object (a stapler, a spray bottle, scissors) is a static base plus one moving part on a
sprung hinge (the scene's ``object``). The base's boxes (``SceneModel.base_box_*``, world frame) are
collision shapes for every finger sample sphere: a smooth box signed distance (log-sum-exp over the six
face planes, like ``polytope_sdf``: C-infinity, exact on the faces, rounded by ``surface_smoothing`` at
edges and corners) and the same penalty law as the object (``contact_force``, with a static body: zero
velocity). The forces act on the finger's joints only; the base feels nothing (it does not move).

Built per scene structure by :func:`build_base` from the types and functions :func:`kernels.build_kernels`
defines; finger_step calls :func:`link_base_contacts` once per link inside a ``wp.static`` branch, so scenes
without a base compile to the same code as before. The reverse pass is warp's generated adjoint
(checked against finite differences in tests/test_object_base.py), apart from ``contact_force``'s
hand-written one. Saved slots: base contact ``b`` of sample sphere ``pi`` keeps its ``contact_force``
result and law in column ``num_points + pi * B + b`` of ``Saved.contact`` / ``Saved.law`` (the first
``num_points`` columns are the object contacts).
"""

# no `from __future__ import annotations`: warp reads the closure-typed annotations at definition time

import types

import warp as wp

from .contact_kernels import CONTACT_CUTOFF

__all__ = ["build_base"]


def build_base(t) -> types.SimpleNamespace:
    """The base-contact functions for the types, scene constants and functions in ``t`` (attributes: dtype,
    vec3, vec4, mat33, vecJ, matJ3, vecC, Model, Saved, J, P, NB (boxes), NPTS (sample spheres in the
    hand), contact_force, joint_forces, fixed_vec3, fixed_mat33, smooth_box)."""
    dtype, vec3, mat33, vecJ, matJ3, vecC = t.dtype, t.vec3, t.mat33, t.vecJ, t.matJ3, t.vecC
    Model, Saved, J, P, NB, NPTS = t.Model, t.Saved, t.J, t.P, t.NB, t.NPTS
    contact_force, joint_forces, fixed_vec3, fixed_mat33 = t.contact_force, t.joint_forces, t.fixed_vec3, t.fixed_mat33
    smooth_box = t.smooth_box

    @wp.func
    def box_sdf(m: Model, b: int, p: vec3):
        """Smooth signed distance and outward unit normal of base box b at p (box frame), packed (d, n):
        :func:`contact_kernels.smooth_box` with the contact's surface smoothing (edges and corners rounded
        by it; on a face, exact once the other faces are a few smoothing lengths below)."""
        return smooth_box(fixed_vec3(m.box_half, b), p, m.smooth)

    @wp.func(inline=True)
    def in_grown_box(m: Model, b: int, point: vec3, reach: dtype):
        """1 when ``point`` (world frame) lies inside box b grown by ``reach`` on every side, else 0."""
        pl = wp.transpose(m.box_rot[b]) * (point - m.box_pos[b])
        h = m.box_half[b]
        if wp.abs(pl[0]) < h[0] + reach and wp.abs(pl[1]) < h[1] + reach and wp.abs(pl[2]) < h[2] + reach:
            return 1
        return 0

    @wp.func(inline=True)  # per sphere and box: out of line, each call copied the Model struct
    def base_near(m: Model, x: vec3, R: mat33, pi: int, b: int):
        """1 when sample sphere pi of a link at (x, R) may touch box b, else 0: its centre is inside the box
        grown by the sphere radius and the contact law's cutoff band. The smooth distance is never below
        the largest face distance, so a sphere outside gets exactly zero from contact_force anyway; the
        test only skips the work. A branch condition: empty adjoint."""
        rad = m.point_radius[pi]
        if rad > dtype(0.0):
            return in_grown_box(m, b, x + R * m.point_pos[pi], rad + dtype(CONTACT_CUTOFF) / m.beta)
        return 0

    @wp.func_grad(base_near)
    def adj_base_near(m: Model, x: vec3, R: mat33, pi: int, b: int, adj_ret: int):
        return

    @wp.func(inline=True)
    def link_base_near(m: Model, x: vec3, i: int, b: int):
        """1 when some sample sphere of link i (origin x) may pass :func:`base_near` for box b, else 0: a
        sphere's centre is within ``link_reach - radius`` of the link origin along every box axis too, so a
        link origin outside the box grown by the link's reach + the band has none near. A branch
        condition: empty adjoint."""
        return in_grown_box(m, b, x, m.link_reach[i] + dtype(CONTACT_CUTOFF) / m.beta)

    @wp.func_grad(link_base_near)
    def adj_link_base_near(m: Model, x: vec3, i: int, b: int, adj_ret: int):
        return

    @wp.func(inline=True)
    def link_near_base(m: Model, x: vec3, i: int):
        """1 when link i (origin x) passes :func:`link_base_near` for some box, else 0: finger_step calls
        :func:`link_base_contacts` (out of line: the call copies the Model struct) only then."""
        near = int(0)
        for b in range(NB):
            near = near + link_base_near(m, x, i, b)
        return near

    @wp.func_grad(link_near_base)
    def adj_link_near_base(m: Model, x: vec3, i: int, adj_ret: int):
        return

    @wp.func
    def base_contact(m: Model, p: vec3, rad: dtype, b: int, base: int, A: matJ3, O: matJ3, qdf: vecJ,
                     saved: Saved, row: int, slot: int):
        """Penalty contact of a finger sphere (centre p, radius rad, world frame) with the static box b;
        packed result as ``contact_force``'s (force on the finger, its torque about the box centre, normal
        force, joint forces)."""
        Rb = fixed_mat33(m.box_rot, b)
        cb = fixed_vec3(m.box_pos, b)
        sd = box_sdf(m, b, wp.transpose(Rb) * (p - cb))
        # dt 0: explicit damping (the base does not move)
        return contact_force(m, p, rad, sd, Rb, cb, vec3(), vec3(), base, A, O, qdf, dtype(0.0), saved, row, slot)

    @wp.func_replay(base_contact)
    def replay_base_contact(m: Model, p: vec3, rad: dtype, b: int, base: int, A: matJ3, O: matJ3, qdf: vecJ,
                            saved: Saved, row: int, slot: int):
        return saved.contact[row, slot]

    @wp.func
    def link_base_contacts(m: Model, x: vec3, R: mat33, i: int, base: int, A: matJ3, O: matJ3, qdf: vecJ,
                           saved: Saved, row: int):
        """Contact of every sample sphere of link i (frame x, R; finger dofs from ``base``, Jacobian rows
        A, O, joint velocities qdf) with every base box: the summed generalised joint forces and normal
        force. ``saved`` (row ``row``, empty when untaped): each contact's result for the reverse pass."""
        total = vecC()  # the contacts' results summed (a whole-vector sum: fewer unrolled adjoint updates)
        for b in range(NB):
            if link_base_near(m, x, i, b) != 0:  # the link's spheres are tested only near the box
                for sp in range(P):
                    pi = i * P + sp
                    if base_near(m, x, R, pi, b) != 0:
                        p = x + R * fixed_vec3(m.point_pos, pi)
                        slot = NPTS + pi * NB + b
                        res = base_contact(m, p, m.point_radius[pi], b, base, A, O, qdf, saved, row, slot)
                        if saved.contact.shape[0] > 0:
                            saved.contact[row, slot] = res
                        total = total + res
        return joint_forces(total), total[6]

    return types.SimpleNamespace(box_sdf=box_sdf, base_near=base_near, base_contact=base_contact,
                                 link_near_base=link_near_base, link_base_contacts=link_base_contacts)
