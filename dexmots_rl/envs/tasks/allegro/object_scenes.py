"""The scenes of the ``operate`` tasks: which objects (``task.objects``), whether they can share one scene and one
policy (:func:`object_topology`), and their MJCF and mesh files in the scene cache (``$DEXMOTS_CACHE``).

A scene of object variants, and a policy trained on one, need one topology: the objects' class, base (free or
fixed) and parts with their joints (names and kinds: the policy's observation and the simulator's kernels are
built for them). :func:`check_one_topology` refuses objects that differ, naming them and what differs;
``dexmots-eval --objects`` checks the objects it is given against the ones a policy trained on
(:func:`check_evaluation_objects`).

The cache holds one folder per object, ``scenes/<object>-<hash>``, rewritten by every build (each file
atomically, so runs building one scene side by side never read a truncated file). A build that cannot write
(a full disk, a read-only or non-directory ``DEXMOTS_CACHE``) raises one ``OSError`` naming the folder and the
variable, and removes the folder it had created: no scene is left half-written.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

from ....atomic import atomic_write
from .urdf_object import UrdfOptions, urdf_load_options

__all__ = ["CACHE_VARIABLE", "build_scene", "cache_root", "check_evaluation_objects", "check_one_topology",
           "object_names", "object_topology", "scene_dir"]

CACHE_VARIABLE = "DEXMOTS_CACHE"


def cache_root() -> Path:
    """``$DEXMOTS_CACHE``, or ``~/.cache/dexmots_rl``."""
    return Path(os.environ.get(CACHE_VARIABLE, Path.home() / ".cache" / "dexmots_rl"))


def scene_dir(object_name: str, options: dict | None = None) -> Path:
    """Where the scene of ``object_name`` (loaded with ``options``) is written (its MJCF and mesh files; the
    recorder and the viewer read it back; a URDF's pre-grasps): :func:`cache_root`, then ``scenes/<object>-<hash>``."""
    key = str(Path(object_name).resolve() if object_name.endswith(".urdf") else object_name)
    if options:
        key += repr(sorted(options.items()))
    digest = hashlib.sha1(key.encode()).hexdigest()[:10]
    return cache_root() / "scenes" / f"{Path(object_name).stem}-{digest}"


def object_names(objects, object_name: str | None = None, field: str = "task.objects") -> list[str]:
    """``task.objects`` as a list of names: a list, or one string of names separated by commas or spaces; the
    keyword ``train`` or ``heldout`` stands for that part of the library split of ``object_name``'s class
    (:func:`~dexmots_rl.assets.objects.object_split`). ``field``: the setting named by errors."""
    from ....assets.objects import INSTANCES, SPLITS, object_split

    names = ([name for name in objects.replace(",", " ").split() if name] if isinstance(objects, str)
             else [str(name) for name in objects])
    if not names:
        raise ValueError(f"{field}={objects!r} names no object: give library names or URDF paths separated by "
                         "commas, or train / heldout")
    if len(names) == 1 and names[0] in SPLITS:
        if object_name is None or object_name not in INSTANCES:
            raise ValueError(f"{field}={names[0]}: the split is of a library class, and task.object "
                             f"{object_name!r} is not a library object (one of {sorted(INSTANCES)})")
        return object_split(object_name)[names[0]]
    return names


def object_topology(asset) -> dict:
    """What objects sharing a scene or a policy must have in common: class, base, and the parts' tree with
    each part's joint (name and kind; None for a part fixed to its parent)."""
    parts = tuple((p.parent, None if p.joint is None else (p.joint.name, p.joint.kind)) for p in asset.parts)
    return {"class": asset.object_class, "base": asset.base, "parts": parts}


def _describe(asset) -> str:
    joints = ", ".join(f"{j.kind} {j.name!r}" for j in asset.joints if j is not None) or "none"
    return f"{asset.name!r} (class {asset.object_class}, {asset.base} base, {len(asset.parts)} parts, joints: {joints})"


def check_one_topology(assets, field: str, reference=None, reference_what: str = "") -> None:
    """Raise ``ValueError`` naming ``field`` when ``assets`` (with ``reference``, an asset described as
    ``reference_what``, first if given) do not all share :func:`object_topology`."""
    first = reference if reference is not None else assets[0]
    for asset in assets:
        one, other = object_topology(first), object_topology(asset)
        differs = next((key for key in one if one[key] != other[key]), None)
        if differs is not None:
            what = f"{reference_what} {_describe(first)}" if reference is not None else _describe(first)
            raise ValueError(f"{field}: {_describe(asset)} differs in its {differs} from {what}; the objects must "
                             "share one class, base and joints")


def check_evaluation_objects(task_config: dict, objects) -> list[str]:
    """The objects ``objects`` (``dexmots-eval --objects``) resolved against a trained ``task_config`` (a
    checkpoint's task section), refused (``ValueError``) when they do not share the topology of the objects
    the policy trained on: its observation and actions are those of one class and topology."""
    from ....assets.objects import load_object

    urdf, joint = UrdfOptions(**(task_config.get("urdf") or {})), task_config.get("joint")

    def load(name: str):  # as the run's env loads it (a URDF with the run's loader options)
        return load_object(name, **urdf_load_options(urdf, joint, name))

    names = object_names(objects, task_config.get("object"), field="--objects")
    trained = task_config.get("objects")
    reference = load(object_names(trained, task_config.get("object"))[0] if trained else task_config["object"])
    check_one_topology([load(name) for name in names], "--objects", reference, "the object the policy was trained on,")
    return names


def build_scene(object_name: str, objects=None, variants: int = 0, variant_scale: float = 0.1,
                variant_seed: int = 0, urdf=None, joint: str | None = None):
    """The hand-and-object scene of ``object_name`` (an :class:`~dexmots_rl.sim.ArticulatedScene`)
    and the object; the MJCF is written to :func:`scene_dir` (atomically: a complete file or none). With
    ``objects`` (names or URDF paths, of one topology) or ``variants`` >= 2 (size variants of ``object_name``),
    a scene of those object variants (:func:`dexmots_rl.sim.load_variants`); the object returned is variant 0's.
    ``urdf`` (a :class:`.urdf_object.UrdfOptions`) and ``joint``: how a URDF is loaded
    (:func:`.urdf_object.urdf_load_options`)."""
    from ....assets.objects import load_object, sample_variants
    from ....sim import load_scene, load_variants

    urdf = urdf or UrdfOptions()
    if objects:
        names = object_names(objects, object_name)
        options = [urdf_load_options(urdf, joint, name) for name in names]
        assets = [load_object(name, **given) for name, given in zip(names, options)]
        check_one_topology(assets, "task.objects")
        keys = list(zip(names, options))
    elif variants >= 2:
        assets = sample_variants(object_name, variants, variant_seed, variant_scale)
        keys = [(object_name, {})] + [(f"{a.name}-seed{variant_seed}-scale{variant_scale!r}", {}) for a in assets[1:]]
    else:
        given = urdf_load_options(urdf, joint, object_name)
        asset = load_object(object_name, **given)
        return load_scene(_write_scene(asset, object_name, given)), asset
    return load_variants([_write_scene(asset, *key) for asset, key in zip(assets, keys)]), assets[0]


def _write_scene(asset, key: str, options: dict | None = None) -> Path:
    """Write the scene of ``asset`` into its cache folder (:func:`scene_dir` of ``key`` and ``options``); see the
    module docstring for what a failed write does."""
    from ....assets.hand_scene import hand_object_scene_xml

    folder = scene_dir(key, options)
    created = False
    try:
        try:
            folder.mkdir(parents=True)
            created = True
        except FileExistsError:
            if not folder.is_dir():
                raise NotADirectoryError(20, "Not a directory", str(folder)) from None
        xml = hand_object_scene_xml(asset, folder)  # writes the mesh files, each atomically
        atomic_write(folder / "scene.xml", lambda f: f.write(xml.encode()))
    except OSError as e:
        if created:
            shutil.rmtree(folder, ignore_errors=True)
        reason = (e.strerror or str(e)).lower()
        raise OSError(e.errno, f"{reason}: cannot write the scene of {key!r} into {folder} ({CACHE_VARIABLE}="
                      f"{cache_root()}); set {CACHE_VARIABLE} to a writable directory with free space") from None
    return folder / "scene.xml"
