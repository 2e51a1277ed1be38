"""allegro_rotate: the Allegro hand turns a knob by a goal angle (the paper's planar rotation, Fig. 3a).

The knob is the claw's octagonal prism scaled to the hand: circumradius 35 mm, height 50 mm, 80 g, on a
vertical hinge under the fingers (DexMOTS's own prism, apothem 0.145 m, is built for the 0.4 m claw
fingers; an Allegro finger is ~0.135 m long). Gravity is off, as in the paper's planar task. Per episode
the goal angle is drawn with magnitude in ``goal_range`` and a random sign, the knob's damping and
friction from their ranges; the hand starts from a grasp (fingertips resting on the knob's faces, the
thumb opposing them) with joint noise. Success: |θ − θ*| < 0.1 rad at the episode end. Reference,
reward and success are :mod:`..knob`'s.

The goal range stops at 0.5 rad: twisting the grasp sideways turns the knob ~0.6-0.7 rad before the
fingers' abduction runs out (measured in this simulator and in MuJoCo on the same scene), and a larger
turn would need finger gaiting, which is a different task.

Contact is the hand's law (:data:`.hand.CONTACT`, sized for a centimetre-scale knob).

Example:
    >>> from dexmots_rl.envs import make_env
    >>> env = make_env("allegro_rotate", num_envs=2, seed=0)
    >>> env.rollout(2)["next", "reward"].shape
    torch.Size([2, 2, 1])
"""

from __future__ import annotations

import dataclasses

from ...config import BenchPoses, PlanProblem
from ...registry import register_task
from ...rewards import RewardCoefficients
from ..knob import KnobTurnConfig, KnobTurnEnv
from . import hand

__all__ = ["AllegroRotateConfig", "AllegroRotateEnv", "INITIAL_POSES"]

# rad, in the hand's joint order (.hand.JOINT_NAMES)
# "grasp": fingertips 0.5 mm into the knob's far faces (+45, 0, -45 deg), the thumb on the near face
GRASP = (-0.102, 0.58, 0.67, 0.639, 0.0, 0.494, 0.604, 0.598, 0.102, 0.58, 0.67, 0.639, 0.919, 1.006, 0.662, 0.787)
# "open": 31-55 mm gaps; closing toward the grasp touches at ~60 % of the way
NEAR_KNOB = (-0.102, 0.33, 0.42, 0.389, 0.0, 0.244, 0.354, 0.348, 0.102, 0.33, 0.42, 0.389, 0.919, 1.15, 0.462,
             0.587)
INITIAL_POSES = {"grasp": GRASP, "open": NEAR_KNOB}


@dataclasses.dataclass
class AllegroRotateConfig(KnobTurnConfig):
    """allegro_rotate's defaults: the task dexmots-train trains (see the module docstring)."""

    name: str = "allegro_rotate"
    initial_choices = tuple(INITIAL_POSES)
    initial: str = "grasp"  # grasp (fingertips on the knob) | open (a few cm away)
    goal_range: tuple[float, float] = (0.2, 0.5)  # |goal angle| (rad), random sign
    damping_range: tuple[float, float] = (0.005, 0.02)  # knob joint damping (N m s/rad)
    friction_range: tuple[float, float] = (0.0, 0.01)  # knob joint Coulomb friction (N m)
    joint_noise: float = 0.02  # rad
    pose_scale: float = 0.2  # rad
    torque_scale: float = 0.02  # N m: the knob's reference torque is ~0.005-0.02 N m
    fingertip_scale: float = 0.05  # m: the hand is centimetres across
    reward: RewardCoefficients = dataclasses.field(
        default_factory=lambda: RewardCoefficients(lambda_pose=1.0, lambda_wrench=0.5, lambda_act=0.01, lambda_f=0.5))


class AllegroRotateEnv(KnobTurnEnv):
    """Allegro hand + knob on a vertical hinge; see the module docstring."""

    asset = "allegro_knob.xml"
    contact_params = hand.CONTACT
    bench = BenchPoses(
        open_q=(*NEAR_KNOB, 0.0),
        # flex every finger toward the knob, the thumb (j13 decreasing) into it
        close_action=(0.0, 0.6, 0.6, 0.6) * 3 + (0.0, -0.6, 0.3, 0.3),
        touch_q=(*GRASP, 0.0),
        free_q=(*hand.OPEN, 0.0),
        squeeze_action=(0.0, 0.3, 0.3, 0.3) * 3 + (0.0, -0.3, 0.0, 0.0),
    )
    plan_problem = PlanProblem(start=(0.0,), goal=(0.5,), steps=60)

    def __init__(self, config: AllegroRotateConfig | None = None, **kwargs):
        super().__init__(AllegroRotateConfig() if config is None else config, **kwargs)

    def start_pose(self) -> tuple[float, ...]:
        return INITIAL_POSES[self.config.initial]


register_task("allegro_rotate", AllegroRotateEnv, AllegroRotateConfig)
