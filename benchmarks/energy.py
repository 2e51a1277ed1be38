"""Bang-bang fingers against a task's object: how fast the strikes fling it, and whether contact adds energy.

    python benchmarks/energy.py                                  # every tool task, repose_cube, allegro_rotate
    python benchmarks/energy.py --tasks repose_cube --num-envs 64 --steps 2000
    python benchmarks/energy.py --objects pliers_b valve_c       # library objects on the ``operate`` task

From each world's start state (the task's reset: a tool in its pre-grasp, the cube on the palm) every hand joint
gets its full motor torque (``gear`` x ±1, a random sign per world and joint) whose sign flips every step, for
``--steps`` steps (``--hold k``: new random signs every k steps instead, as tests/test_articulated.py's). Prints
one JSON line per task: the object's peak base speed (m/s), spin (rad/s) and height gain (m, its origin above its
start; speed and spin count a free object until it falls 0.1 m below its start, ``fallen_worlds`` counts those),
its part joints' peak speed (rad/s or m/s; the knob's hinge), and the largest excess of its energy gain over the
work the motors did up to then (J; kinetic energy of every body, gravity, the joint springs: sim/_energy.py),
beside ``release_j``, the most the hand's links can give by falling 0.2 m. An excess above ``release_j`` is energy
the contact made (``worlds_making_energy`` counts those worlds). ``worlds_outside_physics`` counts the worlds that
ever left it (``HandSimulator.outside_physics``: an object sample deep in the table, a part far past its stop).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch

GRAVITY = 9.81
HAND_DROP = 0.2  # m: the most a link of the fixed-mount hand can fall
FALLEN = 0.1  # m: a free object this far below its start has left the hand (peaks stop counting it)


def measure(task: str, worlds: int, steps: int, seed: int, overrides: dict, hold: int = 0,
            substeps: int | None = None) -> dict:
    from dexmots_rl.envs import make_env
    from dexmots_rl.sim import make_simulator

    env = make_env(task, num_envs=worlds, seed=seed, raw=True, differentiable=False, **overrides)
    sim = env.sim
    if substeps is not None:  # the same scene, contact law and env step, cut into more (or fewer) substeps
        sim = make_simulator(sim.scene, num_worlds=worlds, contact=sim.contact, substeps=substeps, dt=sim.dt)
    td = env.reset()
    q, qd = td["sim", "joint_q"].clone(), td["sim", "joint_qd"].clone()
    params = {name: td["sim", "params", name] for name in sim.scene.param_names}
    step_params = params or sim.default_params()  # a free cube has no parameters
    nu = sim.nu
    free = sim.object_is_free

    def energy(q, qd):
        return sim.object_energy(q, qd, params)

    gear = torch.as_tensor(sim.scene.actuator_gear, dtype=sim.dtype)
    gen = torch.Generator().manual_seed(seed)

    def draw():
        return torch.where(torch.rand(worlds, nu, generator=gen) < 0.5, -1.0, 1.0).to(sim.dtype)

    sign = draw()
    ctrl = sim.zero_control()
    e0, start_z = energy(q, qd), q[:, nu + 2].clone() if free else None
    work = torch.zeros(worlds, dtype=sim.dtype)
    excess = torch.full((worlds,), -float("inf"), dtype=sim.dtype)
    outside = torch.zeros(worlds, dtype=torch.bool)
    speed = spin = height = joint_speed = 0.0
    near = torch.ones(worlds, dtype=torch.bool)  # the object still within the hand's reach (not fallen away)
    start = time.perf_counter()
    with torch.no_grad():
        for step in range(steps):
            ctrl.tau = sign * gear
            out = sim.step(q, qd, ctrl, step_params)
            work += (ctrl.tau * (out.joint_q[:, :nu] - q[:, :nu])).sum(-1)
            q, qd = out.joint_q, out.joint_qd
            excess = torch.maximum(excess, energy(q, qd) - e0 - work.clamp(min=0))
            outside |= sim.outside_physics(q, out.body_pose, step_params).cpu()
            if free:
                # a cube that fell off the palm falls on (the scene has no floor): its speed is gravity's
                near &= q[:, nu + 2] > start_z - FALLEN
                if near.any():
                    speed = max(speed, float(qd[near, nu:nu + 3].norm(dim=-1).max()))
                    spin = max(spin, float(qd[near, nu + 3:nu + 6].norm(dim=-1).max()))
                height = max(height, float((q[:, nu + 2] - start_z).max()))
            parts = qd[:, nu + 6 * free:]
            if parts.shape[1]:
                joint_speed = max(joint_speed, float(parts.abs().max()))
            if not hold:
                sign = -sign
            elif (step + 1) % hold == 0:
                sign = draw()
    finite = bool(torch.isfinite(q).all() and torch.isfinite(qd).all())
    release = float(np.sum(sim.scene.link_mass)) * GRAVITY * HAND_DROP
    return {"task": task, **overrides, "worlds": worlds, "steps": steps, "hold": hold, "substeps": sim.substeps,
            "free_base": bool(free),
            "peak_base_speed": round(speed, 3), "peak_base_spin": round(spin, 2), "peak_height_gain": round(height, 4),
            "peak_joint_speed": round(joint_speed, 3),
            "fallen_worlds": int((~near).sum()) if free else 0, "max_energy_excess_j": round(float(excess.max()), 4),
            "worlds_making_energy": int((excess > release).sum()),
            "release_j": round(release, 3), "motor_work_j": round(float(work.max()), 2), "finite": finite,
            "worlds_outside_physics": int(outside.sum()),
            "seconds": round(time.perf_counter() - start, 1)}


def main(argv=None) -> None:
    from dexmots_rl.envs.tasks.allegro.tools import TOOL_TASKS

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="*", default=None,
                        help="default: every tool task, repose_cube and allegro_rotate (none when --objects is given)")
    parser.add_argument("--objects", nargs="*", default=[], help="library objects, each on the 'operate' task")
    parser.add_argument("--num-envs", type=int, default=64)
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--substeps", type=int, default=None,
                        help="physics substeps per env step (default: the task's; more: a reference for the peaks)")
    parser.add_argument("--hold", type=int, default=0,
                        help="0: every sign flips every step; k > 0: new random signs every k steps, held between")
    args = parser.parse_args(argv)
    tasks = args.tasks if args.tasks is not None else [] if args.objects else [*TOOL_TASKS, "repose_cube",
                                                                                 "allegro_rotate"]
    runs = [(task, {}) for task in tasks]
    runs += [("operate", {"object": name}) for name in args.objects]
    for task, overrides in runs:
        print(json.dumps(measure(task, args.num_envs, args.steps, args.seed, overrides, args.hold,
                                 args.substeps)), flush=True)


if __name__ == "__main__":
    main()
