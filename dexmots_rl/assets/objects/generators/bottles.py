"""Round containers that stand free on the table: a trigger spray bottle, a pump dispenser, a jar with a lid.

Base frame: the bottle's axis is z, its bottom at z = 0, the nozzle or spout points along +x.
Springs are scaled to the Allegro hand (fingertips push ~5 N, finger motors 0.35-0.5 N m), not to the real
tool (a real trigger sprayer needs 10-30 N): each operated joint travels its whole range under at most
about two thirds of what one finger can give, and its preload holds the part at rest against gravity.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..description import Joint, ObjectAsset, Part
from .. import shapes
from .common import (Params, box_geom, capsule_geom, cylinder_geom, grasp_region, param, with_mass)

__all__ = ["SprayBottleParams", "spray_bottle", "PumpDispenserParams", "pump_dispenser", "JarParams", "jar"]

BOTTLE_BLUE = (0.55, 0.75, 0.95, 1.0)
PLASTIC_WHITE = (0.92, 0.92, 0.9, 1.0)
TRIGGER_RED = (0.85, 0.2, 0.15, 1.0)
GLASS = (0.75, 0.88, 0.85, 1.0)
LID_GOLD = (0.85, 0.65, 0.2, 1.0)


def _bottle_profile(radius: float, height: float, neck_radius: float, neck_height: float,
                    collar_radius: float, collar_height: float) -> list[tuple[float, float]]:
    """(r, z) outline of a bottle: rounded bottom edge, straight wall, elliptic shoulder, neck, screw collar."""
    fillet = 0.15 * radius
    shoulder = 0.8 * (radius - neck_radius)
    points = [(0.0, 0.0), (radius - fillet, 0.0)]
    points += [(radius - fillet + fillet * math.sin(a), fillet - fillet * math.cos(a))
               for a in np.linspace(0.2, math.pi / 2, 4)]
    points += [(neck_radius + (radius - neck_radius) * math.cos(a), height + shoulder * math.sin(a))
               for a in np.linspace(0.0, math.pi / 2, 7)]
    top = height + shoulder + neck_height
    points += [(neck_radius, top), (collar_radius, top), (collar_radius, top + collar_height),
               (0.0, top + collar_height)]
    return points


# ------------------------------------------------------------------------------------------ spray bottle
@dataclasses.dataclass(frozen=True)
class SprayBottleParams(Params):
    body_radius: float = param(0.037, 0.03, 0.045, "m", "radius of the bottle")
    body_height: float = param(0.14, 0.09, 0.18, "m", "height of the straight wall (shoulder above it)")
    neck_radius: float = param(0.014, 0.011, 0.018, "m", "radius of the neck")
    head_length: float = param(0.075, 0.055, 0.09, "m", "length of the sprayer head along +x")
    head_height: float = param(0.035, 0.025, 0.045, "m", "height of the sprayer head")
    head_width: float = param(0.03, 0.022, 0.036, "m", "width of the sprayer head")
    trigger_length: float = param(0.045, 0.035, 0.055, "m", "trigger length below its hinge")
    trigger_width: float = param(0.016, 0.012, 0.02, "m", "trigger width")
    body_mass: float = param(0.3, 0.1, 0.6, "kg", "bottle, liquid and head", "mass")
    trigger_mass: float = param(0.012, 0.005, 0.03, "kg", "trigger", "mass")
    trigger_travel: float = param(0.4, 0.3, 0.45, "rad", "trigger pull (the operated range)", "angle")
    trigger_stiffness: float = param(0.15, 0.05, 0.3, "N m/rad", "return spring", "feel")
    trigger_preload: float = param(0.2, 0.05, 0.4, "rad", "spring rest beyond the released stop", "feel")
    trigger_damping: float = param(0.005, 0.001, 0.05, "N m s/rad", "viscous damping", "feel")
    trigger_friction: float = param(0.003, 0.0, 0.02, "N m", "Coulomb friction", "feel")


def spray_bottle(params: SprayBottleParams | None = None, rng=None, name: str = "spray_bottle") -> ObjectAsset:
    """A trigger spray bottle: the bottle with its head and nozzle is the free base; the trigger hangs
    below the head on a sprung hinge about y and is pulled back toward the neck (q > 0).

    Trigger: 0.15 N m/rad from a 0.2 rad preload gives 0.03 N m released and 0.09 N m fully pulled
    (about 2.5 N at a fingertip 3.5 cm below the hinge). ``rng``: draw the parameters around ``params``."""
    p = SprayBottleParams.for_generator(params, rng, name)
    collar_r, collar_h, neck_h = p.neck_radius + 0.005, 0.012, 0.02
    shoulder = 0.8 * (p.body_radius - p.neck_radius)
    z_head = p.body_height + shoulder + neck_h + collar_h  # bottom of the head
    rear, front = -0.6 * p.head_width, p.head_length - 0.6 * p.head_width
    h = p.head_height
    nozzle_z, nozzle_r = z_head + 0.4 * h, 0.0065
    body = shapes.revolve(_bottle_profile(p.body_radius, p.body_height, p.neck_radius, neck_h, collar_r, collar_h))
    head_outline = [(rear, z_head - 0.001), (front, z_head - 0.001), (front, z_head + 0.7 * h),
                    (0.3 * front, z_head + h), (rear + 0.006, z_head + h), (rear, z_head + 0.8 * h)]
    head = shapes.extrude(head_outline, p.head_width, "xz")
    nozzle = shapes.cylinder(nozzle_r, (front - 0.002, 0, nozzle_z), (front + 0.012, 0, nozzle_z))
    tip = shapes.cylinder(0.5 * nozzle_r, (front + 0.011, 0, nozzle_z), (front + 0.015, 0, nozzle_z))
    base_mesh = shapes.to_trimesh(shapes.union([body, head, nozzle, tip]))

    # the trigger's hinge sits under the head, far enough ahead of the collar that the full pull clears it
    hinge = (max(collar_r + 0.012 + p.trigger_length * math.sin(p.trigger_travel), 0.45 * front), 0.0,
             z_head - 0.002)
    length, t = p.trigger_length, p.trigger_width
    trigger_outline = [(-0.004, 0.004), (-0.006, -0.35 * length), (-0.005, -0.8 * length), (-0.001, -length),
                       (0.009, -length), (0.012, -0.85 * length), (0.006, -0.55 * length),
                       (0.006, -0.35 * length), (0.009, -0.1 * length), (0.008, 0.004)]
    trigger_mesh = shapes.to_trimesh(shapes.extrude(trigger_outline, t, "xz"))

    base_geoms = with_mass([
        cylinder_geom("body", p.body_radius, (0, 0, 0), (0, 0, p.body_height + 0.5 * shoulder), BOTTLE_BLUE),
        cylinder_geom("neck", collar_r, (0, 0, p.body_height + 0.5 * shoulder), (0, 0, z_head), PLASTIC_WHITE),
        box_geom("head", (front - rear, p.head_width, h), ((front + rear) / 2, 0, z_head + h / 2), PLASTIC_WHITE),
        cylinder_geom("nozzle", nozzle_r, (front, 0, nozzle_z), (front + 0.015, 0, nozzle_z), PLASTIC_WHITE),
    ], p.body_mass)
    trigger_geoms = with_mass([box_geom("grip", (0.014, t, length), (0.002, 0, -length / 2 + 0.002),
                                        TRIGGER_RED)], p.trigger_mass)
    joint = Joint("trigger", "hinge", (0.0, 1.0, 0.0), (0.0, p.trigger_travel), stiffness=p.trigger_stiffness,
                  rest=-p.trigger_preload, damping=p.trigger_damping, friction=p.trigger_friction)
    # a palm-down hand cannot reach round the head to the trigger's front: the bottle stands turned half a turn
    # (grasp_yaw), the thumb rests on the trigger's front face, index and ring finger on the bottle's back, either
    # side of the head
    def on_back(finger, angle):  # angle: from the back (-x), toward -y (the index's side once turned)
        out = (-math.cos(angle), -math.sin(angle), 0.0)
        return grasp_region(finger, "bottle", (p.body_radius * out[0], p.body_radius * out[1], p.body_height + 0.004),
                            out, (0.0, 0.0, 0.004))

    regions = (on_back("index", 0.6), on_back("ring", -0.6),
               grasp_region("thumb", "trigger", (0.009, 0.0, -0.55 * length), (1, 0, 0), (0.0, 0.003, 0.004),
                            squeeze=-0.0015))  # touching: a press would pull the trigger
    return ObjectAsset(
        name=name, object_class="spray_bottle", base="free", operated_joint="trigger",
        parts=(Part("bottle", base_geoms, visual="bottle"),
               Part("trigger", trigger_geoms, parent="bottle", joint=joint, pos=hinge, visual="trigger")),
        grasp=(0.0, 0.0, float(p.body_height + 0.01)), grasp_regions=regions, grasp_yaw=math.pi, params=p.as_dict(),
        meshes={"bottle": base_mesh, "trigger": trigger_mesh},
        description="trigger spray bottle; pull the trigger back toward the neck")


# ---------------------------------------------------------------------------------------- pump dispenser
@dataclasses.dataclass(frozen=True)
class PumpDispenserParams(Params):
    body_radius: float = param(0.034, 0.028, 0.042, "m", "radius of the bottle")
    body_height: float = param(0.1, 0.07, 0.14, "m", "height of the straight wall")
    neck_radius: float = param(0.013, 0.01, 0.016, "m", "radius of the neck")
    stem_height: float = param(0.025, 0.015, 0.035, "m", "visible pump stem above the collar")
    head_radius: float = param(0.015, 0.012, 0.02, "m", "radius of the pump head")
    spout_length: float = param(0.04, 0.028, 0.05, "m", "spout length along +x")
    body_mass: float = param(0.3, 0.1, 0.5, "kg", "bottle and soap", "mass")
    head_mass: float = param(0.015, 0.005, 0.03, "kg", "pump head and stem", "mass")
    stroke: float = param(0.012, 0.008, 0.016, "m", "pump stroke (the operated range)")
    stiffness: float = param(150.0, 60.0, 220.0, "N/m", "return spring", "feel")
    preload: float = param(0.008, 0.004, 0.012, "m", "spring rest above the released stop", "feel")
    damping: float = param(1.0, 0.2, 3.0, "N s/m", "viscous damping", "feel")
    friction: float = param(0.2, 0.0, 0.5, "N", "Coulomb friction", "feel")


def pump_dispenser(params: PumpDispenserParams | None = None, rng=None, name: str = "pump_dispenser") -> ObjectAsset:
    """A soap pump: the bottle is the free base; the head with its spout slides down (q > 0, axis -z)
    on a spring. 150 N/m from an 8 mm preload: 1.2 N released, 3 N at the bottom of a 12 mm stroke."""
    p = PumpDispenserParams.for_generator(params, rng, name)
    collar_r, collar_h, neck_h = p.neck_radius + 0.006, 0.014, 0.012
    shoulder = 0.8 * (p.body_radius - p.neck_radius)
    z_collar = p.body_height + shoulder + neck_h + collar_h  # top of the collar
    body = shapes.revolve(_bottle_profile(p.body_radius, p.body_height, p.neck_radius, neck_h, collar_r, collar_h))
    base_mesh = shapes.to_trimesh(body)

    # pump part frame: on the axis at the collar's top; the head's top is stem + head height above it
    stem_r, head_h = 0.005, 0.018
    z_head = p.stem_height
    stem = shapes.cylinder(stem_r, (0, 0, -0.004), (0, 0, z_head + 0.002))
    head = shapes.revolve([(0.0, z_head), (p.head_radius, z_head), (p.head_radius, z_head + 0.7 * head_h),
                           (0.7 * p.head_radius, z_head + head_h), (0.0, z_head + head_h)])
    spout_z = z_head + 0.55 * head_h
    spout_end = (p.spout_length, 0.0, spout_z - 0.006)
    spout = shapes.polyline_tube(0.0045, [(0.5 * p.head_radius, 0, spout_z),
                                          (0.75 * p.spout_length, 0, spout_z), spout_end])
    pump_mesh = shapes.to_trimesh(shapes.union([stem, head, spout]))

    base_geoms = with_mass([
        cylinder_geom("body", p.body_radius, (0, 0, 0), (0, 0, p.body_height + 0.5 * shoulder), PLASTIC_WHITE),
        cylinder_geom("collar", collar_r, (0, 0, p.body_height + 0.5 * shoulder), (0, 0, z_collar), GLASS),
    ], p.body_mass)
    pump_geoms = with_mass([
        cylinder_geom("head", p.head_radius, (0, 0, z_head), (0, 0, z_head + head_h), GLASS),
        cylinder_geom("stem", stem_r, (0, 0, 0.0), (0, 0, z_head), GLASS),
        capsule_geom("spout", 0.0045, (0.5 * p.head_radius, 0, spout_z), (0.75 * p.spout_length, 0, spout_z), GLASS),
    ], p.head_mass)
    joint = Joint("pump", "slide", (0.0, 0.0, -1.0), (0.0, p.stroke), stiffness=p.stiffness, rest=-p.preload,
                  damping=p.damping, friction=p.friction)
    # the middle fingertip on the head's top, the thumb behind the collar: the hand sits 4 cm above the head
    back = (-math.cos(0.5), math.sin(0.5), 0.0)
    regions = (grasp_region("middle", "pump", (0.0, 0.0, z_head + head_h), (0, 0, 1), (0.003, 0.003, 0.0)),
               grasp_region("thumb", "bottle", (collar_r * back[0], collar_r * back[1], z_collar - 0.006), back,
                            (0.0, 0.0, 0.003)))
    return ObjectAsset(
        name=name, object_class="pump_dispenser", base="free", operated_joint="pump",
        parts=(Part("bottle", base_geoms, visual="bottle"),
               Part("pump", pump_geoms, parent="bottle", joint=joint, pos=(0.0, 0.0, z_collar), visual="pump")),
        grasp=(0.0, 0.0, float(z_collar + z_head + head_h - 0.04)), grasp_regions=regions, params=p.as_dict(),
        meshes={"bottle": base_mesh, "pump": pump_mesh},
        description="pump dispenser; press the head down")


# ---------------------------------------------------------------------------------------------------- jar
@dataclasses.dataclass(frozen=True)
class JarParams(Params):
    body_radius: float = param(0.04, 0.03, 0.048, "m", "radius of the jar")
    body_height: float = param(0.08, 0.05, 0.11, "m", "height of the jar up to its mouth")
    lid_height: float = param(0.02, 0.014, 0.028, "m", "height of the lid")
    ribs: int = param(24, 16, 32, "", "grip ribs around the lid", "count")
    body_mass: float = param(0.35, 0.15, 0.6, "kg", "jar and contents", "mass")
    lid_mass: float = param(0.02, 0.01, 0.04, "kg", "lid", "mass")
    turn: float = param(1.57, 1.0, 3.14, "rad", "unscrewing turn (the operated range)", "angle")
    friction: float = param(0.04, 0.01, 0.1, "N m", "thread friction (no spring: the lid stays put)", "feel")
    damping: float = param(0.002, 0.0005, 0.01, "N m s/rad", "viscous damping", "feel")


def jar(params: JarParams | None = None, rng=None, name: str = "jar") -> ObjectAsset:
    """A jar: the glass is the free base; the ribbed lid turns about the jar's axis (q > 0 unscrews it)
    against thread friction (0.04 N m: a firm twist, well within one finger's 0.35 N m). The lid does not
    rise as it turns (the thread's pitch is not modelled)."""
    p = JarParams.for_generator(params, rng, name)
    r, top = p.body_radius, p.body_height
    mouth = 0.9 * r
    fillet = 0.12 * r
    profile = [(0.0, 0.0), (r - fillet, 0.0)]
    profile += [(r - fillet + fillet * math.sin(a), fillet - fillet * math.cos(a)) for a in np.linspace(0.2, 1.57, 4)]
    profile += [(r, top - 0.02), (mouth, top - 0.012), (mouth, top), (0.0, top)]
    jar_mesh = shapes.to_trimesh(shapes.revolve(profile))

    lid_r, lid_h = r + 0.002, p.lid_height
    lid = shapes.revolve([(0.0, -0.004), (lid_r, -0.004), (lid_r, lid_h - 0.003), (lid_r - 0.003, lid_h),
                          (0.0, lid_h)])
    rib_r = 0.0022
    ribs = [shapes.cylinder(rib_r, (lid_r * math.cos(a), lid_r * math.sin(a), -0.002),
                            (lid_r * math.cos(a), lid_r * math.sin(a), lid_h - 0.005))
            for a in np.linspace(0, 2 * math.pi, p.ribs, endpoint=False)]
    # a raised radial mark on top shows how far the lid has turned (to a viewer and to a camera)
    mark = shapes.box((0.7 * lid_r, 0.006, 0.003), (0.4 * lid_r, 0.0, lid_h + 0.001))
    lid_mesh = shapes.to_trimesh(shapes.union([lid, mark, *ribs]))

    jar_geoms = with_mass([cylinder_geom("glass", r, (0, 0, 0), (0, 0, top), GLASS)], p.body_mass)
    lid_geoms = with_mass([cylinder_geom("lid", lid_r + rib_r, (0, 0, -0.004), (0, 0, lid_h), LID_GOLD)],
                          p.lid_mass)
    joint = Joint("lid", "hinge", (0.0, 0.0, 1.0), (0.0, p.turn), damping=p.damping, friction=p.friction)
    # index and middle on the lid's rim ahead (+x), the thumb on the rim behind: a pinch across the lid
    rim, mid = lid_r + rib_r, (lid_h - 0.004) / 2

    def on_rim(finger, angle):
        out = (math.cos(angle), math.sin(angle), 0.0)
        return grasp_region(finger, "lid", (rim * out[0], rim * out[1], mid), out, (0.0, 0.0, 0.002))

    regions = (on_rim("index", 0.45), on_rim("middle", -0.35), on_rim("thumb", math.pi - 0.2))
    return ObjectAsset(
        name=name, object_class="jar", base="free", operated_joint="lid",
        parts=(Part("jar", jar_geoms, visual="jar"),
               Part("lid", lid_geoms, parent="jar", joint=joint, pos=(0.0, 0.0, top), visual="lid")),
        grasp=(0.0, 0.0, float(top + lid_h / 2)), grasp_regions=regions, params=p.as_dict(),
        meshes={"jar": jar_mesh, "lid": lid_mesh},
        description="jar with a screw lid; twist the lid counter-clockwise seen from above")
