"""Pose-only demonstrations: an object trajectory the policy is conditioned on and rewarded for following.

A demonstration says how the object moved, not how hard it was pushed (the paper's Exp. 3: follow a
pose-only demonstration). ``make_env(task, demo="<file>")`` (or ``task.demo=<file>`` for ``dexmots-train``;
``demo="shipped"``: the one the package ships for each tool task, ``scripts/make_demos.py``) reads one, derives the generalised forces that motion needs, and uses it where the task's own reference
would be: the goal window the policy sees, the pose and wrench reward terms, and the goal (the
demonstration's last row).

File layout (``.npz`` or a ``.pt`` dict of tensors), one demonstration of T rows:

======== ========== ============================================================================
key      shape      meaning
======== ========== ============================================================================
dt       scalar     s between rows (any; resampled to the env's control step, 1/60 s)
joint_q  [T, K]     rad or m: the task's reference coordinates (a knob's angle, an operated joint)
pos      [T, 3]     m, world frame: the object's (base's) position; optional, default: where it stands
quat     [T, 4]     wxyz: its orientation; optional, default: as it stands
======== ========== ============================================================================

The generalised force of an articulation is what the task's *nominal* part needs for the demonstrated
motion, by the same law as the task's analytic reference (:func:`part_torque`: damping, smoothed Coulomb
friction and spring, velocities by central finite differences); a free body's wrench comes from its poses
(:func:`~dexmots_rl.trajectories.wrenches_from_poses`). A bad file raises one
:class:`~dexmots_rl.trajectories.TrajectoryFormatError` naming the file and the field.

Example:
    >>> import numpy as np, torch
    >>> demo = {"dt": 0.1, "joint_q": np.linspace(0.0, 1.0, 11)[:, None]}
    >>> rows = resample(read_demo(demo), 0.05)
    >>> rows["joint_q"].shape, round(float(rows["joint_q"][1, 0]), 3)
    (torch.Size([21, 1]), 0.05)
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from ..quaternions import slerp
from ..trajectories import PoseWrenchTrajectory, TrajectoryFormatError, wrenches_from_poses
from ..trajectories.joint_law import FRICTION_VELOCITY, part_torque

__all__ = ["FRICTION_VELOCITY", "SHIPPED", "demo_path", "demo_trajectory", "part_torque", "read_demo", "resample"]

SHIPPED = "shipped"  # task.demo=shipped: the demonstration the package ships for the task
MAX_ROWS = 100_000  # a demonstration longer than this (~28 min at 60 Hz) is not an episode's motion


def demo_path(task: str, demo):
    """Where ``task.demo`` points: ``"shipped"`` is the package's demonstration of ``task``
    (``assets/demos/<task>.npz``, made by ``scripts/make_demos.py``), anything else is returned as given."""
    if demo != SHIPPED:
        return demo
    from ..assets import ASSET_DIR

    path = ASSET_DIR / "demos" / f"{task}.npz"
    if not path.is_file():
        shipped = sorted(p.stem for p in (ASSET_DIR / "demos").glob("*.npz"))
        raise TrajectoryFormatError(f"task.demo=shipped: task {task!r} ships no demonstration (tasks that do: "
                                    f"{', '.join(shipped)}); give a file")
    return path


def _load(source) -> tuple[dict, str]:
    if isinstance(source, dict):
        return dict(source), "<dict>"
    path = Path(os.fspath(source)).expanduser()
    if not path.is_file():
        raise TrajectoryFormatError(f"demo {path}: file not found")
    try:
        if path.suffix == ".npz":
            with np.load(path, allow_pickle=False) as data:
                return {k: data[k] for k in data.files}, str(path)
        data = torch.load(path, map_location="cpu", weights_only=True)
    except TrajectoryFormatError:
        raise
    except Exception as exc:  # a truncated or foreign file: one line naming it
        raise TrajectoryFormatError(f"demo {path}: not a readable .npz or .pt file ({type(exc).__name__})") from None
    if not isinstance(data, dict):
        raise TrajectoryFormatError(f"demo {path}: expected a dict of arrays, got {type(data).__name__}")
    return data, str(path)


def _field(data: dict, key: str, where: str, width: int | None, rows: int | None) -> torch.Tensor | None:
    if key not in data:
        return None
    try:
        value = torch.as_tensor(np.asarray(data[key], dtype=np.float64))
    except (TypeError, ValueError):
        raise TrajectoryFormatError(f"demo {where}: field {key!r} is not numeric") from None
    if key == "joint_q" and value.ndim == 1:
        value = value[:, None]
    if value.ndim != 2 or (width is not None and value.shape[1] != width) or value.shape[0] < 2:
        want = f"[T, {width if width is not None else 'K'}] with T >= 2"
        raise TrajectoryFormatError(f"demo {where}: field {key!r} must be {want}, got {tuple(value.shape)}")
    if rows is not None and value.shape[0] != rows:
        raise TrajectoryFormatError(f"demo {where}: field {key!r} has {value.shape[0]} rows, 'joint_q' {rows}")
    if value.shape[0] > MAX_ROWS:
        raise TrajectoryFormatError(f"demo {where}: field {key!r} has {value.shape[0]} rows (at most {MAX_ROWS})")
    if not bool(torch.isfinite(value).all()):
        raise TrajectoryFormatError(f"demo {where}: field {key!r} contains non-finite values")
    return value


def read_demo(source) -> dict:
    """A demonstration (a path, or a dict in the file's layout) checked whole: ``{"dt": float, "joint_q": [T,
    K], "pos": [T, 3] | None, "quat": [T, 4] | None}`` in float64, quaternions normalised."""
    data, where = _load(source)
    unknown = sorted(set(data) - {"dt", "joint_q", "pos", "quat"})
    if unknown:
        raise TrajectoryFormatError(f"demo {where}: unknown field {unknown[0]!r} (fields: dt, joint_q, pos, quat)")
    if "dt" not in data:
        raise TrajectoryFormatError(f"demo {where}: field 'dt' is missing")
    try:
        dt = float(np.asarray(data["dt"]).reshape(()))
    except (TypeError, ValueError):
        raise TrajectoryFormatError(f"demo {where}: field 'dt' must be one number (s)") from None
    if not np.isfinite(dt) or dt <= 0:
        raise TrajectoryFormatError(f"demo {where}: field 'dt' must be a positive number of seconds, got {dt}")
    joint_q = _field(data, "joint_q", where, None, None)
    if joint_q is None:
        raise TrajectoryFormatError(f"demo {where}: field 'joint_q' is missing")
    pos = _field(data, "pos", where, 3, joint_q.shape[0])
    quat = _field(data, "quat", where, 4, joint_q.shape[0])
    if quat is not None:
        norm = quat.norm(dim=-1, keepdim=True)
        if bool((norm < 1e-8).any()):
            raise TrajectoryFormatError(f"demo {where}: field 'quat' has zero-length quaternions")
        quat = quat / norm
    return {"dt": dt, "joint_q": joint_q, "pos": pos, "quat": quat, "source": where}


def resample(demo: dict, dt: float) -> dict:
    """The demonstration at time step ``dt`` (linear in ``joint_q`` and ``pos``, spherical in ``quat``), over
    the same duration; rows past the last sample hold it."""
    rows = demo["joint_q"].shape[0]
    duration = (rows - 1) * demo["dt"]
    count = int(round(duration / dt)) + 1
    t = torch.arange(count, dtype=torch.float64) * dt / demo["dt"]
    lo = t.floor().long().clamp(max=rows - 1)
    hi = (lo + 1).clamp(max=rows - 1)
    frac = (t - lo).unsqueeze(-1)
    out = dict(demo, dt=dt)
    for key in ("joint_q", "pos"):
        if demo[key] is not None:
            out[key] = demo[key][lo] * (1 - frac) + demo[key][hi] * frac
    if demo["quat"] is not None:
        out["quat"] = slerp(demo["quat"][lo], demo["quat"][hi], frac)
    return out


def demo_trajectory(demo: dict, dt: float, pos, quat, nominal, mass: float = 0.0, inertia=None) -> PoseWrenchTrajectory:
    """The :class:`PoseWrenchTrajectory` an articulated task follows: ``demo`` resampled to ``dt``, the pose
    ``pos`` [3] / ``quat`` [4] where the file gives none, each joint's force by :func:`part_torque` with
    ``nominal`` (damping, friction, stiffness, rest; each a float or a [K] sequence), and, where the file
    moves the object, the net wrench of a body of ``mass`` (kg) and ``inertia`` [3, 3] (kg m^2) through
    those poses (zero for an object held where it stands)."""
    joints = len(torch.atleast_1d(torch.as_tensor(nominal[0])))
    if demo["joint_q"].shape[1] != joints:
        raise TrajectoryFormatError(f"demo {demo.get('source', '<dict>')}: field 'joint_q' must have {joints} "
                                    f"column(s) (the task's reference joints), got {demo['joint_q'].shape[1]}")
    rows = resample(demo, dt)
    joint_q = rows["joint_q"]
    count = joint_q.shape[0]
    speed = torch.gradient(joint_q, spacing=dt, dim=0, edge_order=2)[0]
    nominal = tuple(torch.as_tensor(v, dtype=torch.float64) for v in nominal)
    torque = part_torque(speed, joint_q, nominal)
    p = rows["pos"] if rows["pos"] is not None else torch.as_tensor(pos, dtype=torch.float64).expand(count, 3)
    q = rows["quat"] if rows["quat"] is not None else torch.as_tensor(quat, dtype=torch.float64).expand(count, 4)
    wrench = torch.zeros(count, 6, dtype=torch.float64)  # a held base: no net wrench
    if (rows["pos"] is not None or rows["quat"] is not None) and mass > 0 and inertia is not None:
        wrench = wrenches_from_poses(p, q, dt, mass, torch.as_tensor(inertia, dtype=torch.float64))
    return PoseWrenchTrajectory(p.contiguous(), q.contiguous(), wrench, dt, joint_q=joint_q, joint_torque=torque)
