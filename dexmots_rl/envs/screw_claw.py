"""screw_claw: the 2-finger Claw turns an octagonal screw-top knob by a goal angle (DexMOTS "Screw").

Per episode: the goal angle is drawn with magnitude in [pi/4, pi/2] and a random direction; the knob's
joint damping and Coulomb friction are drawn from ``damping_range`` / ``friction_range`` (the paper's
"object joint friction is unknown and randomized per episode"). The hand starts open (proximal joints
spread by ``open_angle``) with a little joint noise. Success: ``|theta - theta_goal| < success_threshold``
(0.1 rad); evaluation reads it at the last step of the episode.

Example:
    >>> from dexmots_rl.envs import make_env
    >>> env = make_env("screw_claw", num_envs=2, seed=0)
    >>> td = env.rollout(3)
    >>> td["next", "reward"].shape
    torch.Size([2, 3, 1])
"""

from __future__ import annotations

import math

import torch

from ..assets import asset_path
from ..sim import load_scene
from .base import DexEnv
from .rewards import angle_tracking_reward

__all__ = ["ScrewClawEnv"]


class ScrewClawEnv(DexEnv):
    """Claw + knob on a vertical hinge; see the module docstring."""

    asset = "claw_screw.xml"

    def __init__(
        self,
        num_envs: int = 1,
        device="cpu",
        differentiable: bool = True,
        action: str = "torque",
        max_episode_steps: int = 100,
        seed: int | None = None,
        goal_range: tuple[float, float] = (math.pi / 4, math.pi / 2),
        damping_range: tuple[float, float] = (0.3, 0.7),
        friction_range: tuple[float, float] = (0.2, 1.0),
        open_angle: float = math.radians(60.0),
        joint_noise: float = 0.05,
        success_threshold: float = 0.1,
        **kwargs,
    ):
        for name, (lo, hi) in (("goal_range", goal_range), ("damping_range", damping_range),
                               ("friction_range", friction_range)):
            if not 0 <= lo <= hi:
                raise ValueError(f"{name} must satisfy 0 <= low <= high, got {(lo, hi)}")
        self.goal_range, self.damping_range, self.friction_range = goal_range, damping_range, friction_range
        self.open_angle, self.joint_noise, self.success_threshold = open_angle, joint_noise, success_threshold
        super().__init__(load_scene(asset_path(self.asset)), num_envs, device=device, differentiable=differentiable,
                         action=action, max_episode_steps=max_episode_steps, seed=seed, **kwargs)
        # joint order in the MJCF: right proximal, right distal, left proximal, left distal
        self._open_pose = torch.tensor([open_angle, 0.0, -open_angle, 0.0], dtype=self.dtype, device=self.device)
        scene = self.sim.scene
        self._lower = torch.as_tensor(scene.dof_lower, dtype=self.dtype, device=self.device)
        self._upper = torch.as_tensor(scene.dof_upper, dtype=self.dtype, device=self.device)

    def _uniform(self, n: int, lo_hi: tuple[float, float]) -> torch.Tensor:
        lo, hi = lo_hi
        return lo + (hi - lo) * self._rand(n, 1)

    def sample_initial(self, n: int) -> dict:
        noise = self.joint_noise * (2 * self._rand(n, self.sim.nu) - 1)
        hand = torch.minimum(torch.maximum(self._open_pose + noise, self._lower), self._upper)
        q = torch.cat([hand, torch.zeros(n, 1, dtype=self.dtype, device=self.device)], -1)
        sign = torch.where(self._rand(n, 1) < 0.5, -1.0, 1.0).to(self.dtype)
        return {
            "joint_q": q,
            "joint_qd": torch.zeros(n, self.sim.nv, dtype=self.dtype, device=self.device),
            "params": torch.cat([self._uniform(n, self.damping_range), self._uniform(n, self.friction_range)], -1),
            "goal": sign * self._uniform(n, self.goal_range),
        }

    def achieved_goal(self, obs: dict) -> torch.Tensor:
        return obs[("object", "q")]

    def task_reward(self, obs: dict, goal: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return angle_tracking_reward(obs[("object", "q")], goal)

    def task_success(self, obs: dict, goal: torch.Tensor) -> torch.Tensor:
        return (obs[("object", "q")] - goal).abs() < self.success_threshold
