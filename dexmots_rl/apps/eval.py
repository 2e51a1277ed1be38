"""``dexmots-eval``: run N episodes of a trained policy deterministically and report success.

    dexmots-eval runs/screw_claw_ahac_seed0                       # its checkpoints/last.pt, 100 episodes
    dexmots-eval runs/screw_claw_ahac_seed0/checkpoints/last.pt --episodes 200 --out eval.json
    dexmots-eval runs/screw_claw_ahac_seed0 --record eval.mcap      # + dexmots-view eval.mcap
    dexmots-eval runs/spray_bottle_ahac_seed0 --objects heldout      # a tool task on its class's held-out objects
    dexmots-eval runs/screw_claw_ahac_seed0 --object-params true.json  # on an object with other physics

``--objects`` evaluates a policy of an articulated-object task on other objects of the same class and topology
(others are refused: the policy's observation and actions are those of its own):
``train`` / ``heldout`` (the class's library split, :func:`dexmots_rl.assets.objects.object_split`) or names
separated by commas; the result says which (``objects``) and breaks success down by object (``success_by_variant``).
``--object-params``: a parameter file (``dexmots-sysid``'s format: the object's joint damping, friction, masses
...) every evaluation world simulates instead of the run's own object parameters (``task.object_params``): a
policy trained on one model of the object, evaluated on another. Each object set and parameter file has its own
file in the run directory, so one does not replace another: ``eval.json`` (the run's own objects),
``eval_train.json``, ``eval_heldout.json``, ``eval_<name>+<name>.json``, ``eval_params_<file stem>.json``
(:func:`default_out`).

The episodes are the checkpoint's task (:func:`dexmots_rl.algorithms.evaluation.evaluate_policy`).
"""

from __future__ import annotations

import argparse
import logging
import re
import sys
from pathlib import Path

from ..atomic import atomic_write_json, dumps_json
from ._cli import os_errors_as_one_line

__all__ = ["default_out", "main"]


def default_out(checkpoint: str, objects: str | None, object_params: str | None = None) -> Path:
    """Where the result goes without ``--out``: the run directory's ``eval.json``; with ``--objects``
    ``eval_<objects>.json`` (names joined by ``+``), with ``--object-params`` ``..._params_<file stem>.json``
    (any character a file name should not hold becomes ``_``)."""
    src = Path(checkpoint)
    run_dir = src if src.is_dir() else src.parent.parent

    def safe(name: str) -> str:
        return re.sub(r"[^A-Za-z0-9_.-]", "_", name.strip())

    parts = ["eval"]
    if objects is not None:
        parts.append("+".join(safe(n) for n in objects.split(",")))
    if object_params is not None:
        parts.append(f"params_{safe(Path(object_params).stem)}")
    return run_dir / f"{'_'.join(parts)}.json"


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="dexmots-eval", description=__doc__.splitlines()[0])
    p.add_argument("checkpoint", help="a checkpoint file or a run directory")
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--seed", type=int, default=12345)
    p.add_argument("--device", default="cpu")
    p.add_argument("--out", default=None,
                   help="JSON file (default: <run dir>/eval.json; with --objects, eval_<objects>.json)")
    p.add_argument("--record", default=None, help="also write the first --record-worlds episodes to this MCAP file")
    p.add_argument("--record-worlds", type=int, default=8)
    p.add_argument("--object-params", default=None,
                   help="a parameter file (dexmots-sysid's) the evaluation worlds simulate instead of the run's own")
    p.add_argument("--objects", default=None,
                   help="articulated-object tasks: train | heldout | names separated by commas (default: the run's)")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(asctime)s %(message)s")
    from ..algorithms.checkpoint import CheckpointError
    from ..algorithms.evaluation import evaluate_policy
    from ..algorithms.registry import policy_from_checkpoint

    with os_errors_as_one_line("dexmots-eval"):
        _run(args, evaluate_policy, policy_from_checkpoint, CheckpointError)


def _run(args, evaluate_policy, policy_from_checkpoint, CheckpointError) -> None:
    try:
        actor, data = policy_from_checkpoint(args.checkpoint, args.device)
        task_cfg = dict(data["config"]["task"])
        if args.objects is not None:
            if "objects" not in task_cfg:
                raise ValueError(f"--objects: task {data['task']!r} has no object variants (task.objects)")
            from ..envs.tasks.allegro.object_scenes import check_evaluation_objects

            task_cfg.update(objects=check_evaluation_objects(task_cfg, args.objects), variants=0)
        if args.object_params is not None:
            task_cfg["object_params"] = str(Path(args.object_params).resolve())
        result = {"task": data["task"], "algo": data["algo"], "iteration": data["iteration"],
                  **({"objects": args.objects} if args.objects is not None else {}),
                  **({"object_params": task_cfg["object_params"]} if args.object_params is not None else {}),
                  **evaluate_policy(actor, task_cfg, args.episodes, args.seed, args.device,
                                     record=args.record, record_worlds=args.record_worlds)}
    except (CheckpointError, ValueError) as e:
        raise SystemExit(f"dexmots-eval: {e}") from None
    out = Path(args.out) if args.out else default_out(args.checkpoint, args.objects, args.object_params)
    print(dumps_json(result), flush=True)  # first: a result that cannot be written is not lost
    try:
        atomic_write_json(out, result)
    except OSError as e:
        raise SystemExit(f"dexmots-eval: the result (printed above) could not be written to {out} "
                         f"({'--out' if args.out else 'the run directory'}): {e.strerror or e}") from None


if __name__ == "__main__":
    main()
