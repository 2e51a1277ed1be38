"""The policies the recording and rollout scripts offer without a checkpoint: a task's scripted controller
(only tasks that define one: :meth:`dexmots_rl.envs.base.DexEnv.scripted_action`) or uniform random actions.
``auto`` (the default) takes the scripted controller where the task has one and random actions elsewhere,
so every task records and rolls out with the defaults."""

from __future__ import annotations

__all__ = ["POLICIES", "RECORD_ALTERNATIVES", "choose_policy", "has_scripted_controller"]

POLICIES = ("auto", "scripted", "random")


def has_scripted_controller(task: str) -> bool:
    """Whether registered task ``task``'s env defines a scripted controller."""
    from ..envs.base import DexEnv
    from ..envs.registry import task_entry

    return task_entry(task).env_class.scripted_action is not DexEnv.scripted_action


RECORD_ALTERNATIVES = ("policy=random (uniform random actions) or checkpoint=<run directory or checkpoint file> "
                       "(a trained policy)")


def choose_policy(policy: str, task: str, alternatives: str = RECORD_ALTERNATIVES) -> str:
    """``scripted`` or ``random`` for option ``policy`` on ``task``; a ``ValueError`` naming the options
    (``alternatives``: how the calling script spells them) when ``policy`` is unknown, or ``scripted`` on a
    task without a controller."""
    if policy not in POLICIES:
        raise ValueError(f"policy must be one of {', '.join(POLICIES)}, got {policy!r}")
    scripted = has_scripted_controller(task)
    if policy == "auto":
        return "scripted" if scripted else "random"
    if policy == "scripted" and not scripted:
        raise ValueError(f"task {task!r} has no scripted controller; use {alternatives}")
    return policy
