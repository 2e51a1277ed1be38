"""Every method's training speed with torch's own intra-op threads against one thread, on the same host, in one run.

    python benchmarks/threads.py --seconds 40 --json threads.json

For each method (``--methods``; screw_claw, seed 0) and each ``torch_threads`` setting (``--settings``: ``default``
is torch's own count, the machine's cores), ``dexmots-train`` trains for ``--seconds`` of training wall-clock
(``budget.wall_clock_s``) with a 2-episode final evaluation; the settings alternate per method, and ``--rounds``
repeats the whole sweep, so load from other jobs falls on both. The rates come from each run's ``metrics.jsonl``:
iterations/s and env-steps/s of training, and for SAC gradient updates/s (its random-action phase shortened to
one batch, the update-to-data ratio 0.25 of the README's example); over the whole run, and ``steady_*`` from the
end of the first iteration (kernel loading, warm-up) where a run made three or more. MPC trains nothing: its rate is the
env steps its planner takes per second in a 4-episode evaluation. Prints one JSON object (``--json``: also writes it).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

__all__: list[str] = []

METHODS = ("ahac", "shac", "ppo", "sac", "pgdm", "mpc")
# per method: the overrides that make a short run measure its steady state
METHOD_OVERRIDES = {
    "sac": ["algo.utd_ratio=0.25", "algo.init_random_frames=640"],
    "mpc": ["eval.episodes=4"],
}


def train_bin() -> str:
    """``dexmots-train`` beside this interpreter (the venv's), else the one on PATH."""
    here = Path(sys.executable).with_name("dexmots-train")
    return str(here) if here.exists() else "dexmots-train"


def rates(run_dir: Path, method: str) -> dict:
    """Training rates of one finished run, from its ``metrics.jsonl``: over the whole run, and (``steady_*``, with
    three iterations or more) from the end of the first iteration, which includes loading the kernels and warming
    up, to the end of the last."""
    rows = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines() if line.strip()]
    first, last = rows[0], rows[-1]
    wall = float(last["wall_clock_s"])
    out = {"iterations": last["iteration"], "env_steps": last["env_steps"], "wall_clock_s": wall,
           "env_steps_per_s": last["env_steps"] / wall}
    if method == "mpc":  # one row: the evaluation's env steps over its wall-clock
        return out
    out["iterations_per_s"] = last["iteration"] / wall
    if "updates" in last:
        out["updates_per_s"] = last["updates"] / wall
    span = wall - float(first["wall_clock_s"])
    if len(rows) >= 3 and span > 0:
        out["steady_iterations_per_s"] = (last["iteration"] - first["iteration"]) / span
        out["steady_env_steps_per_s"] = (last["env_steps"] - first["env_steps"]) / span
        if "updates" in last:
            out["steady_updates_per_s"] = (last["updates"] - first["updates"]) / span
    return out


def run_once(method: str, setting: str, seconds: float, workdir: Path) -> dict:
    run_dir = workdir / f"{method}_{setting}_{time.monotonic_ns()}"
    threads = "null" if setting == "default" else setting
    cmd = [train_bin(), f"algo={method}", f"torch_threads={threads}", f"budget.wall_clock_s={seconds}",
           "eval.episodes=2", "progress=false", "checkpoint_every=100000", f"run_dir={run_dir}",
           *METHOD_OVERRIDES.get(method, [])]
    env = {k: v for k, v in os.environ.items() if k != "DEXMOTS_CPU_THREADS"}
    start = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stderr[-2000:]}")
    return {"setting": setting, "process_s": round(time.perf_counter() - start, 1), **rates(run_dir, method)}


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    p.add_argument("--settings", nargs="+", default=["default", "1"], help="torch_threads values; default: torch's")
    p.add_argument("--seconds", type=float, default=40.0, help="training wall-clock of each run")
    p.add_argument("--rounds", type=int, default=1)
    p.add_argument("--json", default=None, help="also write the result here")
    args = p.parse_args(argv)
    import torch

    result = {"host_cores": os.cpu_count(), "torch_default_threads": torch.get_num_threads(),
              "load_average_start": os.getloadavg(), "seconds": args.seconds, "runs": {m: [] for m in args.methods}}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            for method in args.methods:
                order = args.settings if r % 2 == 0 else list(reversed(args.settings))
                for setting in order:
                    row = run_once(method, setting, args.seconds, Path(tmp))
                    print(json.dumps({"method": method, **row}), file=sys.stderr, flush=True)
                    result["runs"][method].append(row)
    result["load_average_end"] = os.getloadavg()
    text = json.dumps(result, indent=1)
    print(text)
    if args.json:
        Path(args.json).write_text(text + "\n")
    return result


if __name__ == "__main__":
    main()
