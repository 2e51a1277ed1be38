"""Forward throughput of the Allegro hand with an articulated library object, against MuJoCo on the same scene.

    python benchmarks/articulated_check.py --objects spray_bottle_a drawer_a scissors_a --num-envs 256

Prints one JSON line per object: our env-steps/s (forward, no gradients; and forward + backward), MuJoCo's
(``mj_step`` over every world in turn on one core, the same substeps of the same timestep, its own contact on
the same collision geometry), their ratio, the cost of a forward + backward step in forward steps, the CPU
threads our step used (``DEXMOTS_CPU_THREADS``, default: the cores this process may use), and the kernel
compile seconds of the first step (cold only on an empty warp cache). Each rate is the best of ``--repeats``
rounds; ``--clock cpu`` counts this process's CPU time instead of the wall-clock (on a shared machine, with
``DEXMOTS_CPU_THREADS=1``: both simulators on one core each).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import torch


CLOCKS = {"wall": time.perf_counter, "cpu": time.process_time}


def _rate(fn, steps: int, worlds: int, repeats: int, reset=lambda: None, clock=time.perf_counter) -> float:
    """Env-steps per second of ``clock``: the best of ``repeats`` timed rounds of ``steps`` calls, each round from
    ``reset()`` (on a shared machine the best round is the one least disturbed by other jobs)."""
    fn()  # warm
    best = 0.0
    for _ in range(repeats):
        reset()
        start = clock()
        for _ in range(steps):
            fn()
        best = max(best, steps * worlds / (clock() - start))
    return best


def measure(name: str, worlds: int, steps: int, repeats: int, clock: str = "wall") -> dict:
    import mujoco

    from dexmots_rl.assets.hand_scene import hand_object_scene_xml
    from dexmots_rl.assets.objects import load_object
    from dexmots_rl.sim import cpu_threads, load_scene, make_simulator

    folder = Path(tempfile.mkdtemp())
    path = folder / "scene.xml"
    path.write_text(hand_object_scene_xml(load_object(name), folder))
    sim = make_simulator(load_scene(path), num_worlds=worlds)
    q, qd = sim.initial_state()
    ctrl, params = sim.zero_control(), sim.default_params()
    start = time.perf_counter()
    with torch.no_grad():
        sim.step(q, qd, ctrl, params)
    compile_s = time.perf_counter() - start
    # both of ours roll out the same states from the initial one (the cost of a step depends on its contacts)
    state = {}

    def reset():
        state["q"], state["qd"] = q, qd

    def forward():
        with torch.no_grad():
            out = sim.step(state["q"], state["qd"], ctrl, params)
        state["q"], state["qd"] = out.joint_q, out.joint_qd

    tau = torch.zeros(worlds, sim.nu, requires_grad=True)

    def forward_backward():
        c = sim.zero_control()
        c.tau = tau
        out = sim.step(state["q"], state["qd"], c, params)
        out.joint_q.sum().backward()
        state["q"], state["qd"] = out.joint_q.detach(), out.joint_qd.detach()

    reset()
    tick = CLOCKS[clock]
    ours = _rate(forward, steps, worlds, repeats, reset, tick)
    ours_grad = _rate(forward_backward, steps, worlds, repeats, reset, tick)
    m = mujoco.MjModel.from_xml_path(str(path))
    datas = [mujoco.MjData(m) for _ in range(worlds)]

    def mujoco_step():
        for d in datas:
            mujoco.mj_step(m, d, nstep=sim.substeps)

    theirs = _rate(mujoco_step, max(2, steps // 4), worlds, repeats, clock=tick)
    return {"object": name, "worlds": worlds, "ours_forward": round(ours), "ours_forward_backward": round(ours_grad),
            "mujoco": round(theirs), "ratio": round(ours / theirs, 2),
            "backward_cost": round(ours / ours_grad, 2), "threads": cpu_threads(), "clock": clock, "compile_s": round(compile_s, 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--objects", nargs="+", default=["spray_bottle_a", "drawer_a", "scissors_a"])
    parser.add_argument("--num-envs", type=int, default=256)
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=3, help="timed rounds per figure; the best is reported")
    parser.add_argument("--clock", choices=sorted(CLOCKS), default="wall",
                        help="wall: env-steps per second; cpu: per CPU-second of this process (with "
                             "DEXMOTS_CPU_THREADS=1, one core each: other jobs on the machine move it little)")
    args = parser.parse_args()
    for name in args.objects:
        print(json.dumps(measure(name, args.num_envs, args.steps, args.repeats, args.clock)), flush=True)


if __name__ == "__main__":
    main()
