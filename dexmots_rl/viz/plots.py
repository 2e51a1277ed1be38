"""Matplotlib figures (Agg backend): the objective landscape of the paper's Fig. 4, and learning curves.

**Landscape** (:func:`landscape_data`, :func:`plot_landscape`): the screw-claw hand closes on the knob with
the scripted controller of :mod:`dexmots_rl.envs.tasks.screw_claw` until the fingers touch it; from that one
state, every action of a grid over the two distal joints (the other joints keep the scripted action) is
stepped once in a batch of worlds with ``differentiable=True``, and the one-step objectives

* pose only:      ``J_p  = exp(-|θ - θ̄| / pose_scale)``                         (:func:`angle_tracking_reward`)
* pose + wrench:  ``J_pw = J_p + exp(-‖(Δf / force_scale, Δτ / torque_scale)‖)``  (+ :func:`wrench_reward`)

are differentiated through the simulator with respect to the actions (``∂J/∂a``, the arrows). The
reference ``θ̄`` (knob angle) and ``ω̄ = (f̄, τ̄)`` (contact wrench on the knob) are what the grid's centre
action ``a*`` produces. The two panels share one colour scale of ``J - J(a*)`` and one arrow scale, so
what looks flat is flat for the optimiser too; the titles give each panel's range and median ``|∇J|``.
Worlds are doubled (one copy per objective) so one backward pass gives both gradients.

**Curves** (:func:`load_scalars`, :func:`plot_curves`): torchrl ``CSVLogger`` output,
``<run_dir>/<exp_name>/scalars/<name>.csv`` with rows ``step,value`` (any ``*.csv`` below a run dir is
read), one panel per scalar name, one line per run.

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
import logging
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

__all__ = ["landscape_data", "plot_landscape", "load_scalars", "plot_curves", "save_figure"]

log = logging.getLogger(__name__)

STATE_KEYS = (("sim", "joint_q"), ("sim", "joint_qd"), ("sim", "params"), ("task", "goal"))


def _grid_axis(centre: float, span: float, grid: int) -> np.ndarray:
    """``grid`` values spanning ``2 span`` about ``centre``, shifted to stay inside the action box [-1, 1]."""
    lo = min(max(centre - span, -1.0), 1.0 - 2.0 * span)
    return lo + np.linspace(0.0, 2.0 * span, grid)


def landscape_data(task: str = "screw_claw", grid: int = 21, span: float = 0.5,
                   joints: tuple[int, int] = (1, 3), contact_steps: int = 2, max_settle_steps: int = 60, pose_scale: float | None = None,
                   force_scale: float | None = None, torque_scale: float | None = None, squeeze: float = 0.6,
                   twist: float = 0.0, seed: int = 0, dtype: torch.dtype = torch.float32) -> dict:
    """Objective values and gradients over an action grid from one contact state (module docstring).

    ``joints``: the two action entries on the axes (default: right distal, left distal); ``span``: half
    width of the grid in action units; ``contact_steps``: closing steps taken after the first contact;
    ``pose_scale`` defaults to the task's reward scale (0.5 rad for screw_claw); ``force_scale`` /
    ``torque_scale`` default to ``‖f̄‖`` and ``‖f̄‖ R`` (R: the object's bounding radius), i.e. the wrench
    error relative to the reference contact force; ``squeeze`` / ``twist``: the
    scripted controller's closing and twisting actions (settling and the joints off the axes). Returns numpy arrays ``u``,
    ``v`` [G] (axis values), ``J_pose``, ``J_pose_wrench`` [G, G] (index ``[i, j]`` = ``(u[i], v[j])``),
    ``grad_pose``, ``grad_pose_wrench`` [G, G, 2], ``theta``, ``torque`` [G, G], and scalars.
    """
    if grid < 3 or grid % 2 == 0:
        raise ValueError(f"grid must be an odd integer >= 3 (the centre is the reference), got {grid}")
    if not 0 < span <= 1:
        raise ValueError(f"span must be in (0, 1], got {span}")
    from torchrl.envs.utils import step_mdp

    from ..envs import make_env
    from ..envs.rewards import angle_tracking_reward, wrench_reward
    from ..envs.tasks.screw_claw import scripted_claw_action

    if task != "screw_claw":
        raise ValueError(f"the landscape's scripted closing controller is for screw_claw only, got {task!r}")
    g2 = grid * grid
    n = 2 * g2  # one copy of the grid per objective: a single backward pass gives both gradients
    env = make_env(task, num_envs=n, differentiable=True, seed=seed, raw=True, dtype=dtype, action="torque")
    pose_scale = env.pose_scale if pose_scale is None else pose_scale
    td = env.reset()
    for key in STATE_KEYS:  # every world starts from world 0's state
        value = td.get(key)
        td.set(key, value[:1].expand(value.shape).clone())
    touched, steps = 0, 0
    with torch.no_grad():
        while touched <= contact_steps:
            if steps >= max_settle_steps:
                raise RuntimeError(f"no contact after {max_settle_steps} closing steps")
            action = scripted_claw_action(td.get(("task", "goal")), squeeze, twist).to(dtype).expand(n, -1).contiguous()
            td = step_mdp(env.step(td.set("action", action)))
            steps += 1
            touched += int(td.get(("object", "contact_force"))[0, 0] > 0) if touched == 0 else 1
    base = scripted_claw_action(td.get(("task", "goal"))[:1], squeeze, twist)[0].to(dtype)
    u = _grid_axis(float(base[joints[0]]), span, grid)
    v = _grid_axis(float(base[joints[1]]), span, grid)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    actions = base.repeat(n, 1)
    actions[:, joints[0]] = torch.as_tensor(np.tile(uu.ravel(), 2), dtype=dtype)
    actions[:, joints[1]] = torch.as_tensor(np.tile(vv.ravel(), 2), dtype=dtype)
    actions.requires_grad_(True)
    out = env.step(td.clone().set("action", actions)).get("next")
    theta, wrench = out.get(("object", "q")), out.get(("object", "wrench"))
    centre = (grid // 2) * grid + grid // 2
    theta_ref, wrench_ref = theta[centre].detach(), wrench[centre].detach()
    f_ref = max(float(wrench_ref[:3].norm()), 1e-6)
    force_scale = f_ref if force_scale is None else force_scale
    torque_scale = f_ref * env.sim.scene.object_bound if torque_scale is None else torque_scale
    j_pose = angle_tracking_reward(theta, theta_ref, pose_scale)
    j_pw = j_pose + wrench_reward(wrench, wrench_ref, force_scale, torque_scale)
    (j_pose[:g2].sum() + j_pw[g2:].sum()).backward()
    grad = actions.grad[:, list(joints)].detach().double().numpy()
    axis = torch.as_tensor(env.sim.scene.object_base_rot @ env.sim.scene.object_axis, dtype=dtype)

    def grid_of(x):
        return np.asarray(x.detach().double().numpy()).reshape(grid, grid, *x.shape[1:])

    force = out.get(("object", "contact_force")).detach()
    return {
        "u": u, "v": v,
        "J_pose": grid_of(j_pose[:g2, 0]), "J_pose_wrench": grid_of(j_pw[g2:, 0]),
        "grad_pose": grad[:g2].reshape(grid, grid, 2), "grad_pose_wrench": grad[g2:].reshape(grid, grid, 2),
        "theta": grid_of(theta[:g2, 0]), "torque": grid_of((wrench[:g2, 3:] * axis).sum(-1)),
        "reference_action": base.double().numpy().copy(), "centre": (float(u[grid // 2]), float(v[grid // 2])),
        "joint_names": [env.sim.scene.joint_names[j] for j in joints],
        "settle_steps": steps, "contact_force_min": float(force.min()), "contact_force_max": float(force.max()),
        "pose_scale": float(pose_scale), "force_scale": float(force_scale), "torque_scale": float(torque_scale),
        "task": task,
    }


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
        if scalars:
            runs[run.name or str(run)] = scalars
    if not runs:
        raise FileNotFoundError("no scalar CSV files (rows 'step,value') found under "
                                + ", ".join(repr(str(r)) for r in run_dirs))
    return runs


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
