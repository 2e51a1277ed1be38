"""Policy-learning objectives: SHAC (torchrl ``LossModule``), the AHAC adaptive horizon and a policy-smoothness
regulariser (CAPS, ``LossModule``).

PPO / SAC baselines use torchrl's own losses (``torchrl.objectives``) directly.
"""

from __future__ import annotations

from .ahac import AdaptiveHorizon
from .shac import SHACLoss, next_rollout_start
from .smoothness import PolicySmoothnessLoss

__all__ = ["AdaptiveHorizon", "PolicySmoothnessLoss", "SHACLoss", "next_rollout_start"]
