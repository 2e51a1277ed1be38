"""Matplotlib figures (Agg backend): the objective landscape of the paper's Fig. 4, and learning curves.

**Landscape** (:func:`plot_landscape`): the two panels of the one-step objectives over an action grid near
contact, from the data :func:`dexmots_rl.apps.landscape.landscape_data` computes through the simulator.

**Curves** (:func:`load_scalars`, :func:`plot_curves`): torchrl ``CSVLogger`` output,
``<run_dir>/<exp_name>/scalars/<name>.csv`` with rows ``step,value`` (any ``*.csv`` below a run dir is
read), one panel per scalar name, one line per run; a run's final evaluation (its ``metrics.json``) is the last
point of its ``eval_*`` curves.

Example:
    >>> import tempfile, pathlib
    >>> from dexmots_rl.viz.plots import plot_curves
    >>> run = pathlib.Path(tempfile.mkdtemp()) / "exp" / "scalars"
    >>> run.mkdir(parents=True)
    >>> _ = (run / "reward.csv").write_text("0,0.1\\n10,0.5\\n")
    >>> fig = plot_curves([run.parent.parent])
    >>> [ax.get_title() for ax in fig.axes]
    ['reward']
"""

from __future__ import annotations

import csv
import json
import logging
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

__all__ = ["plot_landscape", "load_scalars", "plot_curves", "save_figure"]

log = logging.getLogger(__name__)

def _summary(j: np.ndarray, grad: np.ndarray) -> dict:
    norm = np.linalg.norm(grad, axis=-1)
    return {"range": float(j.max() - j.min()), "median_grad": float(np.median(norm)), "max_grad": float(norm.max())}


def plot_landscape(data: dict, out: str | Path | None = None):
    """Two panels (pose only, pose + wrench) of ``J - J(a*)`` with ``∂J/∂a`` arrows; returns the Figure.

    Also returns the per-panel numbers in ``fig.landscape_summary`` (range, median and max ``|∇J|``).
    """
    u, v = data["u"], data["v"]
    c = len(u) // 2
    panels = [("pose only", data["J_pose"], data["grad_pose"]),
              ("pose + wrench", data["J_pose_wrench"], data["grad_pose_wrench"])]
    rel = [j - j[c, c] for _, j, _ in panels]
    lo, hi = min(r.min() for r in rel), max(r.max() for r in rel)
    if hi - lo < 1e-12:
        lo, hi = lo - 1e-6, hi + 1e-6
    levels = np.linspace(lo, hi, 21)
    gmax = max(np.linalg.norm(g, axis=-1).max() for _, _, g in panels) or 1.0
    step = (u[-1] - u[0]) / max(len(u) - 1, 1)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.8), constrained_layout=True)
    summary = {}
    for ax, (name, j, g), r in zip(axes, panels, rel):
        cs = ax.contourf(u, v, r.T, levels=levels, cmap="viridis")
        ax.contour(u, v, r.T, levels=levels, colors="k", linewidths=0.3, alpha=0.4)
        # one arrow scale for both panels: the largest gradient spans 1.5 grid cells
        ax.quiver(u, v, g[..., 0].T, g[..., 1].T, angles="xy", scale_units="xy", scale=gmax / (1.5 * step),
                  color="w", width=0.004)
        ax.plot(*data["centre"], marker="*", color="r", markersize=12, label="a* (reference)")
        s = summary[name] = _summary(j, g)
        ax.set_title(f"{name}\nrange {s['range']:.2e}, median |∇J| {s['median_grad']:.2e}")
        ax.set_xlabel(f"action: {data['joint_names'][0]}")
        ax.set_ylabel(f"action: {data['joint_names'][1]}")
        ax.set_aspect("equal")
    axes[0].legend(loc="upper right", fontsize=8)
    fig.colorbar(cs, ax=list(axes), label="J(a) - J(a*)  (one-step objective, shared scale)")
    fig.suptitle(f"{data['task']}: one-step objective near contact, arrows ∂J/∂a through the simulator")
    fig.landscape_summary = summary
    if out is not None:
        save_figure(fig, out)
    return fig


def load_scalars(run_dirs) -> dict[str, dict[str, np.ndarray]]:
    """``{run label: {scalar name: array [K, 2] of (step, value)}}`` from every ``*.csv`` below each run
    dir (torchrl CSVLogger layout). Raises ``FileNotFoundError`` naming the dirs when nothing is found."""
    runs: dict[str, dict[str, np.ndarray]] = {}
    for run in run_dirs:
        run = Path(run)
        if not run.is_dir():
            raise FileNotFoundError(f"run directory {str(run)!r} does not exist")
        scalars = {}
        for path in sorted(run.rglob("*.csv")):
            rows = []
            with open(path, newline="") as f:
                for row in csv.reader(f):
                    try:
                        rows.append((float(row[0]), float(row[1])))
                    except (ValueError, IndexError):
                        continue  # header or malformed line
            if rows:
                name = path.stem if path.stem not in scalars else str(path.relative_to(run).with_suffix(""))
                scalars[name] = np.asarray(sorted(rows))
        _add_final_evaluation(run, scalars)
        if scalars:
            runs[run.name or str(run)] = scalars
    if not runs:
        raise FileNotFoundError("no scalar CSV files (rows 'step,value') found under "
                                + ", ".join(repr(str(r)) for r in run_dirs))
    return runs


def _add_final_evaluation(run: Path, scalars: dict[str, np.ndarray]) -> None:
    """The run's final evaluation (``metrics.json``, at its last iteration) as the last point of its ``eval_*``
    curves, which the logger holds only for the periodic evaluations; ``eval_success_rate`` always."""
    try:
        metrics = json.loads((run / "metrics.json").read_text())
    except (OSError, ValueError):  # no final evaluation (yet), or a file being written
        return
    step = metrics.get("iterations")
    if not isinstance(step, (int, float)):
        return
    for key, value in metrics.items():
        name = f"eval_{key}"
        if isinstance(value, (int, float)) and not isinstance(value, bool) and (
                name in scalars or key == "success_rate"):
            earlier = scalars.get(name, np.zeros((0, 2)))
            scalars[name] = np.concatenate([earlier[earlier[:, 0] < step], [[float(step), float(value)]]])


def plot_curves(run_dirs, keys: list[str] | None = None, out: str | Path | None = None, smooth: int = 1):
    """One panel per scalar name (``keys``, default: all found), one line per run; x is the logged step.
    ``smooth`` > 1 applies a moving average of that many points. Returns the Figure."""
    runs = load_scalars(run_dirs)
    names = keys or sorted({k for s in runs.values() for k in s})
    missing = [k for k in names if not any(k in s for s in runs.values())]
    if missing:
        raise KeyError(f"scalars {missing} not found; available: {sorted({k for s in runs.values() for k in s})}")
    cols = min(3, len(names))
    rows = math.ceil(len(names) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.5 * cols, 3.2 * rows), squeeze=False, constrained_layout=True)
    for ax, name in zip(axes.flat, names):
        for label, scalars in runs.items():
            if name in scalars:
                x, y = scalars[name][:, 0], scalars[name][:, 1]
                if smooth > 1 and len(y) >= smooth:
                    y = np.convolve(y, np.ones(smooth) / smooth, mode="valid")
                    x = x[smooth - 1 :]
                ax.plot(x, y, label=label)
        ax.set_title(name)
        ax.set_xlabel("step")
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(names):]:
        ax.remove()
    if len(runs) > 1:
        axes.flat[0].legend(fontsize=8)
    if out is not None:
        save_figure(fig, out)
    return fig


def save_figure(fig, out: str | Path, dpi: int = 120) -> Path:
    """Write ``fig`` to ``out`` (parent dirs created) and return the path."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    log.info("wrote %s", out)
    return out
