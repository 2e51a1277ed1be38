"""Write the demonstrations the package ships (``dexmots_rl/assets/demos/<task>.npz``), one per tool task.

    python scripts/make_demos.py                 # every tool task
    python scripts/make_demos.py --tasks drawer  # one

Each is a scripted motion of the task's operated joint, made without the simulator: a minimum-jerk move
(``10 s^3 - 15 s^4 + 6 s^5``) from the joint's rest position to the task's default goal (90 % of its travel)
over ``--move-steps`` control steps (60 Hz), then held until the episode's last step; the base stays where it
stands (the file gives no ``pos``/``quat``). What a person would show by hand, with no forces: the task derives
the forces (``task.demo=shipped``; layout in :mod:`dexmots_rl.envs.demos`).
"""

from __future__ import annotations

import argparse
import logging

import numpy as np

from dexmots_rl.assets import ASSET_DIR
from dexmots_rl.envs import make_env
from dexmots_rl.envs.tasks.allegro.tools import TOOL_TASKS

log = logging.getLogger("make_demos")


def minimum_jerk(start: float, end: float, move_steps: int, total_steps: int) -> np.ndarray:
    """[total_steps + 1] positions: the move over ``move_steps`` steps, then held."""
    s = np.clip(np.arange(total_steps + 1) / move_steps, 0.0, 1.0)
    return start + (end - start) * (10 * s**3 - 15 * s**4 + 6 * s**5)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", nargs="+", default=sorted(TOOL_TASKS), choices=sorted(TOOL_TASKS))
    parser.add_argument("--move-steps", type=int, default=60)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    for task in args.tasks:
        env = make_env(task, num_envs=1, seed=0, raw=True, differentiable=False)
        joint_q = minimum_jerk(env.joint_rest, env.goal_value, args.move_steps, env.max_episode_steps)
        path = ASSET_DIR / "demos" / f"{task}.npz"
        np.savez(path, dt=np.float64(env.sim.dt), joint_q=joint_q[:, None])
        log.info("%s: %s %s -> %.4f over %d steps, %d rows", path, env.joint_name, env.joint_rest, env.goal_value,
                 args.move_steps, len(joint_q))


if __name__ == "__main__":
    main()
