"""A URDF object in task ``operate``: the loader's options from the task config, and pre-grasps found on first use.

``task.urdf`` (:class:`UrdfOptions`) carries :func:`~dexmots_rl.assets.objects.urdf.load_urdf`'s options to a URDF
``task.object`` (``dexmots-train task=operate task.object=<folder>/mobility.urdf task.urdf.size=0.14
task.urdf.base=fixed``); ``task.joint`` is the loader's ``operated_joint``. A URDF has no shipped pre-grasps:
:func:`cached_pregrasps` searches them on first use (the fallback grasp regions,
:mod:`dexmots_rl.envs.object_pregrasp`) and keeps them in the object's scene folder, beside its ``scene.xml``, so
later runs read them back; ``task.pregrasps=<file>`` overrides, ``task.initial=open`` skips them. When the search
finds none (an object the fallback regions do not fit), the task starts open above the object, as with
``task.initial=open``, and says so once per run; that outcome is cached too (:data:`NO_PREGRASP_FILE`).
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import Optional

from ...fields import rule

__all__ = ["UrdfOptions", "urdf_load_options", "cached_pregrasps", "PREGRASP_FILE", "NO_PREGRASP_FILE"]

log = logging.getLogger(__name__)

PREGRASP_FILE = "pregrasps.json"  # in the object's scene folder
NO_PREGRASP_FILE = "pregrasps-none.txt"  # beside it: why the search found none


@dataclasses.dataclass
class UrdfOptions:
    """How a URDF ``task.object`` (or a URDF among ``task.objects``) is loaded; a library object refuses them."""

    size: Optional[float] = dataclasses.field(default=None, metadata=rule(gt=0))  # m, longest side (None: 0.18)
    scale: Optional[float] = dataclasses.field(default=None, metadata=rule(gt=0))  # a factor instead of size
    base: str = dataclasses.field(default="free", metadata=rule(choices=("free", "fixed")))  # on the table, or fixed
    collision: str = dataclasses.field(default="boxes", metadata=rule(choices=("boxes", "hull")))
    density: float = dataclasses.field(default=500.0, metadata=rule(gt=0))  # kg/m^3 of the collision shapes


def urdf_load_options(options: UrdfOptions, joint: str | None, object_name: str) -> dict:
    """The keyword arguments of :func:`~dexmots_rl.assets.objects.load_object` for ``object_name``: the options
    that differ from the defaults (and ``operated_joint``) for a URDF; for a library object none, or one
    ``ValueError`` naming ``task.urdf`` when some were set."""
    given = {f.name: getattr(options, f.name) for f in dataclasses.fields(UrdfOptions)
             if getattr(options, f.name) != f.default}
    if not object_name.lower().endswith(".urdf"):
        if given:
            raise ValueError(f"task.urdf.{sorted(given)[0]}: the loader's options apply to a .urdf object, and "
                             f"{object_name!r} is a library object")
        return {}
    return {**given, **({"operated_joint": joint} if joint else {})}


def cached_pregrasps(scene, asset, folder: Path, contact, joint: str | None = None) -> Path | None:
    """The pre-grasp file in ``folder`` (the object's scene folder), searched and written on first use; None
    when the search found none (the task then starts open)."""
    import mujoco

    from ....atomic import atomic_write
    from ....envs.object_pregrasp import find_object_pregrasps, object_regions
    from ....envs.pregrasp import PregraspError, save_pregrasps

    path, none = Path(folder) / PREGRASP_FILE, Path(folder) / NO_PREGRASP_FILE
    if not path.is_file() and not none.is_file():
        log.warning("%s: no pre-grasps yet; searching them once, kept in %s", asset.name, path)
        model = mujoco.MjModel.from_xml_path(str(scene.path))
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        try:
            poses = find_object_pregrasps(scene, asset, object_regions(asset, model, data, joint), contact=contact,
                                          joint=joint, progress=True)
            save_pregrasps(path, "operate", poses, 0, object=asset.name)
        except PregraspError as error:
            atomic_write(none, lambda f: f.write(str(error).encode()))
    if path.is_file():
        return path
    log.warning("%s: no pre-grasp found (%s): episodes start with the hand open above the object", asset.name,
                none.read_text().strip())
    return None
