"""Pure-torch differentiable toy environments for the objective tests (no warp, no compilation).

:class:`PointMassEnv` is a batched 2-D double integrator that must reach a per-world goal. Everything is a
torch function of the incoming TensorDict, so ``env.rollout(...)`` outside ``no_grad`` chains gradients
from every reward back to every earlier action, exactly like the warp envs do with ``differentiable=True``.
It has the keys the objectives rely on: ``("next", "reward")``, ``done`` / ``terminated`` / ``truncated``
(step-counter truncation at ``max_episode_steps``, termination when the mass leaves the arena), partial
resets through the ``"_reset"`` mask, and a soft circular wall whose penalty force is reported under
``("object", "contact_force")`` (shape ``[N, 1]``, like the DexMOTS envs) for the AHAC tests.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

__all__ = ["PointMassEnv"]


class PointMassEnv(EnvBase):
    """Point masses ``x'' = force_scale * a - damping * x'`` (semi-implicit Euler) chasing goals.

    Observation ``"observation"`` = ``[pos - goal, vel]`` (4 numbers). Reward
    ``-|pos' - goal|^2 - action_cost * |a|^2``. A wall at radius ``wall_radius`` pushes back with
    ``wall_stiffness * penetration``; a world is terminated when ``|pos| > terminate_radius``.
    """

    batch_locked = True

    def __init__(
        self,
        num_envs: int = 8,
        max_episode_steps: int = 50,
        dt: float = 0.1,
        force_scale: float = 1.0,
        damping: float = 0.5,
        action_cost: float = 0.01,
        wall_radius: float = 2.0,
        wall_stiffness: float = 100.0,
        terminate_radius: float = 3.0,
        init_range: float = 1.0,
        seed: int = 0,
        dtype: torch.dtype = torch.float32,
    ):
        super().__init__(device="cpu", batch_size=torch.Size([num_envs]))
        self.num_envs, self.max_episode_steps, self.dt = num_envs, max_episode_steps, dt
        self.force_scale, self.damping, self.action_cost = force_scale, damping, action_cost
        self.wall_radius, self.wall_stiffness = wall_radius, wall_stiffness
        self.terminate_radius, self.init_range, self.dtype = terminate_radius, init_range, dtype
        n = num_envs
        self.observation_spec = Composite(
            observation=Unbounded((n, 4), dtype=dtype),
            pos=Unbounded((n, 2), dtype=dtype),
            vel=Unbounded((n, 2), dtype=dtype),
            goal=Unbounded((n, 2), dtype=dtype),
            step_count=Unbounded((n, 1), dtype=torch.int64),
            object=Composite(contact_force=Unbounded((n, 1), dtype=dtype), shape=(n,)),
            shape=(n,),
        )
        self.action_spec = Bounded(-1.0, 1.0, shape=(n, 2), dtype=dtype)
        self.reward_spec = Unbounded(shape=(n, 1), dtype=dtype)
        self.full_done_spec = Composite(
            done=Categorical(2, shape=(n, 1), dtype=torch.bool),
            terminated=Categorical(2, shape=(n, 1), dtype=torch.bool),
            truncated=Categorical(2, shape=(n, 1), dtype=torch.bool),
            shape=(n,),
        )
        self.generator = torch.Generator()
        self._set_seed(seed)

    def _set_seed(self, seed: int | None):
        self.generator.manual_seed(0 if seed is None else int(seed))

    def _uniform(self, *shape) -> torch.Tensor:
        u = torch.rand(*shape, generator=self.generator, dtype=self.dtype)
        return (2.0 * u - 1.0) * self.init_range

    @staticmethod
    def _obs(pos, vel, goal) -> torch.Tensor:
        return torch.cat([pos - goal, vel], -1)

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        n = self.num_envs
        pos, goal = self._uniform(n, 2), self._uniform(n, 2)
        vel = torch.zeros(n, 2, dtype=self.dtype)
        step = torch.zeros(n, 1, dtype=torch.int64)
        contact = torch.zeros(n, 1, dtype=self.dtype)
        # Partial resets: torchrl's rollout hands _reset only the "_reset" mask and merges the fresh worlds
        # into the running TensorDict itself (TensorDict.where), so fresh values for every world suffice.
        false = torch.zeros(n, 1, dtype=torch.bool)
        return self._state(pos, vel, goal, step, contact, done=false, terminated=false.clone(), truncated=false.clone())

    def _state(self, pos, vel, goal, step, contact, **extra) -> TensorDict:
        entries = {"observation": self._obs(pos, vel, goal), "pos": pos, "vel": vel, "goal": goal,
                   "step_count": step, ("object", "contact_force"): contact, **extra}
        return TensorDict(entries, batch_size=[pos.shape[0]])

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        pos, vel, goal = tensordict.get("pos"), tensordict.get("vel"), tensordict.get("goal")
        action = tensordict.get("action").clamp(-1.0, 1.0)
        radius = pos.norm(dim=-1, keepdim=True).clamp_min(1e-9)
        penetration = (radius - self.wall_radius).clamp_min(0.0)
        wall_force = -self.wall_stiffness * penetration * pos / radius
        acc = self.force_scale * action - self.damping * vel + wall_force
        vel = vel + self.dt * acc
        pos = pos + self.dt * vel
        reward = -(pos - goal).pow(2).sum(-1, keepdim=True) - self.action_cost * action.pow(2).sum(-1, keepdim=True)
        step = tensordict.get("step_count") + 1
        terminated = pos.detach().norm(dim=-1, keepdim=True) > self.terminate_radius
        truncated = (step >= self.max_episode_steps) & ~terminated
        return self._state(pos, vel, goal, step, wall_force.norm(dim=-1, keepdim=True), reward=reward,
                           done=terminated | truncated, terminated=terminated, truncated=truncated)
