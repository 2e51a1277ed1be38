"""Pre-grasps found through the simulator: hand poses that touch an object where a task needs it.

Our stand-in for the paper's DexGraspNet samples. A task names, per finger, a region on one of the
scene's box geoms (:class:`ContactRegion`: a point on a face, the face's outward normal and how far the
point may move on the face). :func:`find_pregrasps` then, per candidate:

1. draws a target point in every region (seeded) and puts the fingertip sphere's centre one radius out
   along the normal, ``squeeze`` metres deeper (a light squeeze);
2. solves each finger's inverse kinematics to it (damped least squares on MuJoCo's site Jacobian,
   clamped to the joint limits), the unassigned fingers staying at the task's hint pose;
3. settles the hand in *our* simulator: every world holds its IK pose with a stiff PD drive for
   ``settle_steps`` env steps, the object's part held at rest, so contact pushes penetrating links out
   and the squeeze becomes a contact force;
4. keeps the candidate only if MuJoCo's geometry (an independent check: ``mj_geomDistance``) says every
   assigned fingertip is within ``touch_tolerance`` of its geom and no hand geom penetrates any object
   geom by more than ``max_penetration``. (Our penalty contact is smooth: at the Allegro tasks'
   sharpness of 1000 /m and 2 mm surface smoothing it still pushes ~0.3 N at a 3 mm gap, so a fingertip
   that presses lightly rests 2-4 mm out in exact geometry: the default tolerance is 5 mm.)

The poses are stored per task in a JSON file (format, task, seed, poses; written atomically): the package
ships one per task (``assets/pregrasps/<task>.json``); ``dexmots-pregrasp --task <name>`` writes a new one
where the user says, deterministically for a seed, and a task uses it with ``task.pregrasps=<file>``. A file
is read, and checked whole (:func:`load_pregrasps`), when its task's env is built.
Tasks with ``initial="pregrasp"`` draw one of these per episode (:class:`~.tasks.allegro.operate.OperateEnv`).
The articulated objects of task ``operate`` describe their own regions and are searched by
:mod:`.object_pregrasp`, into the same file format (with the ``object`` it belongs to).
"""

from __future__ import annotations

import dataclasses
import json
import logging
from pathlib import Path

import numpy as np

__all__ = ["ContactRegion", "PregraspError", "find_pregrasps", "check_pregrasp", "load_pregrasps",
           "save_pregrasps", "pregrasp_path"]

log = logging.getLogger(__name__)

FORMAT = "dexmots-pregrasps-v1"


class PregraspError(ValueError):
    """No valid pre-grasp was found, or a pre-grasp file is missing or malformed."""


@dataclasses.dataclass(frozen=True)
class ContactRegion:
    """Where finger ``finger`` (index into the scene's fingers) should touch: geom ``geom`` (a box), at
    ``point`` on its face with outward ``normal`` (both in the geom's frame, m), moved up to ``spread``
    (m, along the geom frame's axes) by the candidates."""

    finger: int
    geom: str
    point: tuple[float, float, float]
    normal: tuple[float, float, float]
    spread: tuple[float, float, float] = (0.0, 0.0, 0.0)


def pregrasp_path(task: str) -> Path:
    """The shipped pre-grasp file of ``task``."""
    from ..assets import ASSET_DIR

    return ASSET_DIR / "pregrasps" / f"{task}.json"


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


def check_pregrasp(scene_path, q_hand, regions, touch_tolerance: float = 0.005,
                   max_penetration: float = 0.003) -> tuple[bool, dict]:
    """MuJoCo's verdict on one pre-grasp: ``(ok, details)`` with every assigned fingertip's distance to its
    geom (m, negative: penetrating) and the deepest penetration of any hand geom into any object geom."""
    import mujoco

    from ..sim import load_scene

    model = mujoco.MjModel.from_xml_path(str(scene_path))
    return _check(model, mujoco.MjData(model), load_scene(scene_path), q_hand, regions, touch_tolerance,
                  max_penetration)


def _check(model, data, scene, q_hand, regions, touch_tolerance: float = 0.005,
           max_penetration: float = 0.003) -> tuple[bool, dict]:
    """:func:`check_pregrasp` on an already compiled model (``data`` is overwritten)."""
    import mujoco

    data.qpos[:] = model.qpos0
    data.qpos[:scene.num_hand_dofs] = q_hand
    mujoco.mj_forward(model, data)
    sites = _finger_sites(model, scene)
    body = {mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, n) for n in ("object", "object_base")}
    object_geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] in body]
    hand_geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] not in body and model.geom_contype[g]]
    fromto = np.zeros(6)
    tips = {}
    for r in regions:
        g = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, r.geom)
        tips[scene.finger_names[r.finger]] = float(mujoco.mj_geomDistance(model, data, sites[r.finger][2], g, 0.1,
                                                                          fromto))
    deepest = min(float(mujoco.mj_geomDistance(model, data, h, o, 0.05, fromto)) for h in hand_geoms
                  for o in object_geoms)
    ok = all(-max_penetration <= d <= touch_tolerance for d in tips.values()) and deepest >= -max_penetration
    return ok, {"tip_distance": tips, "deepest_penetration": deepest}


def find_pregrasps(scene_path, regions, hint, candidates: int = 8, seed: int = 0, squeeze: float = 0.003,
                   settle_steps: int = 40, keep: int = 4, contact=None) -> np.ndarray:
    """Up to ``keep`` verified pre-grasps [K, nu] of the scene at ``scene_path`` (see the module docstring);
    ``hint``: the hand pose IK starts from (and the unassigned fingers keep)."""
    import mujoco
    import torch

    from ..sim import Control, Simulator, load_scene

    scene = load_scene(scene_path, contact)
    model = mujoco.MjModel.from_xml_path(str(scene_path))
    data = mujoco.MjData(model)
    nu = scene.num_hand_dofs
    sites = _finger_sites(model, scene)
    rng = np.random.default_rng(seed)
    mujoco.mj_forward(model, data)
    poses = np.zeros((candidates, nu))
    for c in range(candidates):
        q = model.qpos0.copy()
        q[:nu] = hint
        for r in regions:
            g = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, r.geom)
            if g < 0:
                raise PregraspError(f"region of finger {r.finger}: no geom named {r.geom!r} in {scene_path}")
            rot = data.geom_xmat[g].reshape(3, 3)
            local = np.asarray(r.point) + rng.uniform(-1, 1, 3) * np.asarray(r.spread)
            normal = rot @ np.asarray(r.normal, dtype=float)
            radius = float(model.geom_size[sites[r.finger][2], 0])
            target = data.geom_xpos[g] + rot @ local + normal * (radius - squeeze)
            _solve_ik(model, data, q, sites[r.finger][0], sites[r.finger][1], target)
        poses[c] = q[:nu]

    # settle in our simulator: a stiff PD hold of each IK pose; contact pushes the links out
    sim = Simulator(scene, num_worlds=candidates, dtype=torch.float64, contact=contact)
    joint_q, joint_qd = sim.initial_state()
    joint_q[:, :nu] = torch.as_tensor(poses)
    target = joint_q[:, :nu].clone()
    inertia = torch.as_tensor(scene.dof_inertia0)
    kp = (20.0**2 * inertia).expand(candidates, -1)
    kd = 2.0 * torch.sqrt(kp * inertia)
    control = Control(tau=torch.zeros_like(target), q_target=target, kp=kp.clone(), kd=kd.clone())
    params = sim.default_params().expand(candidates).clone() if scene.param_names else None
    if params is not None:  # the part held at rest (a stiff spring; implicit, so stable): the grasp must fit it there
        params["joint_stiffness"] = torch.full_like(params["joint_stiffness"], 100.0)
    with torch.no_grad():
        for _ in range(settle_steps):
            out = sim.step(joint_q, joint_qd, control, params)
            joint_q, joint_qd = out.joint_q, out.joint_qd
    # the limits are soft springs in the simulator: clamp onto the range the env draws start poses in
    settled = np.clip(joint_q[:, :nu].numpy(), scene.dof_lower, scene.dof_upper)
    kept = []
    for c in range(candidates):
        ok, details = _check(model, data, scene, settled[c], regions)  # the scene compiled once, above
        log.info("pregrasp candidate %d: %s %s", c, "kept" if ok else "rejected", details)
        if ok:
            kept.append(settled[c])
        if len(kept) == keep:
            break
    if not kept:
        raise PregraspError(f"no pre-grasp of {candidates} candidates passed the contact check in {scene_path}")
    return np.stack(kept)


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