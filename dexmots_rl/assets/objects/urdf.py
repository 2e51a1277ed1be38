"""Load a PartNet-Mobility-style URDF (``<folder>/mobility.urdf`` with OBJ pieces) into an :class:`ObjectAsset`.

MuJoCo reads the URDF (``mujoco.MjSpec.from_string``, with ``<mujoco><compiler discardvisual="false"
fusestatic="false" strippath="false" meshdir="<folder>"/></mujoco>`` set so that visual geoms, fixed links and
mesh paths relative to the file survive); trimesh loads the meshes. What the loader adds:

* **Parts.** The root link and every link hanging from it on ``fixed`` joints form the base; every link on a
  ``revolute``, ``continuous`` or ``prismatic`` joint starts a moving part, and links fixed below it merge into
  it. A ``continuous`` joint gets the range :data:`CONTINUOUS_RANGE` (one turn, -pi..pi: the description
  needs limits). A ``revolute``/``prismatic`` joint with ``lower == upper`` is welded. At most
  :data:`MAX_MOVING_PARTS` parts move: the operated joint and then the others in the file's order are kept; any
  further joint is welded at position 0 (clamped into its range) and a warning names them.
* **Scale.** PartNet-Mobility objects are roughly unit-normalised: the object is scaled so that the longest
  side of its bounding box (all parts at joint position 0) is ``size`` m (default :data:`DEFAULT_SIZE`, a tool
  in an Allegro hand), or by the factor ``scale``. Prismatic ranges scale with it.
* **Frames.** The base frame is the URDF root frame (axes kept), moved so that its origin is the bottom centre
  of the bounding box: z = 0 is the table under the object. ``params`` records ``scale``, ``size`` and
  ``urdf_origin_x/y/z`` (the root frame's origin in the base frame): a point p of the URDF maps to
  ``urdf_origin + scale * p``.
* **Geometry** (see :mod:`.mesh_fit`): collision is at most ``max_geoms_per_part`` oriented boxes per part
  fitted to the ``<collision>`` pieces (``<visual>`` ones when a link has none), or with ``collision="hull"``
  the convex hull of those pieces as one watertight mesh (a signed distance); the part is drawn as the union
  of the convex hulls of its ``<visual>`` pieces' connected components. A part without any mesh gets a sphere of
  :data:`PIVOT_RADIUS` at its joint (the base: at its first child's joint).
* **Physics.** PartNet has no usable masses: each box (or hull) weighs ``density`` times its volume (boxes'
  overlaps count twice); ``<inertial>`` is ignored. Joints have no spring; damping and friction come from
  ``<dynamics damping friction>`` when present, else :data:`HINGE_DEFAULTS` / :data:`SLIDE_DEFAULTS`, in SI
  units of the scaled object, the friction raised to :data:`HOLD_MARGIN` times the largest pull of gravity on
  the part (and the parts it carries) about its joint: a lid, door or handle without a spring stays where it is
  put, as real ones do (the data set has no friction), instead of falling and rocking the object. ``<limit effort velocity>`` and ``<mimic>`` are ignored.

A bad file raises one :class:`UrdfError` naming the file and the element; nothing is written to disk. Bad
files include magnitudes no object has (:mod:`.urdf_check`'s bounds; a scaled size outside :data:`SIZE_RANGE`;
a slide longer than :data:`MAX_SLIDE_TRAVEL` times the object), meshes without area or with non-finite
vertices, and a file without a moving joint (nothing to operate).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import math
import re
from pathlib import Path

import mujoco
import numpy as np
import trimesh

from . import mesh_fit
from .description import MAX_MOVING_PARTS, Geom, Joint, ObjectAsset, ObjectError, Part
from .urdf_check import MAX_COORDINATE, UrdfError, UrdfJoint, check_urdf

__all__ = ["load_urdf", "UrdfError", "DEFAULT_SIZE", "DEFAULT_DENSITY", "CONTINUOUS_RANGE", "HINGE_DEFAULTS",
           "SLIDE_DEFAULTS", "PIVOT_RADIUS", "MIN_HALF_EXTENT", "SIZE_RANGE", "MAX_SLIDE_TRAVEL",
           "DENSITY_RANGE", "HOLD_MARGIN"]

log = logging.getLogger(__name__)

DEFAULT_SIZE = 0.18  # m, longest side: a hand-held tool for the Allegro hand (it spans about 0.2 m)
DEFAULT_DENSITY = 500.0  # kg/m^3: boxes are solid where real tools are hollow shells of denser plastic
CONTINUOUS_RANGE = (-math.pi, math.pi)
HINGE_DEFAULTS = {"damping": 0.01, "friction": 0.002}  # N m s/rad, N m: a lid or lever that stays where put
SLIDE_DEFAULTS = {"damping": 0.5, "friction": 0.02}  # N s/m, N: a drawer that glides, then stops
PIVOT_RADIUS = 0.005  # m
MIN_HALF_EXTENT = 0.001  # m: flat pieces become 2 mm thick boxes
SIZE_RANGE = (0.01, 1.0)  # m, the scaled object's longest side: a button to a cabinet on the hand's table
MAX_SLIDE_TRAVEL = 2.0  # a slide's limits, in units of the object's longest side
DENSITY_RANGE = (10.0, 2.0e4)  # kg/m^3: foam to lead
HOLD_MARGIN = 1.5  # default joint friction over the largest gravity torque (or force) on the part
GRAVITY = 9.81  # m/s^2
_PALETTE = ((0.62, 0.62, 0.66, 1.0), (0.85, 0.45, 0.2, 1.0), (0.25, 0.55, 0.85, 1.0), (0.35, 0.7, 0.35, 1.0),
            (0.8, 0.75, 0.3, 1.0))


def load_urdf(path: str | Path, *, scale: float | None = None, size: float | None = None,
              density: float = DEFAULT_DENSITY, base: str = "free", operated_joint: str | None = None,
              max_geoms_per_part: int = 4, collision: str = "boxes") -> ObjectAsset:
    """Read a URDF with revolute, continuous, prismatic and fixed joints into an :class:`ObjectAsset`.

    ``scale`` (a factor) or ``size`` (the longest bounding-box side in m; default :data:`DEFAULT_SIZE`) sizes
    it; ``density`` (kg/m^3) gives the masses; ``base``: ``"free"`` (on the table) or ``"fixed"``;
    ``operated_joint``: a URDF joint name (default: the first moving joint in the file); ``collision``:
    ``"boxes"`` (at most ``max_geoms_per_part`` oriented boxes per part) or ``"hull"`` (one watertight mesh
    per part, its convex hull, collided through its signed distance). See the module docstring for the
    approximations."""
    path = Path(path)
    _check_arguments(scale, size, density, base, max_geoms_per_part, collision)
    tree = check_urdf(path)
    where = str(path)
    try:
        with _mujoco_warnings_logged(where):
            spec = mujoco.MjSpec.from_string(tree.mujoco_xml)
    except Exception as error:  # noqa: BLE001 - MuJoCo raises plain ValueError/Exception with its parser's text
        raise UrdfError(f"{where}: MuJoCo cannot read it: {error}") from None

    kept, welded = _choose_moving(where, tree.joints, operated_joint)
    bodies = _bodies(spec.worldbody)
    layout = _Layout(tree.root_link, tree.joints, kept, welded, bodies)
    drawn, collided = _load_pieces(where, spec, layout, bodies, tree.meshdir)

    in_root = [trimesh.transform_points(m.vertices, layout.root_pose[part])
               for part in layout.parts for m in (drawn[part] or collided[part])]
    if not in_root:
        raise UrdfError(f"{where}: no link has <visual> or <collision> geometry")
    corners = np.concatenate(in_root)
    low, high = corners.min(axis=0), corners.max(axis=0)
    longest = float(np.max(high - low))
    if not longest > 0:
        raise UrdfError(f"{where}: the geometry has no extent (all vertices coincide)")
    factor = float(scale) if scale is not None else (size if size is not None else DEFAULT_SIZE) / longest
    if not SIZE_RANGE[0] <= factor * longest <= SIZE_RANGE[1]:
        given = f"scale {scale!r}" if scale is not None else f"size {size!r}"
        raise UrdfError(f"{where}: {given} makes the object {factor * longest:.3g} m long; its longest side must be "
                        f"within {SIZE_RANGE} m")
    for j in tree.joints.values():
        if j.type == "prismatic" and max(abs(j.lower), abs(j.upper)) > MAX_SLIDE_TRAVEL * longest:
            raise UrdfError(f"{where}: joint {j.name!r} <limit>: ({j.lower:g}, {j.upper:g}) slides farther than "
                            f"{MAX_SLIDE_TRAVEL:g} times the object's size ({longest:.3g} in the file's units)")
    origin = -factor * np.array([(low[0] + high[0]) / 2, (low[1] + high[1]) / 2, low[2]])

    operated = (tree.joint_named(operated_joint) if operated_joint is not None else
                next((j for j in tree.joints.values() if j.child in kept), None))
    grasp = _grasp(layout, operated.child if operated else layout.parts[0], drawn, collided, origin, factor)
    parts, meshes = [], {}
    for index, name in enumerate(layout.parts):
        shift = origin if index == 0 else np.zeros(3)
        for piece in drawn[name] + collided[name]:
            piece.apply_scale(factor)
            piece.apply_translation(shift)
        rgba = _PALETTE[index % len(_PALETTE)]
        if collision == "hull" and collided[name]:
            meshes[_safe(name) + "_hull"] = hull = mesh_fit.convex_hull(collided[name], MIN_HALF_EXTENT)
            geoms = [Geom("hull", "mesh", mesh=_safe(name) + "_hull", mass=density * hull.volume, rgba=rgba)]
        else:
            up = layout.root_pose[name][:3, :3].T @ np.array([0.0, 0.0, 1.0])  # the table's normal, part frame
            geoms = _box_geoms(collided[name], max_geoms_per_part, density, rgba, up)
            if index == 0 and geoms:  # flat pieces thickened below the table: the object stands on its boxes
                lift = -min(_lowest(g) for g in geoms)
                if lift > 0:
                    geoms = [dataclasses.replace(g, pos=_vec(np.add(g.pos, (0.0, 0.0, lift)))) for g in geoms]
                    for piece in drawn[name]:
                        piece.apply_translation((0.0, 0.0, lift))
                    origin, grasp = origin + (0.0, 0.0, lift), grasp + np.array((0.0, 0.0, lift))
        if not geoms:
            pivot = (np.zeros(3) if index > 0 else
                     next((factor * layout.pose_in_parent[c][:3, 3] + origin for c in layout.parts[1:]
                           if layout.parent_part[c] == name), origin))
            geoms = [Geom("pivot", "sphere", (PIVOT_RADIUS,), pos=_vec(pivot),
                          mass=density * 4 / 3 * math.pi * PIVOT_RADIUS ** 3, rgba=rgba)]
        visual = None
        if drawn[name]:
            visual = _safe(name) + "_visual"
            meshes[visual] = mesh_fit.hull_mesh(drawn[name], MIN_HALF_EXTENT)
        if index == 0:
            parts.append(Part(_safe(name), tuple(geoms), visual=visual))
            continue
        pose = layout.pose_in_parent[name]
        parent = layout.parent_part[name]
        pos = factor * pose[:3, 3] + (origin if parent == layout.parts[0] else 0.0)
        joint = _joint(spec.body(name).joints[0], tree.joints[name], factor)
        parts.append(Part(_safe(name), tuple(geoms), parent=_safe(parent), joint=joint, pos=_vec(pos),
                          quat=_quat(pose[:3, :3]), visual=visual))

    folder = path.parent
    object_class, labels = _read_metadata(folder)
    name = _safe(folder.name if path.name == "mobility.urdf" and folder.name else path.stem)
    described = ", ".join(f"{p}" + (f" ({labels[p]})" if p in labels else "") for p in layout.parts)
    try:
        return _held_against_gravity(ObjectAsset(
            name=name, object_class=object_class, parts=tuple(parts), base=base,
            operated_joint=_safe(operated.name) if operated else None, grasp=_vec(grasp),
            params={"scale": factor, "size": factor * longest, "density": float(density),
                    "urdf_origin_x": float(origin[0]), "urdf_origin_y": float(origin[1]),
                    "urdf_origin_z": float(origin[2])},
            meshes=meshes,
            description=f"{object_class} loaded from {path} (parts: {described}; scale {factor:.4g})"),
            {_safe(j.name) for j in tree.joints.values() if j.friction is not None})
    except ObjectError as error:  # e.g. two link names that differ only in characters MJCF names cannot hold
        raise UrdfError(f"{where}: {error}") from None


def _held_against_gravity(asset: ObjectAsset, given: set[str]) -> ObjectAsset:
    """``asset`` with the friction of every joint not in ``given`` (those with a file's value) raised to
    :data:`HOLD_MARGIN` times the largest gravity torque about a hinge (over a turn) or force along a slide on
    the part and the parts below it, at rest."""
    from .scene import part_transforms

    world = part_transforms(asset)
    mass, centre = {}, {}
    for part in asset.parts:
        rotation, shift = world[part.name][:3, :3], world[part.name][:3, 3]
        points = [asset.meshes[g.mesh].center_mass if g.kind == "mesh" else np.asarray(g.pos) for g in part.geoms]
        weights = np.array([g.mass for g in part.geoms])
        mass[part.name] = weights.sum()
        centre[part.name] = rotation @ (weights @ np.array(points) / weights.sum()) + shift
    carried = {p.name: [p.name] for p in asset.parts}
    for part in reversed(asset.parts[1:]):  # children come after their parents
        carried[part.parent] += carried[part.name]
    parts = [asset.parts[0]]
    for part in asset.parts[1:]:
        joint = part.joint
        if joint.name not in given:
            total = sum(mass[p] for p in carried[part.name])
            com = sum(mass[p] * centre[p] for p in carried[part.name]) / total
            axis = world[part.name][:3, :3] @ np.asarray(joint.axis)
            if joint.kind == "slide":
                pull = total * GRAVITY * abs(axis[2])
            else:
                arm = com - (world[part.name] @ np.append(joint.anchor, 1.0))[:3]
                arm = arm - (arm @ axis) * axis
                pull = total * GRAVITY * float(np.linalg.norm(arm)) * math.sqrt(max(0.0, 1.0 - axis[2] ** 2))
            joint = dataclasses.replace(joint, friction=float(max(joint.friction, HOLD_MARGIN * pull)))
        parts.append(dataclasses.replace(part, joint=joint))
    return dataclasses.replace(asset, parts=tuple(parts))


@contextlib.contextmanager
def _mujoco_warnings_logged(where: str):
    """Route MuJoCo's warnings (e.g. 'equal lower and upper limits') to the log: by default MuJoCo appends
    them to MUJOCO_LOG.TXT in the working directory, and loading must write no file. The handler is
    process-wide, so it is restored right after."""
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(lambda message: log.info("%s: MuJoCo: %s", where, message))
    try:
        yield
    finally:
        mujoco.set_mju_user_warning(previous)


def _check_arguments(scale, size, density, base, max_geoms_per_part, collision) -> None:
    if scale is not None and size is not None:
        raise ObjectError("load_urdf: give scale or size, not both")
    for field, value in (("scale", scale), ("size", size), ("density", density)):
        if value is not None and not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise ObjectError(f"load_urdf: {field} must be a positive number, got {value!r}")
    if size is not None and not SIZE_RANGE[0] <= size <= SIZE_RANGE[1]:
        raise ObjectError(f"load_urdf: size must be within {SIZE_RANGE} m (the object's longest side), got {size!r}")
    if not DENSITY_RANGE[0] <= density <= DENSITY_RANGE[1]:
        raise ObjectError(f"load_urdf: density must be within {DENSITY_RANGE} kg/m^3, got {density!r}")
    if base not in ("free", "fixed"):
        raise ObjectError(f"load_urdf: base must be 'free' or 'fixed', got {base!r}")
    if not (isinstance(max_geoms_per_part, int) and max_geoms_per_part >= 1):
        raise ObjectError(f"load_urdf: max_geoms_per_part must be an integer >= 1, got {max_geoms_per_part!r}")
    if collision not in ("boxes", "hull"):
        raise ObjectError(f"load_urdf: collision must be 'boxes' or 'hull', got {collision!r}")


def _choose_moving(where: str, joints: dict[str, UrdfJoint], operated: str | None) -> tuple[set, dict]:
    """The child links that move (at most MAX_MOVING_PARTS) and the welded ones with their weld position."""
    movable = [j for j in joints.values() if j.type != "fixed"]
    welded = {j.child: j.lower for j in movable if j.type != "continuous" and j.lower == j.upper}
    for j in movable:
        if j.child in welded:
            log.warning("%s: joint %r has lower == upper (%g): welded", where, j.name, j.lower)
    candidates = [j for j in movable if j.child not in welded]
    if not candidates:
        raise UrdfError(f"{where}: no moving joint (every joint is fixed, or a revolute/prismatic one with "
                        f"lower == upper): there is nothing to operate; joints: {[j.name for j in joints.values()]}")
    if operated is not None:
        chosen = [j for j in candidates if j.name == operated]
        if not chosen:
            raise UrdfError(f"{where}: operated_joint {operated!r} is not a moving joint of the file; "
                            f"its moving joints: {[j.name for j in candidates]}")
        candidates = chosen + [j for j in candidates if j.name != operated]
    kept = candidates[:MAX_MOVING_PARTS]
    extra = candidates[MAX_MOVING_PARTS:]
    if extra:
        log.warning("%s: %d moving joints, at most %d are simulated: %s welded at position 0 (within range)",
                    where, len(candidates), MAX_MOVING_PARTS, [j.name for j in extra])
    for j in extra:
        welded[j.child] = 0.0 if j.type == "continuous" else min(max(0.0, j.lower), j.upper)
    return {j.child for j in kept}, welded


def _bodies(worldbody) -> dict:
    out = {}
    stack = list(worldbody.bodies)
    while stack:
        body = stack.pop()
        out[body.name] = body
        stack.extend(body.bodies)
    return out


class _Layout:
    """Which part each link belongs to, the link's frame in its part's, and each moving part's pose."""

    def __init__(self, root: str, joints: dict[str, UrdfJoint], kept: set, welded: dict, bodies: dict):
        self.parts: list[str] = []
        self.part_of: dict[str, str] = {}
        self.link_in_part: dict[str, np.ndarray] = {}
        self.pose_in_parent: dict[str, np.ndarray] = {}
        self.parent_part: dict[str, str] = {}
        self.root_pose: dict[str, np.ndarray] = {}
        children: dict[str, list[str]] = {}
        for joint in joints.values():
            children.setdefault(joint.parent, []).append(joint.child)
        stack = [root]
        while stack:  # depth first in the file's order: a parent is always placed before its children
            link = stack.pop()
            stack.extend(reversed(children.get(link, [])))
            if link == root or link in kept:
                self.parts.append(link)
                self.part_of[link] = link
                self.link_in_part[link] = np.eye(4)
                if link != root:
                    parent = joints[link].parent
                    self.parent_part[link] = self.part_of[parent]
                    self.pose_in_parent[link] = self.link_in_part[parent] @ _pose(bodies[link])
                    self.root_pose[link] = self.root_pose[self.part_of[parent]] @ self.pose_in_parent[link]
                else:
                    self.root_pose[link] = np.eye(4)
                continue
            parent = joints[link].parent
            self.part_of[link] = self.part_of[parent]
            motion = _motion(bodies[link].joints[0], welded[link]) if link in welded else np.eye(4)
            self.link_in_part[link] = self.link_in_part[parent] @ _pose(bodies[link]) @ motion


def _load_pieces(where: str, spec, layout: _Layout, bodies: dict, meshdir: Path):
    """Per part, its drawn and its collision pieces, in the part's frame and the URDF's (unscaled) units."""
    cache: dict[tuple, trimesh.Trimesh] = {}
    drawn = {p: [] for p in layout.parts}
    collided = {p: [] for p in layout.parts}
    own_visual = {p: [] for p in layout.parts}
    own_collision = {p: [] for p in layout.parts}
    for link, part in layout.part_of.items():
        for geom in bodies[link].geoms:
            is_visual = geom.contype == 0 and geom.conaffinity == 0
            element = f"link {link!r} <{'visual' if is_visual else 'collision'}>"
            mesh = _geom_mesh(where, element, spec, geom, meshdir, cache)
            mesh.apply_transform(layout.root_pose[part] @ layout.link_in_part[link] @ _pose(geom))
            (own_visual if is_visual else own_collision)[part].append(mesh)
    for part in layout.parts:  # pieces in the part frame: undo the part's pose in the root frame
        to_part = np.linalg.inv(layout.root_pose[part])
        for source, target in ((own_visual, drawn), (own_collision, collided)):
            for mesh in source[part]:
                mesh.apply_transform(to_part)
                target[part].append(mesh)
        if not drawn[part]:
            drawn[part] = [m.copy() for m in collided[part]]
        if not collided[part]:
            collided[part] = [m.copy() for m in drawn[part]]
    return drawn, collided


def _geom_mesh(where, element, spec, geom, meshdir: Path, cache: dict) -> trimesh.Trimesh:
    kind, size = geom.type, np.asarray(geom.size, dtype=float)
    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        return trimesh.creation.box(extents=2 * size[:3])
    if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        return trimesh.creation.icosphere(radius=size[0], subdivisions=3)
    if kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
        return trimesh.creation.cylinder(radius=size[0], height=2 * size[1], sections=64)
    if kind != mujoco.mjtGeom.mjGEOM_MESH:
        raise UrdfError(f"{where}: {element}: unsupported geometry (MuJoCo geom type {kind})")
    asset = spec.mesh(geom.meshname)
    file = Path(asset.file) if Path(asset.file).is_absolute() else meshdir / asset.file
    key = (str(file), tuple(np.asarray(asset.scale, dtype=float)))
    if key not in cache:
        try:
            loaded = trimesh.load(str(file), force="mesh", skip_materials=True)
        except Exception as error:  # noqa: BLE001 - trimesh raises many kinds for broken files
            raise UrdfError(f"{where}: {element} mesh {asset.file!r}: cannot be read ({error})") from None
        if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
            raise UrdfError(f"{where}: {element} mesh {asset.file!r}: has no triangles")
        loaded.apply_transform(np.diag([*np.asarray(asset.scale, dtype=float), 1.0]))
        if not np.isfinite(loaded.vertices).all() or np.abs(loaded.vertices).max() > MAX_COORDINATE:
            raise UrdfError(f"{where}: {element} mesh {asset.file!r}: vertices must be finite and within "
                            f"{MAX_COORDINATE:g} of the link's origin")
        if not loaded.area > 0:
            raise UrdfError(f"{where}: {element} mesh {asset.file!r}: degenerate (its triangles have no area)")
        cache[key] = loaded
    return cache[key].copy()


def _box_geoms(pieces, max_boxes: int, density: float, rgba, up) -> list[Geom]:
    geoms = []
    for i, (half, centre, rotation) in enumerate(mesh_fit.fit_boxes(pieces, max_boxes, MIN_HALF_EXTENT, up)):
        geoms.append(Geom(f"box{i}", "box", _vec(half), pos=_vec(centre), quat=_quat(rotation),
                          mass=density * 8.0 * float(np.prod(half)), rgba=rgba))
    return geoms


def _lowest(geom: Geom) -> float:
    """The lowest z of a box geom's corners in its part's frame."""
    rotation = np.zeros(9)
    mujoco.mju_quat2Mat(rotation, np.asarray(geom.quat, dtype=float))
    return float(geom.pos[2] - np.abs(rotation.reshape(3, 3)[2]) @ np.asarray(geom.size))


def _joint(spec_joint, urdf: UrdfJoint, factor: float) -> Joint:
    kind = "slide" if urdf.type == "prismatic" else "hinge"
    defaults = SLIDE_DEFAULTS if kind == "slide" else HINGE_DEFAULTS
    if urdf.type == "continuous":
        limits = CONTINUOUS_RANGE
    else:
        limits = (urdf.lower * factor, urdf.upper * factor) if kind == "slide" else (urdf.lower, urdf.upper)
    axis = np.asarray(spec_joint.axis, dtype=float)
    return Joint(_safe(urdf.name), kind, _vec(axis / np.linalg.norm(axis)), limits,
                 anchor=_vec(factor * np.asarray(spec_joint.pos, dtype=float)),
                 damping=urdf.damping if urdf.damping is not None else defaults["damping"],
                 friction=urdf.friction if urdf.friction is not None else defaults["friction"])


def _grasp(layout: _Layout, part: str, drawn, collided, origin: np.ndarray, factor: float) -> np.ndarray:
    """The centre of ``part``'s bounding box at joint 0, in the base frame (pieces still unscaled)."""
    pieces = drawn[part] or collided[part]
    if not pieces:
        return origin + factor * layout.root_pose[part][:3, 3]
    corners = np.array([m.bounds for m in pieces]).reshape(-1, 3)
    centre = np.append((corners.min(axis=0) + corners.max(axis=0)) / 2, 1.0)
    return origin + factor * (layout.root_pose[part] @ centre)[:3]


def _read_metadata(folder: Path) -> tuple[str, dict[str, str]]:
    """The object class from ``meta.json`` (``model_cat``) and link labels from ``semantics.txt``."""
    object_class, labels = "urdf", {}
    meta = folder / "meta.json"
    if meta.is_file():
        try:
            category = json.loads(meta.read_text()).get("model_cat")
        except (json.JSONDecodeError, UnicodeDecodeError, AttributeError) as error:
            raise UrdfError(f"{meta}: not a JSON object ({error})") from None
        if isinstance(category, str) and category.strip():
            object_class = _safe(category.strip().lower().replace(" ", "_"))
    semantics = folder / "semantics.txt"
    if semantics.is_file():
        for line in semantics.read_text(errors="replace").splitlines():
            fields = line.split()
            if len(fields) >= 3:
                labels[fields[0]] = f"{' '.join(fields[2:])}, {fields[1]}"
    return object_class, labels


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", name)


def _vec(v) -> tuple[float, ...]:
    return tuple(float(x) for x in v)


def _quat(rotation: np.ndarray) -> tuple[float, float, float, float]:
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(rotation, dtype=float).reshape(9))
    return _vec(q / np.linalg.norm(q))


def _pose(element) -> np.ndarray:
    """The 4x4 pose of a MuJoCo spec body or geom (pos, quat) in its parent's frame."""
    transform = np.eye(4)
    rotation = np.zeros(9)
    quat = np.asarray(element.quat, dtype=float)
    mujoco.mju_quat2Mat(rotation, quat / np.linalg.norm(quat))
    transform[:3, :3] = rotation.reshape(3, 3)
    transform[:3, 3] = element.pos
    return transform


def _motion(joint, position: float) -> np.ndarray:
    """The child's displacement by a hinge (about its axis through its anchor) or a slide at ``position``."""
    axis = np.asarray(joint.axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    transform = np.eye(4)
    if joint.type == mujoco.mjtJoint.mjJNT_SLIDE:
        transform[:3, 3] = position * axis
        return transform
    quat, rotation = np.zeros(4), np.zeros(9)
    mujoco.mju_axisAngle2Quat(quat, axis, position)
    mujoco.mju_quat2Mat(rotation, quat)
    anchor = np.asarray(joint.pos, dtype=float)
    transform[:3, :3] = rotation.reshape(3, 3)
    transform[:3, 3] = anchor - transform[:3, :3] @ anchor
    return transform
