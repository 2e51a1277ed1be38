"""Typed task configs: one dataclass per task is the single source of its defaults.

:class:`TaskConfig` holds the fields every task has; a task module subclasses it with its own fields
(each with a comment saying what it is). ``make_env(name, **overrides)`` and ``dexmots-train task=name``
read the same dataclass: the registry stores it in hydra's ConfigStore as the ``task`` group entry, so
the command line is checked against it too (an unknown key or a wrong type fails naming the key).

:meth:`TaskConfig.validate` checks every field against its type annotation and its range (field metadata,
:func:`.fields.rule`) and raises one ``ValueError`` naming ``task.<field>``; it runs whenever an env is built
from a config.

Example:
    >>> from dexmots_rl.envs import task_config
    >>> cfg = task_config("screw_claw", action="torque")
    >>> cfg.action, cfg.goal
    ('torque', 'pose_wrench')
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Optional

from .actions import ACTION_TYPES
from .fields import rule, validate_fields
from .rewards import RewardCoefficients
from .transforms import GOAL_MODES

__all__ = ["BenchPoses", "PlanProblem", "TaskConfig", "check_number", "check_range", "config_from_dict",
           "override_config", "rule", "saved_config_defaults", "ADDED_WITH_THE_OLD_BEHAVIOUR"]


def check_number(name: str, value, low: float = 0.0, strict: bool = True) -> None:
    """A ``ValueError`` naming ``name`` unless ``value`` is a finite real number (not a bool) above ``low``
    (``strict``) or at least ``low``."""
    number = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if not number or not (value > low if strict else value >= low):
        raise ValueError(f"{name} must be a number {'>' if strict else '>='} {low:g}, got {value!r}")


def check_range(name: str, value, low_bound: float = 0.0) -> tuple[float, float]:
    """``value`` as a ``(low, high)`` tuple with ``low_bound <= low <= high`` (both finite), or a
    ``ValueError`` naming ``name``."""
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a pair (low, high), got {value!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and low_bound <= lo <= hi):
        raise ValueError(f"{name} must be (low, high) with {low_bound:g} <= low <= high, got {value!r}")
    return lo, hi


@dataclasses.dataclass
class TaskConfig:
    """Fields every task has. Subclasses add the task's own and override defaults."""

    name: str = ""  # registry name of the task (set by each task's config)
    num_envs: int = 64  # worlds dexmots-train simulates (make_env's num_envs argument overrides it)
    # pose | pose_traj | pose_wrench: the goal representation (paper's ablation)
    goal: str = dataclasses.field(default="pose_wrench", metadata=rule(choices=GOAL_MODES))
    goal_horizon: int = 8  # reference steps ahead in the pose_traj / pose_wrench goals
    # torque | position | vi (variable impedance: PD targets and stiffness per joint)
    action: str = dataclasses.field(default="vi", metadata=rule(choices=ACTION_TYPES))
    max_episode_steps: int = 100  # env steps per episode (60 Hz control)
    substeps: int = 16  # physics substeps per env step
    # plan file / directory from dexmots-plan (from Python also a list of plans); None: the task's analytic reference
    references: Optional[str] = dataclasses.field(default=None, metadata=rule(objects=True))
    # a pose-only demonstration to follow (.npz / .pt, layout in dexmots_rl.envs.demos); None: the task's reference
    demo: Optional[str] = None
    reward: RewardCoefficients = dataclasses.field(default_factory=RewardCoefficients)  # paper Eq. 3's λ
    mirror: bool = False  # worlds with a negative goal see the task mirrored (a mirror-symmetric task's option)
    # identified physical parameters (a dexmots-sysid JSON file): every world uses its values instead of the task's
    # randomised or nominal ones for the parameters it names; None: the task's own
    object_params: Optional[str] = None

    def validate(self) -> "TaskConfig":
        """Check every field against its annotation and rule (one ``ValueError`` naming the first bad
        ``task.<field>``), normalising lists to tuples and a ``reward`` mapping to
        :class:`RewardCoefficients`; returns self. A task adds cross-field checks by extending it."""
        return validate_fields(self, "task")


def _field_names(cls) -> list[str]:
    return [f.name for f in dataclasses.fields(cls)]


def override_config(cfg: TaskConfig, overrides: dict[str, Any]) -> TaskConfig:
    """A copy of ``cfg`` with ``overrides`` applied; an unknown field fails naming it and listing the
    task's fields. ``reward`` may be a dict of coefficients; pairs may be lists."""
    names = _field_names(type(cfg))
    unknown = [k for k in overrides if k not in names]
    if unknown:
        raise ValueError(f"task {cfg.name!r} has no option {unknown[0]!r}; its options are: {', '.join(names)}")
    values = dict(overrides)
    if isinstance(values.get("reward"), dict):  # checked (and built) by validate, naming task.reward.<key>
        values["reward"] = {**dataclasses.asdict(cfg.reward), **values["reward"]}
    return dataclasses.replace(cfg, **values).validate()


# fields added (or whose default changed) after runs were saved, with the value that keeps a saved config's task
# what it trained on (a field missing from a saved config otherwise takes today's default); a task's own field
# applies to the configs that have it
SAVED_CONFIG_DEFAULTS = {"mirror": False, "rest_on_palm": False}
# fields added after runs were saved whose default is what those runs did: a saved config without one is the
# same config as today's with its default (dexmots-table reuses such a finished run)
ADDED_WITH_THE_OLD_BEHAVIOUR = ("urdf", "object_params")


def saved_config_defaults(cls) -> dict[str, Any]:
    """The :data:`SAVED_CONFIG_DEFAULTS` that config class ``cls`` has."""
    names = _field_names(cls)
    return {k: v for k, v in SAVED_CONFIG_DEFAULTS.items() if k in names}


def config_from_dict(cls, data: dict[str, Any]) -> TaskConfig:
    """Build a ``cls`` config from a plain dict (e.g. a checkpoint's or hydra's resolved ``task``); a field
    the dict predates takes its :data:`SAVED_CONFIG_DEFAULTS` value."""
    return override_config(cls(), {**saved_config_defaults(cls), **dict(data)})


@dataclasses.dataclass(frozen=True)
class BenchPoses:
    """A task's poses and actions for the benchmarks (hand dofs then object q, in the MJCF's joint
    order; actions in [-1, 1] per actuator, torque action space), and what the gradient benchmark's loss
    aims at. A task declares them as its class's ``bench`` or builds them per scene
    (:meth:`~dexmots_rl.envs.DexEnv.bench_poses`, e.g. from its pre-grasps)."""

    # where the throughput window starts: the hand open, not touching, closing from here makes contact (a
    # tool task: its pre-grasp, where its episodes start)
    open_q: tuple[float, ...]
    close_action: tuple[float, ...]  # strong closing action used from ``open_q`` (throughput)
    touch_q: tuple[float, ...]  # fingers already on the object (gradients with contact)
    free_q: tuple[float, ...]  # fingers far from the object (gradients without contact)
    squeeze_action: tuple[float, ...]  # moderate closing action that keeps ``touch_q`` in contact
    # action from ``free_q`` that keeps the fingers off the object (a hand that droops under gravity
    # onto the object needs one); empty: none
    release_action: tuple[float, ...] = ()
    # the gradient benchmark's loss (dexmots-bench grad): the operated joint (index among the object's
    # joints; an articulated object's base is not one), its goal (rad or m) and goal speed (rad/s or m/s);
    # None: the benchmark's defaults (a knob turned toward pi/4 at 1 rad/s)
    joint: int = 0
    goal: Optional[float] = None
    goal_speed: Optional[float] = None
    # a free base's tolerated shift (m) and tilt (rad): the loss holds the base where it stands, each
    # deviation divided by its tolerance; None: no base term (a fixed base, or a scene without one)
    base_tolerance: Optional[tuple[float, float]] = None


@dataclasses.dataclass(frozen=True)
class PlanProblem:
    """A task's default wrench-planning problem (``dexmots-bench plan``): object start, goal, env steps."""

    start: tuple[float, ...]
    goal: tuple[float, ...]
    steps: int
    lr: float = 0.5  # Adam step (N, N m) of the wrench optimiser: ~ the wrench the object needs (the claw's
    # knob ~1 N m; a 10-40 g part of an operable object ~0.05-0.3 N m, where 0.5 diverges)
