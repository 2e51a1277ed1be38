"""Rewards as plain torch functions of observation tensors (differentiable, testable alone).

The paper's full reward model (Eq. 1-3: pose, wrench, action and fingertip terms) builds on these.
"""

from __future__ import annotations

import torch

__all__ = ["angle_tracking_reward"]


def angle_tracking_reward(angle: torch.Tensor, goal: torch.Tensor, scale: float = 1.0) -> torch.Tensor:
    """``exp(-|angle - goal| / scale)`` per world: 1 on the goal, decaying with the angle error (rad).

    Example:
        >>> import torch
        >>> angle_tracking_reward(torch.tensor([[0.0]]), torch.tensor([[0.0]]))
        tensor([[1.]])
    """
    return torch.exp(-(angle - goal).abs() / scale)
