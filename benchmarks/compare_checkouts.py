"""Two checkouts of the library on one host: the same dynamics and the same speed, any task.

    python benchmarks/compare_checkouts.py --old ../dexmots_rl-before --new . --rounds 3
    python benchmarks/compare_checkouts.py --old ../dexmots_rl-before --new . --tasks spray_bottle drawer

For each checkout (its repository root, put first on ``PYTHONPATH`` of a child process that runs this file in
``--worker`` mode), every task is rolled out for 60 steps from seed 0 with the same seeded random actions in 8
worlds, and the states, rewards and success flags of the two are compared (``max_abs_diff``; 0.0: bit-identical).
Speed is CPU time, not wall-clock: the process's user + system seconds per env step at 256 worlds in contact
(one simulator and one torch thread; the best of 5 chunks of ``dexmots-bench throughput``'s forward and forward +
backward, from the same bench state: a tool task's from its pre-grasp), so other jobs sharing the cores move it
little. Rounds alternate the checkouts. Prints one JSON object.
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

TASKS = ("screw_claw", "allegro_rotate", "repose_cube")


def worker(tasks, out_path: str) -> None:
    import torch

    torch.set_num_threads(1)
    from dexmots_rl.apps.bench_setup import bench_env, bench_task, bench_tasks, load_task_scene
    from dexmots_rl.apps.bench_throughput import SimBench
    from dexmots_rl.envs import make_env, task_contact

    rollouts, rates = {}, {}
    for task in tasks:
        env = make_env(task, num_envs=8, seed=0, differentiable=False)
        gen = torch.Generator().manual_seed(0)
        td, kept = env.reset(), {"q": [], "reward": [], "success": []}
        for _ in range(60):  # shorter than every task's episode: no resets
            td["action"] = 2 * torch.rand(env.batch_size + env.action_spec.shape[-1:], generator=gen) - 1
            td = env.step(td)
            for name, key in (("q", ("next", "sim", "joint_q")), ("reward", ("next", "reward")),
                              ("success", ("next", "success"))):
                kept[name].append(td[key].clone())
            td = td["next"]
        rollouts[task] = {name: torch.stack(values) for name, values in kept.items()}
        if task in bench_tasks():
            scene, poses, law = load_task_scene(task)[0], bench_task(task), task_contact(task)
        else:  # a tool task: dexmots-bench throughput's bench state
            bench_scene = bench_env(task)
            scene, poses, law = bench_scene.sim.scene, bench_scene.bench_poses(), bench_scene.sim.contact
        bench = SimBench(scene, poses, 256, "cpu", 16, 20, 16, "state", law)
        for kind, chunk in (("fwd", bench.forward_chunk), ("fwdbwd", bench.forward_backward_chunk)):
            chunk()
            best = 0.0
            for _ in range(5):
                start = time.process_time()
                steps = chunk()
                best = max(best, steps / (time.process_time() - start))
            rates[f"{task}/{kind}"] = best
    torch.save({"rollouts": rollouts, "rates": rates}, out_path)


def run_checkout(root: str, tasks, folder: str, tag: str) -> dict:
    import torch

    out = str(Path(folder) / f"{tag}.pt")
    env = {**os.environ, "PYTHONPATH": str(Path(root).resolve()), "DEXMOTS_CPU_THREADS": "1"}
    subprocess.run([sys.executable, __file__, "--worker", out, *tasks], env=env, check=True, cwd=folder)
    return torch.load(out)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--old", help="the older checkout's repository root")
    p.add_argument("--new", help="the newer checkout's repository root")
    p.add_argument("--tasks", nargs="+", default=list(TASKS))
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--worker", help=argparse.SUPPRESS)
    args, rest = p.parse_known_args()
    if args.worker:
        worker(rest or args.tasks, args.worker)
        return
    if not (args.old and args.new):
        p.error("--old and --new are required")
    rates = {"old": [], "new": []}
    with tempfile.TemporaryDirectory() as folder:
        for r in range(args.rounds):
            results = {tag: run_checkout(root, args.tasks, folder, f"{tag}{r}")
                       for tag, root in (("old", args.old), ("new", args.new))}
            for tag in rates:
                rates[tag].append(results[tag]["rates"])
    old, new = results["old"]["rollouts"], results["new"]["rollouts"]
    same = {task: {name: float((old[task][name].double() - new[task][name].double()).abs().max())
                   for name in old[task]} for task in args.tasks}
    print(json.dumps({"max_abs_diff": same, "env_steps_per_cpu_s": rates}, indent=1))


if __name__ == "__main__":
    main()
