"""Pre-grasps of articulated objects: the Allegro hand holding a library object (or a URDF's) where a person does.

Where the fingertips go comes from the object (:attr:`~dexmots_rl.assets.objects.ObjectAsset.grasp_regions`:
per finger, a part, a point and outward normal in that part's frame and a spread, written by each class's
generator from its own sizes). An object without regions (a URDF) gets :func:`fallback_regions`: index and
middle on the front (+x) face of the operated part's bounding box and the thumb on its back face, or one
error saying how to describe them. :func:`find_object_pregrasps` then, per candidate:

1. draws a contact point in every region (seeded), puts the fingertip sphere's centre one radius out along
   the normal, ``squeeze`` metres deeper (or the region's own squeeze), and solves each finger's inverse
   kinematics to it (:mod:`.pregrasp`'s damped least squares on MuJoCo's Jacobian); the other fingers stay
   slightly curled, or curled in where they would touch the object;
2. settles the hand in our simulator (:class:`~dexmots_rl.sim.ArticulatedSimulator`) with a stiff PD hold of
   the IK pose while the whole object is held where it stands (its coordinates reset after every step), so
   contact pushes penetrating links out;
3. releases the object for ``release_steps`` steps, the hand still holding its pose, and keeps a candidate
   only if the base moved less than ``max_base_shift`` and the operated joint stayed within
   ``max_joint_shift`` (a fraction of its range) of rest, beyond what the object does alone on the table
   (:func:`object_drift`): the grasp neither pushes the tool away nor operates it;
4. and only if MuJoCo's geometry (:func:`check_object_pregrasp`, an independent check) finds every named
   fingertip within 5 mm of its part and no hand geom more than 3 mm inside any object geom (the smooth contact
   settles a lightly pressing fingertip 2-4 mm outside the exact surface). A fingertip sphere is measured
   against a mesh geom's own surface (MuJoCo's convex hull would fill a ring's hole), as the simulator's
   signed-distance grid sees it, so a fingertip may sit inside a scissors ring.

The files: ``assets/pregrasps/operate/<object>.json`` ship for every library object (``dexmots-pregrasp
--task operate --all``, the command ``docs/objects.md`` gives); their ``task`` is ``operate`` and their
``object`` the object's name.
"""

from __future__ import annotations

import logging

import numpy as np

from .pregrasp import PregraspError, _finger_sites, _solve_ik

__all__ = ["object_regions", "fallback_regions", "find_object_pregrasps", "check_object_pregrasp",
           "release_drift", "object_drift", "operate_pregrasp_path", "squeeze_torque", "OPERATE_HINT", "FREE_POSE", "TUCKED_POSE"]

log = logging.getLogger(__name__)

# rad: the pose IK starts from (fingers half curled, the thumb opposed under the palm); a finger without a
# region stays at FREE_POSE (slightly curled, the thumb out to the side at the palm's height: clear of the object)
OPERATE_HINT = (0.0, 0.6, 0.6, 0.6) * 3 + (1.2, 0.6, 0.4, 0.4)
FREE_POSE = (0.0, 0.3, 0.3, 0.3) * 3 + (0.3, 0.3, 0.3, 0.3)
TUCKED_POSE = (0.0, 1.5, 1.5, 1.0) * 3 + (0.3, 0.3, 0.3, 0.3)  # the free fingers' second choice: curled in
REGIONS_HELP = ("describe where each fingertip rests with ObjectAsset.grasp_regions (GraspRegion: finger, part, "
                "point and outward normal in the part's frame, spread), or start the task with initial=open")


def operate_pregrasp_path(object_name: str):
    """The shipped pre-grasp file of library object ``object_name`` (task ``operate``)."""
    from ..assets import ASSET_DIR

    return ASSET_DIR / "pregrasps" / "operate" / f"{object_name}.json"


def _body_name(asset, part: str) -> str:
    from ..assets.objects import SCENE_PREFIX

    return "object" if part == asset.parts[0].name else f"{SCENE_PREFIX}{part}"


def _object_bodies(model) -> set[int]:
    import mujoco

    root = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "object")
    out = set()
    for b in range(model.nbody):
        a = b
        while a > 0 and a != root:
            a = int(model.body_parentid[a])
        if a == root and root >= 0:
            out.add(b)
    return out


def fallback_regions(asset, model, data, joint: str | None = None):
    """Regions for an object without described ones: index and middle on the front (+x, world) face of the
    operated part's bounding box (at rest), the thumb on its back face, in the part's frame."""
    import mujoco

    from ..assets.objects import GraspRegion

    joint = joint or asset.operated_joint or (asset.joints[0].name if asset.joints else None)
    part = next((p.name for p in asset.parts[1:] if p.joint.name == joint), None)
    if part is None:
        raise PregraspError(f"object {asset.name!r} has no grasp regions and no moving part to hold; "
                            + REGIONS_HELP)
    body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, _body_name(asset, part))
    corners = []
    for g in range(model.ngeom):
        if model.geom_bodyid[g] != body or not model.geom_contype[g]:
            continue
        centre, half = model.geom_aabb[g, :3], model.geom_aabb[g, 3:]
        rot = data.geom_xmat[g].reshape(3, 3)
        for s in np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).T.reshape(-1, 3):
            corners.append(data.geom_xpos[g] + rot @ (centre + s * half))
    low, high = np.min(corners, 0), np.max(corners, 0)
    mid = (low + high) / 2
    rot, origin = data.xmat[body].reshape(3, 3), data.xpos[body]

    def region(finger, x, y, normal):
        point = rot.T @ (np.array([x, y, mid[2]]) - origin)
        return GraspRegion(finger, part, tuple(point), tuple(rot.T @ np.asarray(normal, float)), (0.002,) * 3)

    width = min(0.012, (high[1] - low[1]) / 4)
    return (region("index", high[0], mid[1] + width, (1, 0, 0)), region("middle", high[0], mid[1] - width, (1, 0, 0)),
            region("thumb", low[0], mid[1], (-1, 0, 0)))


def object_regions(asset, model, data, joint: str | None = None):
    """The object's own grasp regions, or :func:`fallback_regions`."""
    return tuple(asset.grasp_regions) or fallback_regions(asset, model, data, joint)


def _finger_index(scene, finger: str) -> int:
    if finger not in scene.finger_names:
        raise PregraspError(f"grasp region of finger {finger!r}: the hand's fingers are {list(scene.finger_names)}")
    return list(scene.finger_names).index(finger)


def check_object_pregrasp(model, data, scene, asset, q_hand, regions, touch_tolerance: float = 0.005,
                          max_penetration: float = 0.003) -> tuple[bool, dict]:
    """MuJoCo's verdict on one pre-grasp with the object at rest: ``(ok, details)`` with each named fingertip's
    distance to its part (m, negative: penetrating) and the deepest penetration of any hand geom (links, palm)
    into any object geom. ``data`` is overwritten."""
    import mujoco

    nu = scene.num_hand_dofs
    data.qpos[:] = model.qpos0
    data.qpos[:nu] = q_hand
    mujoco.mj_forward(model, data)
    sites = _finger_sites(model, scene)
    bodies = _object_bodies(model)
    object_geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] in bodies and model.geom_contype[g]]
    hand_geoms = [g for g in range(model.ngeom)
                  if model.geom_bodyid[g] not in bodies and model.geom_bodyid[g] > 0 and model.geom_contype[g]]
    tips = {}
    for r in regions:
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, _body_name(asset, r.part))
        tip = sites[_finger_index(scene, r.finger)][2]
        tips[r.finger] = min(_geom_distance(model, data, tip, g, 0.1) for g in object_geoms
                             if model.geom_bodyid[g] == body)
    deepest = min(_geom_distance(model, data, h, o, 0.05) for h in hand_geoms for o in object_geoms)
    ok = all(-max_penetration <= d <= touch_tolerance for d in tips.values()) and deepest >= -max_penetration
    return ok, {"tip_distance": tips, "deepest_penetration": deepest}


def squeeze_torque(scene, asset, q_hand, force: float, joint: str | None = None) -> np.ndarray:
    """Hand joint torques [nu] (N m) that press every fingertip with a grasp region (:func:`object_regions`)
    into its part with ``force`` newtons along the region's inward normal, the object at rest and the hand
    at ``q_hand``: the Jacobian transpose of each fingertip site, from MuJoCo's kinematics. Gravity and the
    contact are not compensated: from a pre-grasp (fingertips already pressing) this closes the grasp."""
    import mujoco

    model = mujoco.MjModel.from_xml_path(str(scene.path))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    regions = object_regions(asset, model, data, joint)
    nu = scene.num_hand_dofs
    data.qpos[:nu] = q_hand
    mujoco.mj_forward(model, data)
    sites = _finger_sites(model, scene)
    tau, jac = np.zeros(nu), np.zeros((3, model.nv))
    for r in regions:
        site, qidx, _ = sites[_finger_index(scene, r.finger)]
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, _body_name(asset, r.part))
        normal = data.xmat[body].reshape(3, 3) @ np.asarray(r.normal, dtype=float)
        mujoco.mj_jacSite(model, data, jac, None, site)
        tau[qidx] += jac[:, qidx].T @ (-force * normal / np.linalg.norm(normal))  # the hand's qpos = its dofs
    return tau


def _geom_distance(model, data, a: int, b: int, reach: float) -> float:
    """Distance (m, negative: penetrating) of geoms ``a`` and ``b``: MuJoCo's, except a sphere against a mesh,
    measured against the mesh itself (MuJoCo collides meshes as their convex hull, which fills a ring's hole
    that the simulator's signed-distance grid leaves open)."""
    import mujoco
    import trimesh

    mesh_type, sphere_type = mujoco.mjtGeom.mjGEOM_MESH, mujoco.mjtGeom.mjGEOM_SPHERE
    if int(model.geom_type[a]) == sphere_type and int(model.geom_type[b]) == mesh_type:
        mid = int(model.geom_dataid[b])
        verts = model.mesh_vert[model.mesh_vertadr[mid]: model.mesh_vertadr[mid] + model.mesh_vertnum[mid]]
        faces = model.mesh_face[model.mesh_faceadr[mid]: model.mesh_faceadr[mid] + model.mesh_facenum[mid]]
        centre = data.geom_xmat[b].reshape(3, 3).T @ (data.geom_xpos[a] - data.geom_xpos[b])  # in the mesh frame
        inside = trimesh.proximity.signed_distance(trimesh.Trimesh(verts, faces, process=False), centre[None])[0]
        return float(-inside - model.geom_size[a][0])  # trimesh: positive inside
    return float(mujoco.mj_geomDistance(model, data, a, b, reach, np.zeros(6)))


def _hold_control(sim, q_hand):
    """A stiff PD hold (20 rad/s, critically damped) of ``q_hand`` [N, nu]."""
    import torch

    from ..sim import Control

    inertia = torch.as_tensor(sim.scene.dof_inertia0, dtype=q_hand.dtype)
    kp = (20.0**2 * inertia).expand_as(q_hand).clone()
    return Control(tau=torch.zeros_like(q_hand), q_target=q_hand.clone(), kp=kp, kd=2.0 * torch.sqrt(kp * inertia))


def release_drift(sim, q_hand, steps: int, joint_index: int, params=None) -> tuple[np.ndarray, np.ndarray]:
    """The object released at rest under a hand holding ``q_hand`` [N, nu] for ``steps`` env steps:
    ``(base shift [N] m, |operated joint - rest| [N])`` at the end (max over the steps)."""
    import torch

    nu, tree = sim.nu, sim.tree
    joint_q, joint_qd = sim.initial_state()
    joint_q[:, :nu] = torch.as_tensor(q_hand, dtype=joint_q.dtype)
    control = _hold_control(sim, joint_q[:, :nu])
    params = sim.default_params() if params is None else params
    start = joint_q[:, nu:].clone()
    j = nu + 7 * tree.free + joint_index
    shift = torch.zeros(sim.num_worlds, dtype=joint_q.dtype)
    moved = torch.zeros_like(shift)
    with torch.no_grad():
        for _ in range(steps):
            out = sim.step(joint_q, joint_qd, control, params)
            joint_q, joint_qd = out.joint_q, out.joint_qd
            if tree.free:
                shift = torch.maximum(shift, (joint_q[:, nu:nu + 3] - start[:, :3]).norm(dim=-1))
            moved = torch.maximum(moved, (joint_q[:, j] - start[:, j - nu]).abs())
    return shift.numpy(), moved.numpy()


def _clearance(model, data, q, finger: str, bodies: set[int]) -> float:
    """The least distance (m) between finger ``finger``'s geoms and the object's at hand pose ``q``."""
    import mujoco

    data.qpos[:] = q
    mujoco.mj_forward(model, data)
    own = [g for g in range(model.ngeom) if model.geom_contype[g] and (mujoco.mj_id2name(
        model, mujoco.mjtObj.mjOBJ_BODY, int(model.geom_bodyid[g])) or "").split("_")[0] == finger]
    others = [g for g in range(model.ngeom) if model.geom_bodyid[g] in bodies and model.geom_contype[g]]
    fromto = np.zeros(6)
    return min(float(mujoco.mj_geomDistance(model, data, a, b, 0.05, fromto)) for a in own for b in others)


def object_drift(sim, steps: int, joint_index: int) -> tuple[float, float]:
    """:func:`release_drift` of the object alone on its table (no hand): what it does by itself, e.g. an
    unsprung lid that falls shut; a grasp is judged by what it adds to that."""
    import torch

    from ..sim import ObjectSimulator

    alone = ObjectSimulator(sim.tree, 1, dtype=sim.dtype, substeps=sim.substeps, sub_dt=sim.sub_dt,
                            table=sim.table, gravity=sim.scene.gravity)
    q, qd = alone.initial_state()
    start, params = q.clone(), alone.default_params()
    j = 7 * sim.tree.free + joint_index
    shift = moved = 0.0
    with torch.no_grad():
        for _ in range(steps):
            q, qd = alone.step(q, qd, params)
            if sim.tree.free:
                shift = max(shift, float((q[0, :3] - start[0, :3]).norm()))
            moved = max(moved, float((q[0, j] - start[0, j]).abs()))
    return shift, moved


def find_object_pregrasps(scene, asset, regions, hint=OPERATE_HINT, free_pose=FREE_POSE, candidates: int = 8,
                          seed: int = 0, squeeze: float = 0.003, settle_steps: int = 30, release_steps: int = 20,
                          keep: int = 4, contact=None, joint: str | None = None, max_base_shift: float = 0.001,
                          max_joint_shift: float = 0.05, progress: bool = False) -> np.ndarray:
    """Up to ``keep`` verified pre-grasps [K, nu] of ``asset`` in ``scene`` (an
    :class:`~dexmots_rl.sim.ArticulatedScene`); see the module docstring. IK starts a finger with a region
    from ``hint``; the others keep ``free_pose``. ``progress``: show the search's stages (tqdm)."""
    import mujoco
    import torch
    from ..progress import progress_bar
    from ..sim import make_simulator

    model = mujoco.MjModel.from_xml_path(str(scene.path))
    data = mujoco.MjData(model)
    nu = scene.num_hand_dofs
    sites = _finger_sites(model, scene)
    bodies = _object_bodies(model)
    rng = np.random.default_rng(seed)
    mujoco.mj_forward(model, data)
    poses = np.zeros((candidates, nu))
    bar = progress_bar(total=candidates + settle_steps + 1, desc=f"pre-grasps of {asset.name}", disable=not progress)
    for c in range(candidates):
        bar.update()
        q = model.qpos0.copy()
        q[:nu] = free_pose
        for r in regions:
            q[sites[_finger_index(scene, r.finger)][1]] = np.asarray(hint)[sites[_finger_index(scene, r.finger)][1]]
        for r in regions:
            body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, _body_name(asset, r.part))
            if body < 0:
                raise PregraspError(f"grasp region of finger {r.finger!r}: object {asset.name!r} has no part "
                                    f"{r.part!r}")
            f = _finger_index(scene, r.finger)
            rot = data.xmat[body].reshape(3, 3)
            local = np.asarray(r.point) + rng.uniform(-1, 1, 3) * np.asarray(r.spread)
            normal = rot @ np.asarray(r.normal, dtype=float)
            radius = float(model.geom_size[sites[f][2], 0])
            depth = squeeze if r.squeeze is None else r.squeeze
            _solve_ik(model, data, q, sites[f][0], sites[f][1], data.xpos[body] + rot @ local
                      + normal / np.linalg.norm(normal) * (radius - depth))
        named = {r.finger for r in regions}
        for f, finger in enumerate(scene.finger_names):  # a free finger in the object curls in instead
            if finger not in named and _clearance(model, data, q, finger, bodies) < 0.002:
                q[sites[f][1]] = np.asarray(TUCKED_POSE)[sites[f][1]]
        poses[c] = q[:nu]

    # settle: a stiff hold of each IK pose with the object held where it stands; contact pushes links out
    sim = make_simulator(scene, num_worlds=candidates, contact=contact)
    joint_q, joint_qd = sim.initial_state()
    joint_q[:, :nu] = torch.as_tensor(poses, dtype=joint_q.dtype)
    rest_q, rest_qd = joint_q[:, nu:].clone(), joint_qd[:, nu:].clone()
    control = _hold_control(sim, joint_q[:, :nu])
    params = sim.default_params()
    with torch.no_grad():
        for _ in range(settle_steps):
            bar.update()
            out = sim.step(joint_q, joint_qd, control, params)
            joint_q = torch.cat([out.joint_q[:, :nu], rest_q], -1)
            joint_qd = torch.cat([out.joint_qd[:, :nu], rest_qd], -1)
    # the limits are soft springs in the simulator: clamp onto the range the env draws start poses in
    settled = np.clip(joint_q[:, :nu].double().numpy(), scene.dof_lower, scene.dof_upper)
    joint = joint or asset.operated_joint or sim.tree.joint_names[0]
    index = sim.tree.joint_names.index(joint)
    lo, hi = sim.tree.joint_range[index]
    shift, moved = release_drift(sim, settled, release_steps, index)
    alone_shift, alone_moved = object_drift(sim, release_steps, index)
    shift, moved = shift - alone_shift, moved - alone_moved
    bar.update()
    bar.close()
    kept = []
    for c in range(candidates):
        ok, details = check_object_pregrasp(model, data, scene, asset, settled[c], regions)
        still = shift[c] < max_base_shift and moved[c] < max_joint_shift * (hi - lo)
        log.info("pregrasp candidate %d of %s: %s %s, base shift %.2g m, joint moved %.3g", c, asset.name,
                 "kept" if ok and still else "rejected", details, shift[c], moved[c])
        if ok and still:
            kept.append(settled[c])
        if len(kept) == keep:
            break
    if not kept:
        raise PregraspError(f"object {asset.name!r}: none of {candidates} pre-grasp candidates touched its regions "
                            "without penetrating and left it at rest (see the log at INFO level); try more "
                            f"--candidates, or {REGIONS_HELP}")
    return np.stack(kept)
