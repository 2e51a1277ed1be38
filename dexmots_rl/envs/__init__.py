"""TorchRL environments: ``DexEnv``, one module per task (:mod:`.tasks`), and the registry.

``make_env(name, **overrides)`` builds exactly the task ``dexmots-train task=<name>`` trains;
``list_tasks()`` names them; ``task_config(name)`` is a task's typed config (its defaults).
"""

from __future__ import annotations

from .actions import ACTION_TYPES, ActionMap, validate_action
from .base import GRADIENT_COUNTS, DexEnv, ScriptedPolicy
from .config import BenchPoses, PlanProblem, TaskConfig
from .references import load_reference_bank
from .registry import OBS_MODES, TASKS, list_tasks, make_env, register_task, task_config, task_contact, task_entry, task_scene
from .rewards import RewardCoefficients, angle_tracking_reward
from .transforms import GOAL_MODES, POLICY_KEYS, GoalConditioning, observation_transform
from . import tasks  # noqa: E402,F401  (registers the tasks)
from .tasks.screw_claw import ScrewClawConfig, ScrewClawEnv  # noqa: E402

try:  # gymnasium ids dexmots/<Task>-v0 (see .gym); the torchrl API does not need gymnasium
    from . import gym  # noqa: E402,F401
except ImportError:  # pragma: no cover - gymnasium is a dependency, but keep torchrl-only installs working
    pass

__all__ = ["ACTION_TYPES", "ActionMap", "validate_action", "BenchPoses", "DexEnv", "GRADIENT_COUNTS", "ScriptedPolicy",
           "GOAL_MODES", "GoalConditioning",
           "OBS_MODES", "POLICY_KEYS", "PlanProblem", "RewardCoefficients", "TASKS", "TaskConfig",
           "load_reference_bank", "list_tasks", "make_env", "observation_transform", "register_task",
           "angle_tracking_reward", "task_config", "task_contact", "task_entry", "task_scene", "ScrewClawConfig", "ScrewClawEnv"]
