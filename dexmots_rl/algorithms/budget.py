"""A training budget every trainer honours the same way, so methods can be compared at equal cost
(``dexmots-table``): ``budget.wall_clock_s`` (training time) and ``budget.env_steps`` in the run config.

Each trainer still has its own schedule (``algo.iterations``, ``algo.total_frames``); the run stops at
whichever comes first: the schedule's end or the budget. A budget stop is a normal end: checkpoint, final
evaluation, ``metrics.json`` (whose ``budget`` entry records the limits and ``stopped_by``). Training time
leaves out the periodic evaluations (the trainers pause the clock around them), so a method evaluated
more often does not lose training time; the learning-rate schedules still follow the schedule, not the
budget.

Example:
    >>> budget = RunBudget(wall_clock_s=60.0, env_steps=None)
    >>> budget.reached({"wall_clock_s": 12.0, "env_steps": 5000}) is None
    True
    >>> budget.reached({"wall_clock_s": 61.0, "env_steps": 9000})
    'wall_clock_s'
    >>> budget.record("wall_clock_s")
    {'wall_clock_s': 60.0, 'env_steps': None, 'stopped_by': 'wall_clock_s'}
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["RunBudget"]


@dataclass(frozen=True)
class RunBudget:
    """Limits on a run's training: seconds of training wall-clock and env steps (``None``: no limit)."""

    wall_clock_s: float | None = None
    env_steps: int | None = None

    @classmethod
    def from_config(cls, cfg) -> "RunBudget":
        """The ``budget`` section of a run config (absent or null fields: no limit)."""
        section = cfg.get("budget") or {}
        wall, steps = section.get("wall_clock_s"), section.get("env_steps")
        return cls(None if wall is None else float(wall), None if steps is None else int(steps))

    def reached(self, counters: dict) -> str | None:
        """The name of the first limit ``counters`` (``wall_clock_s``, ``env_steps``) reached, else ``None``."""
        if self.wall_clock_s is not None and counters["wall_clock_s"] >= self.wall_clock_s:
            return "wall_clock_s"
        if self.env_steps is not None and counters["env_steps"] >= self.env_steps:
            return "env_steps"
        return None

    def record(self, stopped_by: str | None) -> dict:
        """``metrics.json``'s ``budget`` entry; ``stopped_by`` ``None`` means the schedule ended the run."""
        return {"wall_clock_s": self.wall_clock_s, "env_steps": self.env_steps,
                "stopped_by": stopped_by or "schedule"}
