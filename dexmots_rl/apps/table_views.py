"""``dexmots-table``'s second view of the same runs, and a planner's cost.

* :func:`add_equal_steps` — each trained run's success at the task's **equal env-step count**: the smallest
  number of env steps every trained run of the task collected (a budget of CPU time lets a fast-stepping method
  collect many more), read from the run's learning curve (:func:`.table_writer.learning_curve`: its periodic
  evaluations and its final one) as the last evaluation at or before that count. ``runs.csv``'s
  ``equal_env_steps`` and ``success_at_equal_steps``.
* :func:`equal_steps_table` — Table 2's layout for that view, with the count per task.
* :func:`planning_cost_table` — a planner's (``algo=mpc``: it learns nothing and plans in every evaluation
  episode) success beside what its planning cost per evaluation episode: sim steps (forward; the backward
  ones of a gradient refinement apart), CPU and wall seconds (``runs.csv``'s ``planning_*`` columns, from its
  ``metrics.json``; runs made before the CPU time was recorded show their wall-clock only).

Example:
    >>> rows = [{"task": "t", "method": m, "experiment": "table", "status": "finished", "stopped_by": "cpu_s",
    ...          "env_steps": n, "run_dir": m} for m, n in (("a", 100), ("b", 300))]
    >>> curves = {"a": [{"env_steps": 100, "success": 0.5}],
    ...           "b": [{"env_steps": 50, "success": 0.2}, {"env_steps": 150, "success": 0.9}]}
    >>> [(r["equal_env_steps"], r["success_at_equal_steps"]) for r in add_equal_steps(rows, curves.get)]
    [(100, 0.5), (100, 0.2)]
"""

from __future__ import annotations

import statistics
from typing import Callable, Iterable, Mapping, Sequence

from .table_writer import DASH, NO_TRAINING

__all__ = ["add_equal_steps", "equal_steps_table", "planning_cost_table", "planning_cost", "success_at_steps"]


def _trained(row: Mapping) -> bool:
    return (row.get("experiment", "table") == "table" and row.get("status") == "finished"
            and row.get("stopped_by") != NO_TRAINING and row.get("env_steps") is not None)


def success_at_steps(curve: Sequence[Mapping], env_steps: int) -> float | None:
    """The success of the last evaluation of ``curve`` at or before ``env_steps`` (None: none was)."""
    before = [p for p in curve if p.get("env_steps") is not None and p["env_steps"] <= env_steps
              and p.get("success") is not None]
    return float(before[-1]["success"]) if before else None


def add_equal_steps(rows: Iterable[dict], curve_of: Callable[[str], Sequence[Mapping]]) -> list[dict]:
    """``rows`` (``runs.csv``'s) with ``equal_env_steps`` (per task: the fewest env steps of its trained runs) and
    ``success_at_equal_steps`` set on every trained run; ``curve_of``: a run directory -> its learning curve."""
    rows = list(rows)
    fewest: dict[str, int] = {}
    for r in rows:
        if _trained(r):
            fewest[r["task"]] = min(fewest.get(r["task"], r["env_steps"]), r["env_steps"])
    for r in rows:
        if _trained(r):
            r["equal_env_steps"] = fewest[r["task"]]
            r["success_at_equal_steps"] = success_at_steps(curve_of(r["run_dir"]), fewest[r["task"]])
    return rows


def equal_steps_table(rows: Iterable[dict], tasks: Sequence[tuple[str, str]],
                      methods: Sequence[tuple[str, str]]) -> str:
    """Success (%) at each task's equal env-step count (last column), mean ± s.d. over the runs with an
    evaluation by then (``(n=2)`` when some had none); ``no training`` for a planner."""
    rows = [r for r in rows if r.get("experiment", "table") == "table" and r.get("status") == "finished"]
    lines = ["| Environment | " + " | ".join(label for _, label in methods) + " | Env steps |",
             "|---|" + "---:|" * (len(methods) + 1)]
    for task, label in tasks:
        cells, steps = [], None
        for method, _ in methods:
            runs = [r for r in rows if r["task"] == task and r["method"] == method]
            trained = [r for r in runs if _trained(r)]
            if runs and not trained:
                cells.append("no training")
                continue
            values = [100 * float(r["success_at_equal_steps"]) for r in trained
                      if r.get("success_at_equal_steps") is not None]
            steps = steps or next((r.get("equal_env_steps") for r in trained), None)
            if not values:
                cells.append(DASH)
                continue
            cell = f"{statistics.fmean(values):.1f}" + (f" ± {statistics.stdev(values):.1f}" if len(values) > 1 else "")
            cells.append(cell + (f" (n={len(values)})" if len(values) < len(trained) else ""))
        lines.append(f"| {label} | " + " | ".join(cells) + f" | {DASH if steps is None else f'{int(steps):,}'} |")
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


def _mean_cell(values, fmt: str) -> str:
    values = [float(v) for v in values if v is not None]
    return format(statistics.fmean(values), fmt) if values else DASH


def planning_cost_table(rows: Iterable[dict], tasks: Sequence[tuple[str, str]], method: str) -> str:
    """``method``'s success (%) and its planning per evaluation episode (means over its finished runs)."""
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
                     f"{_mean_cell([r.get('planning_cpu_s_per_episode') for r in runs], '.2f')} | "
                     f"{_mean_cell([r.get('planning_wall_s_per_episode') for r in runs], '.2f')} |")
    return "\n".join(lines)
