"""Fixtures bolted to the table (fixed bases): a ROBEL-style valve, a drawer in its cabinet, a door handle.

Valve: base frame under the post, the valve's axis is z. Drawer: base frame under the cabinet's middle,
the drawer pulls out along +x. Door handle: base frame under the door panel's face, the handle sticks out
along +x.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..description import Joint, ObjectAsset, Part
from .. import shapes
from .common import Params, box_geom, capsule_geom, cylinder_geom, grasp_region, param, with_mass

__all__ = ["ValveParams", "valve", "DrawerParams", "drawer", "DoorHandleParams", "door_handle"]

METAL = (0.55, 0.57, 0.6, 1.0)
VALVE_GREEN = (0.2, 0.65, 0.35, 1.0)
WOOD = (0.72, 0.55, 0.35, 1.0)
DRAWER_CREAM = (0.93, 0.88, 0.75, 1.0)


# -------------------------------------------------------------------------------------------------- valve
@dataclasses.dataclass(frozen=True)
class ValveParams(Params):
    spokes: int = param(3, 3, 5, "", "number of spokes", "count")
    spoke_length: float = param(0.062, 0.045, 0.08, "m", "hub axis to a spoke's end cap centre")
    spoke_radius: float = param(0.012, 0.008, 0.018, "m", "spoke radius")
    hub_radius: float = param(0.018, 0.012, 0.025, "m", "hub radius")
    post_height: float = param(0.06, 0.04, 0.09, "m", "height of the valve's underside above the table")
    valve_mass: float = param(0.06, 0.02, 0.12, "kg", "hub and spokes", "mass")
    turn: float = param(1.57, 1.0, 3.14, "rad", "turn (the operated range)", "angle")
    friction: float = param(0.02, 0.005, 0.05, "N m", "Coulomb friction (no spring: the valve stays)", "feel")
    damping: float = param(0.02, 0.005, 0.1, "N m s/rad", "viscous damping", "feel")


def valve(params: ValveParams | None = None, rng=None, name: str = "valve") -> ObjectAsset:
    """A valve in the style of ROBEL's D'Claw valve: a fixed base plate and post, a hub with 3-5 capsule
    spokes turning about z (q > 0: counter-clockwise seen from above) against friction 0.02 N m. ROBEL's
    damping of 2 N m s/rad would take a 0.35 N m finger seconds per quarter turn: 0.02 here."""
    p = ValveParams.for_generator(params, rng, name)
    plate_h, post_r = 0.01, 0.014
    plate = shapes.rounded_box((0.09, 0.09, plate_h), 0.003, (0, 0, plate_h / 2))
    post = shapes.cylinder(post_r, (0, 0, plate_h - 0.001), (0, 0, p.post_height + 0.001))
    base_mesh = shapes.to_trimesh(shapes.union([plate, post]))

    z = p.spoke_radius  # spokes' axis above the valve frame (at the post's top)
    hub_h = 2.0 * p.spoke_radius + 0.004
    angles = np.linspace(0.0, 2 * math.pi, p.spokes, endpoint=False)
    ends = [(p.spoke_length * math.cos(a), p.spoke_length * math.sin(a), z) for a in angles]
    hub = shapes.cylinder(p.hub_radius, (0, 0, 0), (0, 0, hub_h))
    spokes = [shapes.capsule(p.spoke_radius, (0, 0, z), end) for end in ends]
    valve_mesh = shapes.to_trimesh(shapes.union([hub, *spokes]))

    base_geoms = with_mass([box_geom("plate", (0.09, 0.09, plate_h), (0, 0, plate_h / 2), METAL),
                            capsule_geom("post", post_r, (0, 0, plate_h + post_r),
                                         (0, 0, p.post_height - post_r), METAL)], 0.5)
    # the spokes' capsules overlap at the axis and cover the hub: no separate hub geom
    valve_geoms = with_mass([capsule_geom(f"spoke{i}", p.spoke_radius, (0, 0, z), end, VALVE_GREEN)
                             for i, end in enumerate(ends)], p.valve_mass)
    joint = Joint("valve", "hinge", (0.0, 0.0, 1.0), (0.0, p.turn), damping=p.damping, friction=p.friction)
    # index and middle pinch the spoke along +x from either side; the thumb rests on the next spoke's top
    r, at = p.spoke_radius, 0.6 * p.spoke_length
    next_spoke = (at * math.cos(angles[1]), at * math.sin(angles[1]), z + r)
    regions = (grasp_region("index", "valve", (at, r, z), (0, 1, 0), (0.006, 0.0, 0.002)),
               grasp_region("middle", "valve", (at, -r, z), (0, -1, 0), (0.006, 0.0, 0.002)),
               grasp_region("thumb", "valve", next_spoke, (0, 0, 1), (0.002, 0.002, 0.0)))
    return ObjectAsset(
        name=name, object_class="valve", base="fixed", operated_joint="valve",
        parts=(Part("base", base_geoms, visual="base"),
               Part("valve", valve_geoms, parent="base", joint=joint, pos=(0.0, 0.0, p.post_height),
                    visual="valve")),
        grasp=(0.0, 0.0, float(p.post_height + z)), grasp_regions=regions, params=p.as_dict(),
        meshes={"base": base_mesh, "valve": valve_mesh},
        description=f"{p.spokes}-spoke valve; turn it counter-clockwise")


# ------------------------------------------------------------------------------------------------- drawer
@dataclasses.dataclass(frozen=True)
class DrawerParams(Params):
    width: float = param(0.2, 0.14, 0.26, "m", "cabinet width (y)")
    depth: float = param(0.16, 0.12, 0.22, "m", "cabinet depth (x)")
    height: float = param(0.1, 0.07, 0.14, "m", "cabinet height")
    wall: float = param(0.008, 0.005, 0.012, "m", "wall thickness")
    handle_width: float = param(0.08, 0.05, 0.11, "m", "handle span (y)")
    handle_radius: float = param(0.005, 0.004, 0.007, "m", "handle bar radius")
    drawer_mass: float = param(0.15, 0.06, 0.3, "kg", "drawer and handle", "mass")
    travel: float = param(0.08, 0.05, 0.1, "m", "how far it pulls out (the operated range)")
    friction: float = param(0.5, 0.1, 1.5, "N", "runner friction (no spring: it stays open)", "feel")
    damping: float = param(2.0, 0.5, 5.0, "N s/m", "viscous damping", "feel")


def drawer(params: DrawerParams | None = None, rng=None, name: str = "drawer") -> ObjectAsset:
    """A drawer in a small cabinet: the cabinet is fixed; the drawer with a bar handle slides out along +x
    (q > 0) against runner friction (0.5 N, a tenth of a fingertip's push). The travel is scaled down to what
    a hand on a fixed mount reaches (real drawers: 0.1-0.4 m)."""
    p = DrawerParams.for_generator(params, rng, name)
    W, D, H, t = p.width, p.depth, p.height, p.wall
    shell = shapes.box((D, W, H), (0, 0, H / 2))
    cavity = shapes.box((D, W - 2 * t, H - 2 * t), (t, 0, H / 2))  # open at the front (+x)
    cabinet_mesh = shapes.to_trimesh(shapes.difference(shell, cavity))

    # drawer frame: at the cabinet's front face, on the cavity floor
    gap = 0.002
    inner_w, inner_h = W - 2 * t - 2 * gap, H - 2 * t - 2 * gap
    tray_d, side = D - t - 0.004, 0.005
    tray = shapes.difference(shapes.box((tray_d, inner_w, inner_h), (-tray_d / 2, 0, gap + inner_h / 2)),
                             shapes.box((tray_d - 2 * side, inner_w - 2 * side, inner_h),
                                        (-tray_d / 2, 0, gap + side + inner_h / 2)))
    front_t = 0.012
    front = shapes.rounded_box((front_t, W - 0.004, H - 0.004), 0.002, (front_t / 2, 0, H / 2 - t))
    bar_x, hw, zc = front_t + 0.02, p.handle_width / 2, H / 2 - t
    handle = shapes.polyline_tube(p.handle_radius, [(front_t - 0.002, -hw, zc), (bar_x, -hw + 0.008, zc),
                                                    (bar_x, hw - 0.008, zc), (front_t - 0.002, hw, zc)])
    drawer_mesh = shapes.to_trimesh(shapes.union([tray, front, handle]))

    cabinet_geoms = with_mass([
        box_geom("top", (D, W, t), (0, 0, H - t / 2), WOOD),
        box_geom("left", (D, t, H), (0, W / 2 - t / 2, H / 2), WOOD),
        box_geom("right", (D, t, H), (0, -W / 2 + t / 2, H / 2), WOOD),
        box_geom("back", (t, W, H), (-D / 2 + t / 2, 0, H / 2), WOOD),
    ], 1.0)
    drawer_geoms = with_mass([
        box_geom("front", (front_t, W - 0.004, H - 0.004), (front_t / 2, 0, H / 2 - t), DRAWER_CREAM),
        capsule_geom("handle", p.handle_radius, (bar_x, -hw + 0.008, zc), (bar_x, hw - 0.008, zc), DRAWER_CREAM),
        box_geom("bottom", (tray_d, inner_w, side), (-tray_d / 2, 0, gap + side / 2), DRAWER_CREAM),
        box_geom("back", (side, inner_w, inner_h), (-tray_d + side / 2, 0, gap + inner_h / 2), DRAWER_CREAM),
    ], p.drawer_mass)
    joint = Joint("drawer", "slide", (1.0, 0.0, 0.0), (0.0, p.travel), damping=p.damping, friction=p.friction)
    # index and middle over the bar, tucked toward the drawer's front (a fingertip is wider than the gap
    # behind the bar); the thumb stays free (reaching the front past the cabinet's top, it would cross it)
    over = np.array([-0.45, 0.0, 0.89]) / np.linalg.norm([-0.45, 0.0, 0.89])
    y = min(0.013, hw - 0.01)
    regions = (grasp_region("index", "drawer", (bar_x + p.handle_radius * over[0], y, zc + p.handle_radius * over[2]),
                            over, (0.0, 0.002, 0.0)),
               grasp_region("middle", "drawer", (bar_x + p.handle_radius * over[0], -y,
                                                 zc + p.handle_radius * over[2]), over, (0.0, 0.002, 0.0)))
    return ObjectAsset(
        name=name, object_class="drawer", base="fixed", operated_joint="drawer",
        parts=(Part("cabinet", cabinet_geoms, visual="cabinet"),
               Part("drawer", drawer_geoms, parent="cabinet", joint=joint, pos=(D / 2, 0.0, t),
                    visual="drawer")),
        grasp=(float(D / 2 + bar_x), 0.0, float(zc + t)), grasp_regions=regions, params=p.as_dict(),
        meshes={"cabinet": cabinet_mesh, "drawer": drawer_mesh},
        description="drawer in a cabinet; pull it out by its handle")


# -------------------------------------------------------------------------------------------- door handle
@dataclasses.dataclass(frozen=True)
class DoorHandleParams(Params):
    door_width: float = param(0.14, 0.1, 0.2, "m", "width of the door panel section (y)")
    door_height: float = param(0.22, 0.16, 0.28, "m", "height of the door panel section")
    handle_height: float = param(0.14, 0.1, 0.2, "m", "height of the spindle above the table")
    lever_length: float = param(0.11, 0.08, 0.13, "m", "spindle to the lever's end (y)")
    lever_radius: float = param(0.008, 0.006, 0.011, "m", "lever bar radius")
    lever_mass: float = param(0.08, 0.03, 0.15, "kg", "lever and neck", "mass")
    turn: float = param(0.75, 0.6, 0.9, "rad", "how far the lever turns down (the operated range)", "angle")
    stiffness: float = param(0.15, 0.08, 0.3, "N m/rad", "return spring", "feel")
    preload: float = param(0.5, 0.3, 0.8, "rad", "spring rest above the level stop", "feel")
    damping: float = param(0.005, 0.001, 0.03, "N m s/rad", "viscous damping", "feel")
    friction: float = param(0.005, 0.0, 0.02, "N m", "Coulomb friction", "feel")


def door_handle(params: DoorHandleParams | None = None, rng=None, name: str = "door_handle") -> ObjectAsset:
    """A lever door handle on a section of door panel (fixed): the lever sticks out along +x from a round
    rosette and runs along +y; q > 0 turns it down about the spindle (axis -x) against a return spring.
    0.15 N m/rad from a 0.5 rad preload holds the level lever against its weight (0.075 N m against about
    0.04 N m) and needs about 0.15 N m net fully down: under 2 N at the lever's end."""
    p = DoorHandleParams.for_generator(params, rng, name)
    door_t, rosette_r, rosette_t = 0.025, 0.026, 0.01
    door = shapes.rounded_box((door_t, p.door_width, p.door_height), 0.002, (-door_t / 2, 0, p.door_height / 2))
    rosette = shapes.cylinder(rosette_r, (-0.001, 0, p.handle_height), (rosette_t, 0, p.handle_height),
                              radius_top=rosette_r - 0.003)
    base_mesh = shapes.to_trimesh(shapes.union([door, rosette]))

    # lever frame: on the spindle at the rosette's face
    neck_l, r = 0.03, p.lever_radius
    neck = shapes.cylinder(0.011, (-0.002, 0, 0), (neck_l, 0, 0), radius_top=0.009)
    bar = shapes.polyline_tube(r, [(neck_l - r, 0, 0), (neck_l, 0.3 * p.lever_length, 0),
                                   (neck_l - 0.004, p.lever_length, -0.006)])
    lever_mesh = shapes.to_trimesh(shapes.union([neck, bar]))

    base_geoms = with_mass([
        box_geom("door", (door_t, p.door_width, p.door_height), (-door_t / 2, 0, p.door_height / 2), WOOD),
        cylinder_geom("rosette", rosette_r, (0, 0, p.handle_height), (rosette_t, 0, p.handle_height), METAL),
    ], 2.0)
    lever_geoms = with_mass([
        capsule_geom("lever", r, (neck_l, 0.02, 0), (neck_l - 0.002, p.lever_length, -0.004), METAL),
        cylinder_geom("neck", 0.011, (0, 0, 0), (neck_l, 0, 0), METAL),
    ], p.lever_mass)
    joint = Joint("lever", "hinge", (-1.0, 0.0, 0.0), (0.0, p.turn), stiffness=p.stiffness, rest=-p.preload,
                  damping=p.damping, friction=p.friction)
    # index and middle on the lever's top, the thumb under it between them; the lever lies 2.5 cm behind the
    # point under the palm, where the thumb reaches under it
    def on_lever(finger, along, below):  # below: under the lever and a little behind it, where the thumb comes from
        normal = np.array([-0.5, 0.0, -0.87] if below else [0.0, 0.0, 1.0])
        normal /= np.linalg.norm(normal)
        centre = (neck_l - 0.002 * along / p.lever_length, along, -0.004 * along / p.lever_length)
        return grasp_region(finger, "lever", np.add(centre, r * normal), normal, (0.0, 0.004, 0.0))

    regions = (on_lever("index", 0.85 * p.lever_length, False), on_lever("middle", 0.5 * p.lever_length, False),
               on_lever("thumb", 0.7 * p.lever_length, True))
    return ObjectAsset(
        name=name, object_class="door_handle", base="fixed", operated_joint="lever",
        parts=(Part("door", base_geoms, visual="door"),
               Part("lever", lever_geoms, parent="door", joint=joint, pos=(rosette_t, 0.0, p.handle_height),
                    visual="lever")),
        grasp=(float(rosette_t + neck_l + 0.025), float(0.6 * p.lever_length), float(p.handle_height)),
        grasp_regions=regions, params=p.as_dict(), meshes={"door": base_mesh, "lever": lever_mesh},
        description="lever door handle; press the lever down")
