"""What every generator shares: named parameters with documented ranges, seeded sampling, geom builders.

A generator's parameters are a frozen dataclass whose fields are declared with :func:`param` (default, range,
unit, what it is). :meth:`Params.sample` draws a variant around the values it is called on: lengths and masses
by a factor in [1 - scale, 1 + scale], the joint's spring, damping and friction by [1 - 3 scale, 1 + 3 scale]
(real tools vary more in feel than in size), counts uniformly over their range; every draw is clipped to the
field's range. :meth:`Params.validate` raises :class:`ObjectError` naming the first field outside its range.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal, Sequence

import numpy as np
import trimesh

from ..description import Geom, GraspRegion, ObjectError
from ..shapes import rotation_between

__all__ = ["param", "Params", "make_rng", "box_geom", "capsule_geom", "cylinder_geom", "sphere_geom",
           "mesh_geom", "with_mass", "axis_angle_quat", "matrix_quat", "grasp_region"]

Kind = Literal["size", "mass", "feel", "count", "angle"]
JITTER = {"size": 1.0, "mass": 1.0, "feel": 3.0, "angle": 1.0, "count": 0.0}


def param(default: float, low: float, high: float, unit: str, doc: str, kind: Kind = "size"):
    """A parameter field: its default, its range [low, high], unit, what it is, and how it is sampled
    (``size``/``mass``/``angle``: +-scale, ``feel`` (spring, damping, friction): +-3 scale, ``count``: any
    integer in the range)."""
    return dataclasses.field(default=default, metadata={"range": (low, high), "unit": unit, "doc": doc,
                                                        "kind": kind})


def make_rng(rng, where: str = "rng") -> np.random.Generator:
    """A numpy Generator from a seed (an integer >= 0), a Generator, or None (unseeded); anything else raises
    :class:`ObjectError` naming ``where`` (the argument)."""
    if isinstance(rng, np.random.Generator):
        return rng
    if rng is not None and (isinstance(rng, bool) or not isinstance(rng, (int, np.integer)) or rng < 0):
        raise ObjectError(f"{where}: must be a seed (an integer >= 0), a numpy Generator or None, got {rng!r}")
    return np.random.default_rng(rng)


@dataclasses.dataclass(frozen=True)
class Params:
    """Base of every generator's parameters (subclasses declare their fields with :func:`param`).

    Built by keyword (``SprayBottleParams(body_radius=0.035)``): a name that is not a field raises
    :class:`ObjectError` naming it and the fields."""

    def __new__(cls, *args, **kwargs):
        # before the dataclass's __init__, whose TypeError names no field a user can look up
        fields = [f.name for f in dataclasses.fields(cls)]
        unknown = sorted(set(kwargs) - set(fields))
        if unknown:
            raise ObjectError(f"{cls.__name__}: no parameter {unknown[0]!r}; its parameters: {fields}")
        if len(args) > len(fields):
            raise ObjectError(f"{cls.__name__}: {len(args)} values given for {len(fields)} parameters {fields}")
        return super().__new__(cls)

    @classmethod
    def for_generator(cls, params, rng, generator: str) -> "Params":
        """What generator ``generator`` builds from: ``params`` (an instance of this class, or None for the
        defaults), drawn around when ``rng`` is given (see :meth:`sample`), validated. A wrong ``params`` or
        ``rng`` raises :class:`ObjectError` naming the argument."""
        if params is None:
            params = cls()
        elif not isinstance(params, cls):
            raise ObjectError(f"{generator}: params must be a {cls.__name__} (or None), got "
                              f"{type(params).__name__}")
        if rng is not None:
            params = params.sample(make_rng(rng, f"{generator}: rng"))
        params.validate()
        return params

    @classmethod
    def ranges(cls) -> dict[str, tuple[float, float, str, str]]:
        """``{field: (low, high, unit, doc)}`` for every parameter."""
        return {f.name: (*f.metadata["range"], f.metadata["unit"], f.metadata["doc"])
                for f in dataclasses.fields(cls)}

    def as_dict(self) -> dict[str, float]:
        return {f.name: float(getattr(self, f.name)) for f in dataclasses.fields(self)}

    def validate(self) -> None:
        """Raise :class:`ObjectError` naming the first field that is not a finite number within its range."""
        for f in dataclasses.fields(self):
            low, high = f.metadata["range"]
            value = getattr(self, f.name)
            where = f"{type(self).__name__}.{f.name}"
            if f.metadata["kind"] == "count" and (not isinstance(value, (int, np.integer)) or isinstance(value, bool)):
                raise ObjectError(f"{where}: must be an integer in [{low}, {high}], got {value!r}")
            if not isinstance(value, (int, float, np.integer, np.floating)) or not math.isfinite(value):
                raise ObjectError(f"{where}: must be a finite number, got {value!r}")
            if not low <= value <= high:
                raise ObjectError(f"{where}: {value!r} {f.metadata['unit']} is outside its range [{low}, {high}]")

    def sample(self, rng=None, scale: float = 0.1) -> "Params":
        """A variant drawn around these values (see the module docstring); ``rng``: a seed or a Generator."""
        if not 0.0 <= scale <= 0.5:
            raise ObjectError(f"{type(self).__name__}.sample: scale must be in [0, 0.5], got {scale!r}")
        rng = make_rng(rng, f"{type(self).__name__}.sample: rng")
        values = {}
        for f in dataclasses.fields(self):
            low, high = f.metadata["range"]
            kind = f.metadata["kind"]
            if kind == "count":
                values[f.name] = int(rng.integers(int(low), int(high) + 1)) if scale > 0 else getattr(self, f.name)
                continue
            spread = JITTER[kind] * scale
            values[f.name] = float(np.clip(getattr(self, f.name) * rng.uniform(1 - spread, 1 + spread), low, high))
        return dataclasses.replace(self, **values)

    def sample_sizes(self, rng=None, scale: float = 0.1) -> "Params":
        """These values with every size (kind ``"size"``, in m) drawn by a factor in [1 - scale, 1 + scale],
        clipped to its range; masses, angles, counts and the joints' feel are kept (object variants of one
        topology whose physical parameters are randomised elsewhere, by name)."""
        if not 0.0 <= scale <= 0.5:
            raise ObjectError(f"{type(self).__name__}.sample_sizes: scale must be in [0, 0.5], got {scale!r}")
        rng = make_rng(rng, f"{type(self).__name__}.sample_sizes: rng")
        values = {}
        for f in dataclasses.fields(self):
            if f.metadata["kind"] == "size":
                low, high = f.metadata["range"]
                values[f.name] = float(np.clip(getattr(self, f.name) * rng.uniform(1 - scale, 1 + scale), low, high))
        return dataclasses.replace(self, **values)


# ------------------------------------------------------------------------------------------------ geoms
def matrix_quat(rotation: np.ndarray) -> tuple[float, float, float, float]:
    """(w, x, y, z) of a 3x3 rotation, w >= 0."""
    matrix = np.eye(4)
    matrix[:3, :3] = rotation
    q = trimesh.transformations.quaternion_from_matrix(matrix)
    q = q if q[0] >= 0 else -q
    return tuple(float(x) for x in q / np.linalg.norm(q))


def axis_angle_quat(axis: Sequence[float], angle: float) -> tuple[float, float, float, float]:
    """(w, x, y, z) of a rotation by ``angle`` rad about ``axis``."""
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    s = math.sin(angle / 2.0)
    return (math.cos(angle / 2.0), float(axis[0] * s), float(axis[1] * s), float(axis[2] * s))


def _along(p0, p1) -> tuple[tuple, tuple, float]:
    p0, p1 = np.asarray(p0, dtype=float), np.asarray(p1, dtype=float)
    return tuple(float(x) for x in (p0 + p1) / 2.0), matrix_quat(rotation_between((0, 0, 1), p1 - p0)), \
        float(np.linalg.norm(p1 - p0))


def box_geom(name: str, size: Sequence[float], center: Sequence[float], rgba, quat=(1.0, 0.0, 0.0, 0.0)) -> Geom:
    """A box of full extents ``size`` (the Geom keeps half extents) centred at ``center``."""
    return Geom(name, "box", tuple(float(s) / 2.0 for s in size), tuple(float(c) for c in center), tuple(quat),
                rgba=tuple(rgba))


def capsule_geom(name: str, radius: float, p0, p1, rgba) -> Geom:
    """A capsule of ``radius`` around the segment p0-p1."""
    pos, quat, length = _along(p0, p1)
    return Geom(name, "capsule", (float(radius), length / 2.0), pos, quat, rgba=tuple(rgba))


def cylinder_geom(name: str, radius: float, p0, p1, rgba) -> Geom:
    """A cylinder of ``radius`` from p0 to p1."""
    pos, quat, length = _along(p0, p1)
    return Geom(name, "cylinder", (float(radius), length / 2.0), pos, quat, rgba=tuple(rgba))


def sphere_geom(name: str, radius: float, center, rgba) -> Geom:
    return Geom(name, "sphere", (float(radius),), tuple(float(c) for c in center), rgba=tuple(rgba))


def mesh_geom(name: str, mesh: str, rgba) -> Geom:
    """A collision geom that is the watertight mesh ``mesh`` itself (for non-convex shapes: rings)."""
    return Geom(name, "mesh", (), mesh=mesh, rgba=tuple(rgba))


def _volume(g: Geom, meshes: dict) -> float:
    if g.kind == "box":
        return 8.0 * g.size[0] * g.size[1] * g.size[2]
    if g.kind == "sphere":
        return 4.0 / 3.0 * math.pi * g.size[0] ** 3
    if g.kind == "cylinder":
        return math.pi * g.size[0] ** 2 * 2.0 * g.size[1]
    if g.kind == "capsule":
        return math.pi * g.size[0] ** 2 * 2.0 * g.size[1] + 4.0 / 3.0 * math.pi * g.size[0] ** 3
    return float(abs(meshes[g.mesh].volume))


def with_mass(geoms: Sequence[Geom], mass: float, meshes: dict | None = None) -> tuple[Geom, ...]:
    """The geoms with ``mass`` (kg) shared in proportion to their volumes (a part of uniform density)."""
    volumes = np.array([_volume(g, meshes or {}) for g in geoms])
    return tuple(dataclasses.replace(g, mass=float(mass * v / volumes.sum())) for g, v in zip(geoms, volumes))


# ------------------------------------------------------------------------------------------ grasp regions
def grasp_region(finger: str, part: str, surface_point, normal, spread=(0.002, 0.002, 0.002),
                 squeeze: float | None = None) -> GraspRegion:
    """A fingertip's region (:class:`~..description.GraspRegion`): ``surface_point`` on ``part``'s collision
    surface (part frame, m) and the outward ``normal`` there (normalised here)."""
    n = np.asarray(normal, dtype=float)
    n = n / np.linalg.norm(n)
    return GraspRegion(finger, part, tuple(float(x) for x in surface_point), tuple(float(x) for x in n),
                       tuple(float(x) for x in spread), squeeze)
