"""Entry points: ``dexmots-rollout`` (:mod:`.rollout`, the main job) and ``dexmots-bench`` (:mod:`.bench`).

Submodules are imported on use, so importing this package does not load the simulator.
"""

from __future__ import annotations

__all__ = ["bench", "rollout"]
