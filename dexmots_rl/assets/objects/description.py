"""The articulated object model: a base fixed to the world or free on a table, and up to four moving parts.

An :class:`ObjectAsset` is a small tree of rigid :class:`Part` s. The first part is the **base**: fixed to the
world, or free (6 DoF, resting on the table under gravity). Every other part hangs from an earlier one on a
:class:`Joint` (a hinge or a slide) with a range (a stiff, smooth stop), a return spring (stiffness and rest
position), viscous damping and Coulomb friction. Each part collides as a union of primitive :class:`Geom` s
(box, capsule, sphere, cylinder) or as the signed distance of a watertight mesh (``kind="mesh"``), and is drawn
as its visual mesh. Parts touch each other only through their joint limits.

Units: metres, kilograms, radians (hinges) or metres (slides), seconds. Frames: each part's frame is given in
its parent's frame at joint position 0 (``pos`` and the unit quaternion ``quat`` in MuJoCo's (w, x, y, z)
order); a joint's axis and anchor are in its part's frame; geoms are in their part's frame. The base frame of
a free object sits on the table: z = 0 is the table's surface when the object stands in its rest pose.

:meth:`ObjectAsset.mjcf` writes the MJCF that MuJoCo compiles (the simulator's scene format):

* one ``<body name="object">`` for the base, with a ``<freejoint name="object_free"/>`` when free;
* one ``<body name="object/<part>">`` per moving part, with one ``<joint name="object/<joint>">`` (hinge or slide,
  ``limited``, ``range``, ``stiffness``, ``springref``, ``damping``, ``frictionloss``, ``armature``);
* collision geoms ``contype="2" conaffinity="1"`` named ``object/<part>/<geom>``, with their mass (the parts'
  inertias come from them); visual meshes ``contype="0" conaffinity="0" group="1" mass="0"``.

Every name the object puts into a scene starts with ``object`` (:data:`SCENE_PREFIX`), so that a part or joint
named like one of the hand's (``j3``) cannot clash with it; the simulator reads the joints back without the
prefix (:func:`scene_joint_name`), so a user names them as the object does.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Literal

import numpy as np

from ...atomic import atomic_write

__all__ = ["Geom", "Joint", "Part", "GraspRegion", "ObjectAsset", "ObjectError", "MAX_MOVING_PARTS", "GEOM_KINDS",
           "FINGERS", "SCENE_PREFIX", "scene_joint_name"]

MAX_MOVING_PARTS = 4
SCENE_PREFIX = "object/"  # of the object's bodies, joints and geoms in a scene (the base body is "object")
GEOM_KINDS = ("box", "capsule", "sphere", "cylinder", "mesh")
Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]
IDENTITY: Quat = (1.0, 0.0, 0.0, 0.0)
FINGERS = ("index", "middle", "ring", "thumb")  # the Allegro hand's fingers, as its MJCF names them


class ObjectError(ValueError):
    """An object description is inconsistent (the message names the object and the bad field)."""


@dataclasses.dataclass(frozen=True)
class Geom:
    """One collision primitive of a part (part frame).

    ``size``: box: half extents (x, y, z); capsule and cylinder: (radius, half length along local z);
    sphere: (radius,); mesh: unused (the mesh in :attr:`ObjectAsset.meshes` named ``mesh``, part frame).
    ``mass``: kg carried by this geom (its inertia is the solid shape's, computed by MuJoCo).
    """

    name: str
    kind: Literal["box", "capsule", "sphere", "cylinder", "mesh"]
    size: tuple[float, ...] = ()
    pos: Vec3 = (0.0, 0.0, 0.0)
    quat: Quat = IDENTITY
    mass: float = 0.01
    mesh: str | None = None
    rgba: tuple[float, float, float, float] = (0.6, 0.6, 0.65, 1.0)


@dataclasses.dataclass(frozen=True)
class Joint:
    """The joint that moves a part relative to its parent (axis and anchor in the part frame).

    ``range``: (lower, upper) in rad (hinge) or m (slide); the stop is a stiff smooth spring. ``stiffness``
    (N m/rad or N/m) pulls toward ``rest``; ``damping`` (N m s/rad or N s/m); ``friction``: Coulomb (N m or N);
    ``armature``: reflected inertia of the mechanism (kg m^2 or kg)."""

    name: str
    kind: Literal["hinge", "slide"]
    axis: Vec3
    range: tuple[float, float]
    anchor: Vec3 = (0.0, 0.0, 0.0)
    stiffness: float = 0.0
    rest: float = 0.0
    damping: float = 0.01
    friction: float = 0.0
    armature: float = 1e-4


@dataclasses.dataclass(frozen=True)
class Part:
    """A rigid part: its frame in its parent's (at joint 0), its joint (None for the base), its collision
    geoms and the name of its visual mesh in :attr:`ObjectAsset.meshes` (None: drawn from its geoms)."""

    name: str
    geoms: tuple[Geom, ...]
    parent: str | None = None
    joint: Joint | None = None
    pos: Vec3 = (0.0, 0.0, 0.0)
    quat: Quat = IDENTITY
    visual: str | None = None


@dataclasses.dataclass(frozen=True)
class GraspRegion:
    """Where one fingertip rests when a hand holds the tool: on part ``part``, at ``point`` (m) with the
    surface's outward ``normal`` there (both in the part's frame, at joint position 0); a pre-grasp search
    draws the contact within ``spread`` (m, +- along the part frame's axes) of the point and aims the
    fingertip ``squeeze`` (m) into the surface (None: the search's default; 0 where a light press would
    already move the part toward its goal). ``finger``: one of :data:`FINGERS`."""

    finger: str
    part: str
    point: Vec3
    normal: Vec3
    spread: Vec3 = (0.0, 0.0, 0.0)
    squeeze: float | None = None


@dataclasses.dataclass
class ObjectAsset:
    """An operable object: parts[0] is the base, the rest move on joints (see the module docstring).

    ``object_class`` (e.g. ``"spray_bottle"``) and ``params`` (the generator's named sizes and physical values)
    say where it came from; ``operated_joint`` is the joint a task drives by default; ``grasp`` is where a
    hand holds the tool (a point in the base frame, m), placed under the palm in a hand scene, the object
    turned there by ``grasp_yaw`` (rad, about the vertical) so that the hand meets it from the side it is held;
    ``grasp_regions`` say where each fingertip of a holding hand rests (:class:`GraspRegion`, one per
    finger at most; empty: none described, as for a URDF). ``meshes`` maps names to
    watertight ``trimesh.Trimesh`` objects in their part's frame (visual meshes, and the collision of
    ``kind="mesh"`` geoms)."""

    name: str
    object_class: str
    parts: tuple[Part, ...]
    base: Literal["free", "fixed"] = "free"
    operated_joint: str | None = None
    grasp: Vec3 = (0.0, 0.0, 0.0)
    grasp_regions: tuple[GraspRegion, ...] = ()
    grasp_yaw: float = 0.0
    params: dict[str, float] = dataclasses.field(default_factory=dict)
    meshes: dict = dataclasses.field(default_factory=dict)
    description: str = ""

    def __post_init__(self):
        self.validate()

    # ------------------------------------------------------------------------------------------ queries
    @property
    def joints(self) -> tuple[Joint, ...]:
        return tuple(p.joint for p in self.parts[1:])

    def joint(self, name: str) -> Joint:
        for j in self.joints:
            if j.name == name:
                return j
        raise ObjectError(f"object {self.name!r} has no joint {name!r}; its joints: {[j.name for j in self.joints]}")

    # ------------------------------------------------------------------------------------------ checks
    def validate(self) -> None:
        """Raise :class:`ObjectError` naming the object and the bad field."""
        where = f"object {self.name!r}"
        if not self.parts:
            raise ObjectError(f"{where}: needs at least a base part")
        if self.base not in ("free", "fixed"):
            raise ObjectError(f"{where}: base must be 'free' or 'fixed', got {self.base!r}")
        if len(self.parts) - 1 > MAX_MOVING_PARTS:
            raise ObjectError(f"{where}: at most {MAX_MOVING_PARTS} moving parts, got {len(self.parts) - 1}")
        seen: set[str] = set()
        joint_names: set[str] = set()
        for i, part in enumerate(self.parts):
            at = f"{where}, part {part.name!r}"
            if part.name in seen:
                raise ObjectError(f"{at}: duplicate part name")
            if i == 0 and (part.parent is not None or part.joint is not None):
                raise ObjectError(f"{at}: the base (first part) has no parent and no joint")
            if i > 0:
                if part.parent not in seen:
                    raise ObjectError(f"{at}: parent {part.parent!r} must be an earlier part")
                if part.joint is None:
                    raise ObjectError(f"{at}: a moving part needs a joint")
                _check_joint(part.joint, f"{at}, joint {part.joint.name!r}")
                if part.joint.name in joint_names:
                    raise ObjectError(f"{at}: duplicate joint name {part.joint.name!r}")
                joint_names.add(part.joint.name)
            seen.add(part.name)
            _check_finite(part.pos, 3, f"{at}.pos")
            _check_quat(part.quat, f"{at}.quat")
            if not part.geoms:
                raise ObjectError(f"{at}: needs at least one collision geom")
            for g in part.geoms:
                _check_geom(g, f"{at}, geom {g.name!r}", self.meshes)
            if part.visual is not None and part.visual not in self.meshes:
                raise ObjectError(f"{at}.visual: no mesh named {part.visual!r}")
        if self.operated_joint is not None and self.operated_joint not in joint_names:
            raise ObjectError(f"{where}.operated_joint: {self.operated_joint!r} is not one of {sorted(joint_names)}")
        _check_finite(self.grasp, 3, f"{where}.grasp")
        if not math.isfinite(self.grasp_yaw):
            raise ObjectError(f"{where}.grasp_yaw: must be a finite angle in rad, got {self.grasp_yaw!r}")
        fingers: set[str] = set()
        for i, r in enumerate(self.grasp_regions):
            at = f"{where}.grasp_regions[{i}]"
            if r.finger not in FINGERS or r.finger in fingers:
                raise ObjectError(f"{at}.finger: must be one of {FINGERS}, each at most once, got {r.finger!r}")
            fingers.add(r.finger)
            if r.part not in seen:
                raise ObjectError(f"{at}.part: {r.part!r} is not a part of the object; its parts: {sorted(seen)}")
            for field in ("point", "normal", "spread"):
                _check_finite(getattr(r, field), 3, f"{at}.{field}")
            if np.linalg.norm(r.normal) < 1e-9 or min(r.spread) < 0:
                raise ObjectError(f"{at}: the normal must be non-zero and the spread >= 0")
            if r.squeeze is not None and not (math.isfinite(r.squeeze) and abs(r.squeeze) < 0.01):
                raise ObjectError(f"{at}.squeeze: must be None or a depth under 1 cm (m), got {r.squeeze!r}")

    # ------------------------------------------------------------------------------------------- MJCF
    def mjcf(self, mesh_dir: str | Path, pos: Vec3 = (0.0, 0.0, 0.0), quat: Quat = IDENTITY) -> tuple[str, str]:
        """``(assets, body)``: the ``<asset>`` children (mesh files, written into ``mesh_dir`` as OBJ) and the
        ``<body name="object">`` subtree, the base placed at ``pos``/``quat`` in the world."""
        mesh_dir = Path(mesh_dir)
        mesh_dir.mkdir(parents=True, exist_ok=True)
        assets = []
        for name, mesh in self.meshes.items():
            path = mesh_dir / f"{self.name}_{name}.obj"
            # atomically: runs that build the same scene side by side (a sweep's seeds) rewrite these files
            # while another one's MuJoCo compiler may be reading them
            text = mesh.export(file_type="obj")
            atomic_write(path, lambda f, text=text: f.write(text.encode()))
            assets.append(f'    <mesh name="{self.name}_{name}" file="{path.resolve()}"/>\n')
        children: dict[str | None, list[Part]] = {}
        for part in self.parts[1:]:
            children.setdefault(part.parent, []).append(part)

        def body(part: Part, indent: str) -> str:
            name = "object" if part is self.parts[0] else f"{SCENE_PREFIX}{part.name}"
            place = (pos, quat) if part is self.parts[0] else (part.pos, part.quat)
            out = [f'{indent}<body name="{name}" pos="{_v(place[0])}" quat="{_v(place[1])}">\n']
            if part is self.parts[0] and self.base == "free":
                out.append(f'{indent}  <freejoint name="object_free"/>\n')
            if part.joint is not None:
                j = part.joint
                out.append(
                    f'{indent}  <joint name="{SCENE_PREFIX}{j.name}" type="{j.kind}" axis="{_v(j.axis)}" pos="{_v(j.anchor)}" '
                    f'limited="true" range="{_v(j.range)}" stiffness="{_n(j.stiffness)}" springref="{_n(j.rest)}" '
                    f'damping="{_n(j.damping)}" frictionloss="{_n(j.friction)}" armature="{_n(j.armature)}"/>\n')
            for g in part.geoms:
                out.append(f'{indent}  {_geom_xml(g, f"{name}/{g.name}", self.name)}\n')
            if part.visual is not None:
                out.append(f'{indent}  <geom name="{name}/visual" type="mesh" mesh="{self.name}_{part.visual}" '
                           f'contype="0" conaffinity="0" group="1" mass="0" rgba="{_v(part.geoms[0].rgba)}"/>\n')
            for child in children.get(part.name, []):
                out.append(body(child, indent + "  "))
            out.append(f"{indent}</body>\n")
            return "".join(out)

        return "".join(assets), body(self.parts[0], "    ")


def scene_joint_name(name: str) -> str:
    """An object joint's own name from its name in a scene (scenes written before the prefix: unchanged)."""
    return name[len(SCENE_PREFIX):] if name.startswith(SCENE_PREFIX) else name


def _n(x: float) -> str:
    return f"{float(x):.9g}"


def _v(v) -> str:
    return " ".join(_n(x) for x in v)


def _geom_xml(g: Geom, name: str, object_name: str) -> str:
    shape = f'type="mesh" mesh="{object_name}_{g.mesh}"' if g.kind == "mesh" else f'type="{g.kind}" size="{_v(g.size)}"'
    return (f'<geom name="{name}" {shape} pos="{_v(g.pos)}" quat="{_v(g.quat)}" mass="{_n(g.mass)}" '
            f'contype="2" conaffinity="1" rgba="{_v(g.rgba)}"/>')


SIZE_COUNT = {"box": 3, "capsule": 2, "cylinder": 2, "sphere": 1, "mesh": 0}


def _check_finite(v, n: int, field: str) -> None:
    a = np.asarray(v, dtype=float)
    if a.shape != (n,) or not np.isfinite(a).all():
        raise ObjectError(f"{field}: expected {n} finite numbers, got {v!r}")


def _check_quat(q, field: str) -> None:
    _check_finite(q, 4, field)
    if abs(math.sqrt(sum(x * x for x in q)) - 1.0) > 1e-6:
        raise ObjectError(f"{field}: must be a unit quaternion (w, x, y, z), got {q!r}")


def _check_geom(g: Geom, at: str, meshes: dict) -> None:
    if g.kind not in GEOM_KINDS:
        raise ObjectError(f"{at}.kind: must be one of {GEOM_KINDS}, got {g.kind!r}")
    if g.kind == "mesh":
        if g.mesh not in meshes:
            raise ObjectError(f"{at}.mesh: no mesh named {g.mesh!r}")
        if not meshes[g.mesh].is_watertight:
            raise ObjectError(f"{at}.mesh: mesh {g.mesh!r} is not watertight (its signed distance is undefined)")
    else:
        _check_finite(g.size, SIZE_COUNT[g.kind], f"{at}.size")
        if min(g.size) <= 0:
            raise ObjectError(f"{at}.size: sizes must be positive, got {g.size!r}")
    _check_finite(g.pos, 3, f"{at}.pos")
    _check_quat(g.quat, f"{at}.quat")
    if not (math.isfinite(g.mass) and g.mass > 0):
        raise ObjectError(f"{at}.mass: must be a positive mass in kg, got {g.mass!r}")


def _check_joint(j: Joint, at: str) -> None:
    if j.kind not in ("hinge", "slide"):
        raise ObjectError(f"{at}.kind: must be 'hinge' or 'slide', got {j.kind!r}")
    _check_finite(j.axis, 3, f"{at}.axis")
    if np.linalg.norm(j.axis) < 1e-9:
        raise ObjectError(f"{at}.axis: must be non-zero")
    _check_finite(j.anchor, 3, f"{at}.anchor")
    lo, hi = j.range
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ObjectError(f"{at}.range: must be finite with lower < upper, got {j.range!r}")
    for field in ("stiffness", "damping", "friction", "armature"):
        value = getattr(j, field)
        if not (math.isfinite(value) and value >= 0):
            raise ObjectError(f"{at}.{field}: must be finite and >= 0, got {value!r}")
    if not math.isfinite(j.rest):
        raise ObjectError(f"{at}.rest: must be finite, got {j.rest!r}")
