"""A training budget every trainer honours the same way, so methods can be compared at equal cost
(``dexmots-table``): ``budget.wall_clock_s`` (training wall-clock), ``budget.cpu_s`` (training CPU time of
the run's process) and ``budget.env_steps`` in the run config.

Each trainer still has its own schedule (``algo.iterations``, ``algo.total_frames``); the run stops at
whichever comes first: the schedule's end or the budget. A budget stop is a normal end: checkpoint, final
evaluation, ``metrics.json`` (whose ``budget`` entry records the limits and ``stopped_by``). Training time
leaves out the periodic evaluations (the trainers pause :class:`TrainingClock` around them), so a method
evaluated more often does not lose training time.

Why a CPU-time budget: on a machine others share (a laptop, an oversubscribed cluster node), wall-clock
budgets give a run less compute whenever something else runs, so runs of one sweep would not be comparable.
``cpu_s`` counts the user + system time of the run's process (all its threads), which another process's load
does not take away; with one torch and one simulator thread a run gets ``cpu_s`` seconds of one core. Linear learning-rate decays follow whichever end comes first
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
    {'wall_clock_s': 60.0, 'env_steps': None, 'cpu_s': None, 'stopped_by': 'wall_clock_s'}
    >>> RunBudget(cpu_s=30.0).reached({"wall_clock_s": 90.0, "cpu_s": 31.0, "env_steps": 0})
    'cpu_s'
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass

__all__ = ["NO_TRAINING", "RunBudget", "TrainingClock"]

#: ``metrics.json``'s ``budget.stopped_by`` of a method that trains nothing (MPC): no budget applies
NO_TRAINING = "no_training"


@dataclass(frozen=True)
class RunBudget:
    """Limits on a run's training: seconds of training wall-clock, env steps and seconds of the process's
    training CPU time (``None``: no limit)."""

    wall_clock_s: float | None = None
    env_steps: int | None = None
    cpu_s: float | None = None

    @classmethod
    def from_config(cls, cfg) -> "RunBudget":
        """The ``budget`` section of a run config (absent or null fields: no limit)."""
        section = cfg.get("budget") or {}
        wall, steps, cpu = section.get("wall_clock_s"), section.get("env_steps"), section.get("cpu_s")
        return cls(None if wall is None else float(wall), None if steps is None else int(steps),
                   None if cpu is None else float(cpu))

    def _used(self, counters: dict):
        for name in ("wall_clock_s", "env_steps", "cpu_s"):
            limit = getattr(self, name)
            if limit is not None:
                yield name, counters.get(name, 0) / limit

    def reached(self, counters: dict) -> str | None:
        """The name of the first limit ``counters`` (``wall_clock_s``, ``env_steps``, ``cpu_s``) reached, else
        ``None``."""
        return next((name for name, used in self._used(counters) if used >= 1.0), None)

    def progress(self, counters: dict, schedule: float) -> float:
        """How far the run is to its end, in [0, 1]: the largest of ``schedule`` (the fraction of the
        trainer's own schedule done) and the fraction of each limit used."""
        done = [schedule, *(used for _, used in self._used(counters))]
        return min(1.0, max(0.0, *done))

    def record(self, stopped_by: str | None) -> dict:
        """``metrics.json``'s ``budget`` entry; ``stopped_by`` ``None`` means the schedule ended the run."""
        return {"wall_clock_s": self.wall_clock_s, "env_steps": self.env_steps, "cpu_s": self.cpu_s,
                "stopped_by": stopped_by or "schedule"}


class TrainingClock:
    """A run's training time on two clocks, wall-clock and the process's CPU time (user + system, every
    thread), written into a trainer's counters (``wall_clock_s``, ``cpu_s``); :meth:`paused` leaves a stretch
    (an evaluation) out of both. A resumed run continues from its checkpoint's counters."""

    def __init__(self, counters: dict):
        self._wall_start = time.perf_counter() - counters.get("wall_clock_s", 0.0)
        self._cpu_start = time.process_time() - counters.get("cpu_s", 0.0)

    def read(self, counters: dict) -> None:
        """Set ``counters["wall_clock_s"]`` and ``counters["cpu_s"]`` to the training time so far."""
        counters["wall_clock_s"] = time.perf_counter() - self._wall_start
        counters["cpu_s"] = time.process_time() - self._cpu_start

    @contextlib.contextmanager
    def paused(self):
        """Leave what runs inside out of the training time (evaluations are not training)."""
        wall, cpu = time.perf_counter(), time.process_time()
        try:
            yield
        finally:
            self._wall_start += time.perf_counter() - wall
            self._cpu_start += time.process_time() - cpu
