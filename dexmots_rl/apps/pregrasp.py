"""``dexmots-pregrasp``: find a task's pre-grasps through the simulator and write them to a pre-grasp file.

    dexmots-pregrasp --task stapler                    # ./stapler.json
    dexmots-pregrasp --task scissors --candidates 16 --keep 8 --out my_scissors.json
    dexmots-train task=scissors task.pregrasps=my_scissors.json     # train from those pre-grasps

The file goes where ``--out`` says (a file, or a directory for ``<task>.json``; default: the current
directory), never into the installed package; a task uses it through its ``task.pregrasps`` field.
Deterministic for a seed (:func:`dexmots_rl.envs.pregrasp.find_pregrasps`); the file is written atomically.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from ._cli import os_errors_as_one_line

__all__ = ["generate", "main", "output_path"]


def output_path(task: str, out=None) -> Path:
    """Where ``--out`` puts ``task``'s file: ``out`` itself, ``out/<task>.json`` for a directory, or
    ``./<task>.json``."""
    path = Path.cwd() if out is None else Path(out).expanduser()
    return path / f"{task}.json" if path.is_dir() else path


def generate(task: str, candidates: int = 8, keep: int = 4, seed: int = 0, out=None) -> Path:
    """Search ``task``'s pre-grasps and write them to :func:`output_path` ``(task, out)``; returns the path."""
    from ..envs import list_tasks
    from ..envs.pregrasp import find_pregrasps, save_pregrasps
    from ..envs.registry import task_entry

    if task not in list_tasks() or not getattr(task_entry(task).env_class, "contact_regions", ()):
        known = [t for t in list_tasks() if getattr(task_entry(t).env_class, "contact_regions", ())]
        raise ValueError(f"--task {task!r} has no pre-grasp regions; tasks with pre-grasps: {', '.join(known)}")
    env_class = task_entry(task).env_class
    poses = find_pregrasps(env_class.asset_path(), env_class.contact_regions, env_class.pregrasp_hint,
                           candidates=candidates, keep=keep, seed=seed, contact=env_class.contact_params)
    path = output_path(task, out)
    save_pregrasps(path, task, poses, seed)
    return path


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="dexmots-pregrasp", description=__doc__.splitlines()[0])
    p.add_argument("--task", required=True)
    p.add_argument("--candidates", type=int, default=8, help="IK + settle candidates tried")
    p.add_argument("--keep", type=int, default=4, help="pre-grasps kept (the first that pass the contact check)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=None, help="JSON file, or a directory for <task>.json (default: the current "
                                               "directory)")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(asctime)s %(message)s")
    from ..envs.pregrasp import PregraspError

    for name in ("candidates", "keep"):
        if getattr(args, name) < 1:
            raise SystemExit(f"dexmots-pregrasp: --{name} must be >= 1, got {getattr(args, name)}")
    with os_errors_as_one_line("dexmots-pregrasp"):
        try:
            path = generate(args.task, args.candidates, args.keep, args.seed, args.out)
        except (ValueError, PregraspError) as e:
            raise SystemExit(f"dexmots-pregrasp: {e}") from None
    print(path)
    print(f"dexmots-pregrasp: use it with task.pregrasps={path}", file=sys.stderr)


if __name__ == "__main__":
    main()
