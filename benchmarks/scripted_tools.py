"""Open-loop scripted motions on the tool tasks: is a task solvable from its pre-grasp by a fixed joint motion?

    python benchmarks/scripted_tools.py                               # every scripted task, 64 worlds, seeds 0-2
    python benchmarks/scripted_tools.py --tasks scissors --num-envs 16 --seeds 0

A row where every learning method scores 0 % says little unless the task can be done at all. Each script here
starts from the task's own reset (its pre-grasp, its randomised object instance and parameters), ramps a few hand
joints' PD targets away from the pre-grasp pose over ``--ramp`` steps, holds them to the episode's end and counts
the task's own success (the operated joint in its band at the end, the free base moved < 2 cm and turned
< 0.2 rad). The script sees nothing (no feedback), so its success is a floor on what a policy can reach, not a
ceiling. It runs in each action space the task offers: ``vi`` at its highest stiffness (every stiffness action
+1), and ``position`` (the fixed stiffness).

Scripts (joint index: offset in rad from the pre-grasp; Allegro order index 0-3, middle 4-7, ring 8-11, thumb
12-15):

* ``scissors``: the middle finger (in the moving half's ring) abducts to its limit (joint 4, -0.6, clamped at
  -0.47) while the thumb (in the held half's ring) swings the other way about its base (joint 12, -0.7): the two
  rings spread apart, as a person opens scissors.
* ``jar``: found by ``python benchmarks/scripted_tools.py --search jar`` (a cross-entropy search over every
  joint's offset on seed 0: 30 batches of 32 worlds, scored by success, then by the lid's progress while the jar
  stays put). Its largest moves: the middle finger abducts and bends at its base (joints 4 and 5, +0.53 and
  +0.61), the ring finger abducts (joint 8, +0.57) and straightens its tip (joint 11, -0.86), and the thumb's
  tip bends (joint 15, +0.41).

Prints one JSON line per task, action space and seed: the success rate over ``--num-envs`` worlds and the
operated joint's mean final value against the goal.
"""

from __future__ import annotations

import argparse
import json

import torch

SCRIPTS = {
    "scissors": {12: -0.7, 4: -0.6},
    "jar": {0: -0.03, 1: -0.27, 2: 0.12, 3: -0.14, 4: 0.53, 5: 0.61, 6: -0.13, 7: -0.12, 8: 0.57, 9: -0.27,
            10: -0.11, 11: -0.86, 12: -0.22, 13: -0.08, 15: 0.41},
}


def _drive(env, td, offsets: torch.Tensor, action: str, ramp: int, steps: int):
    """The final tensordict after ``steps`` steps from ``td`` whose PD targets move from the pre-grasp by
    ``offsets`` [N, nu] (rad), reached after ``ramp`` steps (``vi``: at the highest stiffness)."""
    actions, start = env.base_env.actions, td["hand", "q"].clone()
    for step in range(steps):
        a = actions.actions_for_targets(start + offsets * min(1.0, step / ramp)).clamp(-1.0, 1.0)
        td["action"] = torch.cat([a, torch.ones_like(a)], -1) if action == "vi" else a
        td = env.step(td)["next"]
    return td


def scripted_rollout(task: str, offsets: dict, action: str, num_envs: int, seed: int, ramp: int,
                     steps: int | None = None):
    """``(env, final tensordict)`` after ``steps`` (default: the episode's) steps of the open-loop script
    ``offsets`` (joint index -> rad from the pre-grasp, reached after ``ramp`` steps) on ``task``."""
    from dexmots_rl.envs import make_env

    env = make_env(task, num_envs=num_envs, seed=seed, action=action, differentiable=False)
    td = env.reset()
    per_joint = torch.zeros_like(td["hand", "q"])
    for joint, offset in offsets.items():
        per_joint[:, joint] = offset
    steps = env.base_env.config.max_episode_steps if steps is None else steps
    return env, _drive(env, td, per_joint, action, ramp, steps)


def search_script(task: str, batches: int, num_envs: int, seed: int, ramp: int, scale: float = 0.6) -> dict:
    """The open-loop script (every hand joint's offset from the pre-grasp, rad) that drives ``task``'s operated
    joint farthest toward its goal with the base held (score: 2 for a success, else the fraction of the way
    from the joint's start to the goal while the base moved < 2 cm and tilted < 0.2 rad, else 0): a third of
    ``batches`` of ``num_envs`` random sparse scripts (one per world), then a cross-entropy search around the
    six best so far (Gaussian steps of 0.12 rad)."""
    from dexmots_rl.envs import make_env

    env = make_env(task, num_envs=num_envs, seed=seed, action="vi", differentiable=False)
    base = env.base_env
    generator = torch.Generator().manual_seed(seed)
    scored: list[tuple[float, list[float]]] = []  # (score, offsets), best first
    for batch in range(batches):
        td = env.reset()
        shape, joint0 = td["hand", "q"].shape, td["object", "q"][:, base.joint_index].clone()
        if batch < batches // 3 or not scored:
            offsets = (torch.rand(shape, generator=generator) * 2 - 1) * scale
            offsets *= (torch.rand(shape, generator=generator) < 0.4).to(offsets)
        else:
            elite = torch.tensor([row for _, row in scored[:6]], dtype=td["hand", "q"].dtype)
            pick = torch.randint(0, len(elite), (num_envs,), generator=generator)
            offsets = (elite[pick] + 0.12 * torch.randn(shape, generator=generator)).clamp(-1.2, 1.2)
        td = _drive(env, td, offsets, "vi", ramp, base.config.max_episode_steps)
        progress = (td["object", "q"][:, base.joint_index] - joint0) / (td["task", "goal"][:, 0] - joint0)
        shift, tilt = base.base_motion({("object", "base_pose"): td["object", "base_pose"]})
        held = (shift < base.config.max_base_shift) & (tilt < base.config.max_base_tilt)
        # a success first; then progress made while the base stays put (tipping the tool over does not count)
        score = 2.0 * td["success"].reshape(-1).float() + held.reshape(-1).float() * progress.clamp(max=1.0)
        scored += [(p, row) for p, row in zip(score.tolist(), offsets.tolist())]
        scored.sort(key=lambda item: -item[0])
    score, offsets = scored[0]
    return {"task": task, "seed": seed, "score": round(score, 4),
            "offsets": {j: round(o, 2) for j, o in enumerate(offsets)}}


def run_script(task: str, offsets: dict, action: str, num_envs: int, seed: int, ramp: int) -> dict:
    """Success of the open-loop script ``offsets`` (joint index -> rad) on ``task`` over ``num_envs`` worlds."""
    env, td = scripted_rollout(task, offsets, action, num_envs, seed, ramp)
    return {"task": task, "action": action, "seed": seed, "num_envs": num_envs,
            "success": round(td["success"].float().mean().item(), 4),
            "joint_final_mean": round(td["object", "q"][:, env.base_env.joint_index].mean().item(), 4),
            "goal": round(td["task", "goal"].mean().item(), 4)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=sorted(SCRIPTS), choices=sorted(SCRIPTS))
    parser.add_argument("--actions", nargs="+", default=["vi", "position"], choices=["vi", "position"])
    parser.add_argument("--num-envs", type=int, default=64)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--ramp", type=int, default=40, help="steps over which the targets move")
    parser.add_argument("--search", metavar="TASK", help="search an open-loop script for TASK instead")
    parser.add_argument("--batches", type=int, default=30, help="with --search: batches of --num-envs scripts")
    args = parser.parse_args()
    if args.search:
        print(json.dumps(search_script(args.search, args.batches, args.num_envs, args.seeds[0], args.ramp)))
        return
    for task in args.tasks:
        for action in args.actions:
            for seed in args.seeds:
                print(json.dumps(run_script(task, SCRIPTS[task], action, args.num_envs, seed, args.ramp)),
                      flush=True)


if __name__ == "__main__":
    main()
