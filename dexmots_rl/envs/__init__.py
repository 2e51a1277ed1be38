"""TorchRL environments: ``DexEnv`` and one module per task; ``make_env`` builds them by name."""

from __future__ import annotations

from .actions import ACTION_TYPES, ActionMap, validate_action
from .base import DexEnv
from .registry import POLICY_KEYS, TASKS, make_env
from .rewards import angle_tracking_reward
from .screw_claw import ScrewClawEnv

__all__ = ["ACTION_TYPES", "ActionMap", "validate_action", "DexEnv", "POLICY_KEYS", "TASKS", "make_env",
           "angle_tracking_reward", "ScrewClawEnv"]
