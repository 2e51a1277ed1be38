"""Where a tool task's env step spends its CPU time, kernel by kernel, forward and reverse.

    DEXMOTS_CPU_THREADS=1 python benchmarks/articulated_kernels.py --tasks spray_bottle drawer scissors

From the task's bench state (``dexmots-bench throughput``'s: the pre-grasp pose, squeezed, settled into contact),
one taped env step's recorded launches and its reverse pass's are each timed alone on one core (this process's CPU
time, best of ``--repeats`` rounds; the launches of all substeps summed per kernel). Prints one JSON line per task:
milliseconds per env step of every kernel (all worlds), forward and reverse, and the totals. The simulator's own
threads are set by ``DEXMOTS_CPU_THREADS`` (use 1: the timings are of one block of worlds). A knob or cube task
(``screw_claw``...) runs its scene read as an object tree (``load_scene(path, articulated=True)``).
"""

from __future__ import annotations

import argparse
import collections
import json
import time


def profile(task: str, worlds: int, repeats: int) -> dict:
    from dexmots_rl.apps.bench_setup import bench_env
    from dexmots_rl.apps.bench_throughput import SimBench
    from dexmots_rl.sim import ArticulatedScene, load_scene

    env = bench_env(task)
    scene = env.sim.scene
    if not isinstance(scene, ArticulatedScene):  # a knob or cube task: its scene read as an object tree
        scene = load_scene(scene.path, contact=env.sim.contact, articulated=True)
    bench = SimBench(scene, env.bench_poses(), worlds, "cpu", 16, 20, 1, "state", env.sim.contact)
    traj, grads = bench._taped_step()
    traj.backward(grads)  # records the adjoint launches
    (lo, _), = traj.blocks  # one block with DEXMOTS_CPU_THREADS=1
    names = traj.kernel_names
    passes = {"forward": (traj._forward_cmds[lo], names, lambda: [a.zero_() for a in traj.accumulated]),
              "reverse": (traj._reverse_cmds[lo], names[::-1], lambda: None)}
    out = {"task": task, "worlds": worlds}
    for what, (cmds, kernels, before) in passes.items():
        best = collections.defaultdict(lambda: float("inf"))
        for _ in range(repeats):
            spent = collections.Counter()
            before()
            for cmd, name in zip(cmds, kernels):
                start = time.process_time()
                cmd()
                spent[name] += time.process_time() - start
            for name, t in spent.items():
                best[name] = min(best[name], t)
        ms = {name: round(1e3 * t, 3) for name, t in sorted(best.items(), key=lambda kv: -kv[1])}
        out[f"{what}_ms"] = ms
        out[f"{what}_total_ms"] = round(sum(ms.values()), 3)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=["spray_bottle", "drawer", "scissors"])
    parser.add_argument("--num-envs", type=int, default=256)
    parser.add_argument("--repeats", type=int, default=5, help="timed rounds; each kernel's best is reported")
    args = parser.parse_args()
    for task in args.tasks:
        print(json.dumps(profile(task, args.num_envs, args.repeats)), flush=True)


if __name__ == "__main__":
    main()
