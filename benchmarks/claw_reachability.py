"""Can the Claw turn the knob to the goal from the pre-sampled grasp? Predictive-sampling MPC answers it.

    python benchmarks/claw_reachability.py --goal 1.5708 --friction 1.0      # hardest: |goal| = pi/2, max friction

At every env step ``--samples`` action sequences of ``--horizon`` steps (Gaussian noise of ``--noise`` around
the previous best, shifted by one step) are simulated from the current state, all in one batch of worlds;
the first action of the sequence with the lowest ``sum_t |theta_t - goal|`` is applied. No policy and no
gradients: it bounds what the task needs (a feasible motion exists, and how many steps it takes), which is
what the SHAC runs are measured against (README, "Training screw_claw"). Prints one JSON object with the
knob angle every 10 steps, the first step within 0.1 rad of the goal and the final error.
"""

from __future__ import annotations

import argparse
import json
import math
import time

import torch

from dexmots_rl.assets import asset_path
from dexmots_rl.envs.actions import ActionMap
from dexmots_rl.envs.screw_claw import INITIAL_POSES
from dexmots_rl.sim import Simulator, load_scene

__all__: list[str] = []


def reach(goal: float, friction: float, damping: float, samples: int, horizon: int, steps: int, noise: float,
          action: str, seed: int) -> dict:
    torch.manual_seed(seed)
    scene = load_scene(asset_path("claw_screw.xml"))
    sim = Simulator(scene, samples)
    actions = ActionMap(sim, action)
    q = torch.tensor([[*INITIAL_POSES["grasp"], 0.0]])
    qd = torch.zeros(1, sim.nv)
    params = torch.tensor([[damping, friction]]).expand(samples, 2).contiguous()
    plan = torch.zeros(horizon, actions.action_dim)
    if action != "torque":  # start from targets that hold the grasp
        plan[:, : sim.nu] = actions.actions_for_targets(q[0, : sim.nu])
    angles, start = [], time.perf_counter()
    for _ in range(steps):
        candidates = (plan + noise * torch.randn(samples, horizon, actions.action_dim)).clamp(-1, 1)
        candidates[0] = plan  # keep the incumbent
        qs, qds, cost = q.expand(samples, -1).contiguous(), qd.expand(samples, -1).contiguous(), 0.0
        for t in range(horizon):
            out = sim.step(qs, qds, actions(candidates[:, t]), params)
            qs, qds = out.joint_q, out.joint_qd
            cost = cost + (qs[:, sim.nu] - goal).abs()
        best = candidates[int(torch.argmin(cost))]
        out = sim.step(q.expand(samples, -1).contiguous(), qd.expand(samples, -1).contiguous(),
                       actions(best[:1].expand(samples, -1)), params)
        q, qd = out.joint_q[:1], out.joint_qd[:1]
        plan = torch.cat([best[1:], best[-1:]])
        angles.append(float(q[0, sim.nu]))
    within = [i + 1 for i, a in enumerate(angles) if abs(a - goal) < 0.1]
    return {"goal": goal, "friction": friction, "damping": damping, "action": action, "samples": samples,
            "horizon": horizon, "angle_every_10_steps": [round(a, 3) for a in angles[9::10]],
            "first_step_within_0.1": within[0] if within else None, "final_error": abs(angles[-1] - goal),
            "wall_clock_s": round(time.perf_counter() - start, 1)}


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--goal", type=float, default=math.pi / 2)
    p.add_argument("--friction", type=float, default=1.0)
    p.add_argument("--damping", type=float, default=0.7)
    p.add_argument("--samples", type=int, default=128)
    p.add_argument("--horizon", type=int, default=15)
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--noise", type=float, default=0.3)
    p.add_argument("--action", default="vi", choices=["torque", "position", "vi"])
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    print(json.dumps(reach(args.goal, args.friction, args.damping, args.samples, args.horizon, args.steps,
                           args.noise, args.action, args.seed)))


if __name__ == "__main__":
    main()
