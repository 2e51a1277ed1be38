"""Warp code of the mesh ray caster in :mod:`._mesh_render`: the scene struct and its kernels.

Forward only (the module is built without adjoints). Every drawn body is one :class:`warp.Mesh` in its own
frame (built once; its BVH never changes); a pixel's ray is moved into each body's frame and traced against
its mesh (``wp.mesh_query_ray``), after a cheap test against the body's bounding sphere. The kernels are
shared by every scene: the body count and the table are runtime values, so nothing is specialised per scene.
"""

from __future__ import annotations

import warp as wp

from ._pixel_funcs import (LABEL_SKY, Backdrop, View, checker, pixel_ray, plane_distance, shade, sphere_span,
                           world_pixel, write_backdrop, write_pixel)

__all__ = ["LABEL_SKY", "LABEL_TABLE", "FIRST_BODY_LABEL", "MeshScene", "mesh_background_kernel",
           "place_bodies", "mesh_render_kernel"]

wp.set_module_options({"enable_backward": False})

LABEL_TABLE = 1  # the sky is 0 (the other renderer's)
FIRST_BODY_LABEL = 2  # drawn body k has label FIRST_BODY_LABEL + k


@wp.struct
class MeshScene:
    mesh: wp.array(dtype=wp.uint64)  # [K] one mesh per drawn body, in that body's frame
    body: wp.array(dtype=int)  # [K] its row of body_pose, -1 for a body that never moves (world frame)
    centre: wp.array(dtype=wp.vec3)  # [K] bounding sphere in the body frame (m)
    radius: wp.array(dtype=float)
    face_start: wp.array(dtype=int)  # [K] first row of face_color of body k
    face_color: wp.array(dtype=wp.vec3)  # [sum of faces] linear RGB in [0, 1]
    num_drawn: int
    has_table: int
    table_z: float  # the table's top surface and its extent in x and y (m)
    table_lo: wp.vec2
    table_hi: wp.vec2
    table_color: wp.vec3
    tile: float  # checker tiles on the table (m): its motion and scale are readable in the image


@wp.kernel
def mesh_background_kernel(sc: MeshScene, view: View, bd: Backdrop):
    """The static part, once per camera: each pixel's ray, and the table (or the sky) behind the scene."""
    p = wp.tid()
    rd = pixel_ray(view, bd.rays, p)
    t = float(-1.0)
    if sc.has_table != 0:
        t = plane_distance(view.pos, rd, sc.table_z)
    q = view.pos + t * rd
    on_table = t > 0.0 and q[0] >= sc.table_lo[0] and q[0] <= sc.table_hi[0] and q[1] >= sc.table_lo[1] \
        and q[1] <= sc.table_hi[1]
    write_backdrop(bd, p, rd, view.light, t, on_table,
                   sc.table_color * (1.0 - 0.08 * float(checker(q, sc.tile))), LABEL_TABLE)


@wp.kernel
def place_bodies(sc: MeshScene, pose: wp.array3d(dtype=float), inv_xform: wp.array2d(dtype=wp.transform),
                 bound: wp.array2d(dtype=wp.vec4)):
    """Each drawn body's world-to-body transform and world bounding sphere, thread = (world, drawn body)."""
    w, k = wp.tid()
    b = sc.body[k]
    tf = wp.transform_identity()
    if b >= 0:
        tf = wp.transform(wp.vec3(pose[w, b, 0], pose[w, b, 1], pose[w, b, 2]),
                          wp.quat(pose[w, b, 4], pose[w, b, 5], pose[w, b, 6], pose[w, b, 3]))
    inv_xform[w, k] = wp.transform_inverse(tf)
    c = wp.transform_point(tf, sc.centre[k])
    bound[w, k] = wp.vec4(c[0], c[1], c[2], sc.radius[k])


@wp.kernel
def mesh_render_kernel(sc: MeshScene, view: View, inv_xform: wp.array2d(dtype=wp.transform),
                       bound: wp.array2d(dtype=wp.vec4), bg: Backdrop, p0: int, image: wp.array3d(dtype=wp.uint8),
                       labels: wp.array2d(dtype=wp.uint8), write_labels: int):
    """One pixel of one world: thread p0 + tid = world * (height * width) + pixel."""
    w, p = world_pixel(view, p0 + wp.tid())
    ro = view.pos
    rd = bg.rays[p]
    best = bg.depth[p]
    hit_body = int(-1)
    normal = wp.vec3(0.0, 0.0, 1.0)
    albedo = wp.vec3(0.0)
    for k in range(sc.num_drawn):
        span = sphere_span(ro, rd, bound[w, k])
        bb = span[0]
        h = span[1]
        # the ray meets the bounding sphere in front of the camera, nearer than what is hit so far
        if h >= 0.0 and -bb + wp.sqrt(h) > 0.0 and -bb - wp.sqrt(h) < best:
            inv = inv_xform[w, k]
            q = wp.mesh_query_ray(sc.mesh[k], wp.transform_point(inv, ro), wp.transform_vector(inv, rd), best)
            if q.result and q.t > 0.0 and q.t < best:
                best = q.t
                hit_body = k
                normal = wp.quat_rotate_inv(wp.transform_get_rotation(inv), q.normal)
                albedo = sc.face_color[sc.face_start[k] + q.face]
    color = bg.color[p]
    label = int(0)  # the background's
    if hit_body >= 0:
        if wp.dot(normal, rd) > 0.0:  # the face seen from behind (an open or thin mesh): light its other side
            normal = -normal
        color = shade(albedo, normal, view.light, 0.5)
        label = FIRST_BODY_LABEL + hit_body
    write_pixel(image, labels, w, p, color, write_labels, label, bg.label[p])
