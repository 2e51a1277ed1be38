"""``dexmots-rollout``: a short scripted rollout of a task, printing a summary.

This is the project's smoke job until training lands: it builds the env, runs a scripted grasp-and-twist
torque controller for a number of steps in every world, and reports throughput, contact, the final angle
error and the success rate of that (untrained) controller.
"""

from __future__ import annotations

import argparse
import json
import logging
import time

import torch

from ..envs import ScriptedPolicy, make_env
from ._cli import errors_as_one_line

__all__ = ["run", "main"]

log = logging.getLogger(__name__)


def main(argv: list[str] | None = None) -> None:
    """Console entry point: bad input (an unknown task, a GPU this machine lacks) and a full disk are one line."""
    with errors_as_one_line("dexmots-rollout"):
        run(argv)


def run(argv: list[str] | None = None) -> dict:
    """Parse ``argv``, run the rollout, print and return the summary."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="screw_claw")
    parser.add_argument("--num-envs", type=int, default=16)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")

    t0 = time.perf_counter()
    env = make_env(args.task, num_envs=args.num_envs, device=args.device, differentiable=False, seed=args.seed,
                   max_episode_steps=args.steps, action="torque")
    policy = ScriptedPolicy(env.base_env)
    env.step(policy(env.reset()))  # first step compiles the warp kernels (cached on disk afterwards)
    setup_s = time.perf_counter() - t0
    td = env.reset()
    t1 = time.perf_counter()
    with torch.no_grad():
        rollout = env.rollout(args.steps, policy, tensordict=td, auto_reset=False,
                              break_when_any_done=False)
    wall = time.perf_counter() - t1
    last = rollout[:, -1]["next"]
    err = (last["achieved_goal"] - last["task", "goal"]).norm(dim=-1)
    summary = {
        "task": args.task,
        "num_envs": args.num_envs,
        "steps": args.steps,
        "setup_s": round(setup_s, 2),
        "rollout_s": round(wall, 3),
        "env_steps_per_s": round(args.num_envs * args.steps / wall, 1),
        "mean_contact_force": float(rollout["next", "object", "contact_force"].mean()),
        "mean_final_angle_error_rad": float(err.mean()),
        "scripted_success_rate": float(last["success"].float().mean()),
        "sim_failures": int(last["info", "sim_failures"].sum()),
    }
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"{args.task}: {args.num_envs} worlds x {args.steps} steps in {wall:.2f} s "
              f"({summary['env_steps_per_s']:.0f} env-steps/s; set-up incl. kernel load {setup_s:.1f} s)")
        print(f"  mean contact force {summary['mean_contact_force']:.1f} N, "
              f"final |angle - goal| {summary['mean_final_angle_error_rad']:.3f} rad, "
              f"scripted success {summary['scripted_success_rate']:.2f}, sim failures {summary['sim_failures']}")
    return summary


if __name__ == "__main__":
    main()
