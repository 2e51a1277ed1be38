"""``dexmots-pregrasp``: find a task's pre-grasps through the simulator and write its pre-grasp file.

    dexmots-pregrasp --task stapler                    # rewrite the shipped assets/pregrasps/stapler.json
    dexmots-pregrasp --task scissors --candidates 16 --keep 8 --out my_scissors.json

Deterministic for a seed (:func:`dexmots_rl.envs.pregrasp.find_pregrasps`); the file is written atomically.
"""

from __future__ import annotations

import argparse
import logging
import sys

from ._cli import os_errors_as_one_line

__all__ = ["main", "generate"]


def generate(task: str, candidates: int = 8, keep: int = 4, seed: int = 0, out=None):
    """Search ``task``'s pre-grasps and write them to ``out`` (default: the shipped file); returns the path."""
    from ..envs import list_tasks
    from ..envs.pregrasp import find_pregrasps, pregrasp_path, save_pregrasps
    from ..envs.registry import task_entry

    if task not in list_tasks() or not getattr(task_entry(task).env_class, "contact_regions", ()):
        known = [t for t in list_tasks() if getattr(task_entry(t).env_class, "contact_regions", ())]
        raise ValueError(f"--task {task!r} has no pre-grasp regions; tasks with pre-grasps: {', '.join(known)}")
    env_class = task_entry(task).env_class
    poses = find_pregrasps(env_class.asset_path(), env_class.contact_regions, env_class.pregrasp_hint,
                           candidates=candidates, keep=keep, seed=seed, contact=env_class.contact_params)
    path = pregrasp_path(task) if out is None else out
    save_pregrasps(path, task, poses, seed)
    return path


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="dexmots-pregrasp", description=__doc__.splitlines()[0])
    p.add_argument("--task", required=True)
    p.add_argument("--candidates", type=int, default=8, help="IK + settle candidates tried")
    p.add_argument("--keep", type=int, default=4, help="pre-grasps kept (the first that pass the contact check)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=None, help="JSON file (default: the task's shipped pre-grasp file)")
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


if __name__ == "__main__":
    main()
