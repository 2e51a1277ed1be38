"""``dexmots-table``'s second view of the same runs, and a planner's cost.

* :func:`add_equal_steps` — each trained run's success at the task's **equal env-step count**: the smallest
  number of env steps every trained run of the task collected (a budget of CPU time lets a fast-stepping method
  collect many more), read from the run's learning curve (:func:`.table_writer.learning_curve`: its periodic
  evaluations and its final one) as the last evaluation at or before that count. ``runs.csv``'s
  ``equal_env_steps``, ``success_at_equal_steps`` and which evaluation that was: its env steps and episodes
  (``equal_steps_eval_env_steps``, ``equal_steps_eval_episodes``; periodic evaluations run
  ``eval.curve_episodes`` episodes, fewer than the final one's ``eval.episodes``).
* :func:`equal_steps_table` — Table 2's layout for that view, each cell saying which evaluations it read, the
  count per task and the run that set it; a planner's column: its success beside its planning CPU seconds per
  evaluation episode.
* :func:`planning_cost_table` — a planner's (``algo=mpc``: it learns nothing and plans in every evaluation
  episode) success beside what its planning cost per evaluation episode: sim steps (forward; the backward
  ones of a gradient refinement apart), CPU and wall seconds (``runs.csv``'s ``planning_*`` columns, from its
  ``metrics.json``; runs made before the CPU time was recorded show :data:`NOT_RECORDED` and their wall-clock).

Example:
    >>> rows = [{"task": "t", "method": m, "experiment": "table", "status": "finished", "stopped_by": "cpu_s",
    ...          "env_steps": n, "run_dir": m} for m, n in (("a", 100), ("b", 300))]
    >>> curves = {"a": [{"env_steps": 100, "success": 0.5, "episodes": 100}],
    ...           "b": [{"env_steps": 50, "success": 0.2, "episodes": 20}, {"env_steps": 150, "success": 0.9}]}
    >>> [(r["equal_env_steps"], r["success_at_equal_steps"], r["equal_steps_eval_episodes"])
    ...  for r in add_equal_steps(rows, curves.get)]
    [(100, 0.5, 100), (100, 0.2, 20)]
"""

from __future__ import annotations

import statistics
from typing import Callable, Iterable, Mapping, Sequence

from .table_writer import DASH, NO_TRAINING, mean_sd_text

__all__ = ["NOT_RECORDED", "add_equal_steps", "equal_steps_table", "evaluation_at_steps", "planning_cost",
           "planning_cost_table"]

NOT_RECORDED = "not recorded"  # a planner's CPU time, by runs made before it was measured


def _trained(row: Mapping) -> bool:
    return (row.get("experiment", "table") == "table" and row.get("status") == "finished"
            and row.get("stopped_by") != NO_TRAINING and row.get("env_steps") is not None)


def evaluation_at_steps(curve: Sequence[Mapping], env_steps: int) -> Mapping | None:
    """The last evaluation of ``curve`` at or before ``env_steps`` (None: none was)."""
    before = [p for p in curve if p.get("env_steps") is not None and p["env_steps"] <= env_steps
              and p.get("success") is not None]
    return before[-1] if before else None


def add_equal_steps(rows: Iterable[dict], curve_of: Callable[[str], Sequence[Mapping]]) -> list[dict]:
    """``rows`` (``runs.csv``'s) with ``equal_env_steps`` (per task: the fewest env steps of its trained runs),
    ``success_at_equal_steps`` and the env steps and episodes of the evaluation it came from set on every trained
    run; ``curve_of``: a run directory -> its learning curve."""
    rows = list(rows)
    fewest: dict[str, int] = {}
    for r in rows:
        if _trained(r):
            fewest[r["task"]] = min(fewest.get(r["task"], r["env_steps"]), r["env_steps"])
    for r in rows:
        if _trained(r):
            point = evaluation_at_steps(curve_of(r["run_dir"]), fewest[r["task"]]) or {}
            r.update(equal_env_steps=fewest[r["task"]], success_at_equal_steps=point.get("success"),
                     equal_steps_eval_env_steps=point.get("env_steps"),
                     equal_steps_eval_episodes=point.get("episodes"))
    return rows


def _span(values: Sequence, text: Callable = str) -> str:
    low, high = min(values), max(values)
    return text(low) if low == high else f"{text(low)}–{text(high)}"


def _trained_cell(runs: Sequence[Mapping]) -> str:
    """Success (%) at the equal count, mean ± s.d., with ``at`` the env steps (thousands) and the episodes of the
    evaluations read."""
    read = [r for r in runs if r.get("success_at_equal_steps") is not None]
    partial = [f"n={len(read)} of {len(runs)}"] if len(read) < len(runs) else []
    if not read:
        return f"{DASH} ({partial[0]})"
    steps = [int(r["equal_steps_eval_env_steps"]) for r in read if r.get("equal_steps_eval_env_steps") is not None]
    episodes = [int(r["equal_steps_eval_episodes"]) for r in read if r.get("equal_steps_eval_episodes") is not None]
    which = ([f"at {_span([s / 1000 for s in steps], '{:.1f}'.format)}k"] if steps else []) + (
        [f"{_span(episodes)} ep"] if episodes else [])
    detail = "; ".join(filter(None, [", ".join(partial), ", ".join(which)]))
    return mean_sd_text([float(r["success_at_equal_steps"]) for r in read], 100) + (f" ({detail})" if detail else "")


def _planner_cell(runs: Sequence[Mapping]) -> str:
    """A planner's success (%, mean ± s.d.) beside its planning CPU seconds per evaluation episode (the mean over
    the runs that recorded it)."""
    success = mean_sd_text([float(r["success"]) for r in runs if r.get("success") is not None], 100)
    cpu = [float(r["planning_cpu_s_per_episode"]) for r in runs if r.get("planning_cpu_s_per_episode") is not None]
    if not cpu:
        return f"{success} (CPU s / episode {NOT_RECORDED})"
    return f"{success} ({statistics.fmean(cpu):.2f} CPU s / episode" + (
        f", n={len(cpu)} of {len(runs)})" if len(cpu) < len(runs) else ")")


def equal_steps_table(rows: Iterable[dict], tasks: Sequence[tuple[str, str]],
                      methods: Sequence[tuple[str, str]]) -> str:
    """Success (%) at each task's equal env-step count, mean ± s.d. over the runs with an evaluation by then
    (``n=1 of 2`` when some had none) and which evaluations were read; a planner's success and planning cost;
    the last column: the count and the run that collected it."""
    rows = [r for r in rows if r.get("experiment", "table") == "table" and r.get("status") == "finished"]
    labels = dict(methods)
    lines = ["| Environment | " + " | ".join(label for _, label in methods) + " | Env steps (the run with the fewest) |",
             "|---|" + "---:|" * (len(methods) + 1)]
    for task, label in tasks:
        cells = []
        for method, _ in methods:
            runs = [r for r in rows if r["task"] == task and r["method"] == method]
            trained = [r for r in runs if _trained(r)]
            cells.append(DASH if not runs else _trained_cell(trained) if trained else _planner_cell(runs))
        fewest = [r for r in rows if r["task"] == task and _trained(r) and r["env_steps"] == r.get("equal_env_steps")]
        first = min(fewest, key=lambda r: (list(labels).index(r["method"]) if r["method"] in labels else len(labels),
                                           r.get("seed") or 0), default=None)
        count = DASH if first is None else (
            f"{int(first['equal_env_steps']):,} ({labels.get(first['method'], first['method'])}, seed {first['seed']})")
        lines.append(f"| {label} | " + " | ".join(cells) + f" | {count} |")
    return "\n".join(lines)


def planning_cost(metrics: Mapping) -> dict:
    """``runs.csv``'s planning columns of a planner's ``metrics.json`` (per evaluation episode); empty for a
    method without planning figures."""
    episodes = metrics.get("episodes")
    if not episodes or "sim_steps" not in metrics:
        return {}
    wall = metrics.get("planning_wall_s_per_episode")
    if wall is None and metrics.get("wall_clock_s") is not None:  # runs made before the per-episode figures
        wall = metrics["wall_clock_s"] / episodes
    return {"planning_sim_steps_per_episode": metrics.get("sim_steps_per_episode", metrics["sim_steps"] // episodes),
            "planning_cpu_s_per_episode": metrics.get("planning_cpu_s_per_episode"),
            "planning_wall_s_per_episode": None if wall is None else round(wall, 4)}


def _mean_cell(values, fmt: str, missing: str = DASH) -> str:
    values = [float(v) for v in values if v is not None]
    return format(statistics.fmean(values), fmt) if values else missing


def planning_cost_table(rows: Iterable[dict], tasks: Sequence[tuple[str, str]], method: str) -> str:
    """``method``'s success (%) and its planning per evaluation episode (means over its finished runs that
    recorded each figure; :data:`NOT_RECORDED` where none did)."""
    rows = [r for r in rows if r.get("experiment", "table") == "table" and r.get("status") == "finished"
            and r["method"] == method]
    lines = ["| Environment | success % | sim steps / episode | CPU s / episode | wall s / episode |",
             "|---|---:|---:|---:|---:|"]
    for task, label in tasks:
        runs = [r for r in rows if r["task"] == task]
        if not runs:
            continue
        success = _mean_cell([100 * float(r["success"]) for r in runs if r.get("success") is not None], ".1f")
        lines.append(f"| {label} | {success} | "
                     f"{_mean_cell([r.get('planning_sim_steps_per_episode') for r in runs], ',.0f')} | "
                     f"{_mean_cell([r.get('planning_cpu_s_per_episode') for r in runs], '.2f', NOT_RECORDED)} | "
                     f"{_mean_cell([r.get('planning_wall_s_per_episode') for r in runs], '.2f')} |")
    return "\n".join(lines)
