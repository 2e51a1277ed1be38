"""A training run's directory: refuse to train over another run, lock it while a trainer uses it, and on
resume cut the logs back to the checkpoint and take the checkpoint's own config.

Logs after a crash: rows of iterations past the last checkpoint were never saved in the model, so on
resume they are **truncated** (``metrics.jsonl`` and the CSV logger's ``*.csv``), and the resumed run
writes them again: every iteration appears once. (TensorBoard event files cannot be truncated; a viewer
shows the rewritten steps on top.)
"""

from __future__ import annotations

import fcntl
import logging
import os
import shutil
from pathlib import Path

from ..atomic import atomic_write, clean_stale_temps
from ..envs.config import saved_config_defaults
from ..envs.registry import list_tasks, task_entry
from .checkpoint import CheckpointError

__all__ = ["RUN_FILES", "RunDirLock", "holds_run", "prepare_fresh_run_dir", "truncate_logs", "resume_config"]

log = logging.getLogger(__name__)

#: what a run leaves in its directory (``overwrite=true`` removes exactly these)
RUN_FILES = ("checkpoints", "metrics.jsonl", "metrics.json", "config.yaml", "logs", "eval.json", "eval.mcap")
#: resume keeps the checkpoint's values of these; an override that differs is a conflict
LOCKED = ("task", "algo", "seed")
#: ... except these, which a resumed run may change (a longer schedule)
RESUME_MAY_CHANGE = ("algo.iterations",)


def holds_run(run_dir: Path) -> bool:
    return any((run_dir / name).exists() for name in ("checkpoints", "metrics.jsonl", "metrics.json"))


class RunDirLock:
    """``fcntl.flock`` on ``<run_dir>/.lock`` for as long as a trainer uses the directory; a second trainer
    fails at once (``ValueError``) instead of interleaving checkpoints and logs. Released on close or
    when the process dies (the kernel drops flocks), so a crash leaves no stale lock."""

    def __init__(self, run_dir: Path):
        run_dir.mkdir(parents=True, exist_ok=True)
        self.path = run_dir / ".lock"
        self._f = open(self.path, "a+")
        try:
            fcntl.flock(self._f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._f.seek(0)
            holder = self._f.read().strip() or "another process"
            self._f.close()
            raise ValueError(f"run_dir {run_dir} is in use by another trainer (pid {holder} holds {self.path}); "
                             "wait for it or pick another run_dir") from None
        self._f.seek(0)
        self._f.truncate()
        self._f.write(f"{os.getpid()}\n")
        self._f.flush()

    def close(self) -> None:
        if not self._f.closed:
            fcntl.flock(self._f.fileno(), fcntl.LOCK_UN)
            self._f.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def prepare_fresh_run_dir(run_dir: Path, overwrite: bool) -> None:
    """Refuse a directory that already holds a run unless ``overwrite``; with it, remove that run's files
    (:data:`RUN_FILES` only: anything else of the user's stays). Call under the :class:`RunDirLock`."""
    if holds_run(run_dir):
        if not overwrite:
            raise ValueError(f"run_dir {run_dir} already holds a run (checkpoints/metrics); pass overwrite=true to "
                             f"replace it, resume={run_dir} to continue it, or choose another run_dir")
        for name in RUN_FILES:
            p = run_dir / name
            if p.is_dir():
                shutil.rmtree(p)
            elif p.exists():
                p.unlink()
        log.info("overwrite=true: removed the previous run in %s", run_dir)
    clean_stale_temps(run_dir / "checkpoints")


def _keep_lines(path: Path, keep) -> int:
    lines = path.read_text().splitlines(keepends=True)
    kept = [line for line in lines if keep(line)]
    if len(kept) != len(lines):
        atomic_write(path, lambda f: f.write("".join(kept).encode()))
    return len(lines) - len(kept)


def truncate_logs(run_dir: Path, iteration: int) -> int:
    """Drop log rows of iterations after ``iteration`` (the checkpoint's); returns how many were dropped."""
    import json

    def jsonl_keep(line: str) -> bool:
        try:
            return int(json.loads(line).get("iteration", 0)) <= iteration
        except (ValueError, AttributeError):
            return False  # a torn last line from the crash

    def csv_keep(line: str) -> bool:
        try:
            return int(line.split(",", 1)[0]) <= iteration
        except ValueError:
            return not line.strip() == ""  # a header (if any) stays
    dropped = 0
    if (run_dir / "metrics.jsonl").is_file():
        dropped += _keep_lines(run_dir / "metrics.jsonl", jsonl_keep)
    for csv in (run_dir / "logs").rglob("*.csv") if (run_dir / "logs").is_dir() else ():
        dropped += _keep_lines(csv, csv_keep)
    clean_stale_temps(run_dir / "checkpoints")
    if dropped:
        log.info("resume: dropped %d log rows past the checkpoint's iteration %d", dropped, iteration)
    return dropped


def _leaves(d, prefix=""):
    if isinstance(d, dict):
        for k, v in d.items():
            yield from _leaves(v, f"{prefix}{k}.")
    else:
        yield prefix[:-1], d


def _select(d, dotted: str):
    for part in dotted.split("."):
        if not isinstance(d, dict) or part not in d:
            return None
        d = d[part]
    return d


def _override_keys(overrides) -> list[str]:
    keys = []
    for o in overrides:
        key = o.split("=", 1)[0].lstrip("+~")
        keys.append(f"{key}.name" if key in ("task", "algo") else key)  # a group choice: compare the name
    return keys


def resume_config(cfg, checkpoint: dict, source, overrides: list[str] | None):
    """The config a resumed run trains with: the checkpoint's ``task``, ``algo`` and ``seed`` with the
    user's run keys (run_dir, stop_after, eval, ...). ``overrides`` are the command line's (hydra's
    ``overrides.task``): one of them that changes a locked key is a :class:`CheckpointError`;
    ``overrides=None`` (a Python caller) compares every locked key of ``cfg``."""
    from omegaconf import OmegaConf

    saved = dict(checkpoint.get("config") or {})
    if isinstance(saved.get("task"), dict) and saved["task"].get("name") in list_tasks():
        # fields the saved task predates keep the task it trained on
        saved["task"] = {**saved_config_defaults(task_entry(saved["task"]["name"]).config_class), **saved["task"]}
    mine = OmegaConf.to_container(cfg, resolve=True)
    if overrides is None:
        keys = [k for section in LOCKED for k, _ in _leaves({section: mine.get(section)})]
    else:
        keys = [k for k in _override_keys(overrides) if k.split(".")[0] in LOCKED]
    keys = [k for k in keys if k not in RESUME_MAY_CHANGE]
    keys.sort(key=lambda k: not k.endswith(".name"))  # a different task/algo is the clearest message
    conflicts = [f"{k}={_select(mine, k)!r} (checkpoint: {_select(saved, k)!r})" for k in keys
                 if _select(mine, k) != _select(saved, k)]
    if conflicts:
        more = f" and {len(conflicts) - 3} more" if len(conflicts) > 3 else ""
        raise CheckpointError(f"resume={source}: {', '.join(conflicts[:3])}{more} conflict with the checkpoint; a resumed "
                              "run keeps its checkpoint's task, algo and seed (drop those overrides or start a new run)")
    merged = OmegaConf.merge(cfg, {k: saved[k] for k in LOCKED if k in saved})
    for key in RESUME_MAY_CHANGE:
        if overrides is None or key in _override_keys(overrides):
            OmegaConf.update(merged, key, OmegaConf.select(cfg, key), merge=False)
    return merged
