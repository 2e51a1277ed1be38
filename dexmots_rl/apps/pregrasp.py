"""``dexmots-pregrasp``: find a task's pre-grasps through the simulator and write them to a pre-grasp file.

    dexmots-pregrasp --task stapler                    # ./stapler_a.json (the stapler task's object)
    dexmots-pregrasp --task scissors --candidates 16 --keep 8 --out my_scissors.json
    dexmots-train task=scissors task.pregrasps=my_scissors.json     # train from those pre-grasps
    dexmots-pregrasp --task operate --object jar_a                  # ./jar_a.json
    dexmots-pregrasp --task operate --object my/mobility.urdf --out mine.json
    dexmots-train task=operate task.object=my/mobility.urdf task.pregrasps=mine.json
    dexmots-pregrasp --task operate --all --out dexmots_rl/assets/pregrasps/operate   # the shipped files

The file goes where ``--out`` says (a file, or a directory for ``<object>.json``; default: the current
directory), never into the installed package unless ``--out`` names it; a task uses it through its
``task.pregrasps`` field. Task ``operate`` needs ``--object`` (a library object or a URDF;
:func:`dexmots_rl.envs.object_pregrasp.find_object_pregrasps`) or ``--all`` (every library object); a tool task
built on it (``spray_bottle``, ``drawer``, ``jar``, ...) searches its own object (``--object`` picks another).
Other tasks start without pre-grasps. Deterministic for a seed; the file is written atomically.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from ._cli import os_errors_as_one_line

__all__ = ["generate_operate", "main", "output_path"]


def output_path(name: str, out=None) -> Path:
    """Where ``--out`` puts the file of object ``name``: ``out`` itself, ``out/<name>.json`` for a directory,
    or ``./<name>.json``."""
    path = Path.cwd() if out is None else Path(out).expanduser()
    return path / f"{name}.json" if path.is_dir() else path


def generate_operate(object_name: str, candidates: int = 8, keep: int = 4, seed: int = 0, out=None) -> Path:
    """Search the pre-grasps of ``object_name`` (a library object or a URDF) in task ``operate``'s scene and
    write them to ``out`` (a file, or a directory for ``<object>.json``; default: the current directory)."""
    import mujoco

    from ..envs.object_pregrasp import find_object_pregrasps, object_regions
    from ..envs.pregrasp import save_pregrasps
    from ..envs.tasks.allegro.operate_object import OperateObjectEnv, build_scene

    scene, asset = build_scene(object_name)
    model = mujoco.MjModel.from_xml_path(str(scene.path))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    poses = find_object_pregrasps(scene, asset, object_regions(asset, model, data), candidates=candidates,
                                  keep=keep, seed=seed, contact=OperateObjectEnv.contact_params)
    path = output_path(Path(object_name).stem if object_name.lower().endswith(".urdf") else object_name, out)
    save_pregrasps(path, "operate", poses, seed, object=asset.name)
    return path


def _object_tasks() -> list[str]:
    """The tasks with pre-grasps: ``operate`` and the tasks built on it (a tool task: its object's)."""
    from ..envs import list_tasks
    from ..envs.registry import task_entry
    from ..envs.tasks.allegro.operate_object import OperateObjectEnv

    return [t for t in list_tasks() if issubclass(task_entry(t).env_class, OperateObjectEnv)]


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="dexmots-pregrasp", description=__doc__.splitlines()[0])
    p.add_argument("--task", required=True)
    p.add_argument("--object", default=None, help="task operate: a library object or a .urdf path")
    p.add_argument("--all", action="store_true",
                   help="task operate: every library object, one file each into the directory --out")
    p.add_argument("--candidates", type=int, default=8, help="IK + settle candidates tried")
    p.add_argument("--keep", type=int, default=4, help="pre-grasps kept (the first that pass the contact check)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=None, help="JSON file, or a directory for <object>.json (default: the "
                                               "current directory)")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(asctime)s %(message)s")
    from ..envs.pregrasp import PregraspError

    for name in ("candidates", "keep"):
        if getattr(args, name) < 1:
            raise SystemExit(f"dexmots-pregrasp: --{name} must be >= 1, got {getattr(args, name)}")
    known = _object_tasks()
    if args.task not in known:
        raise SystemExit(f"dexmots-pregrasp: --task {args.task!r} has no pre-grasps to search; tasks with "
                         f"pre-grasps: {', '.join(known)}")
    if args.task == "operate" and (args.object is None) == (not args.all):
        raise SystemExit("dexmots-pregrasp: --task operate needs --object <name or .urdf path> or --all")
    if args.object is None and not args.all:  # a tool task: its own object
        from ..envs.registry import task_config

        args.object = task_config(args.task).object
    if args.all:
        from ..assets.objects import list_objects

        Path(args.out or ".").mkdir(parents=True, exist_ok=True)
    objects = [name for name, _ in list_objects()] if args.all else [args.object]
    with os_errors_as_one_line("dexmots-pregrasp"):
        try:
            for name in objects:
                path = generate_operate(name, args.candidates, args.keep, args.seed, args.out)
                print(path, flush=True)
        except (ValueError, PregraspError) as e:
            raise SystemExit(f"dexmots-pregrasp: {e}") from None
    if not args.all:
        print(f"dexmots-pregrasp: use it with task.pregrasps={path}", file=sys.stderr)


if __name__ == "__main__":
    main()
