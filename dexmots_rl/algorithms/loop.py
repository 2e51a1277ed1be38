"""The end of every training iteration and of every run, one for all the learning methods (SHAC, AHAC, PPO,
SAC, PGDM), so that each method's ``_train`` holds the method alone.

A trainer builds its env, networks and optimisers, then::

    with TrainingLoop(run, env, iterations, modules, optimizers, policy) as loop:
        worlds = loop.start(env.reset())       # a resumed run: the checkpoint's state, worlds and RNG streams
        while not loop.done:
            ...                                # the method: collect, learn, count iteration and env_steps
            loop.end_iteration(stats, worlds)  # the row, budget, rollback, checkpoint, evaluation
        return loop.finish()                   # the final evaluation (metrics.json)

:meth:`TrainingLoop.end_iteration` reads the training clock (:class:`~.budget.TrainingClock`), logs the
``metrics.jsonl`` row (the counters, then the method's statistics), moves the progress bar, checks the budget
(:class:`~.budget.RunBudget`), lets :class:`~.best_policy.BestPolicy` keep or restore the best policy, writes
a checkpoint every ``checkpoint_every`` iterations, at ``stop_after``, at the end and before each periodic
evaluation, runs that evaluation (not training time), and stops the run at its schedule's end, its budget,
``stop_after`` or a SIGINT / SIGTERM (:class:`StopOnSignal`: the iteration finishes and is checkpointed).
A checkpoint holds what a resume needs to go on exactly as the uninterrupted run (CPU): ``modules``,
``optimizers``, counters, the worlds mid-episode, both RNG streams (:func:`~.checkpoint.rng_states`) and the
keeper's snapshots. The collector methods' :class:`~.common.CollectorLoop` adds their batches' timing, the
normaliser the deployable policy carries and SAC's replay buffer.

In a data-parallel run (:class:`~.distributed.Distributed`) every rank runs the loop; the main rank's clock
decides the budget and every rank stops with it and with a signal any rank got; only the main rank writes.
"""

from __future__ import annotations

import logging
import signal
import sys
import threading

import torch
from tensordict import TensorDict

from ..progress import progress_bar
from .best_policy import BestPolicy
from .budget import RunBudget, TrainingClock
from .checkpoint import restore_rng_states, rng_states
from .distributed import Distributed
from .rundir import RunDirectory

__all__ = ["StopOnSignal", "TrainingLoop", "load_kernels"]

log = logging.getLogger(__name__)


def load_kernels(env) -> None:
    """Compile, or load from warp's cache, the kernels that step ``env`` (its ``load_kernels``), so that a run's
    training clock and its ``budget`` do not count the compile. Warp builds a module at its first launch: with a
    cold cache the suite's first repose_cube runs spent ~65 of their 300 s of training CPU in the first iteration
    (19 s on a warm cache). An env without kernels is left alone."""
    load = getattr(getattr(env, "base_env", env), "load_kernels", None)
    if load is not None:
        load()


class StopOnSignal:
    """SIGINT/SIGTERM while training: finish the iteration, checkpoint, return (no traceback); a second
    signal interrupts at once. Only the main thread can install handlers; elsewhere this is a no-op."""

    def __init__(self):
        self.signal, self._old = None, {}

    def _handle(self, signum, frame):
        if self.signal is not None:
            raise KeyboardInterrupt
        self.signal = signal.Signals(signum).name
        log.warning("%s: stopping after this iteration with a checkpoint (again to abort)", self.signal)

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._old[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc):
        for sig, handler in self._old.items():
            signal.signal(sig, handler)
        self._old = {}


class TrainingLoop:
    """The loop of a run in ``run`` (:class:`~.rundir.RunDirectory`) of ``iterations`` iterations on ``env``.

    ``modules`` / ``optimizers`` (name -> object with a ``state_dict``): what a checkpoint saves and a resume
    loads; ``policy``: what the evaluations run on the plain task env; ``counters``: the method's own counters
    and their starting values (besides ``iteration``, ``env_steps`` and the training clock's seconds); ``best``:
    the keeper of the best policy (None: none); ``dist``: the data-parallel group (None: one process).
    :attr:`counters` continue a resumed run's; the method counts ``iteration`` and ``env_steps`` itself.
    """

    def __init__(self, run: RunDirectory, env, iterations: int, modules: dict, optimizers: dict, policy, *,
                 counters: dict | None = None, best: BestPolicy | None = None, dist: Distributed | None = None):
        self.run, self.cfg, self.env, self.iterations = run, run.cfg, env, iterations
        self.modules, self.optimizers, self.policy, self.best = modules, optimizers, policy, best
        self.dist = dist or Distributed()
        self.counters = {"iteration": 0, "env_steps": 0, "wall_clock_s": 0.0, "cpu_s": 0.0, **(counters or {})}
        if run.start is not None:
            self.counters.update(run.start["counters"])
        self.stop_at = min(iterations, self.cfg.stop_after) if self.cfg.stop_after else iterations
        self.budget, self.stopped_by, self.ended = RunBudget.from_config(self.cfg), None, False
        self.done = self.counters["iteration"] >= self.stop_at
        self.worlds = None  # the worlds' TensorDict where training stands (checkpointed)
        self.bar = progress_bar(total=iterations, initial=self.counters["iteration"],
                                disable=not (self.cfg.progress and self.dist.is_main),
                                desc=f"{self.cfg.algo.name} {self.cfg.task.name}", file=sys.stderr)
        load_kernels(env)  # before the clock starts: a cold cache's compile is not training time
        self.clock = TrainingClock(self.counters)
        self.signals = StopOnSignal()

    def __enter__(self) -> "TrainingLoop":
        self.signals.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        self.bar.close()
        self.signals.__exit__(*exc)

    @property
    def interrupted(self) -> str | None:
        """The signal that stopped the run (``"SIGINT"``, ``"SIGTERM"``), else None."""
        return self.signals.signal

    # ------------------------------------------------------------------------------------------ start
    def start(self, worlds: TensorDict | None) -> TensorDict | None:
        """The worlds to train from: ``worlds`` (the env just reset; None: there is nothing left to run) in a
        fresh run. A resumed run first takes the checkpoint's state of the modules, optimisers and keeper, and
        goes on from the checkpoint's worlds (mid-episode) with both RNG streams where they stood, exactly as
        the uninterrupted run."""
        start = self.run.start
        if start is not None:
            for name, module in self.modules.items():
                module.load_state_dict(start["modules"][name])
            for name, optimizer in self.optimizers.items():
                optimizer.load_state_dict(start["optimizers"][name])
            if self.best is not None and start.get("best") is not None:
                self.best.load_state_dict(start["best"])
            if worlds is not None:
                worlds = self._resumed_worlds(start, worlds)
        self.worlds = worlds
        return worlds

    def _resumed_worlds(self, start: dict, worlds: TensorDict) -> TensorDict:
        if "env_state" not in start:  # an older checkpoint: the same networks, but the episodes start afresh
            log.warning("resume=%s: the checkpoint predates saved episodes; they start afresh, so the run will "
                        "not be the uninterrupted one", self.cfg.resume)
            torch.set_rng_state(start["rng"]["torch"])
            return worlds
        resumed = TensorDict.from_dict(start["env_state"], batch_size=worlds.batch_size, device=worlds.device)
        restore_rng_states(self.env, start["rng"])
        return resumed

    def progress(self) -> float:
        """How far the run is to its end in [0, 1] (its schedule or its budget): linear decays follow it."""
        return self.budget.progress(self.counters, self.counters["iteration"] / self.iterations)

    # ------------------------------------------------------------------------------ end of an iteration
    def end_iteration(self, stats: dict, worlds: TensorDict | None = None) -> bool:
        """Log the iteration just counted with the method's ``stats`` (its ``episode_success`` feeds the
        keeper), checkpoint and evaluate when due; ``worlds``: where training now stands (None: unchanged).
        Sets and returns :attr:`done`: True when the run stops here."""
        dist, counters = self.dist, self.counters
        # every rank sees a signal one rank got, so all stop at the same iteration
        interrupted = bool(dist.sum(torch.tensor([float(self.interrupted is not None)])) > 0)
        if worlds is not None:
            self.worlds = worlds
        self.clock.read(counters)
        # the main rank's clock decides (the others' include its evaluations) and every rank stops with it
        over = self.budget.reached(counters) if dist.is_main else None
        if dist.sum(torch.tensor([float(over is not None)])) > 0:
            self.stopped_by = over or "wall_clock_s"
        row = {"iteration": counters["iteration"], "env_steps": counters["env_steps"],
               "wall_clock_s": round(counters["wall_clock_s"], 3), "cpu_s": round(counters.get("cpu_s", 0.0), 3),
               **stats, **self._timing()}
        if self.best is not None:  # every rank sees the same (summed) success, so all roll back together
            self.best.observe(row["episode_success"])
            row["rollbacks"] = self.best.rollbacks
        self.bar.update(1)
        self.bar.set_postfix(fps=f"{row['env_steps'] / max(row['wall_clock_s'], 1e-9):.0f}",
                             reward=f"{row['reward']:.3f}", success=f"{row['episode_success']:.2f}")
        self.ended = counters["iteration"] >= self.iterations or self.stopped_by is not None
        self.done = self.ended or interrupted or counters["iteration"] >= self.stop_at
        if not dist.is_main:
            return self.done
        self.run.log(row)
        evaluate_now = bool(self.cfg.eval.every) and counters["iteration"] % self.cfg.eval.every == 0 and not self.ended
        if self.done or counters["iteration"] % self.cfg.checkpoint_every == 0 or evaluate_now:
            self.save()
            if evaluate_now:
                with self.clock.paused():  # evaluation is not training time (the budget's clock)
                    self.run.evaluate(self.policy, counters, final=False)
        return self.done

    def _timing(self) -> dict:
        """Timing columns of the row besides the clock's (a collector method's collection and learning)."""
        return {}

    def sync_policy(self) -> None:
        """Bring :attr:`policy` up to date with training before it is saved or evaluated (nothing here)."""

    def save(self) -> None:
        """``checkpoints/last.pt``: what :meth:`start` resumes from."""
        self.sync_policy()
        self.run.checkpoint(self.counters, self.modules, self.optimizers, **self._resume_state())

    def current_worlds(self) -> TensorDict | None:
        """The worlds' TensorDict where training stands (None: there are none to go on with)."""
        return self.worlds

    def _resume_state(self) -> dict:
        """What :meth:`start` needs besides the modules and optimisers: the worlds, the RNG streams, the keeper."""
        state, worlds = {}, self.current_worlds()
        if worlds is not None:
            state["env_state"] = worlds.detach().to_dict()
            state["rng"] = rng_states(self.env)
        if self.best is not None:
            state["best"] = self.best.state_dict()
        return state

    # ------------------------------------------------------------------------------------------- finish
    def finish(self, **extra) -> dict:
        """The run's result: after its schedule or budget, the final evaluation's ``metrics.json`` (with
        ``extra`` entries and which policy was evaluated, ``final_policy``); ``{}`` when ``stop_after``
        stopped it first (``resume=<run_dir>`` continues it); ``{"interrupted": "SIGINT", ...}`` after a
        signal (a checkpoint was saved)."""
        self.bar.close()
        counters, result = self.counters, {}
        if self.interrupted is not None:
            result = {"interrupted": self.interrupted, "iteration": counters["iteration"], "run_dir": str(self.run.dir)}
        elif self.dist.is_main and (self.ended or counters["iteration"] >= self.iterations):
            final_policy = self._final_policy()
            if final_policy["source"] == "best":  # the checkpoint holds the policy that is evaluated
                self.save()
            self.sync_policy()
            result = self.run.evaluate(self.policy, counters, budget=self.budget.record(self.stopped_by),
                                       **extra, final_policy=final_policy)
        self.dist.close()
        return result

    def _final_policy(self) -> dict:
        """Which policy the final evaluation gets. With rollbacks on, the last one (a collapse was already
        rolled back while training); with ``rollback_drop: null``, the best one when its training success
        beats the last window's."""
        best = self.best
        if best is None:
            return {"source": "last"}
        record = {"best_train_success": best.best_score if best.best_iteration is not None else None,
                  "best_iteration": best.best_iteration, "rollbacks": best.rollbacks, "source": "last"}
        if best.rollback_drop is None and best.best_iteration is not None and not best.score >= best.best_score:
            best.restore()
            record["source"] = "best"
        return record
