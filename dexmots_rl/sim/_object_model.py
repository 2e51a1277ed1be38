"""The articulated object of a scene, read from MuJoCo's compiled model: a tree of rigid bodies.

Body ``object`` is the base: fixed to the world (no joint) or free (one free joint). Its descendants are the
moving parts, each on one hinge or slide joint (at most :data:`MAX_PARTS`). What the kernels need is stored
as numpy arrays with units and shapes (``B`` bodies, base first, parents before children; ``P = B - 1`` part
joints; ``S`` surface samples per body):

* ``parent`` [B] index of the parent body (-1 for the base); ``offset_pos`` [B, 3] (m) / ``offset_rot``
  [B, 3, 3]: the body frame in its parent's frame at joint 0 (the base: in the world, for a fixed base; the
  initial pose for a free one);
* ``joint_kind`` [P] HINGE or SLIDE, ``joint_axis`` [P, 3] and ``joint_anchor`` [P, 3] in the part frame;
  ``joint_range`` [P, 2] (rad or m), and the named per-world parameters of every joint (see
  :func:`joint_param_names`): damping, friction, stiffness, rest;
* the named per-world parameters after the joints' (:attr:`ObjectTree.param_names`): ``"<body>/mass"`` (kg) of
  every moving body (a free base and the parts: its inertia scales with it) and, for a free base on a table,
  ``"table/friction"`` (the table's Coulomb coefficient);
* ``mass`` [B] (kg), ``com`` [B, 3] (m, body frame), ``inertia`` [B, 3, 3] (kg m^2 about the com, body frame),
  ``armature`` [P] (kg m^2 or kg);
* ``ancestor`` [B, P] 1 where part joint p moves body b (p's part is b or one of b's ancestors);
* ``sample_pos`` [B, S, 3] (m, body frame) and ``sample_radius`` [B, S] (m; -1 = padding): points on each
  body's collision surface that touch the table;

Parts collide with each other only through their joint limits (not with each other's geoms).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._constants import TABLE_FRICTION
from ._mjcf_shapes import AssetError, _body_inertia, _quat_to_mat

__all__ = ["ObjectTree", "object_tree", "single_body_tree", "single_body_error", "MOUNT", "joint_param_names", "MAX_PARTS", "MAX_SAMPLES", "JOINT_PARAMS", "HINGE",
           "SLIDE", "TABLE_FRICTION_PARAM"]

MAX_PARTS = 4
MAX_SAMPLES = 12  # table-contact samples per body (each is unrolled in the kernel and its adjoint)
HINGE, SLIDE = 0, 1
# per-joint physical parameters, by name: ("sim", "params", "<joint>/<name>") in the env's TensorDict
JOINT_PARAMS = ("damping", "friction", "stiffness", "rest")
TABLE_FRICTION_PARAM = "table/friction"  # the table's Coulomb coefficient (a free base on a table)
MOUNT = "object_mount"  # the fixed, massless base a single hinged body turns on (single_body_tree)
UNLIMITED = 1.0e9  # rad or m: the range of a part joint the MJCF leaves unlimited (its stops are never reached)



def joint_param_names(joint_names) -> tuple[str, ...]:
    """``"<joint>/<param>"`` for every joint and parameter (the order of the packed parameter array)."""
    return tuple(f"{j}/{p}" for j in joint_names for p in JOINT_PARAMS)


@dataclasses.dataclass
class ObjectTree:
    """The object's bodies and joints (see the module docstring for units and shapes)."""

    body_names: list[str]
    joint_names: list[str]
    free: bool
    parent: np.ndarray
    offset_pos: np.ndarray
    offset_rot: np.ndarray
    joint_kind: np.ndarray
    joint_axis: np.ndarray
    joint_anchor: np.ndarray
    joint_range: np.ndarray
    joint_damping: np.ndarray
    joint_friction: np.ndarray
    joint_stiffness: np.ndarray
    joint_rest: np.ndarray
    armature: np.ndarray
    joint_inertia: np.ndarray  # [P] kg m^2 or kg: the mass matrix's diagonal at q0 (sizes the range stops)
    mass: np.ndarray
    com: np.ndarray
    inertia: np.ndarray
    ancestor: np.ndarray
    sample_pos: np.ndarray
    sample_radius: np.ndarray
    q0: np.ndarray  # [nq] initial generalized coordinates: base pos + wxyz quat (free only), then part joints
    table_height: float | None  # z of the table plane (m), None when the scene has none

    @property
    def num_bodies(self) -> int:
        return len(self.body_names)

    @property
    def num_parts(self) -> int:
        return len(self.joint_names)

    @property
    def nq(self) -> int:
        return 7 * self.free + self.num_parts

    @property
    def nv(self) -> int:
        return 6 * self.free + self.num_parts

    @property
    def moving_bodies(self) -> range:
        """The bodies that move (a free base and the parts; a fixed base does not): each has a mass parameter,
        in this order."""
        return range(0 if self.free else 1, self.num_bodies)

    @property
    def table_contact(self) -> bool:
        """Whether the table pushes the object (a free base on a table): it has the ``table/friction`` parameter."""
        return bool(self.free) and self.table_height is not None

    @property
    def param_names(self) -> tuple[str, ...]:
        """The per-world parameters, in the packed array's order: every joint's (:func:`joint_param_names`), every
        moving body's ``"<body>/mass"``, then ``"table/friction"`` with a table contact."""
        masses = tuple(f"{self.body_names[b]}/mass" for b in self.moving_bodies)
        return joint_param_names(self.joint_names) + masses + ((TABLE_FRICTION_PARAM,) if self.table_contact else ())

    def randomized(self, name: str) -> bool:
        """Whether an env draws parameter ``name`` around its nominal value each episode: a joint's damping,
        friction or stiffness (not its rest, nor a mass or a contact's friction, which stay the scene's)."""
        joint, _, kind = name.rpartition("/")
        return joint in self.joint_names and kind in JOINT_PARAMS and kind != "rest"

    def default_param_values(self, table_friction: float = TABLE_FRICTION) -> dict[str, float]:
        """Every parameter's value in this tree (``table_friction``: the table's coefficient)."""
        values = {}
        for i, j in enumerate(self.joint_names):
            for p, arr in zip(JOINT_PARAMS, (self.joint_damping, self.joint_friction, self.joint_stiffness,
                                             self.joint_rest)):
                values[f"{j}/{p}"] = float(arr[i])
        for b in self.moving_bodies:
            values[f"{self.body_names[b]}/mass"] = float(self.mass[b])
        if self.table_contact:
            values[TABLE_FRICTION_PARAM] = float(table_friction)
        return values


def _samples(m, geoms) -> tuple[list, list]:
    """Surface points of a body's collision geoms (body frame) touching the table: box corners, capsule and
    sphere centres (with their radius), cylinder rim points, a mesh hull's extreme vertices."""
    import mujoco
    import trimesh

    pos, rad = [], []
    for g in geoms:
        kind, size = int(m.geom_type[g]), m.geom_size[g]
        rot, centre = _quat_to_mat(m.geom_quat[g]), m.geom_pos[g]
        if kind == mujoco.mjtGeom.mjGEOM_BOX:
            local = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * size[:3]
            r = np.zeros(len(local))
        elif kind == mujoco.mjtGeom.mjGEOM_SPHERE:
            local, r = np.zeros((1, 3)), np.array([size[0]])
        elif kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
            local, r = np.array([[0, 0, -size[1]], [0, 0, size[1]]]), np.full(2, size[0])
        elif kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
            ang = 2 * np.pi * np.arange(6) / 6
            rim = np.stack([size[0] * np.cos(ang), size[0] * np.sin(ang), np.zeros(6)], 1)
            local, r = np.concatenate([rim + [0, 0, size[1]], rim - [0, 0, size[1]]]), np.zeros(12)
        elif kind == mujoco.mjtGeom.mjGEOM_MESH:
            mid = m.geom_dataid[g]
            verts = m.mesh_vert[m.mesh_vertadr[mid]: m.mesh_vertadr[mid] + m.mesh_vertnum[mid]].astype(np.float64)
            hull = trimesh.convex.convex_hull(verts)
            # the hull's vertices farthest along 14 directions (faces, edges and corners of a cube)
            dirs = np.array([d for d in np.ndindex(3, 3, 3) if d != (1, 1, 1)], dtype=float) - 1
            idx = np.unique(np.argmax(hull.vertices @ dirs.T, axis=0))
            local, r = hull.vertices[idx], np.zeros(len(idx))
        else:
            continue  # planes and others: not part of an object
        pos.extend(local @ rot.T + centre)
        rad.extend(r)
    return pos, rad


SUPPORT_TOLERANCE = 1e-3  # m: samples this close to a body's lowest (its frame's -z) are its support on the table


def _stands_on(kept: np.ndarray, kept_rad: np.ndarray, pos: np.ndarray, rad: np.ndarray, com: np.ndarray) -> bool:
    """Whether the kept samples of a base include a support (samples at its lowest) around its mass centre."""
    from scipy.spatial import Delaunay, QhullError

    low = (pos[:, 2] - rad).min()
    support = kept[kept[:, 2] - kept_rad <= low + SUPPORT_TOLERANCE][:, :2]
    try:
        return len(support) >= 3 and Delaunay(support).find_simplex(com[:2]) >= 0
    except QhullError:  # collinear: an edge, not a support
        return False


def _spread_samples(pos: np.ndarray, rad: np.ndarray, count: int) -> list[int]:
    """Indices of ``count`` of the samples: first the body's support (those within :data:`SUPPORT_TOLERANCE` of
    its lowest, along its frame's -z: a free base's frame stands on the table), then the rest, each group spread
    out by farthest-point sampling. A base that keeps only some corners of its bottom tips over them."""
    low = pos[:, 2] - rad
    support = np.flatnonzero(low <= low.min() + SUPPORT_TOLERANCE)
    chosen: list[int] = []
    for group in (support, np.arange(len(pos))):
        left = [k for k in group if k not in chosen]
        while left and len(chosen) < count:
            if chosen:
                gap = np.min(np.linalg.norm(pos[left][:, None] - pos[chosen][None], axis=-1), axis=1)
            else:
                gap = np.linalg.norm(pos[left] - pos[left].mean(axis=0), axis=1)
            chosen.append(left.pop(int(np.argmax(gap))))
    return chosen


def object_tree(m, d) -> ObjectTree:
    """Read the object tree under body ``object`` from a compiled model ``m`` and its data ``d`` after
    ``mj_forward``; raises :class:`AssetError` naming the body or joint that does not fit."""
    import mujoco

    from ..assets.objects.description import scene_joint_name

    def name(kind, i):
        named = mujoco.mj_id2name(m, kind, i) or f"#{i}"
        return scene_joint_name(named) if kind == mujoco.mjtObj.mjOBJ_JOINT else named

    root = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "object")
    if root < 0:
        raise AssetError("the scene has no body named 'object'")
    bodies = [root]
    for b in range(root + 1, m.nbody):  # MuJoCo numbers bodies depth first: descendants follow their root
        if int(m.body_parentid[b]) in bodies:
            bodies.append(b)
    if len(bodies) - 1 > MAX_PARTS:
        raise AssetError(f"body 'object' has {len(bodies) - 1} moving parts; at most {MAX_PARTS} are supported")
    free = False
    if m.body_jntnum[root] == 1 and int(m.jnt_type[m.body_jntadr[root]]) == mujoco.mjtJoint.mjJNT_FREE:
        free = True
    elif m.body_jntnum[root] != 0:
        raise AssetError("body 'object' (the base) must have no joint (fixed) or one free joint")
    if int(m.body_parentid[root]) != 0:
        raise AssetError("body 'object' must be a child of the worldbody")
    parent, off_pos, off_rot, jkind, jaxis, janchor, jrange, jnames = [], [], [], [], [], [], [], []
    damping, friction, stiffness, rest, armature, joint_inertia = [], [], [], [], [], []
    q0 = list(m.qpos0[m.jnt_qposadr[m.body_jntadr[root]]: m.jnt_qposadr[m.body_jntadr[root]] + 7]) if free else []
    for b in bodies:
        parent.append(bodies.index(int(m.body_parentid[b])) if b != root else -1)
        off_pos.append(m.body_pos[b].copy())
        off_rot.append(_quat_to_mat(m.body_quat[b]))
        if b == root:
            continue
        if m.body_jntnum[b] != 1:
            raise AssetError(f"part {name(mujoco.mjtObj.mjOBJ_BODY, b)!r} needs exactly one hinge or slide joint")
        j = int(m.body_jntadr[b])
        kind = int(m.jnt_type[j])
        if kind not in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE):
            raise AssetError(f"joint {name(mujoco.mjtObj.mjOBJ_JOINT, j)!r}: a part's joint is a hinge or a slide")
        if not m.jnt_limited[j]:
            raise AssetError(f"joint {name(mujoco.mjtObj.mjOBJ_JOINT, j)!r} needs a range (limited)")
        dof = int(m.jnt_dofadr[j])
        jnames.append(name(mujoco.mjtObj.mjOBJ_JOINT, j))
        jkind.append(HINGE if kind == mujoco.mjtJoint.mjJNT_HINGE else SLIDE)
        jaxis.append(m.jnt_axis[j] / np.linalg.norm(m.jnt_axis[j]))
        janchor.append(m.jnt_pos[j].copy())
        jrange.append(m.jnt_range[j].copy())
        damping.append(float(m.dof_damping[dof]))
        friction.append(float(m.dof_frictionloss[dof]))
        stiffness.append(float(m.jnt_stiffness[j]))
        rest.append(float(m.qpos_spring[m.jnt_qposadr[j]]))
        armature.append(float(m.dof_armature[dof]))
        joint_inertia.append(float(m.dof_M0[dof]))
        q0.append(float(m.qpos0[m.jnt_qposadr[j]]))
    inertias = [_body_inertia(m, b) for b in bodies]
    num_p = len(bodies) - 1
    ancestor = np.zeros((len(bodies), num_p))
    for i in range(1, len(bodies)):
        k = i
        while k > 0:
            ancestor[i, k - 1] = 1.0
            k = parent[k]
    sample_pos = np.zeros((len(bodies), MAX_SAMPLES, 3))
    sample_radius = -np.ones((len(bodies), MAX_SAMPLES))
    for i, b in enumerate(bodies):
        geoms = [g for g in range(m.ngeom) if m.geom_bodyid[g] == b and (m.geom_contype[g] or m.geom_conaffinity[g])]
        pos, rad = _samples(m, geoms)
        if len(pos) > MAX_SAMPLES:  # the points farthest out in the body frame's spread
            order = list(np.argsort(-np.linalg.norm(np.asarray(pos) - np.mean(pos, 0), axis=1))[:MAX_SAMPLES])
            if i == 0 and free and not _stands_on(np.asarray(pos)[order], np.asarray(rad)[order],
                                                  np.asarray(pos), np.asarray(rad), inertias[0][1]):
                order = _spread_samples(np.asarray(pos), np.asarray(rad), MAX_SAMPLES)
            pos, rad = [pos[k] for k in order], [rad[k] for k in order]
        sample_pos[i, : len(pos)] = pos
        sample_radius[i, : len(pos)] = rad
    table = [g for g in range(m.ngeom) if m.geom_bodyid[g] == 0 and int(m.geom_type[g]) == mujoco.mjtGeom.mjGEOM_PLANE]
    table_height = float(d.geom_xpos[table[0]][2]) if table else None
    return ObjectTree(
        body_names=[name(mujoco.mjtObj.mjOBJ_BODY, b) for b in bodies], joint_names=jnames, free=free,
        parent=np.array(parent), offset_pos=np.array(off_pos), offset_rot=np.array(off_rot),
        joint_kind=np.array(jkind, dtype=np.int32), joint_axis=np.array(jaxis).reshape(num_p, 3),
        joint_anchor=np.array(janchor).reshape(num_p, 3), joint_range=np.array(jrange).reshape(num_p, 2),
        joint_damping=np.array(damping), joint_friction=np.array(friction), joint_stiffness=np.array(stiffness),
        joint_rest=np.array(rest), armature=np.array(armature), joint_inertia=np.array(joint_inertia),
        mass=np.array([i[0] for i in inertias]), com=np.array([i[1] for i in inertias]),
        inertia=np.array([i[2] for i in inertias]), ancestor=ancestor, sample_pos=sample_pos,
        sample_radius=sample_radius, q0=np.array(q0, dtype=np.float64), table_height=table_height)


def _joint_name(m, joint: int) -> str:
    import mujoco

    return mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, joint) or f"#{joint}"


def single_body_error(m, joint: int) -> str:
    """The error of a single object body whose ``joint`` is neither a hinge nor a free joint."""
    return f"joint {_joint_name(m, joint)!r} of body 'object' must be a hinge or a free joint"


def single_body_tree(m, d) -> ObjectTree:
    """Body ``object`` of the knob and cube scenes (one body on one hinge or free joint, nothing below it) as an
    object tree: a free body is a free base with no parts (:func:`object_tree` reads it as it is); a hinged body is
    the one part of a fixed, massless base :data:`MOUNT` placed where its parent's frame puts the body at angle 0,
    so its state is its hinge angle as before. An unlimited hinge gets the range +-:data:`UNLIMITED`."""
    import mujoco

    root = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "object")
    if root < 0:
        raise AssetError("the scene has no body named 'object'")
    joint = int(m.body_jntadr[root])
    if m.body_jntnum[root] != 1:
        raise AssetError("body 'object' needs exactly one joint (hinge or free)")
    if int(m.jnt_type[joint]) not in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_FREE):
        raise AssetError(single_body_error(m, joint))
    if int(m.jnt_type[joint]) == mujoco.mjtJoint.mjJNT_FREE:
        return object_tree(m, d)
    parent = int(m.body_parentid[root])
    parent_rot = d.xmat[parent].reshape(3, 3)
    mount_pos = d.xpos[parent] + parent_rot @ m.body_pos[root]
    mount_rot = parent_rot @ _quat_to_mat(m.body_quat[root])
    dof, adr = int(m.jnt_dofadr[joint]), int(m.jnt_qposadr[joint])
    limited = bool(m.jnt_limited[joint])
    mass, com, inertia = _body_inertia(m, root)
    name = _joint_name(m, joint)
    return ObjectTree(
        body_names=[MOUNT, "object"], joint_names=[name], free=False, parent=np.array([-1, 0]),
        offset_pos=np.stack([mount_pos, np.zeros(3)]), offset_rot=np.stack([mount_rot, np.eye(3)]),
        joint_kind=np.array([HINGE], dtype=np.int32), joint_axis=(m.jnt_axis[joint] / np.linalg.norm(
            m.jnt_axis[joint]))[None], joint_anchor=m.jnt_pos[joint][None].copy(),
        joint_range=(m.jnt_range[joint] if limited else np.array([-UNLIMITED, UNLIMITED]))[None].astype(np.float64),
        joint_damping=np.array([m.dof_damping[dof]]), joint_friction=np.array([m.dof_frictionloss[dof]]),
        joint_stiffness=np.array([m.jnt_stiffness[joint]]), joint_rest=np.array([m.qpos_spring[adr]]),
        armature=np.array([m.dof_armature[dof]]), joint_inertia=np.array([m.dof_M0[dof]]),
        mass=np.array([0.0, mass]), com=np.stack([np.zeros(3), com]), inertia=np.stack([np.zeros((3, 3)), inertia]),
        ancestor=np.array([[0.0], [1.0]]), sample_pos=np.zeros((2, MAX_SAMPLES, 3)),
        sample_radius=-np.ones((2, MAX_SAMPLES)), q0=np.array([m.qpos0[adr]], dtype=np.float64), table_height=None)
