"""The gymnasium ids ``dexmots/<TaskName>-v0`` of the shipped tasks, registered by ``import dexmots_rl``.

Registration names entry points as strings, so nothing heavy is imported until ``gymnasium.make`` /
``gymnasium.make_vec`` builds an env (that imports :mod:`dexmots_rl.envs.gym`, which registers every task of
the registry, a user's own included). Not even gymnasium is imported by ``import dexmots_rl``: when it is
not loaded yet, the ids are registered the moment it is (an import hook that removes itself), so the package
import stays as fast as before.

Example:
    >>> import gymnasium, dexmots_rl
    >>> "dexmots/ScrewClaw-v0" in gymnasium.registry
    True
"""

from __future__ import annotations

import importlib.abc
import importlib.util
import sys

__all__ = ["SHIPPED_TASKS", "gym_id", "register_gym_ids", "register_when_gymnasium_loads"]

#: the registry names of the tasks under dexmots_rl/envs/tasks (a test checks it against the registry)
SHIPPED_TASKS = ("allegro_rotate", "door_handle", "drawer", "jar", "operate", "pliers", "pump_dispenser", "repose_cube",
                 "scissors", "screw_claw", "spray_bottle", "stapler", "valve")


def gym_id(task: str) -> str:
    """The gymnasium id of a task: ``screw_claw`` -> ``dexmots/ScrewClaw-v0``."""
    return "dexmots/" + "".join(part.capitalize() for part in task.split("_")) + "-v0"


def register_gym_ids(tasks=SHIPPED_TASKS) -> list[str]:
    """Register ``dexmots/<Task>-v0`` (single and vector entry points of :mod:`dexmots_rl.envs.gym`) for
    ``tasks``; returns the ids ([] without gymnasium)."""
    try:
        import gymnasium as gym
    except ImportError:  # pragma: no cover - gymnasium is a dependency; a torchrl-only install still imports
        return []
    ids = []
    for task in tasks:
        env_id = gym_id(task)
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point="dexmots_rl.envs.gym:DexGymEnv",
                         vector_entry_point="dexmots_rl.envs.gym:DexVectorEnv", kwargs={"task": task})
        ids.append(env_id)
    return ids


class _RegisterOnImport(importlib.abc.MetaPathFinder):
    """Finds nothing itself: on the first import of gymnasium it lets the other finders find it, removes
    itself, and registers the ids once gymnasium's module has run."""

    def find_spec(self, name, path=None, target=None):
        if name != "gymnasium":
            return None
        if self in sys.meta_path:
            sys.meta_path.remove(self)
        spec = importlib.util.find_spec(name)
        if spec is None or spec.loader is None or not hasattr(spec.loader, "exec_module"):
            return spec
        run_module = spec.loader.exec_module

        def exec_module(module):
            run_module(module)
            register_gym_ids()

        spec.loader.exec_module = exec_module  # this spec's own loader instance
        return spec


def register_when_gymnasium_loads() -> None:
    """Register the shipped ids now if gymnasium is loaded, else the moment it is."""
    if "gymnasium" in sys.modules:
        register_gym_ids()
    elif not any(isinstance(f, _RegisterOnImport) for f in sys.meta_path):
        sys.meta_path.insert(0, _RegisterOnImport())
