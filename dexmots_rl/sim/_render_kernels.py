"""Warp code of the ray caster in :mod:`._render`: the scene struct, ray-shape intersections, kernels (the camera,
the backdrop and the pixel functions both ray casters use are in :mod:`._pixel_funcs`).

Forward only (the module is built without adjoints). All kernels live in this one warp module, compiled
once (a few seconds, cached on disk) and shared by every scene: the object shape, plane count and
segment count are runtime values, so nothing here is specialised per scene or image size.
"""

from __future__ import annotations

import warp as wp

from ._constants import GEOM_CONVEX, GEOM_CYLINDER, GEOM_SPHERE
from ._pixel_funcs import (LABEL_SKY, Backdrop, View, checker, pixel_ray, plane_distance, shade, sphere_span,
                           world_pixel, write_backdrop, write_pixel)

__all__ = ["LABEL_SKY", "LABEL_FLOOR", "LABEL_HAND", "LABEL_OBJECT", "RenderScene", "place_segments",
           "background_kernel", "render_kernel"]

wp.set_module_options({"enable_backward": False})

LABEL_FLOOR, LABEL_HAND, LABEL_OBJECT = 1, 2, 3  # the sky is LABEL_SKY (0)
SDF_MAX_STEPS = 96  # sphere-tracing steps (a dynamic loop: above max_unroll)
OBJECT_COLOR = wp.constant(wp.vec3(0.25, 0.45, 0.9))
MARKER_COLOR = wp.constant(wp.vec3(0.95, 0.95, 0.95))


@wp.struct
class RenderScene:
    seg_a: wp.array(dtype=wp.vec3)  # capsule end points in the link frame
    seg_b: wp.array(dtype=wp.vec3)
    seg_r: wp.array(dtype=float)
    seg_body: wp.array(dtype=int)
    seg_color: wp.array(dtype=wp.vec3)
    num_segments: int
    object_body: int
    shape: int
    planes: wp.array(dtype=wp.vec4)
    num_planes: int
    size: wp.vec3
    bound: float
    sdf: wp.array3d(dtype=float)
    sdf_origin: wp.vec3
    sdf_cell: float
    floor_z: float
    tile: float


@wp.func
def ray_sphere(ro: wp.vec3, rd: wp.vec3, c: wp.vec3, r: float) -> float:
    oc = ro - c
    b = wp.dot(oc, rd)
    h = b * b - (wp.dot(oc, oc) - r * r)
    if h < 0.0:
        return -1.0
    return -b - wp.sqrt(h)


@wp.func
def ray_capsule(ro: wp.vec3, rd: wp.vec3, a: wp.vec3, b: wp.vec3, r: float) -> float:
    """Nearest positive hit distance of a unit ray with a capsule, -1 when it misses."""
    ba = b - a
    oa = ro - a
    baba = wp.dot(ba, ba)
    if baba < 1.0e-12:
        return ray_sphere(ro, rd, a, r)
    bard = wp.dot(ba, rd)
    baoa = wp.dot(ba, oa)
    qa = baba - bard * bard
    qb = baba * wp.dot(rd, oa) - baoa * bard
    qc = baba * wp.dot(oa, oa) - baoa * baoa - r * r * baba
    h = qb * qb - qa * qc
    if h < 0.0:
        return -1.0
    if qa > 1.0e-9:
        t = (-qb - wp.sqrt(h)) / qa
        y = baoa + t * bard
        if y > 0.0 and y < baba:
            return t
    t0 = ray_sphere(ro, rd, a, r)
    t1 = ray_sphere(ro, rd, b, r)
    if t0 < 0.0 or (t1 > 0.0 and t1 < t0):
        return t1
    return t0


@wp.func
def capsule_normal(p: wp.vec3, a: wp.vec3, b: wp.vec3) -> wp.vec3:
    ba = b - a
    s = wp.clamp(wp.dot(p - a, ba) / wp.max(wp.dot(ba, ba), 1.0e-12), 0.0, 1.0)
    return wp.normalize(p - (a + s * ba))


@wp.func
def sdf_value(sc: RenderScene, p: wp.vec3) -> float:
    """Trilinear signed distance in the object frame; outside the grid, distance to it is added."""
    nx = sc.sdf.shape[0]
    ny = sc.sdf.shape[1]
    nz = sc.sdf.shape[2]
    g = (p - sc.sdf_origin) / sc.sdf_cell
    gc = wp.vec3(wp.clamp(g[0], 0.0, float(nx - 1)), wp.clamp(g[1], 0.0, float(ny - 1)),
                 wp.clamp(g[2], 0.0, float(nz - 1)))
    outside = wp.length(g - gc) * sc.sdf_cell
    i = wp.min(int(gc[0]), nx - 2)
    j = wp.min(int(gc[1]), ny - 2)
    k = wp.min(int(gc[2]), nz - 2)
    fx = gc[0] - float(i)
    fy = gc[1] - float(j)
    fz = gc[2] - float(k)
    c00 = wp.lerp(sc.sdf[i, j, k], sc.sdf[i + 1, j, k], fx)
    c10 = wp.lerp(sc.sdf[i, j + 1, k], sc.sdf[i + 1, j + 1, k], fx)
    c01 = wp.lerp(sc.sdf[i, j, k + 1], sc.sdf[i + 1, j, k + 1], fx)
    c11 = wp.lerp(sc.sdf[i, j + 1, k + 1], sc.sdf[i + 1, j + 1, k + 1], fx)
    return wp.lerp(wp.lerp(c00, c10, fy), wp.lerp(c01, c11, fy), fz) + outside


@wp.func
def hit_sphere(sc: RenderScene, ro: wp.vec3, rd: wp.vec3) -> wp.vec4:
    t = ray_sphere(ro, rd, wp.vec3(0.0), sc.size[0])
    if t <= 0.0:
        return wp.vec4(-1.0, 0.0, 0.0, 0.0)
    n = wp.normalize(ro + t * rd)
    return wp.vec4(t, n[0], n[1], n[2])


@wp.func
def hit_cylinder(sc: RenderScene, ro: wp.vec3, rd: wp.vec3) -> wp.vec4:
    r = sc.size[0]
    hh = sc.size[1]
    best = float(1.0e30)
    n = wp.vec3(0.0)
    qa = rd[0] * rd[0] + rd[1] * rd[1]
    if qa > 1.0e-12:
        qb = ro[0] * rd[0] + ro[1] * rd[1]
        qc = ro[0] * ro[0] + ro[1] * ro[1] - r * r
        d = qb * qb - qa * qc
        if d >= 0.0:
            t = (-qb - wp.sqrt(d)) / qa
            z = ro[2] + t * rd[2]
            if t > 0.0 and wp.abs(z) <= hh:
                best = t
                n = wp.normalize(wp.vec3(ro[0] + t * rd[0], ro[1] + t * rd[1], 0.0))
    if wp.abs(rd[2]) > 1.0e-12:
        for s in range(2):
            zc = hh * (2.0 * float(s) - 1.0)
            t = (zc - ro[2]) / rd[2]
            p = ro + t * rd
            if t > 0.0 and t < best and p[0] * p[0] + p[1] * p[1] <= r * r:
                best = t
                n = wp.vec3(0.0, 0.0, 2.0 * float(s) - 1.0)
    if best > 1.0e29:
        return wp.vec4(-1.0, 0.0, 0.0, 0.0)
    return wp.vec4(best, n[0], n[1], n[2])


@wp.func
def hit_convex(sc: RenderScene, ro: wp.vec3, rd: wp.vec3) -> wp.vec4:
    """Slab clipping against the half-spaces ``n.p <= d``."""
    t0 = float(-1.0e30)
    t1 = float(1.0e30)
    n = wp.vec3(0.0)
    for k in range(sc.num_planes):
        pl = sc.planes[k]
        pn = wp.vec3(pl[0], pl[1], pl[2])
        denom = wp.dot(pn, rd)
        dist = pl[3] - wp.dot(pn, ro)
        if wp.abs(denom) < 1.0e-12:
            if dist < 0.0:
                return wp.vec4(-1.0, 0.0, 0.0, 0.0)
        else:
            t = dist / denom
            if denom < 0.0:
                if t > t0:
                    t0 = t
                    n = pn
            else:
                t1 = wp.min(t1, t)
    if t0 > t1 or t0 <= 0.0:
        return wp.vec4(-1.0, 0.0, 0.0, 0.0)
    return wp.vec4(t0, n[0], n[1], n[2])


@wp.func
def hit_sdf(sc: RenderScene, ro: wp.vec3, rd: wp.vec3, t_in: float, t_out: float) -> wp.vec4:
    """Sphere tracing of the signed-distance grid between ``t_in`` and ``t_out``."""
    t = float(t_in)
    eps = 0.05 * sc.sdf_cell
    for _i in range(SDF_MAX_STEPS):
        d = sdf_value(sc, ro + t * rd)
        if d < eps:
            p = ro + t * rd
            e = 0.5 * sc.sdf_cell
            gx = sdf_value(sc, p + wp.vec3(e, 0.0, 0.0)) - sdf_value(sc, p - wp.vec3(e, 0.0, 0.0))
            gy = sdf_value(sc, p + wp.vec3(0.0, e, 0.0)) - sdf_value(sc, p - wp.vec3(0.0, e, 0.0))
            gz = sdf_value(sc, p + wp.vec3(0.0, 0.0, e)) - sdf_value(sc, p - wp.vec3(0.0, 0.0, e))
            n = wp.normalize(wp.vec3(gx, gy, gz))
            return wp.vec4(t, n[0], n[1], n[2])
        t = t + wp.max(d, eps)
        if t > t_out:
            break
    return wp.vec4(-1.0, 0.0, 0.0, 0.0)


@wp.func
def hit_object(sc: RenderScene, ro: wp.vec3, rd: wp.vec3, t_in: float, t_out: float) -> wp.vec4:
    """Ray (object frame) against the object: (distance or -1, local normal). One function per shape,
    so a pixel only pays for the locals of the shape it tests."""
    if sc.shape == GEOM_CONVEX:
        return hit_convex(sc, ro, rd)
    if sc.shape == GEOM_SPHERE:
        return hit_sphere(sc, ro, rd)
    if sc.shape == GEOM_CYLINDER:
        return hit_cylinder(sc, ro, rd)
    return hit_sdf(sc, ro, rd, t_in, t_out)


@wp.func
def body_rot(pose: wp.array3d(dtype=float), w: int, b: int) -> wp.quat:
    return wp.quat(pose[w, b, 4], pose[w, b, 5], pose[w, b, 6], pose[w, b, 3])


@wp.func
def body_pos(pose: wp.array3d(dtype=float), w: int, b: int) -> wp.vec3:
    return wp.vec3(pose[w, b, 0], pose[w, b, 1], pose[w, b, 2])


@wp.kernel
def place_segments(sc: RenderScene, pose: wp.array3d(dtype=float), seg_a: wp.array2d(dtype=wp.vec3),
                   seg_b: wp.array2d(dtype=wp.vec3), seg_bound: wp.array2d(dtype=wp.vec4)):
    """World-frame capsule end points and bounding spheres, thread = (world, segment)."""
    w, s = wp.tid()
    b = sc.seg_body[s]
    rq = body_rot(pose, w, b)
    xb = body_pos(pose, w, b)
    a = xb + wp.quat_rotate(rq, sc.seg_a[s])
    c = xb + wp.quat_rotate(rq, sc.seg_b[s])
    mid = 0.5 * (a + c)
    seg_a[w, s] = a
    seg_b[w, s] = c
    seg_bound[w, s] = wp.vec4(mid[0], mid[1], mid[2], 0.5 * wp.length(c - a) + sc.seg_r[s])


@wp.kernel
def background_kernel(sc: RenderScene, view: View, bd: Backdrop):
    """The static part, once per camera: each pixel's ray, and the floor (or sky) behind the scene."""
    p = wp.tid()
    rd = pixel_ray(view, bd.rays, p)
    t = plane_distance(view.pos, rd, sc.floor_z)
    g = 0.55 + 0.07 * float(checker(view.pos + t * rd, sc.tile))
    write_backdrop(bd, p, rd, view.light, t, t > 0.0, wp.vec3(g, g, g), LABEL_FLOOR)


@wp.kernel
def render_kernel(sc: RenderScene, view: View, pose: wp.array3d(dtype=float), seg_a: wp.array2d(dtype=wp.vec3),
                  seg_b: wp.array2d(dtype=wp.vec3), seg_bound: wp.array2d(dtype=wp.vec4),
                  bg: Backdrop, p0: int, image: wp.array3d(dtype=wp.uint8),
                  labels: wp.array2d(dtype=wp.uint8), write_labels: int):
    """One pixel of one world: thread p0 + tid = world * (height * width) + pixel."""
    w, p = world_pixel(view, p0 + wp.tid())
    ro = view.pos
    rd = bg.rays[p]
    best = bg.depth[p]
    label = int(0)
    normal = wp.vec3(0.0, 0.0, 1.0)
    albedo = wp.vec3(0.0)
    # hand: capsules between the links' sample points (cheap reject on their bounding spheres first)
    for s in range(sc.num_segments):
        if sphere_span(ro, rd, seg_bound[w, s])[1] >= 0.0:
            a = seg_a[w, s]
            c = seg_b[w, s]
            t = ray_capsule(ro, rd, a, c, sc.seg_r[s])
            if t > 0.0 and t < best:
                best = t
                label = LABEL_HAND
                normal = capsule_normal(ro + t * rd, a, c)
                albedo = sc.seg_color[s]
    # the object, in its own frame
    ob = sc.object_body
    ox = body_pos(pose, w, ob)
    oc = ro - ox
    bb = wp.dot(oc, rd)
    h = bb * bb - (wp.dot(oc, oc) - sc.bound * sc.bound)
    if h >= 0.0 and -bb + wp.sqrt(h) > 0.0:  # the ray meets the object's bounding sphere
        oq = body_rot(pose, w, ob)
        lro = wp.quat_rotate_inv(oq, oc)
        lrd = wp.quat_rotate_inv(oq, rd)
        hit = hit_object(sc, lro, lrd, wp.max(-bb - wp.sqrt(h), 0.0), -bb + wp.sqrt(h))
        if hit[0] > 0.0 and hit[0] < best:
            label = LABEL_OBJECT
            normal = wp.quat_rotate(oq, wp.vec3(hit[1], hit[2], hit[3]))
            lp = lro + hit[0] * lrd
            albedo = OBJECT_COLOR
            if lp[0] > 0.0 and wp.abs(lp[1]) < 0.2 * sc.bound:
                albedo = MARKER_COLOR
    color = bg.color[p]
    if label != 0:
        color = shade(albedo, normal, view.light, 0.5)
    write_pixel(image, labels, w, p, color, write_labels, label, bg.label[p])
