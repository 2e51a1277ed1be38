"""The console scripts, thin: ``dexmots-train`` (:mod:`.train`), ``dexmots-eval``, ``dexmots-bench``,
``dexmots-plan``, ``dexmots-record``, ``dexmots-plot``, ``dexmots-rollout``; the logic lives in the
library packages they call. Submodules are imported on use."""

from __future__ import annotations

__all__ = ["bench", "eval", "plan", "plot", "record", "rollout", "train"]
