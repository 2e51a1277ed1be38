"""A training run's directory, written by every method through :class:`RunDirectory`: ``config.yaml`` (the
resolved config), ``metrics.jsonl`` (one row per iteration) and a torchrl logger's ``logs/``,
``checkpoints/last.pt`` (atomic and checksummed, :mod:`.checkpoint`), ``metrics.json`` (the final
evaluation), a lock for as long as a trainer uses it, and resume.

A fresh run refuses a directory holding another run (``overwrite=true`` replaces it); a resume continues
the run in ``resume=<dir>`` with the checkpoint's own task, algo and seed, and its ``config.yaml`` names
that directory.

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

from ..atomic import atomic_write, atomic_write_json, clean_stale_temps, dumps_json
from ..envs.config import saved_config_defaults
from ..envs.registry import list_tasks, task_entry
from ..provenance import provenance
from .checkpoint import CheckpointError, latest_checkpoint, load_checkpoint, save_checkpoint
from .evaluation import evaluate_policy, periodic_episodes
from .validation import validate_run_config

__all__ = ["RUN_FILES", "RunDirLock", "RunDirectory", "holds_run", "prepare_fresh_run_dir", "truncate_logs",
           "resume_config"]

log = logging.getLogger(__name__)

#: what a run leaves in its directory (``overwrite=true`` removes exactly these)
RUN_FILES = ("checkpoints", "metrics.jsonl", "metrics.json", "config.yaml", "logs", "eval.json", "eval.mcap")
#: resume keeps the checkpoint's values of these; an override that differs is a conflict
LOCKED = ("task", "algo", "seed")
#: ... except these, which a resumed run may change (a longer schedule: SHAC's iterations, PPO's frames)
RESUME_MAY_CHANGE = ("algo.iterations", "algo.total_frames")


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
    base = cfg
    other = [k for k in ("task", "algo") if isinstance(saved.get(k), dict)
             and _select(mine, f"{k}.name") != saved[k].get("name")]
    if other:  # the command line's defaults name another task or method: the checkpoint's section replaces it
        base = OmegaConf.create({k: v for k, v in mine.items() if k not in other})
    merged = OmegaConf.merge(base, {k: saved[k] for k in LOCKED if k in saved})
    for key in RESUME_MAY_CHANGE:
        if (overrides is None or key in _override_keys(overrides)) and OmegaConf.select(cfg, key) is not None:
            OmegaConf.update(merged, key, OmegaConf.select(cfg, key), merge=False)
    # the run continues in the resumed directory: its config names it (not the command line's default)
    OmegaConf.update(merged, "run_dir", str(source), merge=False)
    return merged


class RunDirectory:
    """The run directory of one training run, opened before any env is built (every method uses it).

    Opening it validates ``cfg`` (:func:`.validation.validate_run_config`), on resume (``cfg.resume``) loads
    the last checkpoint (:attr:`start`) and takes its config (:func:`resume_config`; :attr:`cfg` is what
    trains), locks the directory (:class:`RunDirLock`), refuses or replaces a previous run
    (:func:`prepare_fresh_run_dir`) or cuts a resumed run's logs back to its checkpoint
    (:func:`truncate_logs`), and writes ``config.yaml``. ``main=False`` (the other ranks of a distributed
    run): the same config and checkpoint, nothing locked or written. ``resumes=False``: the method cannot
    continue a run, and ``resume=`` is refused. ``overrides``: the command line's, compared with the
    checkpoint on resume. Close it (or use it as a context manager) to release the lock; a run that fails
    before writing anything leaves no directory behind.
    """

    def __init__(self, cfg, overrides: list[str] | None = None, main: bool = True, resumes: bool = True):
        self.start: dict | None = None
        if cfg.resume:
            if not resumes:
                raise ValueError(f"algo {cfg.algo.name!r} does not resume runs (resume={cfg.resume}); start a new run")
            self.start = load_checkpoint(latest_checkpoint(cfg.resume))
            cfg = resume_config(cfg, self.start, cfg.resume, overrides)
        validate_run_config(cfg)  # what is validated is what trains: on resume, the checkpoint's config
        if self.start is not None:
            for what, name in (("task", cfg.task.name), ("algo", cfg.algo.name)):
                if self.start.get(what) != name:
                    raise CheckpointError(f"{cfg.resume} was trained with {what} {self.start.get(what)!r}, "
                                          f"not {name!r}")
        self.cfg, self.dir, self.main = cfg, Path(cfg.run_dir), main
        self.logger, self._lock = None, None
        if not main:
            return
        created = not self.dir.exists()
        self._lock = RunDirLock(self.dir)
        try:
            if self.start is None:
                prepare_fresh_run_dir(self.dir, bool(cfg.get("overwrite", False)))
            else:
                truncate_logs(self.dir, int(self.start["iteration"]))
            from omegaconf import OmegaConf
            from torchrl.record.loggers import get_logger

            (self.dir / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
            self.logger = get_logger(cfg.logger, logger_name=str(self.dir), experiment_name="logs")
        except BaseException:
            self.close(remove_if_empty=created)
            raise
        self._created = created

    # ---------------------------------------------------------------------------------- writing
    def log(self, row: dict) -> None:
        """One ``metrics.jsonl`` row (strict JSON: NaN as null) and its finite numbers to the logger."""
        if not self.main:
            return
        with open(self.dir / "metrics.jsonl", "a") as f:
            f.write(dumps_json(row) + "\n")
        for key, value in row.items():
            if key != "iteration" and isinstance(value, (int, float)) and value == value:  # NaN: not a scalar
                self.logger.log_scalar(key, value, step=row["iteration"])

    def checkpoint(self, counters: dict, modules: dict, optimizers: dict, **extra) -> None:
        """``checkpoints/last.pt``: the config, counters, ``{name: state_dict}`` of ``modules`` and
        ``optimizers``, and ``extra`` entries (a method's env state, RNG states...). A baseline's
        ``modules`` hold ``"policy"``: what its :func:`~.registry.policy_from_checkpoint` loader rebuilds."""
        if not self.main:
            return
        from omegaconf import OmegaConf

        save_checkpoint(self.dir / "checkpoints" / "last.pt", {
            "task": self.cfg.task.name,
            "algo": self.cfg.algo.name,
            "config": OmegaConf.to_container(self.cfg, resolve=True),
            "iteration": counters["iteration"],
            "counters": dict(counters),
            "modules": {name: m.state_dict() for name, m in modules.items()},
            "optimizers": {name: o.state_dict() for name, o in optimizers.items()},
            **extra,
        })

    def record_options(self, live: bool = True) -> dict:
        """``evaluate_policy``'s recording options: ``<run_dir>/eval.mcap`` when ``eval.record``
        (``live``: rewritten after every evaluation, for ``dexmots-view --live``)."""
        if not self.cfg.eval.record:
            return {}
        return {"record": self.dir / "eval.mcap", **({"live": True} if live else {})}

    def evaluate(self, policy, counters: dict, final: bool = True, budget: dict | None = None, **extra) -> dict:
        """Deterministic evaluation on the plain task env. During training (``final=False``):
        ``eval.curve_episodes`` episodes, logged as ``eval_*`` entries of a ``metrics.jsonl`` row; the
        final one (``eval.episodes``) writes ``metrics.json`` (:meth:`write_result`) and returns it."""
        cfg = self.cfg
        episodes = cfg.eval.episodes if final else periodic_episodes(cfg.eval)
        ev = evaluate_policy(policy, cfg.task, episodes, cfg.eval.seed, cfg.device, **self.record_options())
        if not final:
            self.log({"iteration": counters["iteration"],
                      **{f"eval_{k}": v for k, v in ev.items() if isinstance(v, (int, float))}})
            return ev
        return self.write_result(ev, counters, budget=budget, **extra)

    def write_result(self, ev: dict, counters: dict, budget: dict | None = None, **extra) -> dict:
        """``metrics.json``: the evaluation ``ev``, the run's counters, its ``budget`` record
        (:meth:`.budget.RunBudget.record`) and ``extra`` entries; returns it."""
        cfg = self.cfg
        result = {"task": cfg.task.name, "algo": cfg.algo.name, **ev, "env_steps": counters["env_steps"],
                  "iterations": counters["iteration"], "train_wall_clock_s": round(counters["wall_clock_s"], 2),
                  "train_cpu_s": round(counters.get("cpu_s", 0.0), 2),
                  "budget": budget or {}, **extra, "run_dir": str(self.dir), "provenance": provenance()}
        if self.main:
            atomic_write_json(self.dir / "metrics.json", result)  # a sweep's restart trusts a complete file
            log.info("%s %s: success %.2f after %d env steps, %.0f s", cfg.algo.name, cfg.task.name,
                     ev["success_rate"], counters["env_steps"], counters["wall_clock_s"])
        return result

    # ---------------------------------------------------------------------------------- closing
    def close(self, remove_if_empty: bool = False) -> None:
        """Release the lock; ``remove_if_empty``: also remove the directory if this run created it and
        left nothing in it but the lock (a run that failed before its first write)."""
        if self._lock is None:
            return
        self._lock.close()
        self._lock = None
        if remove_if_empty and {p.name for p in self.dir.iterdir()} <= {".lock", "config.yaml", "logs"}:
            shutil.rmtree(self.dir, ignore_errors=True)

    def __enter__(self) -> "RunDirectory":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(remove_if_empty=exc_type is not None and getattr(self, "_created", False)
                   and not holds_run(self.dir))
