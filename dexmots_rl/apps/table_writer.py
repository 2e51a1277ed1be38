"""``dexmots-table``'s results: one row per run (``runs.csv``) read from its run directory, and the markdown
tables built from those rows alone, so a CSV can be rendered again (or tested) without the runs.

* :func:`learning_curve` — a run's success over training: its periodic evaluations (``eval_success_rate``
  rows of ``metrics.jsonl``, placed at the env steps and training wall-clock of their iteration) and the final
  evaluation of ``metrics.json``.
* :func:`time_to_success` — the first point of a curve at or above a success rate (90 %).
* :func:`run_row`, :func:`write_csv`, :func:`read_csv` — ``runs.csv`` (:data:`CSV_FIELDS`; the columns of the
  equal-env-steps view and of a planner's cost are filled by :mod:`.table_views`).
* :func:`markdown_table` — Table 2's layout: tasks as rows, methods as columns, success in % as
  mean ± sample s.d. over seeds, and an Average row (mean of the task means ± mean of their s.d., as the paper);
  a Budget column when the tasks' training budgets differ.
* :func:`budget_text` — the sentence stating the training budget (one for all runs, or per task) and warning
  when the finished runs of one comparison had different budgets.
* :func:`time_to_success_table` — the same layout for the mean training time to 90 % success.
* :func:`action_space_table` — Fig. 3b in numbers: one task's success per method (rows) and action space
  (columns), every seed's value, mean ± s.d. and the time to 90 %.
* :func:`quoted_table` — the same layout for figures quoted from elsewhere (the paper's own Table 2), with its
  Average row computed by the same rule.

Example:
    >>> rows = [{"task": "screw_claw", "method": "ppo", "experiment": "table", "status": "finished",
    ...          "success": s} for s in (0.5, 0.7)]
    >>> print(markdown_table(rows, [("screw_claw", "Screw")], [("ppo", "PPO")]))
    | Environment | PPO |
    |---|---:|
    | Screw | 60.0 ± 14.1 |
"""

from __future__ import annotations

import csv
import json
import statistics
from pathlib import Path
from typing import Iterable, Mapping, Sequence

from ..algorithms.budget import NO_TRAINING

__all__ = ["CSV_FIELDS", "NO_TRAINING", "action_space_runs", "action_space_table", "budget_cell", "budget_clock",
           "budget_text", "learning_curve", "machines_text", "markdown_table", "mean_sd_text", "quoted_table",
           "read_csv", "run_row", "sweep_relative", "time_to_success", "time_to_success_table", "write_csv"]

CSV_FIELDS = ("task", "method", "action", "seed", "experiment", "status", "success", "episodes", "wall_clock_s",
              "cpu_s", "env_steps", "time_to_90_s", "env_steps_to_90", "stopped_by", "budget_wall_clock_s",
              "budget_env_steps", "budget_cpu_s", "machine", "commit", "date", "equal_env_steps",
              "success_at_equal_steps", "equal_steps_eval_env_steps", "equal_steps_eval_episodes",
              "planning_sim_steps_per_episode", "planning_cpu_s_per_episode",
              "planning_wall_s_per_episode", "run_dir")
_INTS = ("seed", "episodes", "env_steps", "env_steps_to_90", "budget_env_steps", "equal_env_steps",
         "equal_steps_eval_env_steps", "equal_steps_eval_episodes", "planning_sim_steps_per_episode")
_FLOATS = ("success", "wall_clock_s", "cpu_s", "time_to_90_s", "budget_wall_clock_s", "budget_cpu_s",
           "success_at_equal_steps", "planning_cpu_s_per_episode", "planning_wall_s_per_episode")
DASH = "–"  # a cell without finished runs
# NO_TRAINING (:mod:`dexmots_rl.algorithms.budget`): the ``budget.stopped_by`` of a run that trains nothing
# (``algo=mpc`` plans inside its evaluation episodes); the table reports "no training", not a time to 90 %


def _jsonl(path: Path) -> list[dict]:
    rows = []
    if path.is_file():
        for line in path.read_text().splitlines():
            try:
                rows.append(json.loads(line))
            except ValueError:  # a torn last line of a killed run
                continue
    return rows


def budget_clock(budget: Mapping) -> str:
    """The clock a budget's training time is read on: ``cpu_s`` when it limits CPU time, else ``wall_clock_s``
    (times to 90 % and the curves' time axis use it)."""
    return "cpu_s" if budget.get("cpu_s") is not None else "wall_clock_s"


def learning_curve(run_dir, metrics: dict | None = None) -> list[dict]:
    """``[{"env_steps", "wall_clock_s", "cpu_s", "success", "episodes"}, ...]`` in training order (``episodes``: the
    evaluation's, None where a run did not log it); ``metrics``: the run's final ``metrics.json`` (read from
    ``run_dir`` when ``None``; absent: the periodic evaluations only)."""
    run_dir = Path(run_dir)
    at_iteration, points = {}, []
    for row in _jsonl(run_dir / "metrics.jsonl"):
        if "eval_success_rate" not in row and "env_steps" in row:
            at_iteration[row.get("iteration")] = row  # the training row an evaluation row follows
        elif "eval_success_rate" in row and row.get("iteration") in at_iteration:
            train = at_iteration[row["iteration"]]
            points.append({"env_steps": train["env_steps"], "wall_clock_s": train["wall_clock_s"],
                           "cpu_s": train.get("cpu_s"), "success": row["eval_success_rate"],
                           "episodes": row.get("eval_episodes")})
    if metrics is None and (run_dir / "metrics.json").is_file():
        try:
            metrics = json.loads((run_dir / "metrics.json").read_text())
        except ValueError:
            metrics = None
    if metrics and "success_rate" in metrics:
        points.append({"env_steps": metrics.get("env_steps"), "wall_clock_s": metrics.get("train_wall_clock_s"),
                       "cpu_s": metrics.get("train_cpu_s"), "success": metrics["success_rate"],
                       "episodes": metrics.get("episodes")})
    return points


def time_to_success(curve: Sequence[dict], threshold: float = 0.9) -> dict | None:
    """The first point of ``curve`` whose success is at least ``threshold``, else ``None``."""
    return next((p for p in curve if p["success"] is not None and p["success"] >= threshold), None)


def run_row(run, metrics: dict | None, status: str, threshold: float = 0.9) -> dict:
    """The ``runs.csv`` row of ``run`` (with ``task``, ``method``, ``action``, ``seed``, ``experiment``,
    ``run_dir``); ``metrics``: its final ``metrics.json`` (``None`` unless finished)."""
    row = {k: None for k in CSV_FIELDS}
    row.update(task=run.task, method=run.method, action=run.action, seed=run.seed, experiment=run.experiment,
               status=status, run_dir=sweep_relative(run.run_dir))
    if metrics is not None:
        budget = metrics.get("budget") or {}
        # a planner (algo=mpc) trains nothing: no time to 90 %, and the sweep's training budget did not apply
        trained = metrics.get("iterations") != 0 and budget.get("stopped_by") != NO_TRAINING
        reached = time_to_success(learning_curve(run.run_dir, metrics), threshold) if trained else None
        row.update(success=round(metrics["success_rate"], 4), episodes=metrics.get("episodes"),
                   wall_clock_s=metrics.get("train_wall_clock_s"), cpu_s=metrics.get("train_cpu_s"),
                   env_steps=metrics.get("env_steps"), stopped_by=budget.get("stopped_by") if trained else NO_TRAINING,
                   budget_wall_clock_s=budget.get("wall_clock_s"), budget_env_steps=budget.get("env_steps"),
                   budget_cpu_s=budget.get("cpu_s"))
        made = metrics.get("provenance") or {}  # where and when the run trained (dexmots_rl.provenance)
        if made.get("cpu"):
            row.update(machine=f"{made['cpu']}, {made.get('cores', '?')} cores")
        row.update(commit=made.get("commit"), date=(made.get("date") or "")[:10] or None)
        if reached is not None:  # on the budget's clock
            row.update(time_to_90_s=reached.get(budget_clock(budget)), env_steps_to_90=reached["env_steps"])
    return row


def write_csv(rows: Iterable[dict], path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=CSV_FIELDS, extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: "" if row.get(k) is None else row[k] for k in CSV_FIELDS})
    return path


def sweep_relative(run_dir) -> str:
    """A run directory as ``runs.csv`` keeps it: relative to its sweep directory
    (``runs/<task>/<method>/<action>/seed<n>``), so a results archive names no folder of the machine that made
    it; a directory outside that layout is kept as given."""
    parts = Path(run_dir).parts
    return "/".join(parts[-5:]) if len(parts) >= 5 and parts[-5] == "runs" else str(run_dir)


def read_csv(path) -> list[dict]:
    """``runs.csv`` back as rows with numbers typed, empty cells ``None`` and ``run_dir`` a path: a relative one
    (the sweep's layout) under the folder of ``path``, an absolute one (older sweeps) as it is."""
    rows = []
    with open(path, newline="") as f:
        for raw in csv.DictReader(f):
            row = {k: (v if v != "" else None) for k, v in raw.items()}
            if row.get("run_dir") is not None:
                row["run_dir"] = Path(path).parent / row["run_dir"]  # an absolute run_dir stays itself
            for k in _INTS:
                if row.get(k) is not None:
                    row[k] = int(float(row[k]))
            for k in _FLOATS:
                if row.get(k) is not None:
                    row[k] = float(row[k])
            rows.append(row)
    return rows


def _grouped(rows: Iterable[dict], value: str) -> dict[tuple[str, str], list[float]]:
    groups: dict[tuple[str, str], list[float]] = {}
    for r in rows:
        if r.get("experiment", "table") == "table" and r.get("status") == "finished":
            groups.setdefault((r["task"], r["method"]), [])
            if r.get(value) is not None:
                groups[(r["task"], r["method"])].append(float(r[value]))
    return groups


def _mean_sd(values: Sequence[float]) -> tuple[float, float | None]:
    return statistics.fmean(values), (statistics.stdev(values) if len(values) > 1 else None)


def mean_sd_text(values: Sequence[float], scale: float = 1.0) -> str:
    """``values`` (times ``scale``: 100 for a success rate in %) as ``mean ± s.d.``, one value alone."""
    mean, sd = _mean_sd([scale * v for v in values])
    return f"{mean:.1f}" + (f" ± {sd:.1f}" if sd is not None else "")


def _header(methods, budget_column: bool = False) -> list[str]:
    return ["| Environment | " + " | ".join(label for _, label in methods) + (" | Budget" if budget_column else "")
            + " |", "|---|" + "---:|" * len(methods) + ("---|" if budget_column else "")]


def budget_cell(budget: Mapping) -> str:
    """A training budget in a few words: ``600 s``, ``2,000,000 env steps``, ``none``."""
    parts = []
    if budget.get("wall_clock_s") is not None:
        parts.append(f"{budget['wall_clock_s']:g} s")
    if budget.get("cpu_s") is not None:
        parts.append(f"{budget['cpu_s']:g} s CPU")
    if budget.get("env_steps") is not None:
        parts.append(f"{budget['env_steps']:,} env steps")
    return " or ".join(parts) or "none"


def _budget_phrase(budget: Mapping) -> str | None:
    parts = []
    if budget.get("wall_clock_s") is not None:
        parts.append(f"{budget['wall_clock_s']:g} s of training wall-clock (evaluations excluded)")
    if budget.get("cpu_s") is not None:
        parts.append(f"{budget['cpu_s']:g} s of training CPU time of the run's process (evaluations excluded)")
    if budget.get("env_steps") is not None:
        parts.append(f"{budget['env_steps']:,} env steps")
    return " or ".join(parts) if parts else None


def budget_text(budgets: Mapping[str, Mapping], rows: Sequence[dict]) -> str:
    """The table's budget sentence: ``budgets`` (task -> ``{wall_clock_s, env_steps}`` of every method of it)
    when all tasks share one, else a pointer to the Budget column; how the finished ``rows`` stopped; and a
    warning when the finished trained runs had more than one budget (per task when the tasks' budgets differ:
    runs.csv's ``budget_wall_clock_s``, ``budget_env_steps``)."""
    distinct = list({tuple(sorted(b.items())): b for b in budgets.values()}.values())
    per_task = len(distinct) > 1
    if per_task:
        text = ("Budget per run: the same for every method of a task, stated per task (Budget column; "
                "or the method's own schedule, if it ends first)")
    else:
        phrase = _budget_phrase(distinct[0]) if distinct else None
        text = ("Budget per run: " + phrase + " (or the method's own schedule, if it ends first)" if phrase else
                "Budget per run: none (each method's own schedule: algo.iterations / algo.total_frames)")
    stops = {}
    for r in rows:
        if r["status"] == "finished":
            stops[r["stopped_by"] or "unknown"] = stops.get(r["stopped_by"] or "unknown", 0) + 1
    if stops:
        text += "; runs stopped by " + ", ".join(f"{k} ({n})" for k, n in sorted(stops.items()))
    seen: dict[str | None, set] = {}
    for r in rows:  # a planner has no training budget
        if r["status"] == "finished" and r["stopped_by"] != NO_TRAINING:
            seen.setdefault(r["task"] if per_task else None, set()).add(
                (r["budget_wall_clock_s"], r["budget_env_steps"], r.get("budget_cpu_s")))
    mixed = {task: len(b) for task, b in seen.items() if len(b) > 1}
    if mixed and not per_task:
        text += (f". **Warning: the finished runs had {mixed[None]} different budgets** (runs.csv: "
                 "budget_wall_clock_s, budget_env_steps, budget_cpu_s); remove the odd ones' directories and rerun")
    elif mixed:
        text += (". **Warning: the finished runs of " + ", ".join(f"{t} ({n})" for t, n in mixed.items())
                 + " had different budgets within the task** (runs.csv: budget_wall_clock_s, budget_env_steps, "
                 "budget_cpu_s); "
                 "remove the odd ones' directories and rerun")
    return text + "."


def machines_text(rows: Sequence[dict]) -> str | None:
    """Which machines, commits and dates the finished ``rows`` ran on (runs.csv's ``machine``, ``commit``,
    ``date``), e.g. "Runs by machine: AMD EPYC, 2 cores (86), Intel Xeon, 2 cores (40); commit 14eda8d;
    2026-12-06." (None without any)."""
    finished = [r for r in rows if r["status"] == "finished"]

    def counted(key):
        counts: dict[str, int] = {}
        for r in finished:
            if r.get(key):
                counts[r[key]] = counts.get(r[key], 0) + 1
        return counts

    machines, commits, dates = counted("machine"), counted("commit"), sorted(counted("date"))
    if not machines:
        return None
    text = "Runs by machine: " + ", ".join(f"{m} ({n})" for m, n in sorted(machines.items()))
    if commits:
        text += "; " + ("commit " if len(commits) == 1 else "commits ") + ", ".join(
            f"{c} ({n})" if len(commits) > 1 else c for c, n in sorted(commits.items()))
    if dates:
        text += "; " + (dates[0] if len(dates) == 1 else f"{dates[0]} to {dates[-1]}")
    return text + "."


def markdown_table(rows: Iterable[dict], tasks: Sequence[tuple[str, str]], methods: Sequence[tuple[str, str]],
                   seeds: int | None = None, budgets: Mapping[str, str] | None = None) -> str:
    """Success (% of the evaluation episodes) per task (rows, ``(name, label)`` pairs) and method (columns),
    mean ± sample s.d. over the finished ``table`` runs; a single run shows its value alone, a cell with fewer
    runs than ``seeds`` says how many (``n=2``). The Average row (with more than one task) needs every task.
    ``budgets``: task -> its budget's words (:func:`budget_cell`), a last column."""
    groups = _grouped(rows, "success")
    lines = _header(methods, budgets is not None)
    tail = (lambda task: f" | {budgets.get(task, '')}") if budgets is not None else (lambda task: "")
    stats = {}
    for task, label in tasks:
        cells = []
        for method, _ in methods:
            values = groups.get((task, method)) or []
            if not values:
                cells.append(DASH)
                continue
            stats[(task, method)] = _mean_sd(values)
            cells.append(mean_sd_text(values, 100) + (f" (n={len(values)})" if seeds is not None and len(values) < seeds else ""))
        lines.append(f"| {label} | " + " | ".join(cells) + tail(task) + " |")
    if len(tasks) > 1:
        cells = []
        for method, _ in methods:
            per_task = [stats.get((task, method)) for task, _ in tasks]
            if any(s is None for s in per_task):
                cells.append(DASH)
                continue
            mean = statistics.fmean(m for m, _ in per_task)
            sds = [sd for _, sd in per_task]
            cells.append(f"{100 * mean:.1f}" + ("" if None in sds else f" ± {100 * statistics.fmean(sds):.1f}"))
        lines.append("| Average | " + " | ".join(cells) + tail(None) + " |")
    return "\n".join(lines)


def time_to_success_table(rows: Iterable[dict], tasks: Sequence[tuple[str, str]],
                          methods: Sequence[tuple[str, str]]) -> str:
    """Mean training time (s, on the budget's clock: runs.csv's ``time_to_90_s``) to 90 % success over the finished runs that reached it, and how many of
    the runs did (``84 s (2/3)``); ``–`` when none did; ``no training`` for a planner's runs."""
    rows = list(rows)
    reached = _grouped(rows, "time_to_90_s")
    runs = {key: len(v) for key, v in _grouped(rows, "success").items()}
    untrained = {}
    for r in rows:
        if r["status"] == "finished" and r["stopped_by"] == NO_TRAINING:
            untrained[(r["task"], r["method"])] = untrained.get((r["task"], r["method"]), 0) + 1
    lines = _header(methods)
    for task, label in tasks:
        cells = []
        for method, _ in methods:
            times, n = reached.get((task, method)) or [], runs.get((task, method), 0)
            if n and n == untrained.get((task, method), 0):
                cells.append("no training")
                continue
            cells.append(f"{statistics.fmean(times):.0f} s ({len(times)}/{n})" if times else
                         (f"{DASH} (0/{n})" if n else DASH))
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def action_space_runs(rows: Iterable[dict], task: str) -> dict[tuple[str, str], list[dict]]:
    """``task``'s finished runs of every experiment (the table's own ``vi`` runs count for ``vi``) by
    ``(method, action)``, each list in seed order: what Fig. 3b shows."""
    runs: dict[tuple[str, str], list[dict]] = {}
    for r in rows:
        if r["task"] == task and r.get("status") == "finished" and r.get("success") is not None:
            runs.setdefault((r["method"], r["action"]), []).append(r)
    return {key: sorted(done, key=lambda r: r["seed"]) for key, done in runs.items()}


def action_space_table(rows: Iterable[dict], task: str, methods: Sequence[tuple[str, str]],
                       actions: Sequence[str]) -> str:
    """``task``'s success (%) per method (rows, ``(name, label)`` pairs) and action space (columns) over
    :func:`action_space_runs`: each seed's value in seed order, their mean ± s.d. and, where runs reached
    90 %, the mean time to it (``(46 s, 3/3)``)."""
    runs = action_space_runs(rows, task)
    lines = ["| method | " + " | ".join(actions) + " |", "|---|" + "---:|" * len(actions)]
    for method, label in methods:
        cells = []
        for action in actions:
            done = runs.get((method, action), [])
            if not done:
                cells.append(DASH)
                continue
            cell = (" / ".join(f"{100 * float(r['success']):.0f}" for r in done) + ": "
                    + mean_sd_text([float(r["success"]) for r in done], 100))
            times = [float(r["time_to_90_s"]) for r in done if r.get("time_to_90_s") is not None]
            cells.append(cell + (f" ({statistics.fmean(times):.0f} s, {len(times)}/{len(done)})" if times else ""))
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def quoted_table(quoted: Mapping[str, Mapping[str, tuple[float, float]]], tasks: Sequence[tuple[str, str]],
                 methods: Sequence[tuple[str, str]]) -> str:
    """Table 2's layout for quoted figures (task -> method -> (mean, s.d.) in %), the rows of ``tasks`` that
    have any; the Average row (with more than one row) by :func:`markdown_table`'s rule, where every row has
    the method."""
    shown = [(task, label) for task, label in tasks if quoted.get(task)]
    lines = _header(methods)
    for task, label in shown:
        cells = [f"{quoted[task][m][0]:.1f} ± {quoted[task][m][1]:.1f}" if m in quoted[task] else DASH
                 for m, _ in methods]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    if len(shown) > 1:
        cells = []
        for method, _ in methods:
            values = [quoted[task].get(method) for task, _ in shown]
            cells.append(DASH if None in values else f"{statistics.fmean(v[0] for v in values):.1f} ± "
                                                      f"{statistics.fmean(v[1] for v in values):.1f}")
        lines.append("| Average | " + " | ".join(cells) + " |")
    return "\n".join(lines)
