"""``dexmots-bench``: simulator throughput against MuJoCo, and gradient quality against finite differences.

    dexmots-bench throughput --task screw_claw --json [--num-envs 1 16 64 256 1024] [--device cuda] [--obs rgb]
    dexmots-bench throughput --all --json --num-envs 256   # every registered task against MuJoCo, per CPU-second too
    dexmots-bench grad --task screw_claw --json [--horizons 1 8 32] [--eps 1e-6] [--draws 8]
    dexmots-bench grad --task spray_bottle --json --draws 2          # a tool task, from its pre-grasp
    dexmots-bench grad --task operate --object jar_a --json --draws 2 # any library object
    dexmots-bench pipeline --task screw_claw --json [--num-envs 64 256]   # env/collector vs kernels
    dexmots-bench baselines --task screw_claw --json [--methods ppo sac pgdm]  # vs torchrl's sota loops
    dexmots-bench plan --task screw_claw --json [--iterations 200]
    dexmots-bench train --task screw_claw [--algo ahac|shac] [--seeds 0 1 2 3] --json [hydra overrides ...]
    dexmots-bench compile --device cuda --arch 90 (--task allegro_rotate [...] | --all) [--jobs 2]  # PTX, no GPU
    dexmots-bench gpu --out gpu_check.json   # every figure on one GPU in one JSON file (scripts/gpu_check.sh)
    dexmots-bench sysid --task screw_claw --json [--counts 2 4] [--methods lbfgs gn fd-gn cmaes]  # identification
    dexmots-bench sysid-loop --task screw_claw --seeds 0 1  # train on a wrong, the identified and the true model
    dexmots-bench diagnose --task jar --json [--run <run_dir or checkpoint>] [--horizons 1 4 16 32] [--num-envs 4]

Every number is measured in the same run (nothing is read from files but, for ``diagnose``, the diagnosed
run's own). The result is printed to stdout as one JSON object with ``--json``, a table otherwise; progress goes
to stderr. The logic lives in :mod:`.bench_throughput`, :mod:`.bench_grad`, :mod:`.bench_baselines`,
:mod:`.bench_compile`, :mod:`.bench_gpu`, :mod:`.bench_sysid`, :mod:`.bench_sysid_loop` and
:mod:`.bench_diagnose`; ``compile`` and ``gpu`` always print JSON, and ``compile`` exits non-zero when a kernel
failed to compile.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import statistics
import sys

from ..envs import list_tasks
from ._cli import errors_as_one_line
from .bench_sysid import add_sysid_parser, format_sysid_table, run_sysid_bench
from .bench_sysid_loop import add_sysid_loop_parser, format_sysid_loop_table, run_sysid_loop
from .bench_gpu import GPU_TASKS
from .bench_setup import TRAIN_GOAL_SUCCESS, bench_tasks, grad_bench_tasks, train_one

__all__ = ["GOALS", "build_parser", "format_table", "run", "main"]

log = logging.getLogger(__name__)

# targets the gradient benchmark reports against (not used to tune anything)
GOALS = {"median_rel_err_with_contact": 0.05, "grad_growth_at_longest_horizon": 10.0}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="dexmots-bench", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="bench", required=True)

    def common(p, tasks=None):
        p.add_argument("--task", default="screw_claw", choices=tasks or bench_tasks())
        p.add_argument("--device", default="cpu", help="cpu or cuda[:i]")
        p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
        p.add_argument("-q", "--quiet", action="store_true", help="log only warnings to stderr (no progress)")

    p = sub.add_parser("throughput", help="env-steps/s per wall and CPU second: forward, forward+backward, MuJoCo")
    common(p, list_tasks())  # any registered task, on its own scene
    p.add_argument("--all", action="store_true", help="every registered task, one row per task and world count")
    p.add_argument("--object", default=None,
                   help="the library object operate or a tool task operates (default: the task's own)")
    p.add_argument("--num-envs", type=int, nargs="+", default=[1, 16, 64, 256])
    p.add_argument("--substeps", type=int, default=16)
    p.add_argument("--min-time", type=float, default=1.0, help="seconds of timed work per number")
    p.add_argument("--settle-steps", type=int, default=20, help="env steps from the open pose into contact")
    p.add_argument("--chunk-steps", type=int, default=16, help="env steps per timed chunk (from the contact state)")
    p.add_argument("--obs", default="state", choices=["state", "rgb"],
                   help="rgb: also render a 64x64 image of every world after each step (ours only)")

    p = sub.add_parser("pipeline", help="env.rollout and a torchrl Collector (+VecNorm) against the kernels")
    common(p)
    p.add_argument("--num-envs", type=int, nargs="+", default=[64, 256])
    p.add_argument("--steps", type=int, default=50, help="env steps per timed chunk")
    p.add_argument("--min-time", type=float, default=2.0, help="seconds of timed work per number")
    p.add_argument("--torch-threads", type=int, default=1, help="torch intra-op threads (0: torch's default)")

    p = sub.add_parser("baselines", help="PPO / SAC / PGDM loops: env-steps/s and updates/s against torchrl's "
                                         "sota implementations on the same env")
    p.add_argument("--task", default="screw_claw", choices=list_tasks())
    p.add_argument("--methods", nargs="+", default=["ppo", "sac", "pgdm"], choices=["ppo", "sac", "pgdm"])
    p.add_argument("--iterations", type=int, default=6, help="collector iterations per loop (the first is warm-up)")
    p.add_argument("--num-envs", type=int, default=64)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--torch-threads", type=int, default=1, help="torch intra-op threads (0: torch's default)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.add_argument("-q", "--quiet", action="store_true", help="log only warnings to stderr (no progress)")
    p.add_argument("overrides", nargs="*", help="hydra overrides of both loops' configs, e.g. algo.hidden=[128]; "
                                                "sac:algo.batch_size=256 for one method's only")

    p = sub.add_parser("grad", help="AD vs central finite differences in float64")
    common(p, grad_bench_tasks())
    p.add_argument("--object", default=None,
                   help="the library object operate or a tool task operates (default: the task's own)")
    p.add_argument("--horizons", type=int, nargs="+", default=[1, 8, 32])
    p.add_argument("--eps", type=float, default=1e-6)
    p.add_argument("--num-entries", type=int, default=16, help="action entries checked per row")
    p.add_argument("--floor-rel", type=float, default=1e-3,
                   help="rel_err denominator floor, relative to max |dL/da| of the row")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--draws", type=int, default=8, help="random action sequences per row (medians reported)")

    p = sub.add_parser("plan", help="wrench planning through the simulator: tracking-error reduction")
    common(p)
    p.add_argument("--iterations", type=int, default=200)

    p = sub.add_parser("train", help="train from scratch with dexmots-train's defaults, evaluate, time it")
    common(p, list_tasks())  # any task dexmots-train trains, bench poses or not
    p.add_argument("--algo", default="ahac", choices=["shac", "ahac"], help="default: dexmots-train's")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--seeds", type=int, nargs="+", default=None,
                   help="train once per seed and report the mean and sample s.d. of the success rate")
    p.add_argument("--run-dir", default=None, help="default: runs/bench_<task>_<algo>_seed<seed>")
    p.add_argument("overrides", nargs="*", help="extra hydra overrides, e.g. algo.iterations=300")

    p = sub.add_parser("compile", help="compile every kernel of a task's scene ahead of time (CUDA: no GPU needed)")
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--task", nargs="+", choices=list_tasks(), help="one task or several")
    which.add_argument("--all", action="store_true", help="every registered task")
    p.add_argument("--device", default="cuda", choices=["cuda", "cpu"])
    p.add_argument("--arch", type=int, default=90, help="CUDA compute capability, e.g. 80 (A100), 90 (H100/H200); "
                   "0: this machine's GPU (its own build, loaded on it)")
    p.add_argument("--dtypes", nargs="+", default=["float32"], choices=["float32", "float64"])
    p.add_argument("--jobs", type=int, default=1, help="compile each (task, float type) in its own process")
    p.add_argument("--json", action="store_true", help="accepted for symmetry: the result is always JSON")
    p.add_argument("-q", "--quiet", action="store_true", help="log only warnings to stderr (no progress)")

    p = sub.add_parser("gpu", help="throughput, gradients, CPU agreement and a 3-minute training on one GPU, "
                                   "into one JSON file")
    p.add_argument("--device", default="cuda", help="cuda[:i]; cpu runs the same check (tiny sizes in the tests)")
    p.add_argument("--out", default="gpu_check.json", help="the JSON file (rewritten after every section)")
    p.add_argument("--tasks", nargs="+", default=list(GPU_TASKS), choices=list_tasks())
    p.add_argument("--num-envs", type=int, nargs="+", default=[1024, 4096, 16384])
    p.add_argument("--rgb-envs", type=int, default=4096, help="worlds of the RGB 64x64 rows")
    p.add_argument("--min-time", type=float, default=0.5, help="seconds of timed work per number")
    p.add_argument("--pipeline-steps", type=int, default=32, help="env steps per timed rollout / collector batch")
    p.add_argument("--grad-horizon", type=int, default=8)
    p.add_argument("--grad-draws", type=int, default=4)
    p.add_argument("--agree-steps", type=int, default=100)
    p.add_argument("--agree-envs", type=int, default=16)
    p.add_argument("--train-envs", type=int, default=1024)
    p.add_argument("--train-seconds", type=float, default=180.0)
    p.add_argument("--eval-episodes", type=int, default=100)
    p.add_argument("--compile-jobs", type=int, default=None, help="default: min(8, cores)")
    p.add_argument("--run-dir", default="runs/gpu_check", help="the training run's directory (overwritten)")
    p.add_argument("--json", action="store_true", help="accepted for symmetry: the result is always JSON")
    p.add_argument("-q", "--quiet", action="store_true", help="log only warnings to stderr (no progress)")
    p.add_argument("overrides", nargs="*", help="extra hydra overrides for the training, e.g. algo.horizon=16")
    p = sub.add_parser("diagnose", help="a policy's gradient through the simulator (growth with horizon, capped "
                                        "adjoints, first- vs zeroth-order) and the actions it explores")
    p.add_argument("--task", default=None, choices=list_tasks(), help="default: the run's")
    p.add_argument("--run", default=None, help="a run directory or checkpoint (default: the initial policy)")
    p.add_argument("--zero-mean", action="store_true", help="zero pre-tanh mean actions instead of a policy's")
    p.add_argument("--horizons", type=int, nargs="+", default=[1, 4, 16, 32])
    p.add_argument("--num-envs", type=int, default=4, help="start states (each copied into 2 x pairs worlds)")
    p.add_argument("--pairs", type=int, default=32, help="antithetic pairs per start state (zeroth-order estimate)")
    p.add_argument("--start-steps", type=int, default=0, help="steps of the policy's mean action after the reset")
    p.add_argument("--adjoint-clip", default="run", help="the cap of the gradient through the simulator: 'run' (the "
                                                         "run's or default config's algo.adjoint_clip), a number, none")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default="cpu", help="cpu or cuda[:i]")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.add_argument("-q", "--quiet", action="store_true", help="log only warnings to stderr (no progress)")
    add_sysid_parser(sub)
    add_sysid_loop_parser(sub)
    return parser


def _grad_goals(result: dict) -> dict:
    rows = result["rows"]
    longest = max(r["horizon"] for r in rows)
    met = {"median_rel_err_with_contact": all(r["median_rel_err"] <= GOALS["median_rel_err_with_contact"]
                                              for r in rows if r["contact"])}
    # judged on the velocity loss: a position loss grows ~H^2 backward without any contact (the lever arm of
    # early actions, see bench_grad), so its ratio is reported but says nothing about amplification
    met["grad_growth_at_longest_horizon"] = all(
        r["grad_growth"] <= GOALS["grad_growth_at_longest_horizon"]
        for r in rows if r["horizon"] == longest and r.get("loss_kind") == "velocity" and r["contact"])
    return met


def format_table(result: dict) -> str:
    """A readable table of a result dict."""
    rows = result["rows"]
    cols = list(rows[0])
    fmt = {bool: str, int: str, float: lambda x: f"{x:.4g}"}
    cells = [[fmt.get(type(r[c]), str)(r[c]) for c in cols] for r in rows]
    widths = [max(len(c), *(len(row[i]) for row in cells)) for i, c in enumerate(cols)]
    head = {k: v for k, v in result.items() if k not in ("rows", "goals", "goals_met")}
    lines = [" ".join(f"{k}={v}" for k, v in head.items()),
             "  ".join(c.rjust(w) for c, w in zip(cols, widths))]
    lines += ["  ".join(x.rjust(w) for x, w in zip(row, widths)) for row in cells]
    if "goals" in result:
        lines += [f"goal {k} <= {result['goals'][k.split('[')[0]]}: {'met' if met else 'NOT met'}"
                  for k, met in result["goals_met"].items()]
    return "\n".join(lines)


def run(argv: list[str] | None = None) -> dict:
    """Parse ``argv``, run the chosen benchmark, return its result dict (nothing printed to stdout)."""
    return _execute(build_parser().parse_args(argv))


def _execute(args: argparse.Namespace) -> dict:
    logging.basicConfig(level=logging.WARNING if args.quiet else logging.INFO, stream=sys.stderr,
                        format="%(asctime)s %(message)s")
    # warp reports kernel compilation with print(); keep stdout for the result alone
    with contextlib.redirect_stdout(sys.stderr):
        if args.bench == "throughput":
            from .bench_throughput import run_throughput, run_throughput_all

            options = dict(num_envs=args.num_envs, device=args.device, substeps=args.substeps, min_time=args.min_time,
                           settle_steps=args.settle_steps, chunk_steps=args.chunk_steps, obs=args.obs,
                           object_name=args.object)
            return run_throughput_all(list_tasks(), **options) if args.all else run_throughput(args.task, **options)
        if args.bench == "train":
            return _train_bench(args)
        if args.bench == "gpu":
            from .bench_gpu import run_gpu_check

            return run_gpu_check(args.device, args.tasks, args.num_envs, args.rgb_envs, args.min_time,
                                 args.pipeline_steps, args.grad_horizon, args.grad_draws, args.agree_steps,
                                 args.agree_envs, args.train_envs, args.train_seconds, args.overrides,
                                 args.eval_episodes, args.compile_jobs, args.run_dir, args.out)
        if args.bench == "compile":
            from .bench_compile import run_compile

            tasks = list_tasks() if args.all else args.task[0] if len(args.task) == 1 else args.task
            return run_compile(tasks, args.device, args.arch, args.dtypes, args.jobs)
        if args.bench == "pipeline":
            from .bench_pipeline import run_pipeline

            return run_pipeline(args.task, args.num_envs, args.steps, args.min_time, args.device,
                                args.torch_threads or None)
        if args.bench == "baselines":
            from .bench_baselines import run_baselines

            return run_baselines(args.task, args.methods, args.iterations, args.num_envs, args.seed,
                                 args.torch_threads or None, args.overrides)
        if args.bench == "sysid":
            return run_sysid_bench(args)
        if args.bench == "sysid-loop":
            return run_sysid_loop(args)
        if args.bench == "diagnose":
            from .bench_diagnose import adjoint_clip_option, diagnose

            return diagnose(args.task, args.run, args.horizons, args.num_envs, args.pairs, args.start_steps,
                            args.seed, args.zero_mean, adjoint_clip_option(args.adjoint_clip), args.device)
        if args.bench == "plan":
            from .plan import run_plan_bench

            return run_plan_bench(args.task, args.iterations)
        from .bench_grad import run_grad

        result = run_grad(args.task, args.horizons, args.eps, args.num_entries, args.floor_rel, args.seed,
                          args.device, args.draws, args.object)
        result["goals"], result["goals_met"] = dict(GOALS), _grad_goals(result)
        return result


def _train_bench(args: argparse.Namespace) -> dict:
    if not args.seeds:
        return train_one(args, args.seed, args.run_dir)
    # several seeds: one run each (run_dir/seed<N> when --run-dir is given), then mean and sample s.d.
    runs = [train_one(args, seed, f"{args.run_dir}/seed{seed}" if args.run_dir else None) for seed in args.seeds]
    def mean(key: str) -> float:
        return statistics.fmean(r[key] for r in runs)

    rates = [r["success_rate"] for r in runs]
    return {"task": args.task, "algo": args.algo, "seeds": list(args.seeds), "success_rate": mean("success_rate"),
            "success_rate_std": statistics.stdev(rates) if len(rates) > 1 else 0.0,
            "wall_clock_s": mean("wall_clock_s"), "env_steps": mean("env_steps"),
            "mean_final_error": mean("mean_final_error"), "goal_success_rate": TRAIN_GOAL_SUCCESS, "runs": runs}


def main(argv: list[str] | None = None) -> None:
    """Console entry point: print the result as JSON (``--json``) or as a table."""
    args = build_parser().parse_args(argv)
    with errors_as_one_line("dexmots-bench"):  # bad input (a GPU this machine lacks) and a full disk: one line
        # a GPU this machine lacks: before any work (compile builds for a CUDA arch without one)
        if getattr(args, "device", "cpu") != "cpu" and not (args.bench == "compile" and args.arch):
            from ..sim import check_device

            check_device(args.device)
        result = _execute(args)
    table = {"sysid": format_sysid_table, "sysid-loop": format_sysid_loop_table}.get(args.bench, format_table)
    print(json.dumps(result) if args.json or "rows" not in result else table(result))
    if result.get("ok") is False:  # dexmots-bench compile: a kernel failed (named on stderr and in the JSON)
        sys.exit(1)


if __name__ == "__main__":
    main()
