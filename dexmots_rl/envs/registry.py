"""The task registry: name -> (env class, typed config); ``make_env``, ``list_tasks``, ``task_config``.

A task module registers itself with :func:`register_task` (``envs/tasks/__init__.py`` imports every task
module). Registering also stores the config dataclass in hydra's ConfigStore as ``task/<name>``, which
is what ``dexmots-train task=<name>`` composes: the trainer and ``make_env`` read the same defaults.

Example:
    >>> from dexmots_rl.envs import list_tasks, make_env
    >>> "screw_claw" in list_tasks()
    True
    >>> env = make_env("screw_claw", num_envs=4, differentiable=False, seed=0)
    >>> env.reset()["observation"].shape
    torch.Size([4, 40])
"""

from __future__ import annotations

import dataclasses
from typing import Any

import torch
from torchrl.envs import TransformedEnv

from .base import DexEnv
from .config import TaskConfig, config_from_dict, override_config
from .mirror import MirrorGoal
from .transforms import POLICY_KEYS, observation_transform

__all__ = ["TASKS", "OBS_MODES", "TaskEntry", "register_task", "list_tasks", "task_config", "task_entry",
           "task_scene", "task_contact", "make_env"]

OBS_MODES = ("state", "rgb")


@dataclasses.dataclass(frozen=True)
class TaskEntry:
    """A registered task: its env class and its config dataclass."""

    name: str
    env_class: type[DexEnv]
    config_class: type[TaskConfig]


TASKS: dict[str, TaskEntry] = {}


def register_task(name: str, env_class: type[DexEnv], config_class: type[TaskConfig]) -> None:
    """Add a task (and its config to hydra's ConfigStore as ``task/<name>``). A ``ValueError`` names what
    is wrong: an ``env_class`` that is not a :class:`DexEnv` or lacks one of its abstract hooks, or a config
    whose ``name`` is not ``name``."""
    if not (isinstance(env_class, type) and issubclass(env_class, DexEnv)):
        raise ValueError(f"task {name!r}: the env class must subclass DexEnv, got {env_class!r}")
    missing = sorted(getattr(env_class, "__abstractmethods__", ()))
    if missing:
        raise ValueError(f"task {name!r}: {env_class.__name__} does not implement the task hook(s) "
                         f"{', '.join(missing)} (abstract in DexEnv)")
    if config_class().name != name:
        raise ValueError(f"{config_class.__name__}.name is {config_class().name!r}, registered as {name!r}")
    TASKS[name] = TaskEntry(name, env_class, config_class)
    from hydra.core.config_store import ConfigStore

    ConfigStore.instance().store(group="task", name=name, node=config_class)


def list_tasks() -> list[str]:
    """The registered task names, sorted."""
    return sorted(TASKS)


def task_entry(name: str) -> TaskEntry:
    if name not in TASKS:
        raise ValueError(f"unknown task {name!r}; known tasks: {', '.join(list_tasks())}")
    return TASKS[name]


def task_config(name: str, **overrides: Any) -> TaskConfig:
    """The task's default config with ``overrides`` (unknown names fail, listing the task's options)."""
    entry = task_entry(name)
    return override_config(entry.config_class(), overrides)


def task_scene(name: str):
    """The scene a task's env simulates with its default config (e.g. for the wrench planner): a
    :class:`~dexmots_rl.sim.SceneModel`, or an articulated object's scene."""
    return task_entry(name).env_class.task_scene(task_config(name))


def task_contact(name: str):
    """The :class:`~dexmots_rl.sim.ContactParams` a task's env simulates its scene with (None: the defaults,
    the claw's). Anything that steps :func:`task_scene` as the task (the benchmarks) must pass it to the
    ``Simulator``: the Allegro tasks' law (1000 /m) acts over 1.2 cm, the default over 6 cm."""
    return task_entry(name).env_class.contact_params


def _plain(task) -> dict:
    """A config as a plain dict: a dataclass, a hydra/OmegaConf node or a mapping."""
    if isinstance(task, TaskConfig):
        return dataclasses.asdict(task)
    from omegaconf import DictConfig, OmegaConf

    if isinstance(task, DictConfig):
        return OmegaConf.to_container(task, resolve=True)
    return dict(task)


def make_env(task: str | TaskConfig, num_envs: int | None = None, device="cpu", differentiable: bool = True,
             seed: int | None = None, raw: bool = False, obs: str = "state", dtype: torch.dtype = torch.float32,
             adjoint_clip: float | None = None, **overrides):
    """Build a task env, exactly the task ``dexmots-train task=<name>`` trains unless told otherwise.

    ``task``: a registered name, or a config (a :class:`TaskConfig` or a dict with ``"name"``, e.g. a
    checkpoint's); ``overrides``: config fields (``action="torque"``, ``goal="pose"``,
    ``friction_range=(0.2, 1.0)``, ``reward={"lambda_f": 0.5}``...; an unknown one fails listing the
    task's options). ``num_envs`` defaults to the config's. Returns a ``TransformedEnv`` whose transforms
    write the goal representation and assemble ``"observation"`` (flat, for the policy) without removing
    anything; ``obs="rgb"`` also renders ``"pixels"``; ``raw=True`` returns the bare :class:`DexEnv`.
    ``adjoint_clip``: the simulator's outlier-world gradient clip (a training option).
    """
    if obs not in OBS_MODES:
        raise ValueError(f"unknown obs {obs!r}; known observation modes: {', '.join(OBS_MODES)}")
    if isinstance(task, str):
        cfg = task_config(task, **overrides)
    else:
        data = _plain(task)
        if "name" not in data:
            raise ValueError("a task config needs its 'name'")
        entry = task_entry(data["name"])
        cfg = override_config(config_from_dict(entry.config_class, data), overrides)
    entry = task_entry(cfg.name)
    env = entry.env_class(cfg, num_envs=cfg.num_envs if num_envs is None else num_envs, device=device,
                          differentiable=differentiable, seed=seed, dtype=dtype, adjoint_clip=adjoint_clip)
    env.reference_bank  # a demonstration becomes the task's reference now: its errors surface here
    if raw:
        return env
    env = TransformedEnv(env, observation_transform(cfg.goal, cfg.goal_horizon))
    if cfg.mirror:  # the env refused the option if the task has no mirror
        env.append_transform(MirrorGoal(*env.base_env.mirror_maps(), policy_keys=POLICY_KEYS))
    if obs == "rgb":
        from .pixels import RGBObservation

        env.append_transform(RGBObservation())
    return env
