"""screw_claw: the 2-finger Claw turns an octagonal screw-top knob by a goal angle (DexMOTS "Screw").

The knob task's reference, reward and success are :mod:`.knob`'s. The claw: |goal| in [π/4, π/2], knob
damping in [0.3, 0.7] and friction in [0.2, 1.0] N m per episode; the hand starts from a grasp (the
paper initialises its claw policies from one): distal links resting on the knob, or ``initial="open"``
(proximal joints spread by ``open_angle``), with a little joint noise. Success: |θ − θ*| < 0.1 rad at
the episode end. The scene is symmetric about the xz-plane, and by default (``mirror=True``) worlds with a
negative goal are seen in that mirror (:mod:`..mirror`): the policy learns to turn one way.

Example:
    >>> from dexmots_rl.envs import make_env
    >>> env = make_env("screw_claw", num_envs=2, seed=0)  # the trained task: vi actions, pose+wrench goals
    >>> td = env.rollout(3)
    >>> td["next", "reward"].shape, td["next", "reward_terms", "pose"].shape
    (torch.Size([2, 3, 1]), torch.Size([2, 3, 1]))
"""

from __future__ import annotations

import dataclasses
import math

import torch

from ..config import BenchPoses, PlanProblem
from ..mirror import SignedPermutation
from ..registry import register_task
from ..rewards import RewardCoefficients
from .knob import KnobTurnConfig, KnobTurnEnv

__all__ = ["ScrewClawConfig", "ScrewClawEnv", "scripted_claw_action", "INITIAL_POSES"]

# hand joints (right prox, right distal, left prox, left distal); "open" uses open_angle
# "grasp": the distal links resting on the knob (~6 N of contact at rest). The first grasp, distal joints at
# -+0.6, overlapped the knob by centimetres: the first step kicked it with ~490 N and policies learnt to
# flick the knob with that kick and coast.
INITIAL_POSES = {"open": None, "grasp": (0.5, -0.42, -0.5, 0.42)}


@dataclasses.dataclass
class ScrewClawConfig(KnobTurnConfig):
    """screw_claw's defaults: the task dexmots-train trains (see the module docstring)."""

    name: str = "screw_claw"
    initial_choices = tuple(INITIAL_POSES)
    initial: str = "grasp"  # open (fingers spread) | grasp (resting on the knob, as the paper starts)
    open_angle: float = math.radians(60.0)  # rad: proximal spread of the "open" start
    torque_scale: float = 5.0  # N m; 1 N m made policies let go (squeezing puts 20-50 N m on the hinge)
    # the claw and knob are mirror-symmetric: worlds turning the negative way are seen in the mirror, so a policy
    # learns one direction (AHAC: 100 % on seeds 0-3 against 96-98 %, and no run stuck turning one way only)
    mirror: bool = True
    # lambda_f 0.1 let the fingers flick the knob and let go (36 % success); 1.0 keeps them on it
    reward: RewardCoefficients = dataclasses.field(
        default_factory=lambda: RewardCoefficients(lambda_pose=1.0, lambda_wrench=0.5, lambda_act=0.01, lambda_f=1.0))


def scripted_claw_action(desired_goal: torch.Tensor, squeeze: float = 0.6, twist: float = 0.4) -> torch.Tensor:
    """Close both fingers on the knob and push them tangentially in the goal's direction.

    Joint order: right proximal, right distal, left proximal, left distal (torque actions in [-1, 1]).
    Closing is negative on the right finger and positive on the left; a common-mode offset on the
    proximal joints slides both fingertips the same way around the knob.
    """
    goal_sign = torch.sign(desired_goal)
    close = torch.tensor([-squeeze, -squeeze, squeeze, squeeze], dtype=goal_sign.dtype, device=goal_sign.device)
    twist_dir = torch.tensor([1.0, 0.0, 1.0, 0.0], dtype=goal_sign.dtype, device=goal_sign.device)
    return (close - twist * goal_sign * twist_dir).clamp(-1, 1)


class ScrewClawEnv(KnobTurnEnv):
    """Claw + knob on a vertical hinge; see the module docstring."""

    asset = "claw_screw.xml"
    # joint order: right proximal, right distal, left proximal, left distal, knob angle. Closing is negative
    # on the right finger and positive on the left (see the MJCF joint ranges).
    bench = BenchPoses(
        open_q=(1.047, 0.0, -1.047, 0.0, 0.0),
        close_action=(-1.0, -0.5, 1.0, 0.5),
        touch_q=(*INITIAL_POSES["grasp"], 0.0),  # the grasp start: resting on the knob (~6 N)
        free_q=(1.2, -0.5, -1.2, 0.5, 0.0),
        squeeze_action=(-0.5, -0.5, 0.5, 0.5),
    )
    plan_problem = PlanProblem(start=(0.0,), goal=(math.pi / 2,), steps=60)

    def __init__(self, config: ScrewClawConfig | None = None, **kwargs):
        super().__init__(ScrewClawConfig() if config is None else config, **kwargs)

    def start_pose(self) -> tuple[float, ...]:
        a = self.config.open_angle
        return (a, 0.0, -a, 0.0) if self.config.initial == "open" else INITIAL_POSES["grasp"]

    def mirror_maps(self):
        """The claw and knob reflected in the xz-plane: the fingers swap, every joint angle and velocity and the
        goal's angles and torques negate, the fingertips' y negates; stiffness actions swap unsigned. The
        physics is exactly symmetric (tests/test_mirror.py steps a state and its reflection side by side)."""
        swap, minus = (2, 3, 0, 1), (-1.0,) * 4
        joints = SignedPermutation(swap, minus)
        targets = joints if self.config.action != "vi" else SignedPermutation.concat(
            [joints, SignedPermutation(swap, (1.0,) * 4)])
        knob = SignedPermutation((0,), (-1.0,))
        tips = SignedPermutation((3, 4, 5, 0, 1, 2), (1.0, -1.0, 1.0) * 2)
        maps = {("hand", "q"): joints, ("hand", "qd"): joints, ("object", "q"): knob, ("object", "qd"): knob,
                ("fingertips", "pos"): tips, "desired_goal": SignedPermutation.negate,
                "goal_error": SignedPermutation.negate}
        return maps, targets

    def scripted_action(self, td) -> torch.Tensor:
        """A torque-space grasp-and-twist controller (no learning): the smoke job's and the plots'."""
        return scripted_claw_action(td.get(("task", "goal")))


register_task("screw_claw", ScrewClawEnv, ScrewClawConfig)
