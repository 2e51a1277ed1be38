"""Scene description: an MJCF file compiled by MuJoCo, reduced to the arrays our kernels need.

The simulator is specialised for what every DexMOTS scene is: a fixed-base hand made of serial finger
chains (one hinge or slide joint per link) plus one object, either on a hinge or free-floating. MuJoCo does
the parsing and compilation (inertias from geometry, defaults, angles), so there is no XML code here; this
module only walks the compiled ``MjModel``. Naming conventions in the MJCF:

* body ``hand`` is the fixed base; each child body starts one finger chain;
* body ``object`` is the operated object; its joint is a ``hinge`` (e.g. a knob) or ``free`` (e.g. a cube);
* sites named ``*tip*`` mark fingertips (one per finger, on its last link);
* box geoms on body ``hand`` that collide with the object's geom in MuJoCo terms (``contype``/``conaffinity``)
  are the palm's collision boxes (at most ``mjcf_shapes.MAX_PALM_BOXES``); a free object rests on and pushes against
  them. Visual-only palm geoms (``contype="0" conaffinity="0"``) are ignored.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ._mjcf_shapes import (
    AssetError,
    _body_inertia,
    _link_points,
    _object_points,
    _object_shape,
    _palm_boxes,
    _quat_to_mat,
)
from ._constants import HAND_FRICTION
from ._object_model import HINGE, SLIDE  # one joint-kind enumeration: the hand's and the object's joints
from ._object_model import single_body_error

__all__ = ["AssetError", "SceneModel", "ContactParams", "OBJECT_PARAMS", "load_scene"]

OBJECT_HINGE, OBJECT_FREE = 0, 1
# per-world object joint parameters, by name: the kernels read column OBJECT_PARAMS.index(name) of the
# packed [N, P] array the simulator builds from the named tensors (see Simulator.pack_params)
OBJECT_PARAMS = ("joint_damping", "joint_friction", "joint_stiffness", "joint_rest")


@dataclasses.dataclass(frozen=True)
class ContactParams:
    """Relaxed penalty contact between finger geometry and the object.

    The normal force is ``stiffness * softplus(sharpness * penetration) / sharpness``: it is smooth and
    non-zero slightly before touching, which is what gives useful gradients before contact is made.
    ``damping`` (s/m) scales the force by ``max(1 - damping * v_normal, 0)`` (Hunt-Crossley style); against a
    moving object that damping (``damping * force``) is integrated implicitly along the normal, divided by
    ``1 + dt * damping * force * w`` with ``w`` the object's mobility there, so that a substep never reverses the
    normal velocity of a light object pressed hard (explicit, it did, and contact made energy).
    Friction is Coulomb with the slip velocity smoothed by ``slip_velocity``:
    ``f_t = -mu * f_n * v_t / sqrt(|v_t|^2 + slip_velocity^2)``. Near sticking this is a viscous damper of
    ``mu * f_n / slip_velocity`` integrated explicitly; at 0.02 m/s (about 1.5e4 N s/m on the claw) it is past
    the explicit stability limit at dt = 1/960 s and gradients grew ~1e4x over 32 steps (measured with
    ``dexmots-bench grad``'s velocity loss); 0.2 m/s keeps them bounded (growth ~1.4).
    """

    stiffness: float = 2.0e4
    damping: float = 1.0
    sharpness: float = 200.0
    friction: float = HAND_FRICTION
    slip_velocity: float = 0.2
    surface_smoothing: float = 0.01
    points_per_capsule: int = 4
    # palm contact (a free object's surface samples against the hand's fixed collision boxes): the same law
    # with its own stiffness (N/m per sample point) and sharpness (1/m). The fingers' long-range law
    # (sharpness 200/m: ~ stiffness / sharpness * exp(-sharpness * gap) = 100 N * exp(-200 gap)) would hold
    # a 0.11 kg cube ~3 cm above the palm; at 1e4/m it is 2 N * exp(-1e4 gap) per sample and the cube rests
    # ~0.3 mm above it. Damping, friction and slip velocity are the fingers' (``damping`` etc.).
    palm_stiffness: float = 2.0e4
    palm_sharpness: float = 1.0e4
    palm_smoothing: float = 1.0e-3  # m: edge rounding of the palm boxes' smooth signed distance


@dataclasses.dataclass
class SceneModel:
    """Numpy arrays describing one scene (shared by every world)."""

    path: str
    num_fingers: int
    joints_per_finger: int
    points_per_link: int
    finger_names: list[str]
    joint_names: list[str]
    body_names: list[str]
    # finger chains, indexed [finger * joints_per_finger + link]
    finger_base_pos: np.ndarray  # [F, 3] world position of the frame each finger chain starts from
    finger_base_rot: np.ndarray  # [F, 3, 3]
    link_offset_pos: np.ndarray  # [F*J, 3] link frame in its parent's frame, at q = 0
    link_offset_rot: np.ndarray  # [F*J, 3, 3]
    joint_axis: np.ndarray  # [F*J, 3] in the link frame
    joint_type: np.ndarray  # [F*J] HINGE or SLIDE
    link_mass: np.ndarray  # [F*J]
    link_com: np.ndarray  # [F*J, 3] in the link frame
    link_inertia: np.ndarray  # [F*J, 3, 3] about the com, in the link frame
    dof_armature: np.ndarray  # [F*J]
    dof_damping: np.ndarray  # [F*J]
    dof_friction: np.ndarray  # [F*J]
    dof_lower: np.ndarray  # [F*J]
    dof_upper: np.ndarray  # [F*J]
    dof_limited: np.ndarray  # [F*J] bool
    dof_inertia0: np.ndarray  # [F*J] diagonal of the mass matrix at q = 0 (for stiffness scaling)
    actuator_gear: np.ndarray  # [F*J] motor gear per hand dof (0 when unactuated)
    actuator_effort: np.ndarray  # [F*J] largest joint torque the motor gives (0: unlimited)
    # contact sample points on finger links, indexed [(finger * J + link) * P + point]
    point_pos: np.ndarray  # [F*J*P, 3] in the link frame
    point_radius: np.ndarray  # [F*J*P] 0 = padding
    tip_pos: np.ndarray  # [F, 3] fingertip site in the last link's frame
    # the object
    object_kind: int
    object_base_pos: np.ndarray  # [3] hinge: the frame the hinge rotates in; free: unused
    object_base_rot: np.ndarray  # [3, 3]
    object_axis: np.ndarray  # [3] hinge axis in the object frame
    object_mass: float
    object_com: np.ndarray  # [3] in the object frame
    object_inertia: np.ndarray  # [3, 3] about the com, object frame
    object_armature: float
    object_damping: float
    object_friction: float
    object_stiffness: float  # joint spring toward object_rest (MJCF joint stiffness)
    object_rest: float  # the spring's rest position (MJCF springref)
    object_q0: np.ndarray  # initial generalized coordinates of the object
    object_shape: int
    object_planes: np.ndarray  # [K, 4] outward normal + offset (n.p <= d inside), object frame
    object_shape_size: np.ndarray  # [2] sphere: (radius, 0); cylinder: (radius, half-height)
    object_bound: float  # radius of a sphere about the object origin enclosing its geometry
    object_sdf: np.ndarray  # [X, Y, Z] signed distance grid (negative inside), object frame; [1,1,1] if unused
    object_sdf_origin: np.ndarray  # [3] position of grid point (0, 0, 0)
    object_sdf_cell: float  # grid spacing
    gravity: np.ndarray
    timestep: float
    # palm contact (free objects only; empty arrays when the scene has no colliding palm box): the hand is
    # fixed, so the boxes are stored in the world frame
    palm_box_pos: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3)))  # [B, 3] centre (m)
    palm_box_rot: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3, 3)))  # [B, 3, 3] box -> world
    palm_box_half: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3)))  # [B, 3] half sizes (m)
    # the object's surface samples tested against the palm boxes (object frame, m): a box's 8 corners, 12
    # edge midpoints and 6 face centres (radius 0); a sphere's centre with its radius; a cylinder's two
    # cap centres and 8 points on each cap rim (radius 0); a convex mesh's hull vertices (radius 0)
    object_point_pos: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3)))  # [S, 3]
    object_point_radius: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))  # [S]

    @property
    def num_palm_boxes(self) -> int:
        return len(self.palm_box_pos)
    # the hinge object's range (rad; MJCF joint range when limited): a stiff implicit limit spring holds it
    object_limited: bool = False
    object_range: tuple[float, float] = (-1e9, 1e9)

    @property
    def num_hand_dofs(self) -> int:
        return self.num_fingers * self.joints_per_finger

    @property
    def articulated(self) -> bool:
        """The object moves on a joint (its coordinates are joint angles), not as a free body."""
        return self.object_kind == OBJECT_HINGE

    @property
    def param_names(self) -> tuple[str, ...]:
        """Names of the per-world physical parameters (``("sim", "params", name)``, each ``[N, 1]``); a free
        object has no joint and so no parameters."""
        return OBJECT_PARAMS if self.articulated else ()

    def default_param_values(self) -> dict[str, float]:
        """The MJCF's value of every parameter in :attr:`param_names`."""
        values = {"joint_damping": self.object_damping, "joint_friction": self.object_friction,
                  "joint_stiffness": self.object_stiffness, "joint_rest": self.object_rest}
        return {name: values[name] for name in self.param_names}

    @property
    def object_nq(self) -> int:
        return 1 if self.object_kind == OBJECT_HINGE else 7

    @property
    def object_nv(self) -> int:
        return 1 if self.object_kind == OBJECT_HINGE else 6


def load_scene(path: str | Path, *, contact: ContactParams | None = None, articulated: bool = False):
    """Compile an MJCF file with MuJoCo and extract the hand chains and the object: a :class:`SceneModel` for one
    hinged or free object body (the knob, the cube), an :class:`~dexmots_rl.sim.ArticulatedScene` for an object
    tree. ``articulated=True`` reads a single body as an object tree too (a hinged body: one part on a fixed
    mount; a free body: a free base without parts), for :class:`~dexmots_rl.sim.ArticulatedSimulator`.

    Raises :class:`AssetError` naming the file and the problem when it does not parse or does not
    follow the conventions in the module docstring.
    """
    import mujoco

    contact = contact or ContactParams()
    path = Path(path)
    if not path.is_file():
        raise AssetError(f"asset file {str(path)!r} does not exist")
    try:
        m = mujoco.MjModel.from_xml_path(str(path))
    except Exception as exc:  # mujoco raises ValueError with the parser's message
        raise AssetError(f"asset file {str(path)!r} does not parse: {exc}") from exc
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)

    hand_fields = _hand_chains(m, d, path, contact)
    hand = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "hand")
    obj = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "object")
    if is_articulated_scene(m) or articulated:
        return _tree_scene(m, d, path, hand_fields, hand, obj)
    if m.body_jntnum[obj] != 1:
        raise AssetError("body 'object' needs exactly one joint (hinge or free)")
    oj = int(m.body_jntadr[obj])
    if int(m.jnt_type[oj]) == int(mujoco.mjtJoint.mjJNT_HINGE):
        kind, q0 = OBJECT_HINGE, m.qpos0[m.jnt_qposadr[oj] : m.jnt_qposadr[oj] + 1].copy()
    elif int(m.jnt_type[oj]) == int(mujoco.mjtJoint.mjJNT_FREE):
        kind, q0 = OBJECT_FREE, m.qpos0[m.jnt_qposadr[oj] : m.jnt_qposadr[oj] + 7].copy()
    else:
        raise AssetError(single_body_error(m, oj))
    parent = m.body_parentid[obj]
    base_rot = d.xmat[parent].reshape(3, 3) @ _quat_to_mat(m.body_quat[obj])
    base_pos = d.xpos[parent] + d.xmat[parent].reshape(3, 3) @ m.body_pos[obj]
    shape, planes, size, bound, (sdf, sdf_origin, sdf_cell) = _object_shape(m, obj)
    omass, ocom, oinertia = _body_inertia(m, obj)
    odof = int(m.jnt_dofadr[oj])
    ogeom = [g for g in range(m.ngeom) if m.geom_bodyid[g] == obj][0]
    palm = _palm_boxes(m, d, hand, ogeom) if kind == OBJECT_FREE else (np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3)))
    samples = _object_points(m, ogeom) if len(palm[0]) else (np.zeros((0, 3)), np.zeros(0))

    hand_fields["body_names"] = hand_fields["body_names"] + ["object"]
    return SceneModel(
        path=str(path),
        **hand_fields,
        object_kind=kind,
        object_base_pos=base_pos,
        object_base_rot=base_rot,
        object_axis=m.jnt_axis[oj].copy(),
        object_mass=omass,
        object_com=ocom,
        object_inertia=oinertia,
        object_armature=float(m.dof_armature[odof]),
        object_damping=float(m.dof_damping[odof]),
        object_friction=float(m.dof_frictionloss[odof]),
        object_stiffness=float(m.jnt_stiffness[oj]),
        object_rest=float(m.qpos_spring[m.jnt_qposadr[oj]]) if kind == OBJECT_HINGE else 0.0,
        object_q0=q0,
        object_shape=shape,
        object_planes=planes,
        object_shape_size=size,
        object_bound=bound,
        object_sdf=sdf,
        object_sdf_origin=sdf_origin,
        object_sdf_cell=sdf_cell,
        palm_box_pos=palm[0],
        palm_box_rot=palm[1],
        palm_box_half=palm[2],
        object_point_pos=samples[0],
        object_point_radius=samples[1],
        object_limited=bool(m.jnt_limited[oj]) and kind == OBJECT_HINGE,
        object_range=(float(m.jnt_range[oj, 0]), float(m.jnt_range[oj, 1])) if m.jnt_limited[oj] else (-1e9, 1e9),
    )


def _tree_scene(m, d, path: Path, hand_fields: dict, hand: int, obj: int):
    """The :class:`~dexmots_rl.sim.ArticulatedScene` of a compiled model whose body ``obj`` is an object tree or,
    read as one, a single hinged or free body (see :func:`load_scene`)."""
    from ._articulated_scene import ArticulatedScene, object_geoms, with_mount
    from ._object_model import object_tree, single_body_tree

    obj_geom = [g for g in range(m.ngeom) if m.geom_bodyid[g] == obj][0]
    palm = _palm_boxes(m, d, hand, obj_geom)
    if is_articulated_scene(m):
        return ArticulatedScene(path=str(path), hand=hand_fields, tree=object_tree(m, d), geoms=object_geoms(m),
                                palm=palm)
    tree, geoms = single_body_tree(m, d), object_geoms(m)
    if not tree.free:  # the palm pushes a free object only, as in SceneModel
        geoms, palm = with_mount(geoms), tuple(np.zeros((0,) + a.shape[1:]) for a in palm)
    return ArticulatedScene(path=str(path), hand=hand_fields, tree=tree, geoms=geoms, palm=palm)


def _hand_chains(m, d, path: Path, contact: ContactParams) -> dict:
    """The hand's fields of :class:`SceneModel` (finger chains, contact spheres, drives), read from the compiled
    model ``m`` / data ``d`` of ``path``; the object's body must exist (its geometry is read elsewhere)."""
    import mujoco

    def name(obj, i):
        return mujoco.mj_id2name(m, obj, i) or f"#{i}"

    hand = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "hand")
    obj = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "object")
    if hand < 0 or obj < 0:
        raise AssetError(f"asset file {str(path)!r} needs bodies named 'hand' and 'object'")
    if m.body_jntnum[hand] != 0:
        raise AssetError("body 'hand' must be fixed (no joints)")
    children = {b: [c for c in range(m.nbody) if m.body_parentid[c] == b and c != b] for b in range(m.nbody)}

    chains = []
    for root in children[hand]:
        chain, b = [], root
        while True:
            if m.body_jntnum[b] != 1:
                raise AssetError(f"finger body {name(mujoco.mjtObj.mjOBJ_BODY, b)!r} needs exactly one joint")
            chain.append(b)
            if not children[b]:
                break
            if len(children[b]) > 1:
                raise AssetError(f"finger body {name(mujoco.mjtObj.mjOBJ_BODY, b)!r} branches; fingers are chains")
            b = children[b][0]
        chains.append(chain)
    if not chains or len({len(c) for c in chains}) != 1:
        raise AssetError("every finger must have the same number of links (at least one)")
    num_f, num_j = len(chains), len(chains[0])
    hand_bodies = [b for c in chains for b in c]
    jids = [int(m.body_jntadr[b]) for b in hand_bodies]
    if [int(m.jnt_dofadr[j]) for j in jids] != list(range(num_f * num_j)):
        raise AssetError("hand joints must come first in the MJCF, finger by finger")
    for j in jids:
        if int(m.jnt_type[j]) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            raise AssetError(f"joint {name(mujoco.mjtObj.mjOBJ_JOINT, j)!r}: hand joints are hinge or slide")
        if np.abs(m.jnt_pos[j]).max() > 1e-9:
            raise AssetError(f"joint {name(mujoco.mjtObj.mjOBJ_JOINT, j)!r} must sit at its body origin")

    per_link = [_link_points(m, b, contact.points_per_capsule) for b in hand_bodies]
    num_p = max(1, max(len(p) for p in per_link))
    point_pos = np.zeros((len(hand_bodies) * num_p, 3))
    point_radius = np.zeros(len(hand_bodies) * num_p)
    for i, pts in enumerate(per_link):
        for k, (p, r) in enumerate(pts):
            point_pos[i * num_p + k], point_radius[i * num_p + k] = p, r

    tips = []
    for chain in chains:
        sites = [s for s in range(m.nsite) if m.site_bodyid[s] == chain[-1] and "tip" in name(mujoco.mjtObj.mjOBJ_SITE, s)]
        tips.append(m.site_pos[sites[0]].copy() if sites else np.zeros(3))

    inertias = [_body_inertia(m, b) for b in hand_bodies]
    gear, effort = np.zeros(num_f * num_j), np.zeros(num_f * num_j)
    for a in range(m.nu):
        if int(m.actuator_trntype[a]) == int(mujoco.mjtTrn.mjTRN_JOINT) and m.actuator_trnid[a, 0] in jids:
            dof = jids.index(m.actuator_trnid[a, 0])
            gear[dof] = m.actuator_gear[a, 0]
            # the drive saturates where the motor does: |gear| * ctrl range, or the force range if tighter
            limits = []
            if m.actuator_ctrllimited[a]:
                limits.append(abs(gear[dof]) * np.abs(m.actuator_ctrlrange[a]).max())
            if m.actuator_forcelimited[a]:
                limits.append(np.abs(m.actuator_forcerange[a]).max())
            effort[dof] = min(limits) if limits else 0.0
    dofs = np.arange(num_f * num_j)
    limited = m.jnt_limited[jids].astype(bool)

    return dict(
        num_fingers=num_f,
        joints_per_finger=num_j,
        points_per_link=num_p,
        finger_names=[name(mujoco.mjtObj.mjOBJ_BODY, c[0]) for c in chains],
        joint_names=[name(mujoco.mjtObj.mjOBJ_JOINT, j) for j in jids],
        finger_base_pos=np.stack([d.xpos[hand]] * num_f),
        finger_base_rot=np.stack([d.xmat[hand].reshape(3, 3)] * num_f),
        link_offset_pos=m.body_pos[hand_bodies].copy(),
        link_offset_rot=np.stack([_quat_to_mat(m.body_quat[b]) for b in hand_bodies]),
        joint_axis=m.jnt_axis[jids].copy(),
        joint_type=np.array([HINGE if int(m.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_HINGE) else SLIDE for j in jids]),
        link_mass=np.array([i[0] for i in inertias]),
        link_com=np.stack([i[1] for i in inertias]),
        link_inertia=np.stack([i[2] for i in inertias]),
        dof_armature=m.dof_armature[dofs].copy(),
        dof_damping=m.dof_damping[dofs].copy(),
        dof_friction=m.dof_frictionloss[dofs].copy(),
        dof_lower=np.where(limited, m.jnt_range[jids, 0], -1e9),
        dof_upper=np.where(limited, m.jnt_range[jids, 1], 1e9),
        dof_limited=limited,
        dof_inertia0=m.dof_M0[dofs].copy(),
        actuator_gear=gear,
        actuator_effort=effort,
        point_pos=point_pos,
        point_radius=point_radius,
        tip_pos=np.stack(tips),
        body_names=[name(mujoco.mjtObj.mjOBJ_BODY, b) for b in hand_bodies],
        gravity=m.opt.gravity.copy(),
        timestep=float(m.opt.timestep),
    )


def is_articulated_scene(m) -> bool:
    """Whether body ``object`` of the compiled model is an articulated tree (a base with moving parts below it,
    see :mod:`._object_model`) rather than the single hinged or free body of the knob and cube scenes."""
    import mujoco

    obj = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "object")
    return obj >= 0 and any(int(m.body_parentid[b]) == obj for b in range(obj + 1, m.nbody))
