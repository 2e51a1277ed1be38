"""Simulator: the knob and cube scenes' model arrays on a device, stepped by one fused kernel.

Builder -> model -> state/control -> step, as in Newton/Brax: :func:`load_scene` builds the numpy
:class:`SceneModel`, :class:`Simulator` puts it on a device and owns the kernels, and
:meth:`Simulator.step` (:class:`~dexmots_rl.sim._hand_sim.HandSimulator`'s) maps ``(joint_q, joint_qd, control,
params)`` tensors to the next state plus observations. The state lives in torch tensors owned by the caller (the env keeps them in its
TensorDict), so a step is a pure function and SHAC can chain gradients through many of them.
"""

from __future__ import annotations

import numpy as np
import torch
import warp as wp

from ._constants import GEOM_CONVEX, OBJECT_STOP_FREQUENCY
from ._kernels import build_kernels
from ._mjcf_shapes import MAX_PLANES
from ._energy import scene_object_energy
from ._model import HINGE, OBJECT_FREE, OBJECT_HINGE, ContactParams, SceneModel
from ._hand_sim import PAST_STOP_HINGE, HandSimulator, warp_float
from ._stepper import Trajectory, launch_stream

__all__ = ["Simulator"]


def _box_of_planes(planes) -> tuple[np.ndarray, np.ndarray] | None:
    """(centre, half extents) when the face planes [K, 4] (n . p = d) are the six faces of an axis-aligned
    box, else None."""
    planes = np.asarray(planes, dtype=np.float64).reshape(-1, 4)
    if len(planes) != 6:
        return None
    lo, hi = np.full(3, np.nan), np.full(3, np.nan)
    for n, d in zip(planes[:, :3], planes[:, 3]):
        axis = int(np.argmax(np.abs(n)))
        if not np.allclose(np.abs(n), np.eye(3)[axis], atol=1e-12):
            return None
        if n[axis] > 0:
            hi[axis] = d
        else:
            lo[axis] = -d
    if np.isnan(lo).any() or np.isnan(hi).any() or (hi <= lo).any():
        return None
    return 0.5 * (hi + lo), 0.5 * (hi - lo)


class Simulator(HandSimulator):
    """Many worlds of a knob or cube scene on one device; each env step is ``substeps`` kernel launches (the
    options are :class:`~dexmots_rl.sim._hand_sim.HandSimulator`'s).

    Example:
        >>> import torch
        >>> from dexmots_rl.assets import asset_path
        >>> from dexmots_rl.sim import Simulator, load_scene
        >>> sim = Simulator(load_scene(asset_path("claw_screw.xml")), num_worlds=4)
        >>> q, qd = sim.initial_state()
        >>> out = sim.step(q, qd, sim.zero_control(), sim.default_params())
        >>> out.joint_q.shape
        torch.Size([4, 5])
    """

    def __init__(
        self,
        scene: SceneModel,
        num_worlds: int,
        *,
        device: str = "cpu",
        dtype: torch.dtype = torch.float32,
        substeps: int = 16,
        dt: float | None = None,
        contact: ContactParams | None = None,
        adjoint_clip: float | None = None,
    ):
        if scene.object_shape == GEOM_CONVEX and len(scene.object_planes) > MAX_PLANES:
            raise ValueError(f"object has {len(scene.object_planes)} faces; at most {MAX_PLANES} are supported")
        super().__init__(scene, num_worlds, device=device, dtype=dtype, substeps=substeps, dt=dt, contact=contact,
                         adjoint_clip=adjoint_clip)
        # run each env step's launches as captured graphs (_stepper.py): always on CUDA; on CPU the blocks of
        # worlds in threads are faster, and setting this before the first step selects the graphs there too
        self.graphs = not self.device.is_cpu
        self.nq = scene.num_hand_dofs + scene.object_nq
        self.nv = scene.num_hand_dofs + scene.object_nv
        self.nu = scene.num_hand_dofs
        self.num_bodies = scene.num_hand_dofs + 1
        # (centre, half extents) in m, object frame, of a convex object that is an axis-aligned box (the kernels'
        # box_object; tasks read it too, e.g. how far a turned cube reaches below its centre), else None
        self.object_box = _box_of_planes(scene.object_planes) if scene.object_shape == GEOM_CONVEX else None
        self.kernels = build_kernels(
            warp_float(dtype),
            scene.num_fingers,
            scene.joints_per_finger,
            scene.points_per_link,
            len(scene.object_planes),
            scene.object_kind,
            scene.object_shape,
            bool((np.asarray(scene.joint_type) == HINGE).all()),
            *((scene.num_palm_boxes, len(scene.object_point_pos)) if scene.num_palm_boxes and not scene.articulated
              else ()),
            object_limited=scene.object_limited,
            box_object=self.object_box is not None,
        )
        self.model = self._make_model()
        # adjoint container for the (constant) model struct: its arrays are left null and the model's arrays hold
        # no gradient, so the reverse pass skips every model-gradient accumulation (otherwise one
        # read-modify-write per model read, shared by all worlds and threads)
        self.adjoint_model = self.kernels.Model()

    # ----------------------------------------------------------------------------------------- set-up
    def _make_model(self):
        s, k, c, arr = self.scene, self.kernels, self.contact, self._array
        wdt = warp_float(self.dtype)
        m = k.Model()
        self._fill_finger_chains(m, k, wdt)
        m.jtype = wp.array(s.joint_type.astype(np.int32), dtype=wp.int32, device=self.device)
        # per link: how far its contact spheres reach from the link origin (kernels' link_near test)
        pts = np.asarray(s.point_pos, dtype=np.float64).reshape(s.num_fingers * s.joints_per_finger, -1, 3)
        rad = np.asarray(s.point_radius, dtype=np.float64).reshape(pts.shape[:2])
        m.link_reach = arr(np.where(rad > 0, np.linalg.norm(pts, axis=-1) + rad, 0.0).max(-1), wdt)
        m.obj_base_pos, m.obj_base_rot = k.vec3(*s.object_base_pos), k.mat33(*s.object_base_rot.ravel())
        m.obj_axis, m.obj_mass = k.vec3(*s.object_axis), wdt(s.object_mass)
        m.obj_com, m.obj_inertia = k.vec3(*s.object_com), k.mat33(*s.object_inertia.ravel())
        axis, com = np.asarray(s.object_axis, dtype=np.float64), np.asarray(s.object_com, dtype=np.float64)
        arm = np.cross(axis, com)
        m.obj_axial_inertia = wdt(axis @ np.asarray(s.object_inertia) @ axis + s.object_mass * arm @ arm
                                  + s.object_armature)
        m.obj_bound = wdt(s.object_bound)
        # a hinge's inertia may be singular off its axis (only the axial inertia is read for it)
        inv_inertia = np.zeros((3, 3)) if s.object_kind == OBJECT_HINGE else np.linalg.inv(np.asarray(s.object_inertia,
                                                                                                   dtype=np.float64))
        m.obj_inv_inertia = k.mat33(*inv_inertia.ravel())
        if s.object_limited:
            m.obj_lower, m.obj_upper = wdt(s.object_range[0]), wdt(s.object_range[1])
            m.obj_limit_ke = wdt(float(m.obj_axial_inertia) * OBJECT_STOP_FREQUENCY**2)
        planes = s.object_planes if len(s.object_planes) else np.zeros((1, 4))
        m.planes = arr(planes, k.vec4)
        if self.object_box is not None:
            m.obj_box_center, m.obj_box_half = (k.vec3(*v) for v in self.object_box)
        m.shape_size = k.vec3(*s.object_shape_size, 0.0)
        m.sdf = wp.array(np.asarray(s.object_sdf, dtype=np.float64), dtype=wdt, device=self.device)
        m.sdf_origin, m.sdf_cell = k.vec3(*s.object_sdf_origin), wdt(s.object_sdf_cell)
        m.mu, m.smooth = wdt(c.friction), wdt(c.surface_smoothing)
        if k.palm is not None:
            m.palm_pos, m.palm_rot = arr(s.palm_box_pos, k.vec3), arr(s.palm_box_rot, k.mat33)
            m.palm_half = arr(s.palm_box_half, k.vec3)
            m.obj_point_pos, m.obj_point_radius = arr(s.object_point_pos, k.vec3), arr(s.object_point_radius, wdt)
            m.palm_ke, m.palm_beta = wdt(c.palm_stiffness), wdt(c.palm_sharpness)
            m.palm_smooth = wdt(c.palm_smoothing)
        return m

    @property
    def num_params(self) -> int:
        """Columns of the packed parameter array the kernels read (at least one, so it is never empty)."""
        return max(1, len(self.scene.param_names))

    def new_trajectory(self, save: bool) -> Trajectory:
        return Trajectory(self, save=save)

    @property
    def object_is_free(self) -> bool:
        return self.scene.object_kind == OBJECT_FREE

    def outside_physics(self, joint_q, body_pose, params=None) -> torch.Tensor:
        # no table in these scenes (a dropped cube is its task's termination): only a limited hinge's range
        if not self.scene.object_limited:
            return torch.zeros(joint_q.shape[0], dtype=torch.bool, device=joint_q.device)
        lower, upper = self.scene.object_range
        angle = joint_q[:, self.nu]
        return (angle < lower - PAST_STOP_HINGE) | (angle > upper + PAST_STOP_HINGE)

    def object_energy(self, joint_q, joint_qd, params=None) -> torch.Tensor:
        params = self.default_params() if params is None else params
        stiffness, rest = (params[n] if n in params.keys() else None for n in ("joint_stiffness", "joint_rest"))
        return scene_object_energy(self.scene, joint_q[:, self.nu:], joint_qd[:, self.nu:], stiffness, rest)

    def observe(self, joint_q, joint_qd=None, params=None):
        """Body poses [N, B, 7] and fingertips [N, F, 3] for a state, without stepping (``params``: unused, the
        scene has one object; :meth:`ArticulatedSimulator.observe` reads its variant there)."""
        joint_qd = self._zeros(joint_q.shape[0], self.nv) if joint_qd is None else joint_qd
        q = wp.from_torch(joint_q.detach().to(self.dtype).contiguous())
        qd = wp.from_torch(joint_qd.detach().to(self.dtype).contiguous())
        pose = self._zeros(joint_q.shape[0], self.num_bodies * 7)
        tips = self._zeros(joint_q.shape[0], self.scene.num_fingers * 3)
        wp.launch(self.kernels.observe, dim=joint_q.shape[0], inputs=[self.model, q, qd],
                  outputs=[wp.from_torch(pose), wp.from_torch(tips), 0], device=self.device,
                  stream=launch_stream(self.device))
        return pose.view(-1, self.num_bodies, 7), tips.view(-1, self.scene.num_fingers, 3)
