"""spray_bottle: the Allegro hand pulls a spray bottle's sprung trigger to 90 % of its travel.

The bottle (``assets/allegro_spray_bottle.xml``, :mod:`dexmots_rl.assets.operable`) is held static under
the palm-down hand: its body and head are the base, the trigger (10 g) hangs under the head's front on a
hinge with a return spring. The pre-grasps put the index and middle fingertips on the trigger's front
face and the thumb on the back of the bottle; pulling (the fingers curling toward the thumb) turns the
trigger toward the bottle, range [0, 0.45] rad. Goal 0.405 rad (90 %), success within 0.036 rad at the
episode end; damping, friction and the spring's stiffness are drawn per episode. The rest is
:mod:`.operate`'s.

Example:
    >>> from dexmots_rl.envs import make_env
    >>> env = make_env("spray_bottle", num_envs=2, seed=0)
    >>> round(float(env.reset()["task", "goal"][0]), 3)
    0.405
"""

from __future__ import annotations

import dataclasses

from ...config import BenchPoses, PlanProblem
from ...pregrasp import ContactRegion
from ...registry import register_task
from .operate import OperateConfig, OperateEnv, bench_poses
from .rotate import GRASP

__all__ = ["SprayBottleConfig", "SprayBottleEnv"]


@dataclasses.dataclass
class SprayBottleConfig(OperateConfig):
    """spray_bottle's defaults: the task dexmots-train trains (see the module docstring)."""

    name: str = "spray_bottle"
    success_threshold: float = 0.036  # rad: 8 % of the range, so the band [goal -+ thr] stops short of the stop
    stiffness_range: tuple[float, float] = (0.03, 0.08)  # trigger return spring (N m/rad): 0.012-0.032 N m at the goal


class SprayBottleEnv(OperateEnv):
    """Allegro hand + spray bottle; see the module docstring."""

    asset = "allegro_spray_bottle.xml"
    contact_regions = (
        ContactRegion(0, "trigger", (0.006, 0.0, 0.008), (1.0, 0.0, 0.0), (0.0, 0.004, 0.003)),  # index, upper
        ContactRegion(1, "trigger", (0.006, 0.0, -0.01), (1.0, 0.0, 0.0), (0.0, 0.004, 0.003)),  # middle, lower
        ContactRegion(3, "bottle_body", (-0.0175, 0.0, 0.04), (-1.0, 0.0, 0.0), (0.0, 0.008, 0.008)),  # thumb
    )
    pregrasp_hint = GRASP
    bench: BenchPoses = bench_poses("spray_bottle", close=(0.0, 0.6, 0.6, 0.6) * 3 + (0.0, -0.6, 0.3, 0.3))
    plan_problem = PlanProblem(start=(0.0,), goal=(0.405,), steps=60, lr=0.01)

    def __init__(self, config: SprayBottleConfig | None = None, **kwargs):
        super().__init__(SprayBottleConfig() if config is None else config, **kwargs)


register_task("spray_bottle", SprayBottleEnv, SprayBottleConfig)
