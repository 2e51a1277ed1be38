"""stapler: the Allegro hand presses a stapler's sprung arm down by 90 % of its travel.

The stapler (``assets/allegro_stapler.xml``, :mod:`dexmots_rl.assets.operable`) lies under the
palm-down hand: the base on the table, the arm (40 g) hinged at its back end and held 0.5 rad open by its
spring. The pre-grasps put the index and middle fingertips on the top of the arm's front half and the
thumb on its back half; pressing down turns the arm onto the base, range [0, 0.5] rad. Goal 0.45 rad,
success within 0.04 rad at the episode end; damping, friction and the spring's stiffness are drawn per
episode. The rest is :mod:`.operate`'s.

Example:
    >>> from dexmots_rl.envs import make_env
    >>> env = make_env("stapler", num_envs=2, seed=0)
    >>> round(float(env.reset()["task", "goal"][0]), 3)
    0.45
"""

from __future__ import annotations

import dataclasses

from ...config import BenchPoses, PlanProblem
from ...pregrasp import ContactRegion
from ...registry import register_task
from .operate import OperateConfig, OperateEnv, bench_poses
from .rotate import GRASP

__all__ = ["StaplerConfig", "StaplerEnv"]


@dataclasses.dataclass
class StaplerConfig(OperateConfig):
    """stapler's defaults: the task dexmots-train trains (see the module docstring)."""

    name: str = "stapler"
    success_threshold: float = 0.04  # rad: 8 % of the range, so the band [goal -+ thr] stops short of the stop
    stiffness_range: tuple[float, float] = (0.3, 0.6)  # arm spring (N m/rad): 0.14-0.27 N m at the goal; with
    # (0.05, 0.15) random actions pressed the arm into the success band in 40 % of episodes, with this in none


class StaplerEnv(OperateEnv):
    """Allegro hand + stapler; see the module docstring."""

    asset = "allegro_stapler.xml"
    contact_regions = (
        ContactRegion(0, "arm", (0.03, 0.006, 0.006), (0.0, 0.0, 1.0), (0.01, 0.003, 0.0)),  # index
        ContactRegion(1, "arm", (0.06, -0.004, 0.006), (0.0, 0.0, 1.0), (0.01, 0.003, 0.0)),  # middle
        ContactRegion(3, "arm", (-0.03, 0.0, 0.006), (0.0, 0.0, 1.0), (0.01, 0.004, 0.0)),  # thumb
    )
    pregrasp_hint = GRASP
    bench: BenchPoses = bench_poses("stapler", close=(0.0, 0.6, 0.6, 0.6) * 3 + (0.0, -0.6, 0.3, 0.3))
    plan_problem = PlanProblem(start=(0.0,), goal=(0.45,), steps=60, lr=0.01)

    def __init__(self, config: StaplerConfig | None = None, **kwargs):
        super().__init__(StaplerConfig() if config is None else config, **kwargs)


register_task("stapler", StaplerEnv, StaplerConfig)
