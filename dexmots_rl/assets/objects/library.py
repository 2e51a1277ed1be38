"""The named objects that ship with the package, and the one entry point that loads any object.

Every instance is its generator called with fixed parameters (no random draw), so it is the same object
on every machine. :func:`load_object` takes a library name or the path of a URDF file (PartNet-Mobility layout).
:func:`sample_variants` draws size variants of an instance (one topology: a scene of object variants).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable

from .description import ObjectAsset, ObjectError
from .generators import GENERATORS, PARAMS

__all__ = ["INSTANCES", "SPLITS", "list_objects", "load_object", "object_split", "sample_variants"]

# name -> (class, parameter overrides); the first instance of a class uses the class's defaults
INSTANCES: dict[str, tuple[str, dict]] = {
    "spray_bottle_a": ("spray_bottle", {}),
    "spray_bottle_b": ("spray_bottle", dict(body_radius=0.032, body_height=0.165, head_length=0.065,
                                            trigger_length=0.05, trigger_travel=0.35, trigger_stiffness=0.2,
                                            body_mass=0.25)),
    "scissors_a": ("scissors", {}),
    "scissors_b": ("scissors", dict(blade_length=0.065, handle_length=0.05, ring_radius=0.0135, opening=0.5,
                                    stiffness=0.04, friction=0.005, half_mass=0.025)),
    "stapler_a": ("stapler", {}),
    "stapler_b": ("stapler", dict(length=0.115, width=0.036, arm_length=0.105, open_angle=0.4, stiffness=0.3,
                                  preload=0.3, arm_mass=0.07, base_mass=0.1)),
    "pump_dispenser_a": ("pump_dispenser", {}),
    "pump_dispenser_b": ("pump_dispenser", dict(body_radius=0.04, body_height=0.075, head_radius=0.018,
                                                spout_length=0.032, stroke=0.015, stiffness=110.0,
                                                body_mass=0.4)),
    "jar_a": ("jar", {}),
    "jar_b": ("jar", dict(body_radius=0.032, body_height=0.1, lid_height=0.016, ribs=18, turn=2.5,
                          friction=0.06, body_mass=0.25)),
    "valve_a": ("valve", {}),
    "valve_b": ("valve", dict(spokes=4, spoke_length=0.05, spoke_radius=0.01)),
    "valve_c": ("valve", dict(spokes=5, hub_radius=0.022, turn=3.14, friction=0.03)),
    "drawer_a": ("drawer", {}),
    "drawer_b": ("drawer", dict(width=0.16, height=0.08, handle_width=0.06, travel=0.06, friction=0.8)),
    "pliers_a": ("pliers", {}),
    "pliers_b": ("pliers", dict(jaw_length=0.032, handle_length=0.09, handle_spread=0.02, grip_radius=0.005,
                                half_mass=0.04, stiffness=0.07)),
    "door_handle_a": ("door_handle", {}),
    "door_handle_b": ("door_handle", dict(lever_length=0.09, lever_radius=0.007, handle_height=0.12,
                                          turn=0.65, stiffness=0.2, lever_mass=0.05)),
}


def list_objects() -> list[tuple[str, str]]:
    """``[(name, class), ...]`` of every shipped object, in a stable order."""
    return [(name, object_class) for name, (object_class, _) in INSTANCES.items()]


# the two parts of a class's instances: policies train on one and are evaluated on both (object_split)
SPLITS = ("train", "heldout")


def object_split(object_class: str) -> dict[str, list[str]]:
    """The library instances of ``object_class`` (or of the class of the instance named ``object_class``) in two
    disjoint parts, ``{"train": [...], "heldout": [...]}``: the class's second instance (in :data:`INSTANCES`'
    order, ``<class>_b``) is held out and the others train. The first instance has the class's default
    parameters and later ones vary around them, so with three or more the held-out one lies among the training
    ones (the valve's: four spokes between three and five). Every class has at least two instances, so each
    part is non-empty; instances of one class share their topology, so either part is one scene of variants."""
    if object_class in INSTANCES:
        object_class = INSTANCES[object_class][0]
    names = [name for name, (cls, _) in INSTANCES.items() if cls == object_class]
    if not names:
        classes = sorted({cls for cls, _ in INSTANCES.values()})
        raise ObjectError(f"object_split: unknown class or object {object_class!r}; classes: {classes}")
    return {"train": names[:1] + names[2:], "heldout": names[1:2]}


def load_object(name_or_path: str | Path, **urdf_options) -> ObjectAsset:
    """A shipped object by name (``list_objects()``), or an object read from a URDF file (a path ending in
    ``.urdf``; ``urdf_options`` go to :func:`dexmots_rl.assets.objects.urdf.load_urdf`)."""
    text = str(name_or_path)
    if text.lower().endswith(".urdf"):
        from .urdf import load_urdf  # the URDF reader pulls in MuJoCo's compiler: only when asked for

        return load_urdf(name_or_path, **urdf_options)
    if urdf_options:
        raise ObjectError(f"load_object({text!r}): options {sorted(urdf_options)} apply to URDF files only")
    if text not in INSTANCES:
        raise ObjectError(f"unknown object {text!r}: give a path ending in .urdf or one of "
                          f"{sorted(INSTANCES)}")
    object_class, overrides = INSTANCES[text]
    generator: Callable[..., ObjectAsset] = GENERATORS[object_class]
    params = dataclasses.replace(PARAMS[object_class](), **overrides)
    return generator(params, name=text)


def sample_variants(name: str, k: int, rng=None, size_scale: float = 0.1) -> list[ObjectAsset]:
    """``k`` size variants of the library instance ``name`` (or of a class's defaults, given a class name): variant
    0 is the instance itself, named ``name``; variant i > 0 (named ``<name>_size<i>``) has each size parameter
    drawn within ``size_scale`` (relative) of the instance's (``Params.sample_sizes``), the rest kept. Every
    variant has the instance's topology (bodies and joints), so one scene holds them all
    (:func:`dexmots_rl.sim.load_variants`). ``rng``: a seed or a numpy Generator."""
    from .generators.common import make_rng

    if name in INSTANCES:
        object_class, overrides = INSTANCES[name]
    elif name in PARAMS:
        object_class, overrides = name, {}
    else:
        raise ObjectError(f"sample_variants: unknown object or class {name!r}; objects: {sorted(INSTANCES)}, "
                          f"classes: {sorted(PARAMS)}")
    if not isinstance(k, int) or k < 1:
        raise ObjectError(f"sample_variants: k must be a positive integer, got {k!r}")
    rng = make_rng(rng, "sample_variants: rng")
    base = dataclasses.replace(PARAMS[object_class](), **overrides)
    params = [base] + [base.sample_sizes(rng, size_scale) for _ in range(k - 1)]
    generator = GENERATORS[object_class]
    return [generator(p, name=name if i == 0 else f"{name}_size{i}") for i, p in enumerate(params)]
