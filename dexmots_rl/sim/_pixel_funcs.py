"""Warp code both ray casters use (:mod:`._render`, :mod:`._mesh_render`): the camera's ``View``, the per-pixel
``Backdrop`` computed once per camera, and the functions of a pixel (its ray, the floor or table behind the scene,
the sky, shading, the bytes written). Forward only.
"""

from __future__ import annotations

import warp as wp

__all__ = ["LABEL_SKY", "View", "Backdrop", "shade", "pixel_ray", "world_pixel", "sphere_span", "plane_distance",
           "checker", "sky_color", "write_backdrop", "write_pixel"]

wp.set_module_options({"enable_backward": False})

LABEL_SKY = 0  # the label of a pixel that sees only the sky (both renderers)


@wp.struct
class View:
    pos: wp.vec3
    forward: wp.vec3
    right: wp.vec3
    up: wp.vec3
    tan_half: float
    light: wp.vec3
    height: int
    width: int


@wp.struct
class Backdrop:
    """What a camera sees behind the scene, per pixel, computed once (the background kernels): the pixel's ray,
    the distance to the floor or table (1e30: the sky), its colour and label."""

    rays: wp.array(dtype=wp.vec3)
    depth: wp.array(dtype=float)
    color: wp.array(dtype=wp.vec3)
    label: wp.array(dtype=wp.uint8)


@wp.func
def shade(albedo: wp.vec3, normal: wp.vec3, light: wp.vec3, two_sided: float) -> wp.vec3:
    """Lambert with ambient; ``two_sided`` > 0 adds a soft back light (hand and object)."""
    lam = wp.max(wp.dot(normal, light), two_sided * wp.abs(wp.dot(normal, light)))
    return albedo * (0.35 + 0.65 * lam)


@wp.func
def pixel_ray(view: View, rays: wp.array(dtype=wp.vec3), p: int) -> wp.vec3:
    """The unit direction of pixel ``p``'s ray (row-major pixels, the pinhole at ``view.pos``), also stored in
    ``rays[p]`` (the pixel kernels read it there)."""
    x = p % view.width
    y = p / view.width
    aspect = float(view.width) / float(view.height)
    sx = (2.0 * (float(x) + 0.5) / float(view.width) - 1.0) * view.tan_half * aspect
    sy = (1.0 - 2.0 * (float(y) + 0.5) / float(view.height)) * view.tan_half
    rd = wp.normalize(view.forward + sx * view.right + sy * view.up)
    rays[p] = rd
    return rd


@wp.func
def world_pixel(view: View, pid: int):
    """(world, pixel) of pixel kernel thread ``pid`` = world * (height * width) + pixel."""
    npix = view.width * view.height
    w = pid / npix
    return w, pid - w * npix


@wp.func
def sphere_span(ro: wp.vec3, rd: wp.vec3, sphere: wp.vec4) -> wp.vec2:
    """(b, h) of the unit ray ``ro + t rd`` against a sphere (centre, radius): it meets the sphere where h >= 0,
    at t = -b -+ sqrt(h)."""
    oc = ro - wp.vec3(sphere[0], sphere[1], sphere[2])
    bb = wp.dot(oc, rd)
    return wp.vec2(bb, bb * bb - (wp.dot(oc, oc) - sphere[3] * sphere[3]))


@wp.func
def plane_distance(ro: wp.vec3, rd: wp.vec3, z: float) -> float:
    """Where the ray ``ro + t rd`` meets the horizontal plane at height ``z`` from above: t, or -1 (never)."""
    t = float(-1.0)
    if rd[2] < -1.0e-6:
        t = (z - ro[2]) / rd[2]
    return t


@wp.func
def checker(q: wp.vec3, tile: float) -> int:
    """1 on every other ``tile`` square of the horizontal plane (where ``q`` stands), else 0."""
    check = (int(wp.floor(q[0] / tile)) + int(wp.floor(q[1] / tile))) % 2
    return check * check


@wp.func
def sky_color(rd: wp.vec3) -> wp.vec3:
    """The sky's gradient along a ray that meets nothing."""
    return wp.lerp(wp.vec3(0.75, 0.8, 0.85), wp.vec3(0.45, 0.6, 0.8), wp.clamp(0.5 + 0.5 * rd[2], 0.0, 1.0))


@wp.func
def write_backdrop(bd: Backdrop, p: int, rd: wp.vec3, light: wp.vec3, t: float, hit: bool, albedo: wp.vec3,
                   hit_label: int):
    """Pixel ``p``'s backdrop: the horizontal surface at distance ``t`` where ``hit`` (lit from above), else the
    sky."""
    if hit:
        bd.depth[p] = t
        bd.color[p] = shade(albedo, wp.vec3(0.0, 0.0, 1.0), light, 0.0)
        bd.label[p] = wp.uint8(hit_label)
    else:
        bd.depth[p] = 1.0e30
        bd.color[p] = sky_color(rd)
        bd.label[p] = wp.uint8(LABEL_SKY)


@wp.func
def write_pixel(image: wp.array3d(dtype=wp.uint8), labels: wp.array2d(dtype=wp.uint8), w: int, p: int,
                color: wp.vec3, write_labels: int, label: int, bg_label: wp.uint8):
    """Pixel ``p`` of world ``w``: its colour as bytes and, with ``write_labels``, its label (0: the background's)."""
    for c in range(3):
        image[w, p, c] = wp.uint8(int(wp.clamp(color[c], 0.0, 1.0) * 255.0 + 0.5))
    if write_labels != 0:
        if label == 0:
            labels[w, p] = bg_label
        else:
            labels[w, p] = wp.uint8(label)
