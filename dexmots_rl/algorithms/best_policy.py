"""Keep the best policy seen in training, and roll back to it after a collapse.

SHAC/AHAC on screw_claw occasionally learns and then loses the task (a run's training success peaked at
~0.7 and fell to ~0.3 over 40 iterations before recovering; docs/devnotes.md, training). DiffRL's SHAC
keeps the policy with the best training return for the same reason. Here the score is the mean
training-episode success over the last ``window`` iterations that finished episodes, judged only on
training data (never on evaluation episodes, so the final evaluation stays an unseen measurement).

Example:
    >>> import torch
    >>> net = torch.nn.Linear(2, 1)
    >>> opt = torch.optim.Adam(net.parameters())
    >>> keeper = BestPolicy({"actor": net}, {"actor": opt}, window=2, rollback_drop=0.3)
    >>> for success in (0.2, 0.8, 0.9):
    ...     _ = keeper.observe(success)
    >>> best_weight = net.weight.detach().clone()
    >>> with torch.no_grad():
    ...     _ = net.weight.add_(1.0)   # training moves on ...
    >>> keeper.observe(0.3), keeper.observe(0.2)   # ... and collapses: rolled back on the second
    (False, True)
    >>> torch.equal(net.weight, best_weight), keeper.rollbacks
    (True, 1)
"""

from __future__ import annotations

import copy
import math
from collections import deque

__all__ = ["BestPolicy"]


class BestPolicy:
    """Snapshots of ``modules`` and ``optimizers`` (name -> object with ``state_dict``) at the best score.

    Args:
        window: iterations (with finished episodes) in the moving mean of training success.
        rollback_drop: restore the best snapshot when the mean falls this far below the best (``None``:
            never roll back while training; :meth:`restore` is still available at the end).
    """

    def __init__(self, modules: dict, optimizers: dict, window: int = 10, rollback_drop: float | None = 0.3):
        if window < 1:
            raise ValueError(f"window must be >= 1, got {window!r}")
        self.modules, self.optimizers = modules, optimizers
        self.window, self.rollback_drop = int(window), rollback_drop
        self.recent: deque[float] = deque(maxlen=self.window)
        self.best_score = -math.inf
        self.best_iteration: int | None = None
        self.rollbacks = 0
        self._snapshot = None
        self._seen = 0

    @property
    def score(self) -> float:
        """The mean of the current window (NaN until it is full)."""
        return sum(self.recent) / len(self.recent) if len(self.recent) == self.window else float("nan")

    def observe(self, success: float) -> bool:
        """Add one iteration's training success (NaN: no episode finished, ignored); snapshot on a new
        best; returns whether the best was restored."""
        self._seen += 1
        if not math.isfinite(success):
            return False
        self.recent.append(float(success))
        score = self.score
        if not math.isfinite(score):
            return False
        if score > self.best_score:
            self.best_score, self.best_iteration = score, self._seen
            self._snapshot = self._state()
        elif self.rollback_drop is not None and score < self.best_score - self.rollback_drop:
            self.restore()
            self.rollbacks += 1
            return True
        return False

    def restore(self) -> None:
        """Load the best snapshot into the modules and optimisers (nothing to do before the first)."""
        if self._snapshot is None:
            return
        for group, objects in (("modules", self.modules), ("optimizers", self.optimizers)):
            for name, obj in objects.items():
                obj.load_state_dict(copy.deepcopy(self._snapshot[group][name]))
        self.recent.clear()  # the window restarts from the restored policy

    def _state(self) -> dict:
        return {group: {name: copy.deepcopy(obj.state_dict()) for name, obj in objects.items()}
                for group, objects in (("modules", self.modules), ("optimizers", self.optimizers))}

    def state_dict(self) -> dict:
        return {"recent": list(self.recent), "best_score": self.best_score, "best_iteration": self.best_iteration,
                "rollbacks": self.rollbacks, "seen": self._seen, "snapshot": self._snapshot}

    def load_state_dict(self, state: dict) -> None:
        self.recent = deque(state["recent"], maxlen=self.window)
        self.best_score, self.best_iteration = state["best_score"], state["best_iteration"]
        self.rollbacks, self._seen, self._snapshot = state["rollbacks"], state["seen"], state["snapshot"]
