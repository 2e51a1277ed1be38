"""SHAC's critic regression, run in a background thread while the next rollout is collected.

A SHAC/AHAC iteration ends by fitting the critic to the rollout's TD(lambda) targets (many small minibatch
steps) and moving the target critic towards it. The next iteration's rollout reads only the actor and the
observation normaliser, never the critic, so that fit can run while the rollout is collected; the next actor
loss, which reads the target critic, waits for it (:meth:`CriticFit.wait`). The rollout is mostly Python and
leaves a core idle; the fit is mostly matrix work that releases the GIL. The result is the same as running the
fit inline: its minibatch shuffles come from a generator of its own, so neither thread changes the other's
random numbers (``tests/test_train.py`` checks that a resumed run repeats an uninterrupted one). With data
parallel training the fit stays inline, because its gradient all-reduces must keep their order across ranks.

Example:
    >>> import torch
    >>> fit = CriticFit(lambda data: torch.ones(2) * data, background=True)
    >>> fit.start(3.0)
    >>> fit.wait()
    tensor([3., 3.])
    >>> fit.wait() is None   # nothing started since
    True
    >>> fit.close()
"""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from typing import Callable

import torch

__all__ = ["CriticFit"]


class CriticFit:
    """Runs ``job(data)`` (the critic's fit and target update, returning its minibatch losses) inline or in
    one background thread; one job at a time.

    Args:
        job: called with the data given to :meth:`start`.
        background: run it in a thread (``False``: :meth:`start` runs it at once).
    """

    def __init__(self, job: Callable[..., torch.Tensor], background: bool):
        self._job = job
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="critic-fit") if background else None
        self._pending: Future | torch.Tensor | None = None

    def start(self, data) -> None:
        """Start the job on ``data`` (after the previous one has finished)."""
        self.wait()
        self._pending = self._job(data) if self._pool is None else self._pool.submit(self._job, data)

    def wait(self) -> torch.Tensor | None:
        """Block until the last started job is done; its result (re-raising its exception), or ``None`` when
        no job was started since the last call."""
        pending, self._pending = self._pending, None
        return pending.result() if isinstance(pending, Future) else pending

    def close(self) -> None:
        """Finish the last job and stop the thread."""
        try:
            self.wait()
        finally:
            if self._pool is not None:
                self._pool.shutdown()
