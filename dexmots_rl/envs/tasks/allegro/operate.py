"""Operating an articulated object's sprung joint with the Allegro hand: what spray_bottle, scissors and
stapler share.

The scene (``assets/allegro_<object>.xml``, from :mod:`dexmots_rl.assets.operable`) is a static base plus
one part on a sprung hinge with a range [lower, upper], at rest at its lower end. Per episode the goal is
``lower + f (upper - lower)`` with ``f`` drawn from ``goal_fraction`` (default 0.9 fixed: the original
code's 90 % of the joint's range); the part's damping, Coulomb friction and spring stiffness are drawn
from ``damping_range`` / ``friction_range`` / ``stiffness_range``. The hand starts from one of the task's
pre-grasps (``initial="pregrasp"``, :mod:`dexmots_rl.envs.pregrasp`: fingertips resting on the regions
the task names, drawn per episode) with joint noise, or straight (``"flat"``). Success: the joint
within ``success_threshold`` of the goal at the episode end.

Reference, reward and goal modes are :mod:`..knob`'s: the angle ramps from rest to the goal over
``ramp_steps`` steps, with the torque the nominal part needs (spring, damping, friction); the reward is
the paper's pose + wrench + action + fingertip terms.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import ClassVar, Optional

import numpy as np
import torch

from ....sim import ContactParams
from ...config import BenchPoses, rule
from ...pregrasp import ContactRegion, PregraspError, load_pregrasps, pregrasp_path
from ...rewards import RewardCoefficients
from ..knob import PARAM_BREAKDOWNS, RANGE, KnobTurnConfig, KnobTurnEnv

__all__ = ["OperateConfig", "OperateEnv", "HAND_CONTACT", "FLAT", "bench_poses", "task_pregrasps"]

# the hand's contact law as allegro_rotate sizes it (a centimetre-scale object, fingertips pushing ~5 N)
HAND_CONTACT = ContactParams(stiffness=5.0e3, sharpness=1000.0, surface_smoothing=0.002, slip_velocity=0.1)
FLAT = (0.0,) * 12 + (0.263, 0.0, 0.0, 0.0)  # every joint at 0, the thumb's j12 at its lower limit


@dataclasses.dataclass
class OperateConfig(KnobTurnConfig):
    """Fields of the operable-object tasks (defaults shared; each task sets its own ranges)."""

    initial: str = "pregrasp"  # pregrasp (one of the task's pre-grasps, drawn per episode) | flat
    initial_choices: ClassVar[tuple[str, ...]] = ("pregrasp", "flat")
    # goal = lower + f (upper - lower), f drawn in this range
    goal_fraction: tuple[float, float] = dataclasses.field(default=(0.9, 0.9), metadata=rule(ge=0, le=1, ordered=True))
    goal_range: tuple[float, float] = (0.0, 0.0)  # unused here (the goal is a fraction of the joint's range)
    damping_range: tuple[float, float] = (0.005, 0.02)  # part joint damping (N m s/rad)
    friction_range: tuple[float, float] = (0.0, 0.004)  # part joint Coulomb friction (N m)
    # return spring (N m/rad)
    stiffness_range: tuple[float, float] = dataclasses.field(default=(0.03, 0.08), metadata=RANGE)
    pregrasps: Optional[str] = None  # a pre-grasp file (dexmots-pregrasp --out); None: the one the package ships
    joint_noise: float = 0.02  # rad, on the start pose
    success_threshold: float = 0.05  # rad: |theta - goal| at the episode end (each task: 8 % of its range, so
    # that pushing the part onto its stop is not a success)
    ramp_steps: int = 40
    max_episode_steps: int = 150
    pose_scale: float = 0.1  # rad
    torque_scale: float = 0.02  # N m
    fingertip_scale: float = 0.05  # m
    reward: RewardCoefficients = dataclasses.field(
        default_factory=lambda: RewardCoefficients(lambda_pose=1.0, lambda_wrench=0.5, lambda_act=0.01, lambda_f=0.5))


@functools.lru_cache(maxsize=None)
def _read_pregrasps(path: str, modified_ns: int, task: str, lower: tuple, upper: tuple) -> np.ndarray:
    return load_pregrasps(path, len(lower), task, lower, upper)


def task_pregrasps(task: str, scene, path: str | None = None) -> np.ndarray:
    """``task``'s pre-grasps [K, hand dofs], from ``path`` (a user's file) or the shipped file, checked whole
    against the task and ``scene``'s joint ranges (:func:`~dexmots_rl.envs.pregrasp.load_pregrasps`); read
    once per file version."""
    file = Path(path).expanduser() if path is not None else pregrasp_path(task)
    try:
        modified = file.stat().st_mtime_ns
    except OSError:
        modified = -1  # load_pregrasps names the missing file
    nu = scene.num_hand_dofs
    return _read_pregrasps(str(file), modified, task, tuple(float(x) for x in scene.dof_lower[:nu]),
                           tuple(float(x) for x in scene.dof_upper[:nu]))


class OperateEnv(KnobTurnEnv):
    """Allegro hand + an operable object; a task gives ``asset``, ``contact_regions``,
    ``pregrasp_hint`` and its bench poses."""

    contact_params = HAND_CONTACT
    contact_regions: ClassVar[tuple[ContactRegion, ...]] = ()  # where the pre-grasps put the fingertips
    pregrasp_hint: ClassVar[tuple[float, ...]] = FLAT  # the pose the pre-grasp search starts from
    # no goal breakdown: the goal is the same every episode
    breakdowns = {**PARAM_BREAKDOWNS, "stiffness": ("sim", "params", "joint_stiffness")}

    def __init__(self, config: OperateConfig, **kwargs):
        super().__init__(config, **kwargs)
        lower, upper = self.sim.scene.object_range
        self._joint_range = (float(lower), float(upper))
        if self.config.initial == "pregrasp":
            poses = task_pregrasps(self.config.name, self.sim.scene, self.config.pregrasps)
            self._pregrasps = torch.as_tensor(poses, dtype=self.dtype, device=self.device)

    def start_pose(self) -> tuple[float, ...]:
        return FLAT

    def _param_ranges(self) -> dict:
        return {**super()._param_ranges(), "joint_stiffness": self.config.stiffness_range}

    def sample_start(self, n: int) -> torch.Tensor:
        if self.config.initial != "pregrasp":
            return super().sample_start(n)
        pick = (self._rand(n) * len(self._pregrasps)).long().clamp(max=len(self._pregrasps) - 1)
        return self._pregrasps[pick]

    def sample_goal(self, n: int) -> torch.Tensor:
        lower, upper = self._joint_range
        return lower + self._uniform(n, self.config.goal_fraction) * (upper - lower)


class _LazyBenchPoses:
    """A task class's ``bench`` poses, built on first use: they read the shipped pre-grasp file, which is
    read when something needs it (a benchmark), not when the task module is imported."""

    def __init__(self, task: str, close: tuple[float, ...]):
        self.task, self.close, self.poses = task, close, None

    def __get__(self, instance, owner) -> BenchPoses:
        if self.poses is None:
            from .rotate import GRASP

            try:
                from ....sim import load_scene

                scene = load_scene(owner.asset_path())
                touch = tuple(float(x) for x in task_pregrasps(self.task, scene)[0])
            except PregraspError:  # no (valid) file yet: the knob task's grasp
                touch = GRASP
            self.poses = BenchPoses(open_q=(*FLAT, 0.0), close_action=self.close, touch_q=(*touch, 0.0),
                                    free_q=(*FLAT, 0.0), squeeze_action=tuple(0.5 * a for a in self.close))
        return self.poses


def bench_poses(task: str, close: tuple[float, ...]) -> BenchPoses:
    """A task's benchmark poses: straight fingers (open and free), its first pre-grasp (touching; the knob
    task's grasp until the pre-grasp file exists), ``close`` and half of it as the squeeze (a class attribute
    built on first use)."""
    return _LazyBenchPoses(task, close)
