"""The generalised force a sprung, damped joint with Coulomb friction needs: one law for the analytic
references, the demonstrations and the joint planner's first guess."""

from __future__ import annotations

import torch

__all__ = ["FRICTION_VELOCITY", "part_torque"]

# rad/s (or m/s): the references' smoothing of Coulomb friction (the knob's and the hand's joints in the simulator;
# an object tree's joints hold exactly below their friction instead, sim/_joint_friction.py)
FRICTION_VELOCITY = 0.05


def part_torque(speed: torch.Tensor, angle: torch.Tensor, nominal) -> torch.Tensor:
    """The generalised force (N m or N) a sprung, damped joint with Coulomb friction needs to move at
    ``speed`` through ``angle``: ``d ω + f tanh(ω / 0.05) + k (θ - θ_rest)``; ``nominal`` is ``(damping,
    friction, stiffness, rest)`` (the analytic references' law: inertia neglected, quasi-static)."""
    damping, friction, stiffness, rest = nominal
    return damping * speed + friction * torch.tanh(speed / FRICTION_VELOCITY) + stiffness * (angle - rest)
