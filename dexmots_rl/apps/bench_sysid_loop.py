"""``dexmots-bench sysid-loop``: does identifying the object's physics recover the policy a true model would give?

One command runs the whole loop on a task whose object parameters ``task.object_params`` sets (every world then
simulates the file's values instead of its randomised ones):

1. the truth (``--truth NAME=VALUE ...``) and a nominal model wrong by ``--nominal-scale`` (each true value
   times it) are written as parameter files;
2. ``dexmots-record`` records ``--record-worlds`` episodes on the truth (the task's scripted controller where it
   has one, random actions elsewhere);
3. ``dexmots-sysid`` identifies the named parameters from that recording, starting from the nominal model, and
   writes the identified model's file;
4. for each seed, one policy is trained on each model (the truth, the nominal, the identified; the same method,
   budget and seed) and every policy is evaluated on the truth (``dexmots-eval --object-params``).

The result: each model's values, each policy's success on the truth per seed and its mean, and whether the
identified model's mean success is within ``--goal-points`` of the truth's. Every file (parameter files, the
recording, the identification's report, the runs) lies under ``--out-dir``, which a re-run overwrites.
"""

from __future__ import annotations

import argparse
import logging
import statistics
from pathlib import Path

from .sysid import _named_values

__all__ = ["MODELS", "add_sysid_loop_parser", "run_sysid_loop", "format_sysid_loop_table"]

log = logging.getLogger(__name__)

#: the models a policy is trained on, in the table's order
MODELS = ("truth", "nominal", "identified")


def add_sysid_loop_parser(sub) -> None:
    p = sub.add_parser("sysid-loop", help="train on a wrong nominal model, on the identified one and on the truth; "
                                          "evaluate each policy on the truth")
    p.add_argument("--task", default="screw_claw")
    p.add_argument("--truth", nargs="+", type=_named_values(float, "NAME=VALUE"), metavar="NAME=VALUE",
                   default=[("joint_damping", 1.0), ("joint_friction", 1.0)],
                   help="the true object parameters (default: the knob's damping and friction at 1.0)")
    p.add_argument("--nominal-scale", type=float, default=0.5,
                   help="the nominal model: every true value times this (0.5: the truth is twice the nominal)")
    p.add_argument("--record-worlds", type=int, default=8, help="episodes recorded on the truth")
    p.add_argument("--record-steps", type=int, default=None, help="steps per recorded episode (default: the task's)")
    p.add_argument("--method", default="lbfgs", help="dexmots-sysid's --method")
    p.add_argument("--sysid-iterations", type=int, default=30)
    p.add_argument("--algo", default="ahac", choices=["shac", "ahac"])
    p.add_argument("--seeds", type=int, nargs="+", default=[0])
    p.add_argument("--episodes", type=int, default=100, help="evaluation episodes on the truth per policy")
    p.add_argument("--goal-points", type=float, default=5.0,
                   help="the identified model's policy should be within this many points of the truth's")
    p.add_argument("--device", default="cpu")
    p.add_argument("--out-dir", default="runs/sysid_loop")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.add_argument("-q", "--quiet", action="store_true", help="log only warnings to stderr (no progress)")
    p.add_argument("overrides", nargs="*", help="hydra overrides of every training, e.g. algo.iterations=100")


def _check_truth(task: str, truth: dict[str, float], nominal_scale: float) -> None:
    """One ``ValueError`` naming the bad ``--truth`` item or ``--nominal-scale`` before any file is written."""
    from ..envs import make_env

    if not nominal_scale > 0 or nominal_scale == 1:
        raise ValueError(f"--nominal-scale must be positive and not 1 (a wrong model), got {nominal_scale}")
    known = make_env(task, num_envs=1, raw=True, differentiable=False).scene.param_names
    for name, value in truth.items():
        if name not in known or name == "variant":
            raise ValueError(f"--truth {name}={value}: task {task!r}'s object has no parameter {name!r}; its "
                             f"parameters are {', '.join(n for n in known if n != 'variant')}")
        if not value > 0:
            raise ValueError(f"--truth {name}={value}: must be positive (the nominal model scales it)")


def run_sysid_loop(args) -> dict:
    from ..algorithms.evaluation import evaluate_policy
    from ..algorithms.registry import policy_from_checkpoint
    from ..envs.object_params import write_object_params
    from .bench_setup import train_one
    from .record import run as record
    from .sysid import run as sysid

    truth = dict(args.truth)
    _check_truth(args.task, truth, args.nominal_scale)
    out = Path(args.out_dir).resolve()
    out.mkdir(parents=True, exist_ok=True)
    files = {model: out / f"{model}.json" for model in MODELS}
    nominal = {name: value * args.nominal_scale for name, value in truth.items()}
    write_object_params(files["truth"], args.task, truth)
    write_object_params(files["nominal"], args.task, nominal)

    log.info("recording %d episodes on the truth", args.record_worlds)
    data = out / "truth.mcap"
    record([f"task={args.task}", f"task.object_params={files['truth']}", f"num_envs={args.record_worlds}",
            f"out={data}", f"device={args.device}",
            *([f"steps={args.record_steps}"] if args.record_steps is not None else [])])
    log.info("identifying %s from the nominal model", ", ".join(truth))
    identified = sysid(["--data", str(data), "--params", *truth, "--out", str(files["identified"]),
                        "--method", args.method, "--iterations", str(args.sysid_iterations),
                        "--init", *(f"{name}={value}" for name, value in nominal.items())])

    models = {"truth": truth, "nominal": nominal, "identified": identified["values"]}
    runs = []
    for seed in args.seeds:
        for model in MODELS:
            run_dir = out / f"{model}_seed{seed}"
            log.info("training seed %d on the %s model", seed, model)
            train_args = argparse.Namespace(task=args.task, algo=args.algo, device=args.device, overrides=[
                f"task.object_params={files[model]}", "overwrite=true", *args.overrides])
            trained = train_one(train_args, seed, str(run_dir))
            actor, checkpoint = policy_from_checkpoint(run_dir, args.device)
            task_cfg = {**checkpoint["config"]["task"], "object_params": str(files["truth"])}
            on_truth = evaluate_policy(actor, task_cfg, args.episodes, device=args.device)
            runs.append({"model": model, "seed": seed, "success_on_truth": on_truth["success_rate"],
                         "final_error_on_truth": on_truth["mean_final_error"],
                         "success_on_own_model": trained["success_rate"], "env_steps": trained["env_steps"],
                         "train_wall_clock_s": trained["wall_clock_s"], "run_dir": str(run_dir)})
            log.info("seed %d, %s model: %.0f %% on the truth", seed, model, 100 * on_truth["success_rate"])

    mean = {model: statistics.fmean(r["success_on_truth"] for r in runs if r["model"] == model) for model in MODELS}
    gap = 100 * (mean["truth"] - mean["identified"])
    return {"task": args.task, "algo": args.algo, "seeds": list(args.seeds), "episodes": args.episodes,
            "models": models, "identification": identified, "rows": runs, "mean_success_on_truth": mean,
            "identified_gap_points": gap, "goal_points": args.goal_points, "goal_met": gap <= args.goal_points}


def format_sysid_loop_table(result: dict) -> str:
    models = result["models"]
    lines = [f"{result['task']} ({result['algo']}, seeds {result['seeds']}): success on the truth over "
             f"{result['episodes']} episodes"]
    for model in MODELS:
        values = ", ".join(f"{name}={value:.4g}" for name, value in models[model].items())
        per_seed = " / ".join(f"{100 * r['success_on_truth']:.0f}" for r in result["rows"] if r["model"] == model)
        mean = 100 * result["mean_success_on_truth"][model]
        lines.append(f"{model:>10}  {values:<48} {per_seed:>12} %  mean {mean:.1f} %")
    met = "met" if result["goal_met"] else "NOT met"
    lines.append(f"identified vs truth: {result['identified_gap_points']:.1f} points (goal <= "
                 f"{result['goal_points']:g}: {met})")
    return "\n".join(lines)
