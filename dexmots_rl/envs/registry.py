"""Task registry and ``make_env``."""

from __future__ import annotations

from torchrl.envs import TransformedEnv

from .base import DexEnv
from .screw_claw import ScrewClawEnv
from .transforms import GOAL_MODES, POLICY_KEYS, observation_transform

__all__ = ["TASKS", "POLICY_KEYS", "OBS_MODES", "make_env"]

TASKS: dict[str, type[DexEnv]] = {"screw_claw": ScrewClawEnv}
OBS_MODES = ("state", "rgb")


def make_env(task: str, num_envs: int = 1, device="cpu", differentiable: bool = True, seed: int | None = None,
             raw: bool = False, goal: str = "pose", goal_horizon: int = 8, obs: str = "state", **kwargs):
    """Build a task env with ``num_envs`` worlds.

    Returns a ``TransformedEnv`` whose transforms write the goal representation ``goal`` (one of
    ``"pose"``, ``"pose_traj"``, ``"pose_wrench"``; see :mod:`dexmots_rl.envs.transforms`) and assemble
    ``"observation"`` (flat, for the policy) without removing anything; ``obs="rgb"`` also renders
    ``"pixels"``. ``raw=True`` returns the bare :class:`DexEnv`. Other keyword arguments go to the task
    (e.g. ``action="vi"``, ``references="plans/"``, ``friction_range=(0.2, 1.0)``).

    Example:
        >>> from dexmots_rl.envs import make_env
        >>> env = make_env("screw_claw", num_envs=4, device="cpu", differentiable=False, seed=0)
        >>> env.reset()["observation"].shape
        torch.Size([4, 18])
    """
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; known tasks: {', '.join(sorted(TASKS))}")
    if goal not in GOAL_MODES:
        raise ValueError(f"unknown goal {goal!r}; known goal modes: {', '.join(GOAL_MODES)}")
    if obs not in OBS_MODES:
        raise ValueError(f"unknown obs {obs!r}; known observation modes: {', '.join(OBS_MODES)}")
    env = TASKS[task](num_envs=num_envs, device=device, differentiable=differentiable, seed=seed, **kwargs)
    if raw:
        return env
    env = TransformedEnv(env, observation_transform(goal, goal_horizon))
    if obs == "rgb":
        from .pixels import RGBObservation

        env.append_transform(RGBObservation())
    return env
