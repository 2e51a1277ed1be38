"""``dexmots-plan``: optimise an object-centric pose + wrench plan through the simulator and save it.

    dexmots-plan --task screw_claw --goal 1.5708 --steps 60 --out plans/knob.pt
    dexmots-plan --task screw_claw --goal 0.8 1.2 1.5708 --friction 0.2 0.6 1.0 --out plans/bank   # one file per plan
    dexmots-plan --task drawer --goal 0.065 --steps 40 --out plans/drawer.pt      # an articulated object's joint

For a task on an articulated object (``operate`` and the tool tasks) the plan is the force on the task's
operated joint with the base held (:func:`dexmots_rl.trajectories.joint_planner.optimize_joint_torques`);
``--start`` / ``--goal`` are that joint's position, ``--damping`` / ``--friction`` its parameters.

Prints the final tracking error (and the initial one, with zero wrenches). Writes are atomic. A bank
directory of plans is what ``make_env(..., references=...)`` reads (see :mod:`dexmots_rl.envs`).
``dexmots-bench plan`` times the same optimisation (:func:`run_plan_bench`).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import math
import sys
import time
from pathlib import Path

import torch

from ._cli import os_errors_as_one_line

__all__ = ["build_parser", "main", "run_plan_bench", "validate_args"]

log = logging.getLogger(__name__)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="dexmots-plan", description=__doc__.splitlines()[0])
    p.add_argument("--task", default="screw_claw")
    p.add_argument("--start", type=float, nargs="+", default=None,
                   help="object coordinates at the start (hinge: angle; free body: x y z qw qx qy qz)")
    p.add_argument("--goal", type=float, nargs="+", required=True,
                   help="goal coordinates; for a hinge several angles give several plans")
    p.add_argument("--steps", type=int, default=60, help="env steps of the plan")
    p.add_argument("--iterations", type=int, default=200)
    p.add_argument("--lr", type=float, default=None, help="Adam step (default: the task's PlanProblem.lr)")
    p.add_argument("--damping", type=float, nargs="+", default=None, help="object joint damping per plan")
    p.add_argument("--friction", type=float, nargs="+", default=None, help="object joint friction per plan")
    p.add_argument("--out", required=True, help="a .pt file (one plan) or a directory (one file per plan)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    return p


def _plan_inputs(args, scene):
    nq = scene.object_nq
    goal = torch.tensor(args.goal, dtype=torch.float64).reshape(-1, nq)
    start = (torch.as_tensor(scene.object_q0, dtype=torch.float64).reshape(1, nq) if args.start is None
             else torch.tensor(args.start, dtype=torch.float64).reshape(-1, nq))
    n = max(goal.shape[0], start.shape[0], len(args.damping or [0]), len(args.friction or [0]))
    damping = torch.tensor(args.damping or [scene.object_damping], dtype=torch.float64)
    friction = torch.tensor(args.friction or [scene.object_friction], dtype=torch.float64)
    for name, t in (("goal", goal), ("start", start), ("damping", damping), ("friction", friction)):
        if t.shape[0] not in (1, n):
            raise SystemExit(f"dexmots-plan: --{name} gives {t.shape[0]} values; expected 1 or {n}")
    params = {"joint_damping": damping.expand(n), "joint_friction": friction.expand(n)}
    return start.expand(n, nq), goal.expand(n, nq), params


def validate_args(args) -> None:
    """One-line ``SystemExit`` naming the option for a value no plan can use; runs before any work, so
    nothing is written. Coordinates are bounded like the references an env accepts (|x| <= 100)."""
    from ..envs.references import MAX_ABS_COORDINATE

    def bad(name, why):
        raise SystemExit(f"dexmots-plan: --{name} {why}")

    for name, positive in (("steps", args.steps), ("iterations", args.iterations)):
        if positive <= 0:
            bad(name, f"must be a positive integer, got {positive}")
    if args.lr is not None and not (math.isfinite(args.lr) and args.lr > 0):
        bad("lr", f"must be a positive finite number, got {args.lr}")
    for name in ("start", "goal"):
        for v in getattr(args, name) or []:
            if not (math.isfinite(v) and abs(v) <= MAX_ABS_COORDINATE):
                bad(name, f"values must be finite with |x| <= {MAX_ABS_COORDINATE:g}, got {v}")
    for name in ("damping", "friction"):
        for v in getattr(args, name) or []:
            if not (math.isfinite(v) and v >= 0):
                bad(name, f"values must be finite and >= 0, got {v}")


def main(argv: list[str] | None = None) -> None:
    args = build_parser().parse_args(argv)
    validate_args(args)
    with os_errors_as_one_line("dexmots-plan"):
        _plan(args)


def _plan(args) -> None:
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(asctime)s %(message)s")
    from ..envs import task_scene
    from ..trajectories import optimize_wrenches

    with contextlib.redirect_stdout(sys.stderr):  # warp prints compile messages
        try:
            scene = task_scene(args.task)
        except ValueError as e:
            raise SystemExit(f"dexmots-plan: {e}") from None
        t0 = time.perf_counter()
        log.info("dexmots-plan: %d iterations of a %d-step plan on %s (a progress bar on a terminal)",
                 args.iterations, args.steps, args.task)
        if getattr(scene, "tree", None) is not None:  # an articulated object: its operated joint
            result = _plan_joint(args, scene)
        else:
            start, goal, params = _plan_inputs(args, scene)
            lr = args.lr if args.lr is not None else _task_lr(args.task)
            result = optimize_wrenches(scene, start, goal, args.steps, iterations=args.iterations, lr=lr,
                                       params=params)
        wall = time.perf_counter() - t0
    out = Path(args.out)
    files = []
    if len(result.trajectories) == 1 and out.suffix == ".pt":
        result.trajectory.save(out)
        files.append(str(out))
    else:
        out.mkdir(parents=True, exist_ok=True)
        for i, traj in enumerate(result.trajectories):
            path = out / f"plan_{i:03d}.pt"
            traj.save(path)
            files.append(str(path))
    summary = {"task": args.task, "plans": len(files), "initial_error": result.initial_error,
               "final_error": result.final_error, "wall_clock_s": round(wall, 2), "files": files}
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"wrote {len(files)} plan(s) to {out}: tracking error {result.initial_error:.4g} -> "
              f"{result.final_error:.4g} ({wall:.1f} s)")


def _plan_joint(args, scene):
    """The plan of an articulated task's operated joint (the task's ``joint``, or its object's operated joint)."""
    from ..assets.objects import load_object
    from ..envs import task_config
    from ..trajectories.joint_planner import optimize_joint_torques

    config = task_config(args.task)
    tree = scene.tree
    joint = config.joint or load_object(config.object).operated_joint or tree.joint_names[0]
    j = tree.joint_names.index(joint)
    start = args.start if args.start is not None else [float(tree.q0[7 * tree.free + j])]
    n = max(len(args.goal), len(start), len(args.damping or [0]), len(args.friction or [0]))
    for name, values in (("goal", args.goal), ("start", start), ("damping", args.damping or [0]),
                         ("friction", args.friction or [0])):
        if len(values) not in (1, n):
            raise SystemExit(f"dexmots-plan: --{name} gives {len(values)} values; expected 1 or {n}")
    params = {f"{joint}/{name}": torch.tensor(values, dtype=torch.float32).expand(n)
              for name, values in (("damping", args.damping), ("friction", args.friction)) if values}
    try:
        return optimize_joint_torques(scene, joint, torch.tensor(start).expand(n), torch.tensor(args.goal).expand(n),
                                      args.steps, iterations=args.iterations, lr=args.lr, params=params)
    except ValueError as e:  # a start or goal outside the joint's range, named
        raise SystemExit(f"dexmots-plan: --{e} ({args.task}'s operated joint)") from None


def _task_lr(task: str) -> float:
    """The task's planner step (``PlanProblem.lr``), 0.5 for a task without a plan problem."""
    from ..envs import task_entry

    problem = task_entry(task).env_class.plan_problem
    return problem.lr if problem is not None else 0.5


def run_plan_bench(task: str, iterations: int) -> dict:
    """``dexmots-bench plan``: the task's default plan from zero wrenches, timed, in one run."""
    from ..envs import task_entry, task_scene
    from ..trajectories import optimize_wrenches

    problem = task_entry(task).env_class.plan_problem
    if problem is None:
        raise ValueError(f"task {task!r} declares no plan problem (DexEnv.plan_problem)")
    scene, start, goal, steps = task_scene(task), problem.start, problem.goal, problem.steps
    optimize_wrenches(scene, start, goal, 1, iterations=1, progress=False)  # compile outside the timing
    t0 = time.perf_counter()
    result = optimize_wrenches(scene, start, goal, steps, iterations=iterations, lr=problem.lr, progress=False)
    wall = time.perf_counter() - t0
    return {"task": task, "iterations": iterations, "steps": steps, "initial_error": result.initial_error,
            "final_error": result.final_error, "reduction": result.initial_error / max(result.final_error, 1e-12),
            "wall_clock_s": round(wall, 2), "goal_reduction": 10.0,
            "goal_met": result.initial_error / max(result.final_error, 1e-12) >= 10.0}


if __name__ == "__main__":
    main()
