"""Gymnasium facades over any registered task: :class:`DexVectorEnv` (a ``gymnasium.vector.VectorEnv`` of
batched worlds) and :class:`DexGymEnv` (one world, a ``gymnasium.Env``).

Both wrap ``make_env(task, ...)`` (non-differentiable: gymnasium hands out numpy arrays) and expose its
flat policy ``"observation"`` (float32 ``Box``) and its action box ``[-1, 1]``. ``import dexmots_rl``
registers ``dexmots/<TaskName>-v0`` for every shipped task, importing this module for every task in ``list_tasks()``
(``screw_claw`` -> ``dexmots/ScrewClaw-v0``), with a ``vector_entry_point``, so
``gymnasium.make_vec("dexmots/ScrewClaw-v0", num_envs=N)`` builds N batched worlds in one simulator.

**Autoreset: SAME_STEP** (``metadata["autoreset_mode"]``). A world that terminates or is truncated at a
step is reset within that same step: the returned observation is already the new episode's first one,
and the finished episode's last observation is in ``info["final_obs"]`` (rows where
``info["_final_obs"]`` is true; other rows are zero). Rewards, ``terminated`` and ``truncated`` are the
finished step's. Chosen over NEXT_STEP because the worlds share one simulator batch: every call steps
every world, there is no "reset-only" step for a subset.

``info["success"]`` (with the ``"_success"`` mask) is each world's task success after the step.

Example:
    >>> import gymnasium as gym
    >>> import dexmots_rl  # noqa: F401  (registers the ids)
    >>> envs = gym.make_vec("dexmots/ScrewClaw-v0", num_envs=3)
    >>> obs, info = envs.reset(seed=0)
    >>> obs.shape, envs.single_action_space.shape
    ((3, 40), (8,))
    >>> obs, reward, terminated, truncated, info = envs.step(envs.action_space.sample())
    >>> reward.dtype, info["success"].shape
    (dtype('float32'), (3,))
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from ..gym_ids import gym_id, register_gym_ids

__all__ = ["DexGymEnv", "DexVectorEnv", "gym_id", "register_gym_envs"]


def _spaces(env) -> tuple[gym.spaces.Box, gym.spaces.Box]:
    obs_dim = env.observation_spec["observation"].shape[-1]
    act_dim = env.action_spec.shape[-1]
    obs = gym.spaces.Box(-np.inf, np.inf, shape=(obs_dim,), dtype=np.float32)
    act = gym.spaces.Box(-1.0, 1.0, shape=(act_dim,), dtype=np.float32)
    return obs, act


def _action_array(action, space: gym.spaces.Box) -> np.ndarray:
    """``action`` as a float32 array of exactly ``space``'s shape, or a ``ValueError`` naming the expected
    shape (an array of the right size but another shape, e.g. transposed, is refused, not reshaped)."""
    try:
        array = np.asarray(action, dtype=np.float32)
    except (TypeError, ValueError):
        raise ValueError(f"action must be an array of shape {space.shape}, got {type(action).__name__}") from None
    if array.shape != space.shape:
        raise ValueError(f"action must have shape {space.shape}, got {array.shape}")
    return array


def _numpy(x: torch.Tensor, dtype=np.float32) -> np.ndarray:
    return x.detach().to("cpu").numpy().astype(dtype, copy=False)


class DexVectorEnv(VectorEnv):
    """``num_envs`` worlds of ``task`` as a gymnasium vector env (SAME_STEP autoreset; module docstring).

    ``overrides`` are task config fields (``action="torque"``, ...), as for ``make_env``."""

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(self, task: str = "screw_claw", num_envs: int = 1, device: str = "cpu", seed: int | None = None,
                 render_mode: str | None = None, **overrides: Any):
        from .registry import make_env

        if render_mode is not None:
            raise ValueError(f"render_mode {render_mode!r} is not supported (record with dexmots-record instead)")
        self.env = make_env(task, num_envs=num_envs, device=device, differentiable=False, seed=seed, **overrides)
        self.task, self.num_envs, self.render_mode = task, num_envs, None
        self.single_observation_space, self.single_action_space = _spaces(self.env)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self._td = None

    def _info(self, td) -> dict:
        success = _numpy(td.get("success").reshape(self.num_envs), bool)
        return {"success": success, "_success": np.ones(self.num_envs, dtype=bool)}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self.env.set_seed(int(seed), static_seed=True)
        self._td = self.env.reset()
        return _numpy(self._td.get("observation")), self._info(self._td)

    def step(self, actions):
        if self._td is None:
            raise RuntimeError("call reset() before step()")
        action = torch.as_tensor(_action_array(actions, self.action_space), device=self.env.device)
        action = action.to(self.env.base_env.dtype)
        out = self.env.step(self._td.clone().set("action", action))
        nxt = out.get("next")
        obs, info = _numpy(nxt.get("observation")), self._info(nxt)
        reward = _numpy(nxt.get("reward").reshape(self.num_envs))
        terminated = _numpy(nxt.get("terminated").reshape(self.num_envs), bool)
        truncated = _numpy(nxt.get("truncated").reshape(self.num_envs), bool)
        done = terminated | truncated
        root = nxt.exclude("reward")
        if done.any():
            mask = torch.as_tensor(done, device=self.env.device).reshape(self.num_envs, 1)
            root = self.env.reset(root.set("_reset", mask))  # partial: the other worlds keep their state
            info["final_obs"] = np.where(done[:, None], obs, 0.0).astype(np.float32)
            info["_final_obs"] = done
            info["final_info"] = {"success": info["success"].copy(), "_success": done}
            obs = _numpy(root.get("observation"))
        self._td = root
        return obs, reward, terminated, truncated, info

    def close_extras(self, **kwargs) -> None:
        self._td = None


class DexGymEnv(gym.Env):
    """One world of ``task`` as a ``gymnasium.Env`` (no autoreset: call ``reset`` after an episode ends,
    as gymnasium's single-env API requires)."""

    metadata = {"render_modes": []}

    def __init__(self, task: str = "screw_claw", device: str = "cpu", seed: int | None = None,
                 render_mode: str | None = None, **overrides: Any):
        from .registry import make_env

        if render_mode is not None:
            raise ValueError(f"render_mode {render_mode!r} is not supported (record with dexmots-record instead)")
        self.env = make_env(task, num_envs=1, device=device, differentiable=False, seed=seed, **overrides)
        self.task, self.render_mode = task, None
        self.observation_space, self.action_space = _spaces(self.env)
        self._td = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self.env.set_seed(int(seed), static_seed=True)
        self._td = self.env.reset()
        return _numpy(self._td.get("observation")[0]), {"success": bool(self._td.get("success").item())}

    def step(self, action):
        if self._td is None:
            raise RuntimeError("call reset() before step()")
        a = torch.as_tensor(_action_array(action, self.action_space), device=self.env.device).reshape(1, -1)
        out = self.env.step(self._td.clone().set("action", a.to(self.env.base_env.dtype)))
        nxt = out.get("next")
        self._td = nxt.exclude("reward")
        return (_numpy(nxt.get("observation")[0]), float(nxt.get("reward").item()), bool(nxt.get("terminated").item()),
                bool(nxt.get("truncated").item()), {"success": bool(nxt.get("success").item())})


def register_gym_envs() -> list[str]:
    """Register ``dexmots/<Task>-v0`` (single and vector entry points) for every registered task."""
    from .registry import list_tasks

    return register_gym_ids(list_tasks())


register_gym_envs()
