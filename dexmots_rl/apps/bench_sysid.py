"""``dexmots-bench sysid``: identification through the simulator's gradients against the finite-difference
Gauss-Newton and CMA-ES, on the same synthetic recordings with the truth known.

For each parameter count (the first ``k`` of ``--params``, default every parameter of the task's scene), seed
and initial scale: a recording of ``--worlds`` x ``--steps`` (:func:`~dexmots_rl.sysid.synthetic_trajectories`,
measurement noise ``--position-noise`` / ``--angle-noise``) is identified by every method from the truth scaled
by ``--scales`` (a positive parameter multiplied, a rest position shifted by ``(scale - 1) / 2`` rad or m). A method
*reaches* the error when every parameter is within ``--tolerance`` of the truth (relative; a rest position's
error against at least 0.1 rad or m, as its truth may be 0); reported: the simulated world-steps (forward; reverse ones apart) and the process CPU
seconds spent until then, and the final errors.
"""

from __future__ import annotations

import logging
import statistics

import numpy as np

__all__ = ["add_sysid_parser", "run_sysid_bench", "format_sysid_table"]

log = logging.getLogger(__name__)


def add_sysid_parser(sub) -> None:
    p = sub.add_parser("sysid", help="identification cost: gradients vs FD Gauss-Newton vs CMA-ES")
    p.add_argument("--task", default="screw_claw")
    p.add_argument("--object", default=None, help="the library object (or URDF) of operate / a tool task")
    p.add_argument("--initial", default=None, help="the hand's start (task.initial; e.g. open: no pre-grasp search)")
    p.add_argument("--params", nargs="+", default=None, help="parameter names, in the order counts take them")
    p.add_argument("--counts", type=int, nargs="+", default=None, help="parameter counts (default: all of them)")
    p.add_argument("--truth", nargs="+", default=[], metavar="NAME=VALUE",
                   help="true values (default: the scene's nominal ones)")
    p.add_argument("--methods", nargs="+", default=["lbfgs", "gn", "fd-gn", "cmaes"],
                   help="lbfgs, gn, fd-gn, cmaes, and lbfgs+starts (L-BFGS estimating the segments' start states too)")
    p.add_argument("--seeds", type=int, nargs="+", default=[0])
    p.add_argument("--scales", type=float, nargs="+", default=[0.5, 2.0])
    p.add_argument("--worlds", type=int, default=4)
    p.add_argument("--steps", type=int, default=48)
    p.add_argument("--segment-steps", type=int, default=8)
    p.add_argument("--position-noise", type=float, default=0.0)
    p.add_argument("--angle-noise", type=float, default=0.0)
    p.add_argument("--iterations", type=int, default=40)
    p.add_argument("--tolerance", type=float, default=0.05)
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.add_argument("-q", "--quiet", action="store_true", help="log only warnings to stderr (no progress)")


def _truth(args, scene_values: dict) -> dict:
    truth = dict(scene_values)
    for item in args.truth:
        name, sep, value = item.partition("=")
        if not sep or name not in truth:
            raise ValueError(f"--truth {item!r}: expected NAME=VALUE with NAME one of {', '.join(truth)}")
        truth[name] = float(value)
    return truth


def _errors(values: np.ndarray, truth: np.ndarray, positive: np.ndarray) -> np.ndarray:
    """Relative errors; a rest position's against at least 0.1 (rad or m: its truth may be 0)."""
    return np.abs(values - truth) / np.where(positive, np.abs(truth), np.maximum(np.abs(truth), 0.1))


def _initial(names, truth: dict, scale: float, log_space: np.ndarray) -> dict:
    return {n: truth[n] * scale if positive else truth[n] + 0.5 * (scale - 1.0) for n, positive in zip(names, log_space)}


def run_sysid_bench(args) -> dict:
    from ..envs import make_env
    from ..sysid import ShootingProblem, identify, synthetic_trajectories
    from ..sysid.problem import is_positive

    overrides = {key: value for key, value in (("object", args.object), ("initial", args.initial)) if value}
    env = make_env(args.task, num_envs=1, raw=True, **overrides)
    scene_values = {k: v for k, v in env.sim.default_param_values().items() if k != "variant"}
    truth = _truth(args, scene_values)
    names = list(args.params or scene_values)
    counts = args.counts or [len(names)]
    rows = []
    for seed in args.seeds:
        data = synthetic_trajectories(args.task, truth, worlds=args.worlds, steps=args.steps, seed=seed,
                                      position_noise=args.position_noise, angle_noise=args.angle_noise, **overrides)
        for count in counts:
            chosen = names[:count]
            positive = np.array([is_positive(n) for n in chosen])
            true = np.array([truth[n] for n in chosen])
            for scale in args.scales:
                for method in args.methods:
                    problem = ShootingProblem(data, chosen, segment_steps=args.segment_steps, seed=seed,
                                              initial=_initial(chosen, truth, scale, positive),
                                              free_starts=method == "lbfgs+starts")
                    result = identify(problem, method.partition("+")[0], iterations=args.iterations, seed=seed)
                    reached = None
                    for record in result.history:
                        if _errors(problem.space.values_np(record["z"]), true, positive).max() <= args.tolerance:
                            reached = record
                            break
                    final = _errors(np.array([result.values[n] for n in chosen]), true, positive)
                    rows.append({"seed": seed, "count": count, "scale": scale, "method": method,
                                 "reached": reached is not None,
                                 "forward_steps": reached["forward_steps"] if reached else None,
                                 "backward_steps": reached["backward_steps"] if reached else None,
                                 "cpu_seconds": reached["cpu_seconds"] if reached else None,
                                 "final_max_error": float(final.max()), "final_loss": result.history[-1]["loss"],
                                 "condition_number": result.condition_number,
                                 "unidentifiable": result.unidentifiable,
                                 "total_cpu_seconds": result.history[-1]["cpu_seconds"]})
                    log.info("%s k=%d x%g seed %d: %s, max error %.3g", method, count, scale, seed,
                             "reached" if reached else "not reached", final.max())
    return {"task": args.task, "object": args.object, "names": names, "truth": {n: truth[n] for n in names},
            "worlds": args.worlds, "steps": args.steps, "segment_steps": args.segment_steps,
            "noise": {"position_m": args.position_noise, "angle_rad": args.angle_noise},
            "tolerance": args.tolerance, "rows": rows, "summary": _summary(rows)}


def _summary(rows: list[dict]) -> list[dict]:
    """Per (parameter count, method): how many runs reached the error, and their median cost."""
    out = []
    for count in sorted({r["count"] for r in rows}):
        for method in dict.fromkeys(r["method"] for r in rows):
            group = [r for r in rows if r["count"] == count and r["method"] == method]
            won = [r for r in group if r["reached"]]

            def median(key):
                return statistics.median(r[key] for r in won) if won else None

            out.append({"count": count, "method": method, "reached": f"{len(won)}/{len(group)}",
                        "forward_steps": median("forward_steps"), "backward_steps": median("backward_steps"),
                        "cpu_seconds": median("cpu_seconds"),
                        "final_max_error": statistics.median(r["final_max_error"] for r in group)})
    return out


def format_sysid_table(result: dict) -> str:
    lines = [f"{result['task']}: {result['worlds']} worlds x {result['steps']} steps, segments of "
             f"{result['segment_steps']}, noise {result['noise']}, tolerance {result['tolerance']:.0%}",
             f"{'params':>6} {'method':<7} {'reached':>8} {'fwd steps':>10} {'rev steps':>10} {'CPU s':>8} "
             f"{'final err':>10}"]
    for s in result["summary"]:
        def fmt(v, spec):
            return format(v, spec) if v is not None else "-"

        lines.append(f"{s['count']:>6} {s['method']:<7} {s['reached']:>8} {fmt(s['forward_steps'], '>10.0f')} "
                     f"{fmt(s['backward_steps'], '>10.0f')} {fmt(s['cpu_seconds'], '>8.2f')} "
                     f"{s['final_max_error']:>10.2%}")
    return "\n".join(lines)
