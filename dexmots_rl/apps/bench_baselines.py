"""``dexmots-bench baselines``: each model-free baseline's training loop against torchrl's own implementation of
its algorithm on the same env, in one run.

    dexmots-bench baselines --task screw_claw --json [--methods ppo sac pgdm] [--iterations 6] [--num-envs 64]
    dexmots-bench baselines --methods sac algo.batch_size=256   # hydra overrides of both loops' configs
    dexmots-bench baselines sac:algo.batch_size=256 algo.hidden=[128]  # <method>: only that method's

For each method, ``ours`` is ``dexmots-train algo=<method>`` itself (the method's config, a short schedule of
``--iterations`` collector iterations, a one-episode final evaluation, in a temporary run directory): its
``metrics.jsonl`` rows time each iteration's collection and learning apart (:class:`~dexmots_rl.algorithms.
common.CollectorLoop`). ``reference`` is torchrl's sota loop (:mod:`.bench_reference`; PGDM: sota PPO on
PGDM's observation and reward) with the same sizes, timed the same way. The first iteration of each is left
out (the env's first reset, the lazy buffers). Reported per method and implementation, on CPU seconds (what
another process's load does not take away) and wall seconds:

* ``env_steps_per_cpu_s`` / ``_wall_s``: env steps over the collection's time (the collector stepping the
  non-differentiable env under the policy, its transforms included);
* ``updates_per_cpu_s`` / ``_wall_s``: gradient steps over the learning's time (everything between two
  collections: buffer writes, sampling, advantages, the updates and the loop's bookkeeping);

and ``ratio`` = ours / reference of each CPU figure (1: as fast as torchrl's; the goal is >= 0.5). Both run
with ``--torch-threads`` torch threads (1, as on a shared machine).
"""

from __future__ import annotations

import json
import logging
import tempfile
from pathlib import Path

import torch

from .bench_reference import ppo_reference, sac_reference

__all__ = ["METHODS", "RATIO_GOAL", "run_baselines", "rates"]

log = logging.getLogger(__name__)

METHODS = ("ppo", "sac", "pgdm")
RATIO_GOAL = 0.5  # ours at least half the reference's rate ("within 2x")


def rates(rows: list[dict]) -> dict:
    """Env-steps and updates per CPU and wall second of timing ``rows`` (the first left out as warm-up; the
    update rates over the rows that updated)."""
    rows = rows[1:]
    learning = [r for r in rows if r["updates"] > 0]
    out = {}
    for clock in ("cpu", "wall"):
        collect = sum(r[f"collect_{clock}_s"] for r in rows)
        learn = sum(r[f"learn_{clock}_s"] for r in learning)
        out[f"env_steps_per_{clock}_s"] = sum(r["env_steps"] for r in rows) / collect if collect > 0 else float("nan")
        out[f"updates_per_{clock}_s"] = sum(r["updates"] for r in learning) / learn if learn > 0 else float("nan")
    return out


def _our_rows(run_dir: Path) -> list[dict]:
    """Per-iteration timing rows of a run's ``metrics.jsonl`` (env steps and updates of each iteration)."""
    rows, steps, updates = [], 0, 0
    for line in (run_dir / "metrics.jsonl").read_text().splitlines():
        row = json.loads(line)
        rows.append({"env_steps": row["env_steps"] - steps, "updates": row.get("updates", 0) - updates,
                     **{k: row[k] for k in ("collect_cpu_s", "collect_wall_s", "learn_cpu_s", "learn_wall_s")}})
        steps, updates = row["env_steps"], row.get("updates", 0)
    return rows


def _config(task: str, method: str, iterations: int, num_envs: int, run_dir: Path, seed: int, extra=()):
    """``dexmots-train``'s config of ``method`` on ``task`` (plus the hydra overrides ``extra``), cut to
    ``iterations`` collector iterations (SAC learning from the second)."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from .train import CONFIG_DIR

    overrides = [f"task={task}", f"algo={method}", f"seed={seed}", f"task.num_envs={num_envs}", f"run_dir={run_dir}",
                 "progress=false", "overwrite=true", "eval.episodes=1", *extra]
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose("config", overrides=overrides)
    frames = int(cfg.algo.frames_per_batch)
    if frames % num_envs:  # the configs size a batch for their own world count: keep its steps per world
        frames = num_envs * max(1, frames // int(cfg.task.num_envs))
    OmegaConf.update(cfg, "algo.frames_per_batch", frames)
    OmegaConf.update(cfg, "algo.total_frames", float(frames * iterations))
    if method == "sac":
        OmegaConf.update(cfg, "algo.init_random_frames", frames)
    if "minibatch_size" in cfg.algo:
        OmegaConf.update(cfg, "algo.minibatch_size", min(int(cfg.algo.minibatch_size), frames))
    return cfg


def _reference(method: str, cfg, iterations: int, num_envs: int, seed: int) -> list[dict]:
    if method == "sac":
        return sac_reference(cfg.task.name, cfg.algo, iterations, num_envs, seed)
    transforms = ()
    if method == "pgdm":
        from ..algorithms.pgdm import PGDMObservation, pgdm_variant

        pgdm_variant(cfg.algo)  # its checks
        transforms = (PGDMObservation(cfg.algo),)
    return ppo_reference(cfg.task.name, cfg.algo, iterations, num_envs, seed, transforms)


def method_row(task: str, method: str, iterations: int, num_envs: int, seed: int = 0, overrides=()) -> dict:
    """Ours and the reference of one method (see the module docstring); ``overrides``: hydra overrides of
    the method's config, which both loops then use."""
    from ..algorithms.registry import train

    with tempfile.TemporaryDirectory(prefix=f"bench_{method}_") as tmp:
        cfg = _config(task, method, iterations, num_envs, Path(tmp) / "run", seed, overrides)
        train(cfg)
        ours = rates(_our_rows(Path(cfg.run_dir)))
    reference = rates(_reference(method, cfg, iterations, num_envs, seed))
    row = {"method": method, "frames_per_batch": int(cfg.algo.frames_per_batch),
           **{f"ours_{k}": v for k, v in ours.items()}, **{f"reference_{k}": v for k, v in reference.items()}}
    for key in ("env_steps_per_cpu_s", "updates_per_cpu_s"):
        row[f"ratio_{key}"] = ours[key] / reference[key]
    log.info("baselines %s %s: %s", task, method, row)
    return row


def _method_overrides(overrides, method: str) -> list[str]:
    """The overrides that apply to ``method``: those without a ``<method>:`` prefix and its own, unprefixed."""
    out = []
    for override in overrides:
        prefix, sep, rest = override.partition(":")
        if not sep or "=" in prefix:  # no method prefix (a ':' inside the value)
            out.append(override)
        elif prefix not in METHODS:
            raise ValueError(f"override {override!r}: unknown method {prefix!r}; known: {', '.join(METHODS)}")
        elif prefix == method:
            out.append(rest)
    return out


def run_baselines(task: str, methods=METHODS, iterations: int = 6, num_envs: int = 64, seed: int = 0,
                  torch_threads: int | None = 1, overrides=()) -> dict:
    """Every method's row (see the module docstring) with ``torch_threads`` torch threads (None: torch's);
    ``overrides``: hydra overrides of every method's config."""
    if iterations < 2:
        raise ValueError(f"--iterations must be >= 2 (the first is warm-up), got {iterations}")
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise ValueError(f"--methods: unknown {', '.join(unknown)}; known: {', '.join(METHODS)}")
    previous = torch.get_num_threads()
    if torch_threads is not None:
        torch.set_num_threads(torch_threads)
    try:
        rows = [method_row(task, m, iterations, num_envs, seed, _method_overrides(overrides, m)) for m in methods]
    finally:
        torch.set_num_threads(previous)
    met = all(r[f"ratio_{k}"] >= RATIO_GOAL for r in rows for k in ("env_steps_per_cpu_s", "updates_per_cpu_s"))
    return {"task": task, "iterations": iterations, "num_envs": num_envs,
            "torch_threads": torch.get_num_threads() if torch_threads is None else torch_threads, "rows": rows,
            "ratio_goal": RATIO_GOAL, "ratio_goal_met": met}
