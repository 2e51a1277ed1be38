"""Policy-learning objectives: SHAC (torchrl ``LossModule``) and the AHAC adaptive horizon.

PPO / SAC baselines use torchrl's own losses (``torchrl.objectives``) directly.
"""

from __future__ import annotations

from .ahac import AdaptiveHorizon
from .shac import SHACLoss, next_rollout_start

__all__ = ["AdaptiveHorizon", "SHACLoss", "next_rollout_start"]
