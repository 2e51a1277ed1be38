"""Action spaces: map a policy action in [-1, 1] to the simulator's joint-space drive.

* ``"torque"``: ``tau = a * gear`` (the MJCF motor gear per joint).
* ``"position"``: PD targets spanning the joint range, ``q* = lower + (a + 1) / 2 * (upper - lower)``,
  stiffness ``kp = stiffness_frequency^2 * I0`` per joint (``I0``: joint-space inertia at q = 0) and
  critical damping ``kd = 2 sqrt(kp * I0)``; the simulator integrates both terms implicitly.

Actions are clamped to [-1, 1]; non-finite actions are rejected (see :func:`validate_action`).
"""

from __future__ import annotations

import math

import torch

from ..sim import Control, Simulator

__all__ = ["ACTION_TYPES", "ActionMap", "validate_action"]

ACTION_TYPES = ("torque", "position")


def validate_action(action: torch.Tensor, num_envs: int, action_dim: int) -> None:
    """Raise ``ValueError`` naming the ``action`` field when its shape, dtype or values are wrong."""
    if not isinstance(action, torch.Tensor):
        raise ValueError(f"action must be a torch.Tensor, got {type(action).__name__}")
    if not action.is_floating_point():
        raise ValueError(f"action must be a floating-point tensor, got dtype {action.dtype}")
    if tuple(action.shape) != (num_envs, action_dim):
        raise ValueError(f"action has shape {tuple(action.shape)}, expected ({num_envs}, {action_dim})")
    if not bool(torch.isfinite(action).all()):
        bad = (~torch.isfinite(action)).any(-1).nonzero().flatten().tolist()
        raise ValueError(f"action contains NaN or inf (worlds {bad[:8]}); non-finite actions are rejected")


class ActionMap:
    """Turns clamped policy actions into a :class:`~dexmots_rl.sim.Control` (differentiably)."""

    def __init__(self, sim: Simulator, kind: str = "torque", stiffness_frequency: float = 20.0):
        if kind not in ACTION_TYPES:
            raise ValueError(f"action type {kind!r} is unknown; known: {', '.join(ACTION_TYPES)}")
        self.kind, self.num_worlds = kind, sim.num_worlds
        scene = sim.scene

        def t(x):
            return torch.as_tensor(x, dtype=sim.dtype, device=sim.torch_device)

        self.gear = t(scene.actuator_gear)
        finite = scene.dof_limited
        self.lower = t(scene.dof_lower * finite - math.pi * (1 - finite))
        self.upper = t(scene.dof_upper * finite + math.pi * (1 - finite))
        inertia0 = t(scene.dof_inertia0)
        self.kp = stiffness_frequency**2 * inertia0
        self.kd = 2.0 * torch.sqrt(self.kp * inertia0)
        self._zeros = torch.zeros(sim.num_worlds, sim.nu, dtype=sim.dtype, device=sim.torch_device)

    def __call__(self, action: torch.Tensor) -> Control:
        a = action.clamp(-1.0, 1.0)
        z = self._zeros[: a.shape[0]]
        if self.kind == "torque":
            return Control(tau=a * self.gear, q_target=z, kp=z, kd=z)
        target = self.lower + 0.5 * (a + 1.0) * (self.upper - self.lower)
        return Control(tau=z, q_target=target, kp=self.kp.expand_as(a), kd=self.kd.expand_as(a))
