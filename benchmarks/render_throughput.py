"""RGB observation throughput of task ``operate``: env-steps/s with and without 64x64 images, and the renderer alone.

    python benchmarks/render_throughput.py [--objects spray_bottle_a drawer_a scissors_a] [--num-envs 16 64 256]
        [--size 64] [--steps 16] [--min-time 2] [--device cpu] [--json]

For each object and world count: ``state`` and ``rgb`` are env-steps/s of ``env.rollout`` with random actions
(``make_env("operate", object=..., differentiable=False)``, alone or with the :class:`RGBObservation` that
``obs="rgb"`` appends, at ``--size``: it renders an image of every world after each reset and step); ``render`` is
images/s of :meth:`MeshRenderer.render_state` alone on the rollout's last states. Each rate is the best of
``--repeats`` windows of at least ``--min-time`` seconds (the first rollout, which compiles and caches the kernels,
is not timed). The report names the machine (CPU, cores, GPU), the date and the commit.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import time

import torch

from dexmots_rl.envs import make_env
from dexmots_rl.envs.pixels import RGBObservation

__all__: list[str] = []


def _rate(fn, min_time: float, repeats: int, sync) -> float:
    """Best of ``repeats`` windows: ``fn()`` returns the work it did; work per second."""
    best = 0.0
    for _ in range(repeats):
        sync()
        done, start = 0, time.perf_counter()
        while time.perf_counter() - start < min_time:
            done += fn()
            sync()
        best = max(best, done / (time.perf_counter() - start))
    return best


def measure(name: str, n: int, args) -> dict:
    sync = torch.cuda.synchronize if args.device.startswith("cuda") else (lambda: None)
    row = {"object": name, "num_envs": n}
    for obs in ("state", "rgb"):
        env = make_env("operate", object=name, num_envs=n, differentiable=False, seed=0, device=args.device)
        if obs == "rgb":  # what obs="rgb" appends, at --size
            env.append_transform(RGBObservation(height=args.size, width=args.size))
        td = env.rollout(args.steps, break_when_any_done=False)  # compiles, fills the caches

        def chunk(env=env):
            env.rollout(args.steps, break_when_any_done=False)
            return args.steps * n
        row[obs] = _rate(chunk, args.min_time, args.repeats, sync)
        if obs == "rgb":
            pixels = env.transform[-1]
            q = td["next", "sim", "joint_q"][:, -1].contiguous()
            renderer, sim = pixels.renderer, env.base_env.sim
            row["render"] = _rate(lambda: (renderer.render_state(sim, q), n)[1], args.min_time, args.repeats, sync)
    return row


def _machine(device: str) -> dict:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    gpu = torch.cuda.get_device_name(torch.device(device)) if device.startswith("cuda") else None
    return {"cpu": cpu, "cores": len(os.sched_getaffinity(0)), "gpu": gpu, "device": device,
            "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"), "commit": commit,
            "load_1min": os.getloadavg()[0]}


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--objects", nargs="+", default=["spray_bottle_a", "drawer_a", "scissors_a"])
    p.add_argument("--num-envs", nargs="+", type=int, default=[16, 64, 256])
    p.add_argument("--size", type=int, default=64, help="image height and width (pixels)")
    p.add_argument("--steps", type=int, default=16, help="env steps per timed rollout")
    p.add_argument("--min-time", type=float, default=2.0, help="seconds per timed window")
    p.add_argument("--repeats", type=int, default=2, help="timed windows per rate (the best is kept)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    args = p.parse_args(argv)
    report = {"machine": _machine(args.device), "size": args.size,
              "rows": [measure(name, n, args) for name in args.objects for n in args.num_envs]}
    if args.json:
        print(json.dumps(report, indent=1))
        return
    print(report["machine"], file=sys.stderr)
    print(f"{'object':<16} {'worlds':>6} {'state':>10} {'rgb':>10} {'render img/s':>13}")
    for r in report["rows"]:
        print(f"{r['object']:<16} {r['num_envs']:>6} {r['state']:>10.0f} {r['rgb']:>10.0f} {r['render']:>13.0f}")


if __name__ == "__main__":
    main()
