"""Procedural operable objects for the Allegro hand: a spray bottle, scissors and a stapler.

Each object is a static base (body ``object_base``: up to four boxes the finger spheres collide with) and
one moving part (body ``object``: one box on a sprung hinge with a range), built from the named sizes of
an :class:`OperableObject`. :func:`scene_xml` puts it under the Allegro hand of ``allegro_knob.xml``
(same links, joints, motors and mount: palm down, fingers along world +x, fingertips curling down and
back toward the thumb), so the three scenes differ only in the object. The shipped files
``allegro_<name>.xml`` are this module's output; ``python -m dexmots_rl.assets.operable`` rewrites them
(deterministically: the text depends only on the numbers below).

The objects (world frame, metres; the knob of ``allegro_rotate`` would stand at the origin):

* **spray bottle**: the bottle's body and head are the base; the trigger hangs under the head's front on a
  hinge about +y with a return spring. Pulling the trigger toward the bottle (the fingers curling) is
  +θ; range [0, 0.45] rad (PartNet's trigger moves 4.5°, which a 0.1 rad band would make trivial).
* **scissors**, lying flat: the held blade with its handle is the base; the operated blade and its
  handle are one bar on a vertical pivot beyond the fingertips. Pushing the operated handle toward the
  held one (−y) closes the scissors, +θ; range [0, 0.35] rad (20°), a 2.6 cm sideways push of the
  handle where the hand holds it.
* **stapler**: the base lies on the table, the arm is hinged at its back end about +y and held open by
  its spring; pressing the front of the arm down is +θ, range [0, 0.5] rad (closed on the base).

Gravity is off, as in the knob scenes: the parts' springs alone set their rest positions.

Example:
    >>> xml = scene_xml(OBJECTS["stapler"])
    >>> "object_base" in xml and 'range="0 0.5"' in xml
    True
"""

from __future__ import annotations

import dataclasses
import math
import re

from . import asset_path

__all__ = ["Box", "OperableObject", "OBJECTS", "scene_xml", "scene_file", "write_scenes"]


@dataclasses.dataclass(frozen=True)
class Box:
    """A box: centre and half sizes (m) and a rotation about z (rad) in its body's frame."""

    name: str
    pos: tuple[float, float, float]
    half: tuple[float, float, float]
    yaw: float = 0.0


@dataclasses.dataclass(frozen=True)
class OperableObject:
    """A static base plus one part on a sprung hinge; every size in metres, angles in rad."""

    name: str
    description: str
    base: tuple[Box, ...]  # the static base's boxes (world frame)
    part: Box  # the moving part's collision box (in the part's frame, the hinge at its origin)
    hinge_pos: tuple[float, float, float]  # the hinge's origin (world)
    hinge_pitch: float  # the part frame's rotation about world y at θ = 0 (rad)
    axis: tuple[float, float, float]  # hinge axis in the part frame
    joint_range: tuple[float, float]  # rad
    mass: float  # kg, of the moving part
    damping: float  # N m s/rad
    friction: float  # N m (Coulomb)
    stiffness: float  # N m/rad: the return spring, toward springref
    springref: float = 0.0  # rad
    # kg m^2 added to the part's axial inertia (its mechanism's reflected inertia). The joint's Coulomb friction
    # is explicit in the simulator, so dt f / (v_f I) must stay below ~1 (v_f = 0.05 rad/s): a 10 g trigger
    # alone (4.4e-6 kg m^2) made it 9.5 at f = 0.002 N m, and its velocity chattered about zero
    armature: float = 0.0

    def __post_init__(self):
        if not self.joint_range[0] < self.joint_range[1]:
            raise ValueError(f"{self.name}: joint_range must be increasing, got {self.joint_range}")
        if not 1 <= len(self.base) <= 4:
            raise ValueError(f"{self.name}: base needs 1 to 4 boxes, got {len(self.base)}")


SPRAY_BOTTLE = OperableObject(
    name="spray_bottle",
    description="a spray bottle: body and head (base), a sprung trigger under the head's front",
    base=(Box("bottle_body", (-0.0275, 0.0, -0.045), (0.0175, 0.024, 0.065)),
          Box("bottle_head", (-0.0165, 0.0, 0.04), (0.0285, 0.016, 0.014))),
    part=Box("trigger", (0.0, 0.0, -0.018), (0.006, 0.013, 0.018)),
    hinge_pos=(0.012, 0.0, 0.026),
    hinge_pitch=0.0,
    axis=(0.0, 1.0, 0.0),
    joint_range=(0.0, 0.45),  # pulled fully, the trigger's lower back edge meets the bottle's front
    mass=0.01,
    damping=0.01,
    friction=0.002,
    stiffness=0.05,
    armature=2e-4,  # the trigger's pump: 2e-4 kg m^2 keeps the explicit friction stable (see armature)
)

SCISSORS = OperableObject(
    name="scissors",
    description="scissors lying flat: the held blade and handle (base), the operated blade and handle on a pivot",
    base=(Box("held_handle", (0.075 - 0.055 * 0.9394, -0.055 * 0.3429, -0.022), (0.055, 0.009, 0.007), yaw=0.35),
          Box("pivot", (0.075, 0.0, -0.022), (0.012, 0.012, 0.007))),
    part=Box("operated_blade", (-0.02, 0.0, 0.0), (0.085, 0.008, 0.009)),
    hinge_pos=(0.075, 0.0, 0.0),
    hinge_pitch=0.0,
    axis=(0.0, 0.0, 1.0),  # +θ swings the handle (at -x from the pivot) toward -y, onto the held one
    joint_range=(0.0, 0.35),
    mass=0.03,
    damping=0.01,
    friction=0.002,
    stiffness=0.02,
    armature=1e-4,  # the pivot's friction stable at 0.004 N m (see armature)
)

STAPLER = OperableObject(
    name="stapler",
    description="a stapler: the base on the table, the arm hinged at its back end and held open by a spring",
    base=(Box("stapler_base", (0.0, 0.0, -0.032), (0.09, 0.02, 0.008)),),
    part=Box("arm", (0.082, 0.0, 0.006), (0.082, 0.017, 0.006)),
    hinge_pos=(-0.08, 0.0, -0.024),
    hinge_pitch=-0.5,  # the arm's front tilted 0.5 rad up: open
    axis=(0.0, 1.0, 0.0),  # +θ turns the front down, onto the base
    joint_range=(0.0, 0.5),
    mass=0.04,
    damping=0.01,
    friction=0.002,
    stiffness=0.45,  # a stapler's spring: ~2 N at the arm's front at the goal
)

OBJECTS = {o.name: o for o in (SPRAY_BOTTLE, SCISSORS, STAPLER)}


def _num(x: float) -> str:
    return f"{x:.6g}"


def _vec(v) -> str:
    return " ".join(_num(x) for x in v)


def _box_geom(box: Box, rgba: str, indent: str) -> str:
    quat = f' quat="{_vec((math.cos(box.yaw / 2), 0.0, 0.0, math.sin(box.yaw / 2)))}"' if box.yaw else ""
    return (f'{indent}<geom name="{box.name}" type="box" pos="{_vec(box.pos)}" size="{_vec(box.half)}"{quat} '
            f'contype="2" conaffinity="1" rgba="{rgba}"/>\n')


def scene_xml(obj: OperableObject) -> str:
    """The MJCF text of the Allegro hand (``allegro_knob.xml``'s) with ``obj`` in place of the knob."""
    hand = asset_path("allegro_knob.xml").read_text()
    start, end = hand.index('    <body name="hand"'), hand.index('    <body name="object"')
    hand_body = hand[start:end]
    head = hand[hand.index("  <compiler"):hand.index("  <asset>")]
    actuators = hand[hand.index("  <actuator>"):]
    pitch = obj.hinge_pitch
    quat = _vec((math.cos(pitch / 2), 0.0, math.sin(pitch / 2), 0.0))
    base = "".join(_box_geom(b, "0.55 0.55 0.6 1", "      ") for b in obj.base)
    body = (
        f'    <!-- {obj.description} -->\n'
        f'    <body name="object_base" pos="0 0 0">\n{base}'
        f'      <body name="object" pos="{_vec(obj.hinge_pos)}" quat="{quat}">\n'
        f'        <joint name="{obj.part.name}_hinge" type="hinge" axis="{_vec(obj.axis)}" '
        f'range="{_vec(obj.joint_range)}" damping="{_num(obj.damping)}" frictionloss="{_num(obj.friction)}" '
        f'stiffness="{_num(obj.stiffness)}" springref="{_num(obj.springref)}" armature="{_num(obj.armature)}"/>\n'
        f'        <geom name="{obj.part.name}" type="box" pos="{_vec(obj.part.pos)}" size="{_vec(obj.part.half)}" '
        f'mass="{_num(obj.mass)}" contype="2" conaffinity="1" rgba="0.3 0.5 0.8 1"/>\n'
        '      </body>\n'
        '    </body>\n'
        '  </worldbody>\n'
    )
    header = (f"<!-- Allegro hand v4 (right) + {obj.description}.\n"
              "     Generated by dexmots_rl.assets.operable (python -m dexmots_rl.assets.operable): edit that module,\n"
              "     not this file. The hand is allegro_knob.xml's; body \"object_base\" is static (its boxes collide with\n"
              "     the finger spheres), body \"object\" is the moving part on a sprung hinge with a range. -->\n")
    # the knob scene's hand notes describe the knob: keep only its compiler/option/default blocks
    xml = f'{header}<mujoco model="allegro_{obj.name}">\n{head}  <worldbody>\n{hand_body}{body}{actuators}'
    return re.sub(r"\n{3,}", "\n\n", xml)


def scene_file(name: str) -> str:
    """The bundled scene file name of object ``name``."""
    if name not in OBJECTS:
        raise ValueError(f"unknown operable object {name!r}; known: {', '.join(OBJECTS)}")
    return f"allegro_{name}.xml"


def write_scenes() -> list:
    """(Re)write the bundled scene files; returns their paths."""
    paths = []
    for name, obj in OBJECTS.items():
        path = asset_path(scene_file(name))
        path.write_text(scene_xml(obj))
        paths.append(path)
    return paths


if __name__ == "__main__":
    write_scenes()
