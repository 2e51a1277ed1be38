"""The knob and cube scenes on the fused kernel and on the split (object tree) kernels, in one run.

``load_scene(path, articulated=True)`` reads a knob or cube scene as an object tree (a hinged body: one part on a
fixed mount; a free body: a free base without parts), which :class:`~dexmots_rl.sim.ArticulatedSimulator` steps
with the tool scenes' kernels. For each task this prints, as JSON:

* ``agreement``: both simulators from the task's open pose under the closing action plus seeded noise (uniform in
  ``[-noise, noise]`` per joint and step, clipped to the motors' range), ``steps`` env steps: the largest
  difference over worlds and steps of the hand's joints (rad), the object's coordinates (rad for the knob; m and
  quaternion components for the cube) and the fingers' summed normal force (relative to its largest value), and
  the object's coordinates at the end (their spread in both); ``max_one_step_gap``: the largest difference of
  one step of each from the same state (the fused trajectory's), which the laws' differences make, without the
  divergence of two contact-rich trajectories (``mean_one_step_gap``: its mean over worlds, coordinates and
  steps);
* ``agreement_fused_palm_law`` (the cube, whose palm pushes it): the same with the split kernels' palm pushing
  with the fused kernel's palm law (:func:`palm_law`) instead of the table's;
* ``speed``: env-steps per second (wall and CPU) of a forward step and of a forward + backward step
  (``dexmots-bench throughput``'s protocol: settled into contact, chunks of ``chunk_steps``), the two simulators
  measured alternately ``repeats`` times, the best of each kept, and split over fused.

Run: ``DEXMOTS_CPU_THREADS=1 python benchmarks/split_vs_fused.py --num-envs 256``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging

import torch

from dexmots_rl.apps.bench_setup import bench_env, measure_rates
from dexmots_rl.apps.bench_throughput import SimBench
from dexmots_rl.sim import (ArticulatedSimulator, ContactParams, Control, TableContact, cpu_threads, load_scene,
                            make_simulator)

__all__ = ["agreement", "speed"]

log = logging.getLogger(__name__)
TASKS = ("screw_claw", "allegro_rotate", "repose_cube")


def scenes(task: str, **law_changes):
    """(the task's bench poses, its contact law with ``law_changes``, its fused scene, the same MJCF as an object
    tree)."""
    env = bench_env(task)
    fused, law = env.sim.scene, dataclasses.replace(env.sim.contact, **law_changes)
    return env.bench_poses(), law, fused, load_scene(fused.path, contact=law, articulated=True)


def palm_law(law: ContactParams) -> TableContact:
    """The fused kernel's palm law in the split kernels' terms (they push with the table's law): its stiffness,
    sharpness, and the fingers' damping, friction and slip velocity; its box stays exact, not rounded."""
    return TableContact(stiffness=law.palm_stiffness, sharpness=law.palm_sharpness, damping=law.damping,
                        friction=law.friction, slip_velocity=law.slip_velocity)


def agreement(task: str, worlds: int = 4, steps: int = 50, noise: float = 0.3, seed: int = 0,
              dtype: torch.dtype = torch.float32, same_palm: bool = False, **law_changes) -> dict:
    """The two simulators' trajectories under the same actions (see the module docstring); ``same_palm``: the split
    kernels' palm pushes with :func:`palm_law` (default: the table's law, as in the tool scenes); ``law_changes``:
    fields of the task's :class:`~dexmots_rl.sim.ContactParams` to change (e.g. ``friction=0.0``)."""
    poses, law, fused_scene, split_scene = scenes(task, **law_changes)
    sims = [make_simulator(fused_scene, num_worlds=worlds, contact=law, dtype=dtype),
            ArticulatedSimulator(split_scene, worlds, contact=law, dtype=dtype,
                                 table=palm_law(law) if same_palm else None)]
    nu = sims[0].nu
    gear = torch.as_tensor(fused_scene.actuator_gear, dtype=dtype)
    generator = torch.Generator().manual_seed(seed)
    actions = (torch.as_tensor(poses.close_action, dtype=dtype)
               + noise * (2 * torch.rand(steps, worlds, nu, generator=generator, dtype=dtype) - 1)).clamp(-1, 1)
    states = [(torch.as_tensor(poses.open_q, dtype=dtype).expand(worlds, s.nq).clone(),
               torch.zeros(worlds, s.nv, dtype=dtype)) for s in sims]
    gap = {"hand_q": 0.0, "object_q": 0.0, "contact_force": 0.0}
    one_step = {"hand_q": 0.0, "object_q": 0.0, "hand_qd": 0.0, "object_qd": 0.0}
    one_step_mean = dict.fromkeys(one_step, 0.0)
    force_scale = 0.0
    z = torch.zeros(worlds, nu, dtype=dtype)
    for t in range(steps):
        control = Control(actions[t] * gear, z, z, z)
        # the split kernels' step from the fused trajectory's state: the laws' difference over one step
        resync = sims[1].step(*states[0], control, sims[1].default_params())
        outs = []
        for i, sim in enumerate(sims):
            out = sim.step(*states[i], control, sim.default_params())
            states[i] = (out.joint_q, out.joint_qd)
            outs.append(out)
        for key, a, b in (("q", outs[0].joint_q, resync.joint_q), ("qd", outs[0].joint_qd, resync.joint_qd)):
            for part, cols in (("hand", slice(0, nu)), ("object", slice(nu, None))):
                diff = (a[:, cols] - b[:, cols]).abs()
                one_step[f"{part}_{key}"] = max(one_step[f"{part}_{key}"], diff.max().item())
                one_step_mean[f"{part}_{key}"] += diff.mean().item() / steps
        (qa, _), (qb, _) = states
        gap["hand_q"] = max(gap["hand_q"], (qa[:, :nu] - qb[:, :nu]).abs().max().item())
        gap["object_q"] = max(gap["object_q"], (qa[:, nu:] - qb[:, nu:]).abs().max().item())
        gap["contact_force"] = max(gap["contact_force"], (outs[0].contact_force - outs[1].contact_force).abs().max().item())
        force_scale = max(force_scale, outs[0].contact_force.abs().max().item())
    gap["contact_force"] /= max(force_scale, 1e-12)
    end = [s[0][:, nu:] for s in states]
    return {"steps": steps, "worlds": worlds, "noise": noise, "max_gap": gap, "max_one_step_gap": one_step,
            "mean_one_step_gap": one_step_mean,
            "max_contact_force": force_scale,
            "object_q_end_fused": end[0].tolist(), "object_q_end_split": end[1].tolist()}


def split_scene_has_palm(task: str) -> bool:
    return len(scenes(task)[3].palm[0]) > 0


def speed(task: str, num_envs: int = 256, min_time: float = 2.0, repeats: int = 2, settle_steps: int = 20,
          chunk_steps: int = 16) -> dict:
    """Forward and forward + backward env-steps per second of both simulators, measured alternately."""
    poses, law, fused_scene, split_scene = scenes(task)
    benches = {name: SimBench(scene, poses, num_envs, "cpu", 16, settle_steps, chunk_steps, contact=law)
               for name, scene in (("fused", fused_scene), ("split", split_scene))}
    best = {}
    for name, bench in benches.items():  # warm-up: replay plans, tapes, thread pools
        bench.forward_chunk()
        bench.forward_backward_chunk()
    for _ in range(repeats):
        for kind in ("fwd", "fwdbwd"):
            for name, bench in benches.items():
                chunk = bench.forward_chunk if kind == "fwd" else bench.forward_backward_chunk
                wall, cpu = measure_rates(chunk, min_time)
                key = f"{name}_{kind}"
                best[key] = max(best.get(key, (0.0, 0.0)), (wall, cpu))
                log.info("%s %s: %.0f env-steps/s, %.0f per CPU-second", task, key, wall, cpu)
    row = {"num_envs": num_envs, "contact_fraction": {n: b.contact_fraction() for n, b in benches.items()}}
    for key, (wall, cpu) in best.items():
        row[f"{key}_steps_per_s"], row[f"{key}_steps_per_cpu_s"] = wall, cpu
    for kind in ("fwd", "fwdbwd"):
        row[f"split_over_fused_{kind}_cpu"] = best[f"split_{kind}"][1] / best[f"fused_{kind}"][1]
    for name in benches:
        row[f"{name}_fwdbwd_cost_cpu"] = best[f"{name}_fwd"][1] / best[f"{name}_fwdbwd"][1]
    return row


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=list(TASKS))
    parser.add_argument("--num-envs", type=int, default=256)
    parser.add_argument("--min-time", type=float, default=2.0)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--steps", type=int, default=50, help="env steps of the agreement rollout")
    parser.add_argument("--no-speed", action="store_true", help="the agreement only")
    parser.add_argument("--law", nargs="*", default=[], metavar="FIELD=VALUE",
                        help="contact-law fields changed in the agreement rollouts (e.g. friction=0)")
    args = parser.parse_args(argv)
    law = {k: float(v) for k, v in (item.split("=", 1) for item in args.law)}
    logging.basicConfig(level=logging.INFO)
    result = {"threads": cpu_threads(), "tasks": {}}
    for task in args.tasks:
        entry = {"agreement": agreement(task, steps=args.steps, **law)}
        if split_scene_has_palm(task):
            entry["agreement_fused_palm_law"] = agreement(task, steps=args.steps, same_palm=True, **law)
        if not args.no_speed:
            entry["speed"] = speed(task, args.num_envs, args.min_time, args.repeats)
        result["tasks"][task] = entry
        print(json.dumps({task: entry}), flush=True)


if __name__ == "__main__":
    main()
