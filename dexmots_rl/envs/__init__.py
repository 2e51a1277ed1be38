"""TorchRL environments: ``DexEnv`` and one module per task; ``make_env`` builds them by name."""

from __future__ import annotations

from .actions import ACTION_TYPES, ActionMap, validate_action
from .base import DexEnv
from .references import load_reference_bank
from .registry import OBS_MODES, TASKS, make_env
from .rewards import RewardCoefficients, angle_tracking_reward
from .screw_claw import ScrewClawEnv
from .transforms import GOAL_MODES, POLICY_KEYS, GoalConditioning, observation_transform

__all__ = ["ACTION_TYPES", "ActionMap", "validate_action", "DexEnv", "GOAL_MODES", "GoalConditioning", "OBS_MODES",
           "POLICY_KEYS", "RewardCoefficients", "TASKS", "load_reference_bank", "make_env", "observation_transform",
           "angle_tracking_reward", "ScrewClawEnv"]
