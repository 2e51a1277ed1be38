"""Pre-grasp files and the inverse kinematics the pre-grasp search shares.

A pre-grasp is a hand pose that touches an object where a task needs it (our stand-in for the paper's
DexGraspNet samples). :mod:`.object_pregrasp` finds them for the articulated objects of task ``operate`` and
the tool tasks built on it (fingertip inverse kinematics with :func:`_solve_ik`, settled in our simulator,
checked in MuJoCo's geometry). They are stored per object in a JSON file (format, task, object, seed, poses;
written atomically by :func:`save_pregrasps`): the package ships one per library object
(``assets/pregrasps/operate/<object>.json``); ``dexmots-pregrasp`` writes a new one where the user says,
deterministically for a seed, and a task uses it with ``task.pregrasps=<file>``. A file is read, and checked
whole (:func:`load_pregrasps`), when its task's env is built.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

__all__ = ["PregraspError", "load_pregrasps", "save_pregrasps"]

log = logging.getLogger(__name__)

FORMAT = "dexmots-pregrasps-v1"


class PregraspError(ValueError):
    """No valid pre-grasp was found, or a pre-grasp file is missing or malformed."""


def _finger_sites(model, scene) -> list[tuple[int, list[int], int]]:
    """Per finger: (tip site id, its qpos indices, its tip geom id)."""
    import mujoco

    out = []
    for f, name in enumerate(scene.finger_names):
        site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, f"{name}_tip")
        geom = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, f"{name}_tip")
        if site < 0 or geom < 0:
            raise PregraspError(f"scene {scene.path}: finger {name!r} needs a site and a geom named {name}_tip")
        joints = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j)
                  for j in scene.joint_names[f * scene.joints_per_finger:(f + 1) * scene.joints_per_finger]]
        out.append((site, [int(model.jnt_qposadr[j]) for j in joints], geom))
    return out


def _solve_ik(model, data, q, site: int, qidx: list[int], target: np.ndarray, iterations: int = 200) -> None:
    """Move ``q[qidx]`` so that ``site`` reaches ``target`` (in place): damped least squares, clamped."""
    import mujoco

    jac = np.zeros((3, model.nv))
    lo, hi = model.jnt_range[[model.dof_jntid[i] for i in qidx]].T
    for _ in range(iterations):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        err = target - data.site_xpos[site]
        if np.linalg.norm(err) < 1e-5:
            break
        mujoco.mj_comPos(model, data)
        mujoco.mj_jacSite(model, data, jac, None, site)
        j = jac[:, qidx]
        step = j.T @ np.linalg.solve(j @ j.T + 1e-4 * np.eye(3), err)
        q[qidx] = np.clip(q[qidx] + np.clip(step, -0.2, 0.2), lo, hi)


def save_pregrasps(path, task: str, poses: np.ndarray, seed: int, **fields) -> None:
    """Write pre-grasps atomically (JSON: format, task, seed, poses, and ``fields``, e.g. ``object``)."""
    from ..atomic import atomic_write_json

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(path, {"format": FORMAT, "task": task, **fields, "seed": seed,
                             "poses": [[round(float(x), 6) for x in p] for p in poses]})


#: rad: how far past a joint limit a stored pose may lie (the files round to 1e-6 rad)
LIMIT_TOLERANCE = 1e-3


def load_pregrasps(path, num_dofs: int, task: str | None = None, lower=None, upper=None,
                   object_name: str | None = None) -> np.ndarray:
    """Pre-grasps [K, num_dofs] from ``path``, the whole file checked: its format, its ``task`` (when ``task``
    is given, the file must be that task's), and every entry of ``poses`` (a list of ``num_dofs`` finite
    joint angles, within ``[lower, upper]`` per joint when given, rad). One :class:`PregraspError` naming
    the file and the first bad field or entry (``poses[2][5]``) otherwise; nothing is clamped. With
    ``object_name``, a file that names its ``object`` must name that one."""
    path = Path(path)
    if not path.is_file():
        raise PregraspError(f"{path}: no pre-grasp file (write one with: dexmots-pregrasp --task <name>)")
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise PregraspError(f"{path}: not a pre-grasp file ({e})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise PregraspError(f"{path}: field 'format' must be {FORMAT!r}")
    if task is not None and data.get("task") != task:
        raise PregraspError(f"{path}: field 'task' is {data.get('task')!r}, but the file is loaded for task {task!r} "
                            "(a pre-grasp file holds one task's hand poses)")
    if object_name is not None and data.get("object", object_name) != object_name:
        raise PregraspError(f"{path}: field 'object' is {data.get('object')!r}, but the file is loaded for object "
                            f"{object_name!r} (a pre-grasp file holds one object's hand poses)")
    poses = data.get("poses")
    if not isinstance(poses, list) or not poses:
        raise PregraspError(f"{path}: field 'poses' must be a non-empty list of poses ({num_dofs} joint angles each)")
    for i, pose in enumerate(poses):
        if not isinstance(pose, list) or len(pose) != num_dofs:
            size = f"{len(pose)} values" if isinstance(pose, list) else type(pose).__name__
            raise PregraspError(f"{path}: poses[{i}] must be a list of {num_dofs} joint angles, got {size}")
        for j, q in enumerate(pose):
            if isinstance(q, bool) or not isinstance(q, (int, float)) or not np.isfinite(q):
                raise PregraspError(f"{path}: poses[{i}][{j}] must be a finite joint angle (rad), got {q!r}")
            if lower is not None and not lower[j] - LIMIT_TOLERANCE <= q <= upper[j] + LIMIT_TOLERANCE:
                raise PregraspError(f"{path}: poses[{i}][{j}] = {q:g} rad is outside joint {j}'s range "
                                    f"[{lower[j]:.4g}, {upper[j]:.4g}]")
    return np.asarray(poses, dtype=np.float64)