"""Simulator (model arrays on a device) and SimStep, the autograd Function for one env step.

Builder -> model -> state/control -> step, as in Newton/Brax: :func:`load_scene` builds the numpy
:class:`SceneModel`, :class:`Simulator` puts it on a device and owns the kernels, and
:meth:`Simulator.step` maps ``(joint_q, joint_qd, control, params)`` tensors to the next state plus
observations. The state lives in torch tensors owned by the caller (the env keeps them in its
TensorDict), so a step is a pure function and SHAC can chain gradients through many of them.
"""

from __future__ import annotations

import dataclasses
import weakref

import numpy as np
import torch
import warp as wp
from tensordict import TensorDict

from .kernels import build_kernels
from .mjcf_shapes import MAX_PLANES
from .model import HINGE, OBJECT_HINGE, ContactParams, SceneModel
from .stepper import Trajectory, launch_stream

__all__ = ["Control", "StepOutput", "Simulator", "SimStep", "check_device"]

# the object's range stop: implicit (stable at any stiffness), k = axial inertia x (1000 rad/s)^2; the
# stapler's arm (3.6e-4 kg m^2) gets 360 N m/rad and goes ~0.01 rad past its stop under 1 N m
OBJECT_LIMIT_FREQUENCY = 1000.0  # rad/s
LIMIT_FREQUENCY = 60.0  # rad/s: joint-limit springs are as stiff as a 60 rad/s oscillator on the joint's inertia


@dataclasses.dataclass
class Control:
    """Joint-space drive for the hand, one row per world: ``tau + kp (q_target - q) - kd qd``.

    Torque control sets ``tau`` only; position control sets ``q_target``/``kp``/``kd``; variable
    impedance also varies ``kp`` per step. The PD terms are integrated implicitly (stable at any gain) and
    saturate smoothly at the motor's effort (``|gear| * ctrlrange`` of the MJCF motor): ``e tanh(drive / e)``.
    ``object_wrench`` [N, 6] (optional) is an external force + torque on the object in the world frame,
    torque about the object origin (a hinge feels its axis component): the wrench planner drives the
    object alone with it.
    """

    tau: torch.Tensor
    q_target: torch.Tensor
    kp: torch.Tensor
    kd: torch.Tensor
    object_wrench: torch.Tensor | None = None


class StepOutput(tuple):
    """``(joint_q, joint_qd, wrench, contact_force, body_pose, fingertips)`` after one env step.

    wrench: [N, 6] mean over substeps of the hand's net contact force (N) and torque (N m) on the object
    (world frame, torque about the object origin): the fingers' and, where the palm collides with a free
    object, the palm's; contact_force: [N] mean over substeps of the fingers' summed normal contact force
    magnitudes (N);
    body_pose: [N, B, 7] pos + wxyz quat of every hand link then the object; fingertips: [N, F, 3].
    """

    __slots__ = ()
    names = ("joint_q", "joint_qd", "wrench", "contact_force", "body_pose", "fingertips")

    def __getattr__(self, item):
        return self[self.names.index(item)]


def _wp_dtype(dtype: torch.dtype):
    if dtype == torch.float32:
        return wp.float32
    if dtype == torch.float64:
        return wp.float64
    raise ValueError(f"dtype must be torch.float32 or torch.float64, got {dtype}")



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


def check_device(device) -> torch.device:
    """``torch.device(device)`` with its index (``"cuda"`` is the current GPU, ``cuda:<i>``: warp's device
    table needs the index), or a ``ValueError`` naming it when it is a GPU this machine lacks (warp would
    fail later with an ``IndexError`` deep in its device table)."""
    dev = torch.device(device)
    if dev.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        index = (torch.cuda.current_device() if count else 0) if dev.index is None else dev.index
        if index >= count:
            raise ValueError(f"device {str(device)!r} is not available: this machine has {count} CUDA device(s)"
                             f"{'' if count else ' (or torch was built without CUDA)'}; use device='cpu'")
        dev = torch.device("cuda", index)
    elif dev.type != "cpu":
        raise ValueError(f"device {str(device)!r} is not supported: use 'cpu' or 'cuda[:index]'")
    return dev


class Simulator:
    """Many worlds of one scene on one device; each env step is ``substeps`` kernel launches.

    ``adjoint_clip`` (default ``None``: exact gradients) scales down, in every backward step, the gradient
    of any world whose state adjoint exceeds that multiple of the median world's (training option; counted
    in :attr:`clipped_adjoints`).

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
        device: str = "cpu",
        dtype: torch.dtype = torch.float32,
        substeps: int = 16,
        dt: float | None = None,
        contact: ContactParams | None = None,
        adjoint_clip: float | None = None,
    ):
        if num_worlds <= 0:
            raise ValueError(f"num_worlds must be positive, got {num_worlds}")
        if substeps <= 0:
            raise ValueError(f"substeps must be positive, got {substeps}")
        if adjoint_clip is not None and not adjoint_clip >= 1.0:
            raise ValueError(f"adjoint_clip must be None or >= 1 (a multiple of the median world), got {adjoint_clip}")
        if scene.object_shape == 0 and len(scene.object_planes) > MAX_PLANES:
            raise ValueError(f"object has {len(scene.object_planes)} faces; at most {MAX_PLANES} are supported")
        self.scene, self.num_worlds, self.substeps = scene, num_worlds, substeps
        self.torch_device = check_device(device)
        self.device = wp.device_from_torch(self.torch_device)
        self.dtype = dtype
        self.sub_dt = scene.timestep if dt is None else dt / substeps
        self.dt = self.sub_dt * substeps
        self.contact = contact or ContactParams()
        self.adjoint_clip = adjoint_clip
        self._clipped = torch.zeros((), dtype=torch.int64, device=self.torch_device)  # see clipped_adjoints
        # run each env step's launches as captured graphs (stepper.py): always on CUDA; on CPU the blocks of
        # worlds in threads are faster, and setting this before the first step selects the graphs there too
        self.graphs = not self.device.is_cpu
        self.nq = scene.num_hand_dofs + scene.object_nq
        self.nv = scene.num_hand_dofs + scene.object_nv
        self.nu = scene.num_hand_dofs
        self.num_bodies = scene.num_hand_dofs + 1
        # (centre, half extents) in m, object frame, of a convex object that is an axis-aligned box (the kernels'
        # box_object; tasks read it too, e.g. how far a turned cube reaches below its centre), else None
        self.object_box = _box_of_planes(scene.object_planes) if scene.object_shape == 0 else None
        self.kernels = build_kernels(
            _wp_dtype(dtype),
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

    # ----------------------------------------------------------------------------------------- set-up
    def _make_model(self):
        s, k, c = self.scene, self.kernels, self.contact
        wdt = _wp_dtype(self.dtype)

        def arr(x, dtype):
            return wp.array(np.asarray(x, dtype=np.float64), dtype=dtype, device=self.device)

        limit_ke = s.dof_inertia0 * LIMIT_FREQUENCY**2 * s.dof_limited
        m = k.Model()
        m.base_pos, m.base_rot = arr(s.finger_base_pos, k.vec3), arr(s.finger_base_rot, k.mat33)
        m.off_pos, m.off_rot = arr(s.link_offset_pos, k.vec3), arr(s.link_offset_rot, k.mat33)
        m.axis = arr(s.joint_axis, k.vec3)
        m.jtype = wp.array(s.joint_type.astype(np.int32), dtype=wp.int32, device=self.device)
        m.mass, m.com, m.inertia = arr(s.link_mass, wdt), arr(s.link_com, k.vec3), arr(s.link_inertia, k.mat33)
        m.armature, m.damping, m.friction = arr(s.dof_armature, wdt), arr(s.dof_damping, wdt), arr(s.dof_friction, wdt)
        m.lower, m.upper, m.limit_ke = arr(s.dof_lower, wdt), arr(s.dof_upper, wdt), arr(limit_ke, wdt)
        m.effort = arr(s.actuator_effort, wdt)
        m.point_pos, m.point_radius = arr(s.point_pos, k.vec3), arr(s.point_radius, wdt)
        # per link: how far its contact spheres reach from the link origin (kernels' link_near test)
        pts = np.asarray(s.point_pos, dtype=np.float64).reshape(s.num_fingers * s.joints_per_finger, -1, 3)
        rad = np.asarray(s.point_radius, dtype=np.float64).reshape(pts.shape[:2])
        m.link_reach = arr(np.where(rad > 0, np.linalg.norm(pts, axis=-1) + rad, 0.0).max(-1), wdt)
        m.tip_pos = arr(s.tip_pos, k.vec3)
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
            m.obj_limit_ke = wdt(float(m.obj_axial_inertia) * OBJECT_LIMIT_FREQUENCY**2)
        planes = s.object_planes if len(s.object_planes) else np.zeros((1, 4))
        m.planes = arr(planes, k.vec4)
        if self.object_box is not None:
            m.obj_box_center, m.obj_box_half = (k.vec3(*v) for v in self.object_box)
        m.shape_size = k.vec3(*s.object_shape_size, 0.0)
        m.sdf = wp.array(np.asarray(s.object_sdf, dtype=np.float64), dtype=wdt, device=self.device)
        m.sdf_origin, m.sdf_cell = k.vec3(*s.object_sdf_origin), wdt(s.object_sdf_cell)
        m.gravity = k.vec3(*s.gravity)
        m.ke, m.kd, m.beta = wdt(c.stiffness), wdt(c.damping), wdt(c.sharpness)
        m.mu, m.v_slip, m.smooth = wdt(c.friction), wdt(c.slip_velocity), wdt(c.surface_smoothing)
        if k.palm is not None:
            m.palm_pos, m.palm_rot = arr(s.palm_box_pos, k.vec3), arr(s.palm_box_rot, k.mat33)
            m.palm_half = arr(s.palm_box_half, k.vec3)
            m.obj_point_pos, m.obj_point_radius = arr(s.object_point_pos, k.vec3), arr(s.object_point_radius, wdt)
            m.palm_ke, m.palm_beta = wdt(c.palm_stiffness), wdt(c.palm_sharpness)
            m.palm_smooth = wdt(c.palm_smoothing)
        return m

    @property
    def clipped_adjoints(self) -> int:
        """Worlds x steps whose adjoint ``adjoint_clip`` scaled down, since construction (counted on the
        device; reading it synchronises, so read it once per iteration, not per step)."""
        return int(self._clipped)

    def _zeros(self, *shape):
        return torch.zeros(*shape, dtype=self.dtype, device=self.torch_device)

    def initial_state(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The MJCF's reference configuration in every world (hand at 0, object at its q0)."""
        q = self._zeros(self.num_worlds, self.nq)
        q[:, self.nu :] = torch.as_tensor(self.scene.object_q0, dtype=self.dtype)
        return q, self._zeros(self.num_worlds, self.nv)

    def zero_control(self) -> Control:
        z = self._zeros(self.num_worlds, self.nu)
        return Control(z, z, z, z)

    @property
    def num_params(self) -> int:
        """Columns of the packed parameter array the kernels read (at least one, so it is never empty)."""
        return max(1, len(self.scene.param_names))

    def default_params(self) -> TensorDict:
        """Per-world physical parameters from the MJCF, by name (:attr:`SceneModel.param_names`): a
        TensorDict ``[N]`` of ``[N, 1]`` tensors, e.g. ``"joint_damping"``, ``"joint_friction"``."""
        values = {name: torch.full((self.num_worlds, 1), v, dtype=self.dtype, device=self.torch_device)
                  for name, v in self.scene.default_param_values().items()}
        return TensorDict(values, batch_size=[self.num_worlds], device=self.torch_device)

    def pack_params(self, params) -> torch.Tensor:
        """The named parameters (a TensorDict or dict of ``[N, 1]`` tensors) as the ``[N, P]`` array the
        kernels read, in :attr:`SceneModel.param_names` order (differentiable: a cat)."""
        names = self.scene.param_names
        if not names:
            return self._zeros(self.num_worlds, 1)
        missing = [n for n in names if n not in params.keys()]
        if missing:
            raise ValueError(f"params lacks {', '.join(missing)}; this scene's parameters are {', '.join(names)}")
        return torch.cat([params[n].reshape(-1, 1) for n in names], -1)

    # ------------------------------------------------------------------------------------------- step
    def step(self, joint_q, joint_qd, control: Control, params) -> StepOutput:
        """One env step (``substeps`` physics substeps); differentiable w.r.t. every tensor input.
        ``params``: the named per-world parameters (:meth:`default_params`)."""
        n = joint_q.shape[0]
        if n != self.num_worlds:
            raise ValueError(f"joint_q has {n} worlds, the simulator was built for {self.num_worlds}")
        ext = control.object_wrench
        if ext is None:
            if getattr(self, "_no_wrench", None) is None:
                self._no_wrench = self._zeros(n, 6)  # read only: SimStep copies its inputs
            ext = self._no_wrench
        return StepOutput(SimStep.apply(self, joint_q, joint_qd, control.tau, control.q_target, control.kp, control.kd,
                                        self.pack_params(params), ext))

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

    def adjoint_model(self):
        """Adjoint container for the (constant) model struct. Its arrays are left null and the model's
        arrays hold no gradient, so the reverse pass skips every model-gradient accumulation (otherwise
        one read-modify-write per model read, shared by all worlds and threads)."""
        if getattr(self, "_adj_model", None) is None:
            self._adj_model = self.kernels.Model()
        return self._adj_model

    def _replay(self, inputs: list[torch.Tensor]) -> list[torch.Tensor]:
        """Gradient-free step on one persistent trajectory (no saved intermediates)."""
        if getattr(self, "_fast", None) is None:
            self._fast = Trajectory(self, save=False)
        self._fast.load(inputs[0], inputs[1], inputs[2:])
        self._fast.forward()
        return self._fast.outputs()

    def _take_trajectory(self) -> tuple[Trajectory, int]:
        """A taped trajectory from the pool and its lease: hand both back with :meth:`_return_trajectory`
        after the backward pass, or when the step's graph is dropped without one."""
        pool = self.__dict__.setdefault("_pool", [])
        traj = pool.pop() if pool else Trajectory(self)
        traj.lease += 1
        return traj, traj.lease

    def _return_trajectory(self, traj: Trajectory, lease: int) -> None:
        if traj.lease == lease:  # not returned already for this lease (backward, then the graph's release)
            traj.lease += 1
            self._pool.append(traj)


def _clip_outlier_worlds(sim: Simulator, grads: list[torch.Tensor | None]) -> list[torch.Tensor | None]:
    """Scale down every gradient row of a world whose state adjoint is more than ``sim.adjoint_clip`` times
    the median over worlds (scale-free: nothing happens while the worlds' adjoints are alike).

    Worlds are independent, so a world's adjoint only carries its own future rewards; in stiff contact
    it can grow by orders of magnitude over a few steps while the others stay put (measured on the claw:
    median 2e-2, a few worlds 1e2-1e6), and one such world then sets the clipped direction of the whole
    batch. Capping it keeps that world's direction and the others' signal."""
    state = torch.cat([grads[0], grads[1]], dim=-1).norm(dim=-1)
    limit = sim.adjoint_clip * state.median()
    scale = torch.where(state > limit, limit / state.clamp_min(torch.finfo(state.dtype).tiny), torch.ones_like(state))
    sim._clipped += (scale < 1).sum()  # on the device: no host synchronisation in the backward pass
    return [None if g is None else g * scale.view(-1, *([1] * (g.dim() - 1))) for g in grads]


class SimStep(torch.autograd.Function):
    """One env step as an autograd Function (for :class:`Simulator` and, through the same trajectory protocol,
    :class:`~dexmots_rl.sim.ArticulatedSimulator`): when an input needs a gradient, forward runs on a pooled
    trajectory that keeps the step's substeps and the intermediates the reverse pass replays, and
    backward runs the kernels' adjoints over it in reverse, then returns it to the pool (no tape, no
    trajectory and no gradient buffers otherwise). Inputs: ``sim, joint_q, joint_qd, tau,
    q_target, kp, kd, params, object_wrench``; outputs as :class:`StepOutput` (an articulated object's step adds
    its joints' generalised contact forces: :class:`~dexmots_rl.sim.articulated.ArticulatedStepOutput`)."""

    @staticmethod
    def forward(ctx, sim: Simulator, *inputs):
        inputs = [t.detach() if t.dtype == sim.dtype else t.detach().to(sim.dtype) for t in inputs]
        ctx.sim = sim
        if not any(ctx.needs_input_grad[1:]):
            ctx.traj = None
            return tuple(sim._replay(inputs))
        traj, ctx.lease = sim._take_trajectory()
        # the trajectory goes back to the pool after backward, or when the graph is dropped without one
        weakref.finalize(ctx, sim._return_trajectory, traj, ctx.lease)
        traj.load(inputs[0], inputs[1], inputs[2:])
        traj.forward()
        ctx.traj = traj
        return tuple(traj.outputs())

    @staticmethod
    def backward(ctx, *grad_outputs):
        if ctx.traj is None:
            raise RuntimeError("SimStep supports one backward pass per forward (retain_graph / double "
                               "backward is not supported): step again to differentiate again")
        needed = list(ctx.needs_input_grad[1:])
        if ctx.sim.adjoint_clip is not None:
            needed[:2] = [True, True]  # the clip measures each world by its state adjoint
        grads = ctx.traj.backward(grad_outputs, needed)
        ctx.sim._return_trajectory(ctx.traj, ctx.lease)
        ctx.traj = None
        if ctx.sim.adjoint_clip is not None:
            grads = _clip_outlier_worlds(ctx.sim, grads)
        return (None, *[g if need else None for g, need in zip(grads, ctx.needs_input_grad[1:])])
