"""Checks of a URDF file before MuJoCo reads it, so that a bad file fails with its name and the bad element.

MuJoCo's URDF reader accepts some files that cannot become an object (a ``floating`` or ``planar`` joint, a
limit with lower > upper, a second parent) and reports others without the element; these checks run first and
raise :class:`UrdfError` naming the file and the element. They also prepare the text MuJoCo reads: the
``<mujoco><compiler .../></mujoco>`` element that keeps visual geoms, keeps fixed links as bodies and resolves
mesh paths relative to the file (or to the file's own ``meshdir``).
"""

from __future__ import annotations

import dataclasses
import math
import xml.etree.ElementTree as ET
from pathlib import Path

from .description import ObjectError

__all__ = ["UrdfError", "UrdfJoint", "CheckedUrdf", "check_urdf", "JOINT_TYPES", "MAX_COORDINATE", "MAX_HINGE_LIMIT",
           "MAX_DYNAMICS"]

JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed")
# Magnitudes beyond these are typing errors, not objects: in float32 they leave no digits for a step's motion.
MAX_COORDINATE = 1.0e3  # m: an origin, a slide's limit, a mesh scale factor (the file's units, before scaling)
MAX_HINGE_LIMIT = 4.0 * math.pi  # rad: two turns either way (a screw cap's thread)
# <dynamics> values, in SI units of the scaled object: N m s/rad and N m (a hinge), N s/m and N (a slide);
# a hand's finger gives about 0.5 N m or 5 N, so larger values hold a part still for any hand
MAX_DYNAMICS = {("revolute", "damping"): 10.0, ("revolute", "friction"): 10.0,
                ("prismatic", "damping"): 1.0e3, ("prismatic", "friction"): 1.0e2}
_GEOMETRIES = ("mesh", "box", "cylinder", "sphere")


class UrdfError(ObjectError):
    """A URDF file cannot be loaded (the message names the file and the element)."""


@dataclasses.dataclass(frozen=True)
class UrdfJoint:
    """A joint as the file gives it (``lower``/``upper``: None for fixed and continuous joints;
    ``damping``/``friction``: None when the file has no ``<dynamics>`` value)."""

    name: str
    type: str
    parent: str
    child: str
    lower: float | None = None
    upper: float | None = None
    damping: float | None = None
    friction: float | None = None


@dataclasses.dataclass(frozen=True)
class CheckedUrdf:
    root_link: str
    joints: dict[str, UrdfJoint]  # by child link, in the file's order
    meshdir: Path
    mujoco_xml: str

    def joint_named(self, name: str) -> UrdfJoint:
        return next(j for j in self.joints.values() if j.name == name)


def check_urdf(path: Path) -> CheckedUrdf:
    where = str(path)
    try:
        data = path.read_bytes()
    except OSError as error:
        raise UrdfError(f"{where}: cannot be read ({error.strerror or error})") from None
    try:
        robot = ET.fromstring(data)
    except ET.ParseError as error:
        raise UrdfError(f"{where}: not well-formed XML ({error})") from None
    if robot.tag != "robot":
        raise UrdfError(f"{where}: the root element is <{robot.tag}>, a URDF's is <robot>")

    meshdir = _meshdir(path, robot)
    links: list[str] = []
    for index, link in enumerate(robot.findall("link")):
        name = link.get("name")
        if not name:
            raise UrdfError(f"{where}: <link> number {index + 1} has no name")
        if name in links:
            raise UrdfError(f"{where}: link {name!r}: defined twice")
        links.append(name)
        for tag in ("visual", "collision"):
            for element in link.findall(tag):
                _check_geometry(where, f"link {name!r} <{tag}>", element, meshdir)
    if not links:
        raise UrdfError(f"{where}: no <link>")

    joints: dict[str, UrdfJoint] = {}
    names: set[str] = set()
    for index, element in enumerate(robot.findall("joint")):
        joint = _joint(where, index, element, set(links))
        if joint.name in names:
            raise UrdfError(f"{where}: joint {joint.name!r}: defined twice")
        if joint.child in joints:
            raise UrdfError(f"{where}: joint {joint.name!r}: link {joint.child!r} is already the child of joint "
                            f"{joints[joint.child].name!r} (a URDF is a tree)")
        names.add(joint.name)
        joints[joint.child] = joint
    roots = [link for link in links if link not in joints]
    reached = set(roots)
    frontier = list(roots)
    while frontier:
        link = frontier.pop()
        for joint in joints.values():
            if joint.parent == link and joint.child not in reached:
                reached.add(joint.child)
                frontier.append(joint.child)
    if len(reached) < len(links):
        cycle = [j.name for j in joints.values() if j.child not in reached]
        raise UrdfError(f"{where}: joints {cycle} form a cycle (links {sorted(set(links) - reached)} "
                        f"cannot be reached from a root link)")
    if len(roots) != 1:
        raise UrdfError(f"{where}: links {roots} have no parent joint; a URDF has exactly one root link")

    compiler = _compiler(robot)
    compiler.set("discardvisual", "false")
    compiler.set("fusestatic", "false")
    compiler.set("strippath", "false")
    compiler.set("meshdir", str(meshdir))
    return CheckedUrdf(roots[0], joints, meshdir, ET.tostring(robot, encoding="unicode"))


def _meshdir(path: Path, robot: ET.Element) -> Path:
    folder = path.resolve().parent
    compiler = robot.find("mujoco/compiler")
    given = compiler.get("meshdir") if compiler is not None else None
    return (folder / given).resolve() if given else folder


def _compiler(robot: ET.Element) -> ET.Element:
    mujoco = robot.find("mujoco")
    if mujoco is None:
        mujoco = ET.Element("mujoco")
        robot.insert(0, mujoco)
    compiler = mujoco.find("compiler")
    if compiler is None:
        compiler = ET.SubElement(mujoco, "compiler")
    return compiler


def _numbers(where: str, element: str, text: str | None, count: int, default: tuple,
             largest: float = math.inf) -> tuple:
    """``count`` finite numbers of magnitude at most ``largest`` from an attribute's text (``default`` if absent)."""
    if text is None:
        return default
    try:
        values = tuple(float(x) for x in text.split())
    except ValueError:
        values = ()
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise UrdfError(f"{where}: {element}: expected {count} finite numbers, got {text!r}")
    if any(abs(v) > largest for v in values):
        raise UrdfError(f"{where}: {element}: {text!r} is out of range (each at most {largest:g} in magnitude)")
    return values


def _check_origin(where: str, element: str, parent: ET.Element) -> None:
    origin = parent.find("origin")
    if origin is not None:
        _numbers(where, f"{element} <origin xyz>", origin.get("xyz"), 3, (0.0,) * 3, MAX_COORDINATE)
        _numbers(where, f"{element} <origin rpy>", origin.get("rpy"), 3, (0.0,) * 3, MAX_HINGE_LIMIT)


def _check_geometry(where: str, element: str, item: ET.Element, meshdir: Path) -> None:
    _check_origin(where, element, item)
    geometry = item.find("geometry")
    shapes = [child for child in geometry] if geometry is not None else []
    if len(shapes) != 1 or shapes[0].tag not in _GEOMETRIES:
        found = [child.tag for child in shapes]
        raise UrdfError(f"{where}: {element}: <geometry> must hold one of {list(_GEOMETRIES)}, found {found}")
    shape = shapes[0]
    if shape.tag != "mesh":
        return
    filename = shape.get("filename")
    if not filename:
        raise UrdfError(f"{where}: {element} <mesh>: no filename")
    scale = _numbers(where, f"{element} <mesh scale>", shape.get("scale"), 3, (1.0,) * 3, MAX_COORDINATE)
    if any(s == 0 for s in scale):
        raise UrdfError(f"{where}: {element} <mesh scale>: a zero scale flattens the mesh, got {scale}")
    file = Path(filename) if Path(filename).is_absolute() else meshdir / filename
    if not file.is_file():
        raise UrdfError(f"{where}: {element} <mesh filename={filename!r}>: no such file ({file})")


def _joint(where: str, index: int, element: ET.Element, links: set[str]) -> UrdfJoint:
    name = element.get("name")
    if not name:
        raise UrdfError(f"{where}: <joint> number {index + 1} has no name")
    at = f"joint {name!r}"
    kind = element.get("type")
    if kind not in JOINT_TYPES:
        raise UrdfError(f"{where}: {at}: joint type {kind!r} is not supported (supported: {list(JOINT_TYPES)})")
    ends = {}
    for end in ("parent", "child"):
        item = element.find(end)
        link = item.get("link") if item is not None else None
        if not link:
            raise UrdfError(f"{where}: {at}: no <{end} link=...>")
        if link not in links:
            raise UrdfError(f"{where}: {at}: <{end} link={link!r}> names no <link>")
        ends[end] = link
    if ends["parent"] == ends["child"]:
        raise UrdfError(f"{where}: {at}: link {ends['child']!r} is its own parent (a cycle)")
    _check_origin(where, at, element)
    if kind != "fixed":
        axis = _numbers(where, f"{at} <axis xyz>", element.find("axis").get("xyz") if element.find("axis")
                        is not None else None, 3, (1.0, 0.0, 0.0))
        if math.sqrt(sum(a * a for a in axis)) < 1e-9:
            raise UrdfError(f"{where}: {at} <axis xyz>: the axis is zero")
    lower = upper = None
    if kind in ("revolute", "prismatic"):
        limit = element.find("limit")
        if limit is None or limit.get("lower") is None or limit.get("upper") is None:
            raise UrdfError(f"{where}: {at}: a {kind} joint needs <limit lower=... upper=...>")
        largest = MAX_HINGE_LIMIT if kind == "revolute" else MAX_COORDINATE
        (lower,) = _numbers(where, f"{at} <limit lower>", limit.get("lower"), 1, (), largest)
        (upper,) = _numbers(where, f"{at} <limit upper>", limit.get("upper"), 1, (), largest)
        if lower > upper:
            raise UrdfError(f"{where}: {at}: <limit> lower {lower:g} > upper {upper:g}")
    damping = friction = None
    dynamics = element.find("dynamics")
    if dynamics is not None:
        for field in ("damping", "friction"):
            if dynamics.get(field) is not None:
                largest = MAX_DYNAMICS[("prismatic" if kind == "prismatic" else "revolute", field)]
                (value,) = _numbers(where, f"{at} <dynamics {field}>", dynamics.get(field), 1, (), largest)
                if value < 0:
                    raise UrdfError(f"{where}: {at} <dynamics {field}>: must be >= 0, got {value:g}")
                damping, friction = (value, friction) if field == "damping" else (damping, value)
    return UrdfJoint(name, kind, ends["parent"], ends["child"], lower, upper, damping, friction)
