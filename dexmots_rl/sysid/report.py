"""The identification report: ``report.txt``, ``report.json`` and three plots in a folder.

* ``params.png``: each parameter's value over the method's evaluations, relative to the truth where known
  (else to the answer);
* ``replay_error.png``: the training loss over the evaluations, with the held-out replay error at the initial
  guess and at the answer;
* ``trajectories.png``: predicted (initial guess and answer) against recorded object coordinates on a few
  held-out segments.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np
import torch

from ..atomic import atomic_write, atomic_write_json, json_safe
from .identify import Identification
from .problem import ShootingProblem

__all__ = ["format_report", "write_report"]

log = logging.getLogger(__name__)


def format_report(result: Identification, problem: ShootingProblem) -> str:
    """The report's text: the parameters (initial, identified, one standard deviation, truth and relative error
    where known), the condition number and the unidentifiable parameters, the replay errors and the cost."""
    lines = [f"data: {problem.traj.source} ({problem.traj.num_worlds} worlds x {problem.traj.num_frames} frames), "
             f"task {problem.traj.task['name']!r}",
             f"segments: {len(problem.train_index)} training, {len(problem.val_index)} held out, "
             f"{problem.steps} steps each; method {result.method}, {len(result.history) - 1} evaluations", ""]
    rel = result.relative_errors()
    head = f"{'parameter':<28}{'initial':>12}{'identified':>12}{'std':>11}"
    lines.append(head + (f"{'truth':>12}{'rel. error':>11}" if rel else ""))
    for n in result.names:
        row = f"{n:<28}{result.initial[n]:>12.5g}{result.values[n]:>12.5g}{result.std[n]:>11.3g}"
        lines.append(row + (f"{result.truth[n]:>12.5g}{100 * rel[n]:>10.2f}%" if rel else ""))
    lines += ["", f"Gauss-Newton matrix condition number: {result.condition_number:.3g}",
              "unidentifiable (the data cannot tell them apart): " + (", ".join(result.unidentifiable) or "none")]
    for name, err in (("training", result.train_error), ("held-out", result.validation_error)):
        if err:
            lines.append(f"{name} replay RMS (noise units): {err['initial']['rms']:.4g} initial -> "
                         f"{err['identified']['rms']:.4g} identified  ({_units(err['identified'])})")
    cost = result.history[-1]
    lines.append(f"cost: {cost['forward_steps']} simulated world-steps forward, {cost['backward_steps']} in reverse, "
                 f"{cost['cpu_seconds']:.1f} CPU s")
    return "\n".join(lines) + "\n"


def _units(err: dict) -> str:
    return ", ".join(f"{k} {v:.3g}" for k, v in err.items() if k != "rms")


def _plot_params(result, problem, ax) -> None:
    values = np.array([problem.space.values_np(h["z"]) for h in result.history])
    ref = result.truth or result.values
    for i, name in enumerate(result.names):
        ax.plot(values[:, i] / ref[name], label=name)
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.set_xlabel("evaluation")
    ax.set_ylabel("value / truth" if result.truth else "value / identified")
    ax.set_yscale("log")
    ax.legend(fontsize=7)


def _plot_error(result, ax) -> None:
    loss = np.array([h["loss"] for h in result.history])
    ax.plot(np.sqrt(loss), label="training RMS")
    if result.validation_error:
        last = len(loss) - 1
        ax.plot([0, last], [result.validation_error["initial"]["rms"], result.validation_error["identified"]["rms"]],
                "o", label="held-out RMS")
    ax.set_yscale("log")
    ax.set_xlabel("evaluation")
    ax.set_ylabel("replay RMS (noise units)")
    ax.legend(fontsize=7)


def _plot_trajectories(result, problem, fig, count: int = 4) -> None:
    index = (problem.val_index if len(problem.val_index) else problem.train_index)[:count]
    z0 = problem.space.to_z(problem.space.initial)
    z1 = problem.space.to_z([result.values[n] for n in result.names])
    scales = problem.scales.numpy()
    preds = []
    with torch.no_grad():
        for z in (z0, z1):
            zt = torch.as_tensor(z, dtype=problem.dtype).expand(len(index), -1)
            preds.append(problem.residuals(zt, index).numpy() * scales + problem.target[index].numpy())
    recorded = problem.target[index].numpy()
    first = problem.env.sim.nu - problem.first  # the object's first coordinate among the compared ones
    coordinate = first + int(np.argmax(recorded[..., first:].std(axis=(0, 1))))  # the object's that moves most
    t = np.arange(1, problem.steps + 1) * problem.traj.dt
    for k in range(len(index)):
        ax = fig.add_subplot(1, len(index), k + 1)
        ax.plot(t, recorded[k, :, coordinate], "k.", label="recorded")
        ax.plot(t, preds[0][k, :, coordinate], "--", label="initial guess")
        ax.plot(t, preds[1][k, :, coordinate], "-", label="identified")
        ax.set_xlabel("s")
        ax.set_ylabel({"position": "m", "angle": "rad", "quaternion": "quaternion entry"}[problem.kinds[coordinate]])
        ax.set_title(f"segment {int(index[k])}, object coordinate {coordinate - first}", fontsize=8)
    fig.axes[0].legend(fontsize=7)


def write_report(result: Identification, problem: ShootingProblem, folder: str | os.PathLike) -> Path:
    """Write ``report.txt``, ``report.json`` and the plots to ``folder``; returns it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    text = format_report(result, problem)
    atomic_write(folder / "report.txt", lambda f: f.write(text.encode()))
    summary = result.summary()
    summary["correlation"] = result.correlation.tolist()
    atomic_write_json(folder / "report.json", json_safe(summary))
    for name, draw in (("params.png", lambda fig: _plot_params(result, problem, fig.add_subplot())),
                       ("replay_error.png", lambda fig: _plot_error(result, fig.add_subplot())),
                       ("trajectories.png", lambda fig: _plot_trajectories(result, problem, fig))):
        fig = plt.figure(figsize=(10, 3.5) if name == "trajectories.png" else (5, 3.5))
        draw(fig)
        fig.tight_layout()
        atomic_write(folder / name, lambda f: fig.savefig(f, format="png", dpi=100))
        plt.close(fig)
    log.info("wrote the report to %s", folder)
    return folder
