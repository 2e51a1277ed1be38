"""What PGDM's start does on a task before any learning: its warm-start action against plain PPO's initial mean.

    python benchmarks/pgdm_start.py --task pump_dispenser
    python benchmarks/pgdm_start.py --task pliers --num-envs 32 --steps 150

Three constant, deterministic actions are held for ``--steps`` steps in ``--num-envs`` worlds of the task env
with PGDM's observation and reward (``configs/algo/pgdm.yaml``): the zero action (PPO's initial mean: the joint
targets at the middle of their range), PGDM's warm start (the mean start pose's joint targets,
``algorithms/pgdm.py:start_action``) and each world's own start pose. Prints, per action, the mean per-step PGDM
reward, the task's reward and its terms, and how far the operated part moved (its joint's units); then how far
the warm start's joint targets are from each world's own start pose, and the PGDM reward per step of a part that
stays at rest against the 10 of one following the reference exactly.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch
from omegaconf import OmegaConf

from dexmots_rl.algorithms.pgdm import PGDMFeatures, PGDMObservation, start_action
from dexmots_rl.envs import make_env

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "algo" / "pgdm.yaml"


def hold(task: str, algo, action_of, num_envs: int, steps: int) -> dict:
    """Per-step means over ``steps`` steps of a constant action ``action_of(env, reset td)``."""
    env = make_env(task, num_envs=num_envs, differentiable=False, seed=0)
    env.append_transform(PGDMObservation(algo))
    base = env.base_env
    td = env.reset()
    part0 = td["object", "q"][:, base.joint_index]
    action = action_of(env, td).to(td["observation"].dtype).expand(num_envs, -1)
    sums: dict[str, float] = {}
    with torch.no_grad():
        for _ in range(steps):
            td = env.step(td.set("action", action))
            nxt = td["next"]
            values = {"pgdm_reward": nxt["pgdm_reward"], "task_reward": nxt["reward"],
                      **{f"term_{k}": v for k, v in nxt["reward_terms"].items()}}
            for key, value in values.items():
                sums[key] = sums.get(key, 0.0) + float(value.float().mean()) / steps
            td = env.step_mdp(td)
    return {**{k: round(v, 4) for k, v in sums.items()},
            "part_moved": round(float((td["object", "q"][:, base.joint_index] - part0).abs().mean()), 5)}


def own_start(env, td) -> torch.Tensor:
    base = env.base_env
    action = base.actions.actions_for_targets(td["sim", "joint_q"][:, : base.sim.nu])
    return torch.cat([action, torch.zeros_like(action)], -1) if base.action_type == "vi" else action


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="pump_dispenser")
    parser.add_argument("--num-envs", type=int, default=32)
    parser.add_argument("--steps", type=int, default=150)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    algo = OmegaConf.load(CONFIG)
    env = make_env(args.task, num_envs=args.num_envs, differentiable=False, seed=0)
    base = env.base_env
    td = env.reset()
    nu = base.sim.nu
    warm_targets = base.actions.targets(start_action(env)[:nu].expand(args.num_envs, -1))
    gap = (warm_targets - td["sim", "joint_q"][:, :nu]).abs()
    features = PGDMFeatures(base, algo)
    ref = base.goal_window(td, torch.arange(args.steps).expand(args.num_envs, -1), False)[..., 0]
    rest = td["object", "q"][:, base.joint_index: base.joint_index + 1]
    error = (ref - rest).abs()  # the part at rest against the reference, in its joint's units
    sharp = algo.tracking_sharpness * (error if features.slides else algo.rotation_weight * error / torch.pi)
    result = {
        "task": args.task, "action": base.action_type, "part_slides": features.slides,
        "goal_travel": round(float(error[:, -1].mean()), 5),
        "warm_start_vs_own_start_rad": {"mean": round(float(gap.mean()), 4), "max": round(float(gap.max()), 4)},
        "pgdm_reward_part_at_rest": round(float((algo.tracking_scale * torch.exp(-sharp)).mean()), 4),
        "pgdm_reward_following_the_reference": algo.tracking_scale,
        "hold": {name: hold(args.task, algo, fn, args.num_envs, args.steps) for name, fn in (
            ("zero (PPO's initial mean)", lambda env, td: torch.zeros(env.action_spec.shape[-1])),
            ("warm start (PGDM)", lambda env, td: start_action(env)),
            ("each world's own start pose", own_start))},
    }
    json.dump(result, sys.stdout, indent=1)
    print()


if __name__ == "__main__":
    main()
