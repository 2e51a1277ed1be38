"""``dexmots-table``'s figures (matplotlib, Agg backend), from the runs' learning curves and ``runs.csv`` rows.

* :func:`plot_learning_curves` — Fig. 3c: success vs env steps and vs training wall-clock for one task, one
  line per method. Each seed's curve
  (:func:`dexmots_rl.apps.table_writer.learning_curve`) is interpolated onto a common
  grid over the range every seed covers; the line is the mean over seeds, the band their min–max.
* :func:`plot_action_spaces` — Fig. 3b: success per action space (``task.action``) and method for one task,
  bars of the mean over seeds with ± s.d. error bars.

Example:
    >>> import tempfile, pathlib
    >>> curve = [{"env_steps": 100, "wall_clock_s": 1.0, "success": 0.2},
    ...          {"env_steps": 200, "wall_clock_s": 2.0, "success": 0.6}]
    >>> out = pathlib.Path(tempfile.mkdtemp()) / "curves.png"
    >>> fig = plot_learning_curves({"ppo": [curve, curve]}, {"ppo": "PPO"}, "Screw", out)
    >>> out.is_file(), [ax.get_xlabel() for ax in fig.axes]
    (True, ['env steps', 'training wall-clock (s)'])
"""

from __future__ import annotations

import statistics
from pathlib import Path
from typing import Mapping, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .plots import save_figure  # noqa: E402

__all__ = ["plot_action_spaces", "plot_learning_curves"]

#: the x axes of a learning curve: env steps, then training time on one of these clocks
TIME_AXES = {"wall_clock_s": "training wall-clock (s)", "cpu_s": "training CPU time (s)"}
GRID_POINTS = 100


def _xy(curve: Sequence[dict], x_key: str) -> tuple[np.ndarray, np.ndarray]:
    points = [(p[x_key], p["success"]) for p in curve if p.get(x_key) is not None and p.get("success") is not None]
    points.sort()
    return np.array([x for x, _ in points], float), 100 * np.array([y for _, y in points], float)


def _seed_spread(curves: Sequence[Sequence[dict]], x_key: str):
    """``(grid, mean, low, high)`` over the seeds, on the x range all of them cover; ``None`` if none."""
    seeds = [xy for xy in (_xy(c, x_key) for c in curves) if len(xy[0])]
    if not seeds:
        return None
    lo, hi = max(x[0] for x, _ in seeds), min(x[-1] for x, _ in seeds)
    if hi <= lo:  # one point each, or seeds that do not overlap: the points themselves
        grid = np.array(sorted({float(v) for x, _ in seeds for v in x}))
        values = np.array([np.interp(grid, x, y) for x, y in seeds])
    else:
        grid = np.linspace(lo, hi, GRID_POINTS)
        values = np.array([np.interp(grid, x, y) for x, y in seeds])
    return grid, values.mean(0), values.min(0), values.max(0)


def plot_learning_curves(curves: Mapping[str, Sequence[Sequence[dict]]], labels: Mapping[str, str], title: str,
                         out: str | Path | None = None, time_key: str = "wall_clock_s"):
    """``curves``: method → one curve per seed (lists of ``{"env_steps", "wall_clock_s", "cpu_s", "success"}``);
    ``labels``: method → legend label; ``time_key``: the time axis's clock (``wall_clock_s`` or ``cpu_s``).
    Returns the Figure (written to ``out`` when given)."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), constrained_layout=True)
    for ax, (x_key, x_label) in zip(axes, (("env_steps", "env steps"), (time_key, TIME_AXES[time_key]))):
        for method, seeds in curves.items():
            if seeds and all(len(c) == 1 and not c[0]["wall_clock_s"] for c in seeds):
                # a planner (algo=mpc) trains nothing: its evaluated success as a level, not a curve
                level = 100 * statistics.fmean(c[0]["success"] for c in seeds)
                n = len(seeds)
                ax.axhline(level, linestyle="--", linewidth=1.2, color=f"C{list(curves).index(method)}",
                           label=f"{labels.get(method, method)} ({n} seed{'s' if n > 1 else ''}, no training)")
                continue
            spread = _seed_spread(seeds, x_key)
            if spread is None:
                continue
            grid, mean, low, high = spread
            n = len(seeds)
            label = f"{labels.get(method, method)} ({n} seed{'s' if n > 1 else ''})"
            (line,) = ax.plot(grid, mean, color=f"C{list(curves).index(method)}", label=label)
            if n > 1:
                ax.fill_between(grid, low, high, color=line.get_color(), alpha=0.2, linewidth=0)
        ax.set_xlabel(x_label)
        ax.set_ylabel("success (%)")
        ax.set_ylim(-2, 102)
        ax.grid(alpha=0.3)
    if any(ax.get_lines() for ax in axes):
        axes[0].legend(fontsize=8, loc="best")
    fig.suptitle(f"{title}: success during training (mean over seeds, band: min–max)")
    if out is not None:
        save_figure(fig, out)
    return fig


def plot_action_spaces(values: Mapping[tuple[str, str], Sequence[float]], title: str,
                       methods: Sequence[tuple[str, str]], actions: Sequence[str], out: str | Path | None = None):
    """Bars of a task's success (%) per action space (groups) and method (bars, ``(name, label)`` pairs);
    ``values``: ``(method, action)`` -> the success (%) of each finished run
    (:func:`dexmots_rl.apps.table_writer.action_space_runs`); error bars: sample s.d. over seeds."""
    fig, ax = plt.subplots(figsize=(1.6 + 1.4 * len(actions), 3.6), constrained_layout=True)
    width = 0.8 / max(len(methods), 1)
    x = np.arange(len(actions))
    for i, (method, label) in enumerate(methods):
        runs = [values.get((method, a), []) for a in actions]
        means = [statistics.fmean(v) if v else float("nan") for v in runs]  # no bar where nothing finished
        sds = [statistics.stdev(v) if len(v) > 1 else 0.0 for v in runs]
        ax.bar(x + (i - (len(methods) - 1) / 2) * width, means, width, yerr=sds, capsize=3, label=label)
    ax.set_xticks(x, list(actions))
    ax.set_xlabel("action space (task.action)")
    ax.set_ylabel("success (%)")
    ax.set_ylim(0, 105)
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"{title}: success by action space")
    if out is not None:
        save_figure(fig, out)
    return fig
