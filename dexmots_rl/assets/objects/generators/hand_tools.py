"""Hand tools that lie or stand free on the table: scissors, a desktop stapler, pliers.

Scissors and pliers: base frame at the pivot on the table, blades or jaws along +x, lying flat (z up).
Stapler: base frame under the middle of its base plate, the front (where it staples) along +x.
"""

from __future__ import annotations

import dataclasses
import math

from ..description import Joint, ObjectAsset, Part
from .. import shapes
import numpy as np

from .common import (Params, axis_angle_quat, box_geom, capsule_geom, grasp_region, mesh_geom, param,
                     with_mass)

__all__ = ["ScissorsParams", "scissors", "StaplerParams", "stapler", "PliersParams", "pliers"]

STEEL = (0.78, 0.8, 0.84, 1.0)
HANDLE_ORANGE = (0.95, 0.5, 0.1, 1.0)
HANDLE_BLUE = (0.2, 0.4, 0.85, 1.0)
STAPLER_GREY = (0.55, 0.57, 0.6, 1.0)
STAPLER_RED = (0.75, 0.12, 0.12, 1.0)


# ---------------------------------------------------------------------------------------------- scissors
@dataclasses.dataclass(frozen=True)
class ScissorsParams(Params):
    blade_length: float = param(0.085, 0.06, 0.1, "m", "blade length from the pivot to the tip")
    blade_width: float = param(0.016, 0.012, 0.02, "m", "blade width at the pivot")
    thickness: float = param(0.004, 0.003, 0.006, "m", "thickness of one half (blade and shank)")
    handle_length: float = param(0.06, 0.045, 0.075, "m", "pivot to ring centre along -x")
    handle_spread: float = param(0.02, 0.014, 0.028, "m", "ring centre's offset from the axis (each side)")
    # a robot finger's hole: the Allegro's fingertip is 24 mm across (a person's scissors: 10-12.5 mm)
    ring_radius: float = param(0.014, 0.013, 0.015, "m", "inner radius of a finger ring")
    ring_band: float = param(0.0045, 0.0035, 0.006, "m", "width of a ring's band")
    half_mass: float = param(0.035, 0.015, 0.06, "kg", "one half (blade, shank, ring)", "mass")
    opening: float = param(0.6, 0.45, 0.8, "rad", "how far the scissors open (the operated range)", "angle")
    stiffness: float = param(0.0, 0.0, 0.05, "N m/rad", "closing spring (0: plain scissors)", "feel")
    preload: float = param(0.2, 0.0, 0.4, "rad", "closing spring's rest beyond the closed stop", "feel")
    friction: float = param(0.01, 0.002, 0.03, "N m", "pivot friction (holds an opening)", "feel")
    damping: float = param(0.002, 0.0005, 0.01, "N m s/rad", "viscous damping", "feel")


def _scissor_half(p: ScissorsParams, side: float, z0: float, colour, tag: str, meshes: dict) -> tuple:
    """Blade, shank and ring of one half (side +1: ring on +y, blade's edge on -y), the blade's bottom at z0."""
    t, ring_t = p.thickness, 1.5 * p.thickness
    w, length = p.blade_width, p.blade_length
    outline = [(-0.012, -side * 0.35 * w), (0.5 * length, -side * 0.05 * w), (length, side * 0.02 * w),
               (0.8 * length, side * 0.35 * w), (0.3 * length, side * 0.55 * w), (-0.012, side * 0.5 * w)]
    if side < 0:  # keep the outline counter-clockwise
        outline = outline[::-1]
    blade = shapes.extrude(outline, t).translate((0, 0, z0 + t / 2))
    outer = p.ring_radius + p.ring_band
    # both rings lie on the table (the upper half's shank bends down to its ring), so the scissors lie flat
    centre = (-p.handle_length, side * p.handle_spread, ring_t / 2)
    ring = shapes.ring(p.ring_radius, outer, ring_t, centre)
    shank_r = 0.3 * p.ring_band + 0.5 * t  # a round shank a little thicker than the blade, resting on z0
    shank_start = (0.0, 0.0, z0 + shank_r)
    # the shank ends on the ring's outer rim, its round end clear of the hole (a finger fits in the ring)
    shank_end = (-p.handle_length + outer, side * p.handle_spread * 0.8, shank_r)
    shank = shapes.capsule(shank_r, shank_start, shank_end)
    pivot = shapes.cylinder(0.005, (0, 0, z0), (0, 0, z0 + t + 0.0015))
    meshes[f"half_{tag}"] = shapes.to_trimesh(shapes.union([blade, ring, shank, pivot]))
    meshes[f"ring_{tag}"] = shapes.to_trimesh(ring)
    geoms = [box_geom("blade", (length * 0.9, 0.6 * w, t), (0.43 * length, 0.0, z0 + t / 2), STEEL),
             capsule_geom("shank", shank_r, shank_start, shank_end, colour),
             mesh_geom("ring", f"ring_{tag}", colour)]
    # the part is drawn in its handle's colour; the steel blade colours only the blade's collision geom
    return with_mass([geoms[1], geoms[0], geoms[2]], p.half_mass, meshes)


def scissors(params: ScissorsParams | None = None, rng=None, name: str = "scissors") -> ObjectAsset:
    """Scissors lying flat: one half (blade, shank, ring) is the free base; the other lies on it and turns
    about the pivot (axis z): q > 0 opens the blades and the rings. Plain scissors have no spring, only
    pivot friction (0.01 N m: an opening stays); the rings are non-convex, so they collide as meshes."""
    p = ScissorsParams.for_generator(params, rng, name)
    meshes: dict = {}
    base_geoms = _scissor_half(p, +1.0, 0.0, HANDLE_ORANGE, "a", meshes)
    moving_geoms = _scissor_half(p, -1.0, p.thickness, HANDLE_BLUE, "b", meshes)
    joint = Joint("pivot", "hinge", (0.0, 0.0, 1.0), (0.0, p.opening), stiffness=p.stiffness, rest=-p.preload,
                  damping=p.damping, friction=p.friction)
    # the thumb in the base half's ring, the middle finger in the other's (the rings lie 2.5 cm behind the point
    # under the palm, where the thumb reaches down), each tip touching its hole's far wall at mid-height, the
    # side it pushes to spread the rings; squeeze 0: touching, so the pre-grasp itself does not open them
    mid = 0.75 * p.thickness
    regions = (grasp_region("thumb", "half_a", (-p.handle_length, p.handle_spread + p.ring_radius, mid),
                            (0, -1, 0), squeeze=0.0),
               grasp_region("middle", "half_b", (-p.handle_length, -p.handle_spread - p.ring_radius, mid),
                            (0, 1, 0), squeeze=0.0))
    return ObjectAsset(
        name=name, object_class="scissors", base="free", operated_joint="pivot",
        parts=(Part("half_a", base_geoms, visual="half_a"),
               Part("half_b", moving_geoms, parent="half_a", joint=joint, visual="half_b")),
        grasp=(float(0.025 - p.handle_length), 0.0, float(p.thickness)), grasp_regions=regions,
        params=p.as_dict(), meshes=meshes,
        description="scissors lying flat; open them by spreading the finger rings")


# ----------------------------------------------------------------------------------------------- stapler
@dataclasses.dataclass(frozen=True)
class StaplerParams(Params):
    length: float = param(0.15, 0.11, 0.18, "m", "length of the base plate")
    width: float = param(0.042, 0.034, 0.05, "m", "width of the base plate")
    arm_length: float = param(0.14, 0.1, 0.17, "m", "hinge to the front of the arm")
    arm_height: float = param(0.024, 0.018, 0.03, "m", "height of the arm")
    hinge_height: float = param(0.032, 0.026, 0.04, "m", "height of the hinge above the table")
    base_mass: float = param(0.2, 0.08, 0.35, "kg", "base plate and hinge block", "mass")
    arm_mass: float = param(0.12, 0.05, 0.2, "kg", "arm (magazine and cover)", "mass")
    open_angle: float = param(0.3, 0.2, 0.45, "rad", "arm's lift at rest = its travel (operated range)", "angle")
    stiffness: float = param(0.4, 0.2, 0.7, "N m/rad", "return spring", "feel")
    preload: float = param(0.35, 0.2, 0.5, "rad", "spring rest above the open stop", "feel")
    damping: float = param(0.01, 0.002, 0.05, "N m s/rad", "viscous damping", "feel")
    friction: float = param(0.005, 0.0, 0.02, "N m", "Coulomb friction", "feel")


def stapler(params: StaplerParams | None = None, rng=None, name: str = "stapler") -> ObjectAsset:
    """A desktop stapler: the base plate with the hinge block at the back is the free base; the arm is
    hinged at the back (axis y) and rests lifted by ``open_angle``; q > 0 presses it down flat.

    Spring: 0.4 N m/rad from a 0.35 rad preload holds the arm (0.14 N m against about 0.08 N m of its
    weight) and needs about 0.18 N m net at full press: under 2 N at a fingertip near the front."""
    p = StaplerParams.for_generator(params, rng, name)
    half = p.length / 2
    plate_h, block_l = 0.012, 0.03
    plate = shapes.rounded_box((p.length, p.width, plate_h), 0.004, (0, 0, plate_h / 2))
    anvil = shapes.box((0.03, 0.4 * p.width, 0.002), (half - 0.03, 0, plate_h + 0.0005))
    # the hinge block stops under the hinge's knuckle; the arm's magazine starts ahead of it
    block_h = p.hinge_height - 0.006
    block = shapes.rounded_box((block_l, 0.8 * p.width, block_h), 0.004,
                               (-half + block_l / 2 + 0.002, 0, block_h / 2))
    base_mesh = shapes.to_trimesh(shapes.union([plate, anvil, block]))

    # arm frame: at the hinge, arm along +x when pressed flat; its bottom clears the plate by 2 mm then
    h, arm_w = p.arm_height, 0.75 * p.width
    drop = p.hinge_height - plate_h - 0.002  # hinge to the arm's bottom face
    mag_start = block_l - 0.008
    mag_l = p.arm_length - 0.01 - mag_start
    magazine = shapes.rounded_box((mag_l, 0.8 * arm_w, h - 0.006), 0.003,
                                  (mag_start + mag_l / 2, 0, -drop + (h - 0.006) / 2))
    cover_outline = [(-0.012, -drop + h - 0.012), (p.arm_length - 0.02, -drop + h - 0.012),
                     (p.arm_length, -drop + h - 0.018), (p.arm_length + 0.004, -drop + h - 0.008),
                     (p.arm_length - 0.02, -drop + h), (0.3 * p.arm_length, -drop + h + 0.004),
                     (-0.012, -drop + h - 0.002)]
    cover = shapes.extrude(cover_outline, arm_w, "xz")
    knuckle = shapes.cylinder(0.007, (0, -0.4 * arm_w, 0), (0, 0.4 * arm_w, 0))
    arm_mesh = shapes.to_trimesh(shapes.union([magazine, cover, knuckle]))

    base_geoms = with_mass([
        box_geom("plate", (p.length, p.width, plate_h), (0, 0, plate_h / 2), STAPLER_GREY),
        box_geom("block", (block_l, 0.8 * p.width, block_h), (-half + block_l / 2 + 0.002, 0, block_h / 2),
                 STAPLER_GREY),
    ], p.base_mass)
    arm_geoms = with_mass([
        box_geom("cover", (p.arm_length + 0.016, arm_w, 0.012), (p.arm_length / 2 - 0.004, 0, -drop + h - 0.006),
                 STAPLER_RED),
        box_geom("magazine", (mag_l, 0.8 * arm_w, h - 0.006), (mag_start + mag_l / 2, 0, -drop + (h - 0.006) / 2),
                 STAPLER_RED),
    ], p.arm_mass)
    hinge = (-half + 0.012, 0.0, p.hinge_height)
    joint = Joint("arm", "hinge", (0.0, 1.0, 0.0), (0.0, p.open_angle), stiffness=p.stiffness,
                  rest=-p.preload, damping=p.damping, friction=p.friction)
    # index and middle side by side on the arm's top toward the front, the thumb on the base plate's top
    # edge on its side (+y); the hand sits 3 cm ahead of the plate's middle, 8 mm above the hinge
    arm_top, edge = (0.75 * p.arm_length, 0.0, -drop + h), (0.0, p.width / 2, plate_h)
    # (touching the arm, aimed 1.5 mm short of it: a press would push it down, toward the goal)
    regions = (grasp_region("index", "arm", np.add(arm_top, (0, 0.012, 0)), (0, 0, 1), (0.006, 0.002, 0.0), -0.0015),
               grasp_region("middle", "arm", np.add(arm_top, (0, -0.012, 0)), (0, 0, 1), (0.006, 0.002, 0.0),
                            -0.0015),
               grasp_region("thumb", "base", edge, (0, 1, 1), (0.006, 0.0, 0.0)))
    return ObjectAsset(
        name=name, object_class="stapler", base="free", operated_joint="arm",
        parts=(Part("base", base_geoms, visual="base"),
               Part("arm", arm_geoms, parent="base", joint=joint, pos=hinge,
                    quat=axis_angle_quat((0.0, 1.0, 0.0), -p.open_angle), visual="arm")),
        grasp=(0.03, 0.0, float(p.hinge_height + 0.008)), grasp_regions=regions, params=p.as_dict(),
        meshes={"base": base_mesh, "arm": arm_mesh},
        description="desktop stapler; press the arm down onto the base")



# ------------------------------------------------------------------------------------------------- pliers
@dataclasses.dataclass(frozen=True)
class PliersParams(Params):
    jaw_length: float = param(0.036, 0.025, 0.05, "m", "pivot to jaw tip")
    jaw_width: float = param(0.016, 0.012, 0.02, "m", "jaw width at the pivot")
    thickness: float = param(0.006, 0.004, 0.008, "m", "thickness of one half")
    handle_length: float = param(0.11, 0.08, 0.13, "m", "pivot to handle end along -x")
    handle_spread: float = param(0.025, 0.018, 0.032, "m", "handle end's offset from the axis at rest")
    grip_radius: float = param(0.006, 0.0045, 0.008, "m", "radius of a handle's plastic grip")
    half_mass: float = param(0.06, 0.03, 0.1, "kg", "one half (jaw, handle, grip)", "mass")
    stiffness: float = param(0.1, 0.04, 0.2, "N m/rad", "opening spring", "feel")
    preload: float = param(0.2, 0.05, 0.4, "rad", "spring rest beyond the open stop", "feel")
    friction: float = param(0.005, 0.0, 0.02, "N m", "pivot friction", "feel")
    damping: float = param(0.002, 0.0005, 0.01, "N m s/rad", "viscous damping", "feel")


def _pliers_half(p: PliersParams, side: float, z0: float, tag: str, meshes: dict) -> tuple:
    """Jaw, boss and handle of one half; side +1: the handle ends on +y and the jaw points to -y of +x."""
    t, half_open = p.thickness, math.atan2(p.handle_spread, p.handle_length)
    jaw_dir = (math.cos(half_open), -side * math.sin(half_open))
    normal = (-jaw_dir[1], jaw_dir[0])
    w0, length = p.jaw_width / 2, p.jaw_length

    def at(u, v):  # a point u along the jaw, v across it
        return (u * jaw_dir[0] + v * normal[0], u * jaw_dir[1] + v * normal[1])

    outline = [at(-0.012, -w0), at(0.7 * length, -0.5 * w0), at(length, -0.25 * w0), at(length, 0.15 * w0),
               at(0.5 * length, 0.8 * w0), at(-0.012, w0)]
    jaw = shapes.extrude(outline, t).translate((0, 0, z0 + t / 2))
    # both grips lie on the table (the handles bend down from the stacked pivot), so the pliers lie flat
    end = (-p.handle_length, side * p.handle_spread, p.grip_radius)
    grip_start = (-0.4 * p.handle_length, side * 0.4 * p.handle_spread, p.grip_radius)
    shaft = shapes.polyline_tube(0.45 * t, [(0, 0, z0 + t / 2), (-0.25 * p.handle_length,
                                            side * 0.25 * p.handle_spread, z0 + t / 2), (*end[:2], p.grip_radius)])
    grip = shapes.capsule(p.grip_radius, grip_start, end)
    boss = shapes.cylinder(0.55 * p.jaw_width, (0, 0, z0), (0, 0, z0 + t))
    rivet = shapes.cylinder(0.004, (0, 0, z0), (0, 0, z0 + t + 0.0015))
    meshes[tag] = shapes.to_trimesh(shapes.union([jaw, shaft, grip, boss, rivet]))
    jaw_centre = at(0.4 * length, 0.0)
    geoms = [capsule_geom("grip", p.grip_radius, grip_start, end, HANDLE_BLUE if side < 0 else STAPLER_RED),
             box_geom("jaw", (length + 0.012, 1.6 * w0, t), (*jaw_centre, z0 + t / 2), STEEL,
                      quat=axis_angle_quat((0, 0, 1), math.atan2(jaw_dir[1], jaw_dir[0]))),
             capsule_geom("shaft", 0.45 * t, (0, 0, z0 + t / 2), grip_start, STEEL)]
    return with_mass(geoms, p.half_mass)


def _on_grip(p: PliersParams, finger: str, part: str, side: float, along: float):
    """A fingertip on the outer upper flank of a grip (``along``: 0 at the grip's start, 1 at its end): the
    thumb on one handle and two fingers on the other pinch the pliers the way a squeeze closes them."""
    start = np.array([-0.4 * p.handle_length, side * 0.4 * p.handle_spread, p.grip_radius])
    end = np.array([-p.handle_length, side * p.handle_spread, p.grip_radius])
    d = (end - start) / np.linalg.norm(end - start)
    outward = np.array([-d[1], d[0], 0.0])
    outward = outward if outward[1] * side > 0 else -outward
    normal = (outward + (0.0, 0.0, 1.0)) / np.sqrt(2.0)
    return grasp_region(finger, part, start + along * (end - start) + p.grip_radius * normal, normal,
                        (0.003, 0.0, 0.0))


def pliers(params: PliersParams | None = None, rng=None, name: str = "pliers") -> ObjectAsset:
    """Pliers lying flat with their handles spread by an opening spring: one half is the free base; the
    other turns about the pivot (axis -z) and q > 0 squeezes the handles together, closing the jaws. The
    range stops the handles at 90 % of the way to touching. Spring 0.1 N m/rad from a 0.2 rad preload: about
    0.06 N m fully squeezed, under 1 N at the grips."""
    p = PliersParams.for_generator(params, rng, name)
    meshes: dict = {}
    squeeze = 0.9 * 2.0 * math.atan2(p.handle_spread, p.handle_length)
    base_geoms = _pliers_half(p, +1.0, 0.0, "half_a", meshes)
    moving_geoms = _pliers_half(p, -1.0, p.thickness, "half_b", meshes)
    joint = Joint("pivot", "hinge", (0.0, 0.0, -1.0), (0.0, squeeze), stiffness=p.stiffness, rest=-p.preload,
                  damping=p.damping, friction=p.friction)
    regions = (_on_grip(p, "thumb", "half_a", +1.0, 0.5), _on_grip(p, "middle", "half_b", -1.0, 0.25),
               _on_grip(p, "ring", "half_b", -1.0, 0.7))
    return ObjectAsset(
        name=name, object_class="pliers", base="free", operated_joint="pivot",
        parts=(Part("half_a", base_geoms, visual="half_a"),
               Part("half_b", moving_geoms, parent="half_a", joint=joint, visual="half_b")),
        grasp=(float(0.02 - 0.7 * p.handle_length), 0.0, float(p.thickness)), grasp_regions=regions,
        params=p.as_dict(), meshes=meshes,
        description="pliers lying flat; squeeze the handles together")
