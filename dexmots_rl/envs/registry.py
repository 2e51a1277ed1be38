"""Task registry and ``make_env``."""

from __future__ import annotations

from torchrl.envs import CatTensors, TransformedEnv

from .base import DexEnv
from .screw_claw import ScrewClawEnv

__all__ = ["TASKS", "POLICY_KEYS", "make_env"]

TASKS: dict[str, type[DexEnv]] = {"screw_claw": ScrewClawEnv}

# what the default policy input "observation" is assembled from (never read back by the env)
POLICY_KEYS = [
    ("hand", "q"),
    ("hand", "qd"),
    ("object", "q"),
    ("object", "qd"),
    ("fingertips", "pos"),
    "desired_goal",
]


def make_env(task: str, num_envs: int = 1, device="cpu", differentiable: bool = True, seed: int | None = None,
             raw: bool = False, **kwargs):
    """Build a task env with ``num_envs`` worlds.

    Returns a ``TransformedEnv`` whose transforms assemble ``"observation"`` (flat, for the policy) from
    the env's keys without removing them; ``raw=True`` returns the bare :class:`DexEnv`.

    Example:
        >>> from dexmots_rl.envs import make_env
        >>> env = make_env("screw_claw", num_envs=4, device="cpu", differentiable=False, seed=0)
        >>> env.reset()["observation"].shape
        torch.Size([4, 17])
    """
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; known tasks: {', '.join(sorted(TASKS))}")
    env = TASKS[task](num_envs=num_envs, device=device, differentiable=differentiable, seed=seed, **kwargs)
    if raw:
        return env
    return TransformedEnv(env, observation_transform(env))


def observation_transform(env: DexEnv):
    """Flatten and concatenate :data:`POLICY_KEYS` into ``"observation"`` (keeping the inputs)."""
    from torchrl.envs import Compose, FlattenObservation

    return Compose(
        FlattenObservation(-2, -1, in_keys=[("fingertips", "pos")], out_keys=[("fingertips", "pos_flat")]),
        CatTensors(in_keys=[k if k != ("fingertips", "pos") else ("fingertips", "pos_flat") for k in POLICY_KEYS],
                   out_key="observation", del_keys=False),
    )
