"""``dexmots-rollout``: a short rollout of a task without training, printing a summary.

A smoke job: it builds the env, steps every world for a number of steps under a fixed controller and reports
throughput, contact, sim failures and how far the object moved toward its goal. The controller
(``--policy``): the task's scripted one where it has one (screw_claw: close both fingers on the knob and
push them around it, in torque space), else uniform random actions. Neither solves a task: the claw's
fingers reach about half of the goal angle without regrasping, which no fixed push does (train a policy
with ``dexmots-train`` for that), so no success rate is reported.
"""

from __future__ import annotations

import argparse
import json
import logging
import time

import torch

from ..envs import ScriptedPolicy, make_env
from ._cli import errors_as_one_line
from ._policies import POLICIES, choose_policy

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
    parser.add_argument("--policy", default="auto", choices=POLICIES,
                        help="auto: the task's scripted controller where it has one, else random actions")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")

    t0 = time.perf_counter()
    chosen = choose_policy(args.policy, args.task, "--policy random (uniform random actions)")
    env = make_env(args.task, num_envs=args.num_envs, device=args.device, differentiable=False, seed=args.seed,
                   max_episode_steps=args.steps, **({"action": "torque"} if chosen == "scripted" else {}))
    policy = ScriptedPolicy(env.base_env) if chosen == "scripted" else None
    td = env.reset()
    # the first step compiles the warp kernels (cached on disk afterwards)
    env.step(policy(td) if policy is not None else env.rand_action(td))
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
        "policy": chosen,
        "num_envs": args.num_envs,
        "steps": args.steps,
        "setup_s": round(setup_s, 2),
        "rollout_s": round(wall, 3),
        "env_steps_per_s": round(args.num_envs * args.steps / wall, 1),
        "mean_contact_force": float(rollout["next", "object", "contact_force"].mean()),
        "mean_final_goal_error": float(err.mean()),  # |achieved goal - goal| (rad for a knob, its pose for a cube)
        "mean_start_goal_error": float((rollout[:, 0]["achieved_goal"] - rollout[:, 0]["task", "goal"]).norm(dim=-1)
                                       .mean()),
        "sim_failures": int(last["info", "sim_failures"].sum()),
    }
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"{args.task} ({chosen} policy): {args.num_envs} worlds x {args.steps} steps in {wall:.2f} s "
              f"({summary['env_steps_per_s']:.0f} env-steps/s; set-up incl. kernel load {setup_s:.1f} s)")
        print(f"  mean contact force {summary['mean_contact_force']:.1f} N, "
              f"|achieved - goal| {summary['mean_start_goal_error']:.3f} at the start, "
              f"{summary['mean_final_goal_error']:.3f} at the end, sim failures {summary['sim_failures']}")
    return summary


if __name__ == "__main__":
    main()
