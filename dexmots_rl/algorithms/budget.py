"""A training budget every trainer honours the same way, so methods can be compared at equal cost
(``dexmots-table``): ``budget.wall_clock_s`` (training time) and ``budget.env_steps`` in the run config.

Each trainer still has its own schedule (``algo.iterations``, ``algo.total_frames``); the run stops at
whichever comes first: the schedule's end or the budget. A budget stop is a normal end: checkpoint, final
evaluation, ``metrics.json`` (whose ``budget`` entry records the limits and ``stopped_by``). Training time
leaves out the periodic evaluations (the trainers pause the clock around them), so a method evaluated
more often does not lose training time. Linear learning-rate decays follow whichever end comes first
(:meth:`RunBudget.progress`): a run cut by its budget has annealed, as it would have at its schedule's end.

Example:
    >>> budget = RunBudget(wall_clock_s=60.0, env_steps=None)
    >>> budget.reached({"wall_clock_s": 12.0, "env_steps": 5000}) is None
    True
    >>> budget.reached({"wall_clock_s": 61.0, "env_steps": 9000})
    'wall_clock_s'
    >>> budget.progress({"wall_clock_s": 30.0, "env_steps": 5000}, schedule=0.1)
    0.5
    >>> budget.record("wall_clock_s")
    {'wall_clock_s': 60.0, 'env_steps': None, 'stopped_by': 'wall_clock_s'}
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["NO_TRAINING", "RunBudget"]

#: ``metrics.json``'s ``budget.stopped_by`` of a method that trains nothing (MPC): no budget applies
NO_TRAINING = "no_training"


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

    def progress(self, counters: dict, schedule: float) -> float:
        """How far the run is to its end, in [0, 1]: the largest of ``schedule`` (the fraction of the
        trainer's own schedule done) and the fraction of each limit used."""
        done = [schedule]
        if self.wall_clock_s is not None:
            done.append(counters["wall_clock_s"] / self.wall_clock_s)
        if self.env_steps is not None:
            done.append(counters["env_steps"] / self.env_steps)
        return min(1.0, max(0.0, *done))

    def record(self, stopped_by: str | None) -> dict:
        """``metrics.json``'s ``budget`` entry; ``stopped_by`` ``None`` means the schedule ended the run."""
        return {"wall_clock_s": self.wall_clock_s, "env_steps": self.env_steps,
                "stopped_by": stopped_by or "schedule"}
