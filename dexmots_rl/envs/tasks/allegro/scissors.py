"""scissors: the Allegro hand closes a pair of scissors lying flat, by 90 % of their opening.

The scissors (``assets/allegro_scissors.xml``, :mod:`dexmots_rl.assets.operable`) lie under the
palm-down hand: the held blade and its handle are the base; the operated blade and handle (30 g) are one
bar on a vertical pivot beyond the fingertips. The pre-grasps put the index fingertip on the operated
handle's outer side, the middle fingertip on its top, the thumb on its end and the ring fingertip
on the held handle; pushing the operated handle sideways onto the held one (the hand's abduction) closes
the scissors, range [0, 0.35] rad (20°: a 2.6 cm sideways push where the hand holds it). Goal 0.315 rad,
success within 0.028 rad at the episode end; damping, friction and a light return spring are drawn per
episode. The hardest of the three (as in the paper's Table 2): the push is sideways, where the fingers'
abduction is weakest. The rest is :mod:`.operate`'s.

Example:
    >>> from dexmots_rl.envs import make_env
    >>> env = make_env("scissors", num_envs=2, seed=0)
    >>> round(float(env.reset()["task", "goal"][0]), 3)
    0.315
"""

from __future__ import annotations

import dataclasses

from ...config import BenchPoses, PlanProblem
from ...pregrasp import ContactRegion
from ...registry import register_task
from .operate import OperateConfig, OperateEnv, bench_poses
from .rotate import GRASP

__all__ = ["ScissorsConfig", "ScissorsEnv"]


@dataclasses.dataclass
class ScissorsConfig(OperateConfig):
    """scissors' defaults: the task dexmots-train trains (see the module docstring)."""

    name: str = "scissors"
    success_threshold: float = 0.028  # rad: 8 % of the range, so the band [goal -+ thr] stops short of the stop
    stiffness_range: tuple[float, float] = (0.005, 0.03)  # a light return spring (N m/rad)


class ScissorsEnv(OperateEnv):
    """Allegro hand + scissors; see the module docstring."""

    asset = "allegro_scissors.xml"
    contact_regions = (
        ContactRegion(0, "operated_blade", (-0.06, 0.008, 0.0), (0.0, 1.0, 0.0), (0.006, 0.0, 0.003)),  # index
        ContactRegion(1, "operated_blade", (-0.035, 0.0, 0.009), (0.0, 0.0, 1.0), (0.006, 0.003, 0.0)),  # middle
        ContactRegion(2, "held_handle", (-0.01, 0.0, 0.007), (0.0, 0.0, 1.0), (0.008, 0.004, 0.0)),  # ring
        ContactRegion(3, "operated_blade", (-0.085, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 0.003, 0.003)),  # thumb
    )
    pregrasp_hint = GRASP
    bench: BenchPoses = bench_poses("scissors", close=(0.6, 0.3, 0.3, 0.3) * 3 + (0.0, 0.6, 0.0, 0.0))
    plan_problem = PlanProblem(start=(0.0,), goal=(0.315,), steps=60, lr=0.01)

    def __init__(self, config: ScissorsConfig | None = None, **kwargs):
        super().__init__(ScissorsConfig() if config is None else config, **kwargs)


register_task("scissors", ScissorsEnv, ScissorsConfig)
