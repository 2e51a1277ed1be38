"""What every simulator of a hand and an object shares: the control, the step's outputs, the trajectory protocol,
the autograd Function of one env step and the base class that pools trajectories for it.

:class:`HandSimulator` is the common base of :class:`~dexmots_rl.sim.Simulator` (the knob and cube scenes, one
fused kernel) and :class:`~dexmots_rl.sim.ArticulatedSimulator` (a hand and an articulated object on a table):
both step ``(joint_q, joint_qd, control, params)`` to a :class:`StepOutput` through :class:`SimStep`, which runs
a :class:`TapeTrajectory` (the buffers and recorded launches of one env step) forward, and its adjoint launches
in reverse for the gradient. A subclass builds its kernels and model and says how to make a trajectory.
"""

from __future__ import annotations

import dataclasses
import warnings
import weakref
from typing import Protocol

import numpy as np
import torch
from tensordict import TensorDict

__all__ = ["Control", "StepOutput", "TapeTrajectory", "HandSimulator", "SimStep", "check_device", "warp_float",
           "BELOW_TABLE", "PAST_STOP_HINGE", "PAST_STOP_SLIDE"]

# A world whose object is this far inside the table or past a stop has left the physics (it tunnelled, or the stop
# gave way): the contact and the stops hold a body within millimetres of them (a stop ~0.01 rad under 1 N m)
BELOW_TABLE = 0.05  # m: a table-contact sample of the object this far below the table's top
PAST_STOP_HINGE = 0.5  # rad: an object hinge this far beyond its range
PAST_STOP_SLIDE = 0.05  # m: an object slide this far beyond its range
LIMIT_FREQUENCY = 60.0  # rad/s: the hand's range stops are as stiff as an oscillator of this frequency on the joint


def warp_float(dtype: torch.dtype):
    """The warp float type of a torch float type (float32 or float64)."""
    import warp as wp

    if dtype not in (torch.float32, torch.float64):
        raise ValueError(f"dtype must be torch.float32 or torch.float64, got {dtype}")
    return wp.float32 if dtype == torch.float32 else wp.float64


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
    magnitudes (N); body_pose: [N, B, 7] pos + wxyz quat of every hand link then the object; fingertips: [N, F, 3].
    """

    __slots__ = ()
    names = ("joint_q", "joint_qd", "wrench", "contact_force", "body_pose", "fingertips")

    def __getattr__(self, item):
        # a missing field must raise AttributeError (hasattr, getattr with a default, dir() and completion rely on it)
        try:
            index = self.names.index(item)
        except ValueError:
            raise AttributeError(f"{type(self).__name__} has no field {item!r}; its fields are "
                                 f"{', '.join(self.names)}") from None
        return self[index]

    def __dir__(self):
        return sorted(set(super().__dir__()) | set(self.names))


class TapeTrajectory(Protocol):
    """The buffers and recorded launches of one env step of every world, reusable step after step: what
    :class:`SimStep` drives (sim/_stepper.py's ``Trajectory``, sim/_articulated_stepper.py's
    ``ArticulatedTrajectory``)."""

    lease: int  # bumped whenever the simulator's pool hands the trajectory out or takes it back

    def load(self, q: torch.Tensor, qd: torch.Tensor, controls: list[torch.Tensor]) -> None:
        """Copy the step's inputs in: state ``q`` [N, nq], ``qd`` [N, nv] and the controls (tau, q_target, kp, kd
        [N, nu], packed parameters [N, P], object wrench [N, 6])."""

    def forward(self) -> None:
        """Run the step's launches (all substeps, then the observation)."""

    def outputs(self) -> list[torch.Tensor]:
        """The step's results, fresh tensors in :attr:`HandSimulator.output_type` order."""

    def backward(self, grad_outputs, needed: list[bool] | None = None) -> list[torch.Tensor | None]:
        """Adjoints of the outputs -> adjoints of (joint_q, joint_qd, tau, q_target, kp, kd, params, object_wrench);
        an input not ``needed`` may come back as None. Non-finite entries are left in: :class:`SimStep` zeroes
        and counts them."""


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


class HandSimulator:
    """Many worlds of one hand-and-object scene on one device; each env step is ``substeps`` physics substeps.

    ``adjoint_clip`` (default ``None``: exact gradients) scales down, in every backward step, the gradient
    of any world whose state adjoint exceeds that multiple of the median world's (training option; counted
    in :attr:`clipped_adjoints`). Whatever the option, a world whose gradient has an entry that is not finite
    (its adjoint overflowed in stiff contact, or its state blew up) gets a zero gradient that step, counted in
    :attr:`nonfinite_gradients`; the other worlds' gradients are exact.

    Subclasses set ``kernels``/``model`` and the sizes (:attr:`nq`, :attr:`nv`, :attr:`nu`, :attr:`num_bodies`,
    :attr:`num_params`) and implement :meth:`new_trajectory` and :meth:`observe`.
    """

    output_type: type[StepOutput] = StepOutput  # what step() returns

    def __init__(self, scene, num_worlds: int, *, device="cpu", dtype: torch.dtype = torch.float32, substeps: int = 16,
                 dt: float | None = None, contact=None, adjoint_clip: float | None = None):
        from ._model import ContactParams

        if num_worlds <= 0:
            raise ValueError(f"num_worlds must be positive, got {num_worlds}")
        if substeps <= 0:
            raise ValueError(f"substeps must be positive, got {substeps}")
        if adjoint_clip is not None and not adjoint_clip >= 1.0:
            raise ValueError(f"adjoint_clip must be None or >= 1 (a multiple of the median world), got {adjoint_clip}")
        if dtype not in (torch.float32, torch.float64):
            raise ValueError(f"dtype must be torch.float32 or torch.float64, got {dtype}")
        import warp as wp

        self.scene, self.num_worlds, self.substeps, self.dtype = scene, num_worlds, substeps, dtype
        self.torch_device = check_device(device)
        self.device = wp.device_from_torch(self.torch_device)
        self.sub_dt = scene.timestep if dt is None else dt / substeps  # s
        self.dt = self.sub_dt * substeps  # s: one env step
        self.contact = contact or ContactParams()
        self.adjoint_clip = adjoint_clip
        # per world, int64 [N], counted on the device (no host synchronisation in the backward pass): the backward
        # steps whose adjoint adjoint_clip scaled down, and those whose non-finite gradient was zeroed
        self.clipped_adjoint_steps = torch.zeros(num_worlds, dtype=torch.int64, device=self.torch_device)
        self.nonfinite_gradient_steps = torch.zeros(num_worlds, dtype=torch.int64, device=self.torch_device)
        self._fast: TapeTrajectory | None = None  # the gradient-free steps' trajectory, made at the first one
        self._pool: list[TapeTrajectory] = []  # taped trajectories not in use (SimStep takes and returns them)
        self._no_wrench: torch.Tensor | None = None  # [N, 6] zeros: the object wrench of a control without one

    # ------------------------------------------------------------------------------------ subclass API
    nq: int  # state coordinates: the hand's joints, then the object's
    nv: int  # state velocities
    nu: int  # hand joints (actuated)
    num_bodies: int  # bodies in StepOutput.body_pose: the hand's links, then the object's
    kernels: object  # the step's kernel namespace (and the model struct type); the object tree's for an articulated scene
    more_kernels: list = []  # any other kernel namespaces the step launches (an articulated scene's hand kernels)
    object_tree = None  # the articulated object's ObjectTree (its layout in the state), None: one hinged or free body

    @property
    def object_is_free(self) -> bool:
        """Whether the object (an articulated object's base) is a free body: its state starts with a position
        and a wxyz quaternion."""
        raise NotImplementedError

    def object_energy(self, joint_q, joint_qd, params=None) -> torch.Tensor:
        """[N] the object's energy (J) in states ``joint_q``, ``joint_qd`` of this simulator: kinetic energy of
        every body, gravity's potential, the joint springs' (``params``: the named parameters, default the
        MJCF's)."""
        raise NotImplementedError

    @property
    def param_names(self) -> tuple[str, ...]:
        """Names of the per-world physical parameters (``("sim", "params", name)``, each ``[N, 1]``)."""
        return self.scene.param_names

    @property
    def num_params(self) -> int:
        """Columns of :meth:`pack_params`' result (never zero: the kernels take no empty array)."""
        raise NotImplementedError

    def new_trajectory(self, save: bool) -> TapeTrajectory:
        """A trajectory of this simulator's step; ``save``: it keeps what the reverse pass needs."""
        raise NotImplementedError

    def observe(self, joint_q, joint_qd=None, params=None):
        """Body poses [N, B, 7] and fingertips [N, F, 3] for a state, without stepping."""
        raise NotImplementedError

    def outside_physics(self, joint_q: torch.Tensor, body_pose: torch.Tensor, params=None) -> torch.Tensor:
        """[N] bool: the worlds whose state (a step's ``joint_q`` and ``body_pose``) has left the physics: a
        table-contact sample of the object more than :data:`BELOW_TABLE` below the table's top, or an object joint
        more than :data:`PAST_STOP_HINGE` (a hinge) or :data:`PAST_STOP_SLIDE` (a slide) beyond its range.
        Tensor operations only (no host read); ``params``: the named parameters (a world's object variant)."""
        raise NotImplementedError

    def check_params(self, params) -> None:
        """Raise ValueError naming a parameter the kernels cannot take (default: nothing to check)."""

    # ------------------------------------------------------------------------------------------ model
    def _array(self, x, dtype):
        """A model array of ``x`` (read in float64) in the warp ``dtype``, on the device."""
        import warp as wp

        return wp.array(np.asarray(x, dtype=np.float64), dtype=dtype, device=self.device)

    def _fill_finger_chains(self, m, k, wdt) -> None:
        """Set the hand's fields of model struct ``m`` that the fused and the split kernels share: the finger chains
        (frames, joints, inertias, drives, range stops), their contact spheres and tips, gravity and the fingers'
        contact law (``k``: the kernels' namespace, for its vec3 and mat33; ``wdt``: the float type)."""
        s, c, arr = self.scene, self.contact, self._array
        m.base_pos, m.base_rot = arr(s.finger_base_pos, k.vec3), arr(s.finger_base_rot, k.mat33)
        m.off_pos, m.off_rot = arr(s.link_offset_pos, k.vec3), arr(s.link_offset_rot, k.mat33)
        m.axis = arr(s.joint_axis, k.vec3)
        m.mass, m.com, m.inertia = arr(s.link_mass, wdt), arr(s.link_com, k.vec3), arr(s.link_inertia, k.mat33)
        m.armature, m.damping, m.friction = arr(s.dof_armature, wdt), arr(s.dof_damping, wdt), arr(s.dof_friction, wdt)
        m.lower, m.upper = arr(s.dof_lower, wdt), arr(s.dof_upper, wdt)
        m.limit_ke = arr(s.dof_inertia0 * LIMIT_FREQUENCY**2 * s.dof_limited, wdt)
        m.effort = arr(s.actuator_effort, wdt)
        m.point_pos, m.point_radius = arr(s.point_pos, k.vec3), arr(s.point_radius, wdt)
        m.tip_pos = arr(s.tip_pos, k.vec3)
        m.gravity = k.vec3(*s.gravity)
        m.ke, m.kd, m.beta, m.v_slip = wdt(c.stiffness), wdt(c.damping), wdt(c.sharpness), wdt(c.slip_velocity)

    # ------------------------------------------------------------------------------------------ state
    def _zeros(self, *shape):
        return torch.zeros(*shape, dtype=self.dtype, device=self.torch_device)

    def initial_state(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The MJCF's reference configuration in every world (hand at 0, object at its q0)."""
        q = self._zeros(self.num_worlds, self.nq)
        q[:, self.nu:] = torch.as_tensor(self.scene.object_q0, dtype=self.dtype)
        return q, self._zeros(self.num_worlds, self.nv)

    def zero_control(self) -> Control:
        z = self._zeros(self.num_worlds, self.nu)
        return Control(z, z, z, z)

    def default_params(self) -> TensorDict:
        """Per-world physical parameters from the MJCF, by name (:attr:`param_names`): a TensorDict ``[N]`` of
        ``[N, 1]`` tensors, e.g. ``"joint_damping"``."""
        values = {name: torch.full((self.num_worlds, 1), v, dtype=self.dtype, device=self.torch_device)
                  for name, v in self.default_param_values().items()}
        return TensorDict(values, batch_size=[self.num_worlds], device=self.torch_device)

    def default_param_values(self) -> dict[str, float]:
        """Every parameter's nominal value (:attr:`param_names`): the scene's, and a contact law's coefficient
        from this simulator's law."""
        return self.scene.default_param_values()

    def pack_params(self, params) -> torch.Tensor:
        """The named parameters (a TensorDict or dict of ``[N, 1]`` tensors) as the ``[N, P]`` array the
        kernels read, in :attr:`param_names` order (differentiable: a cat)."""
        names = self.param_names
        if not names:
            return self._zeros(self.num_worlds, self.num_params)
        missing = [n for n in names if n not in params.keys()]
        if missing:
            raise ValueError(f"params lacks {', '.join(missing)}; this scene's parameters are {', '.join(names)}")
        return torch.cat([params[n].reshape(-1, 1) for n in names], -1)

    @property
    def clipped_adjoints(self) -> int:
        """Worlds x steps whose adjoint ``adjoint_clip`` scaled down, since construction (the sum of
        :attr:`clipped_adjoint_steps`; reading it synchronises, so read it once per iteration, not per step)."""
        return int(self.clipped_adjoint_steps.sum())

    @property
    def nonfinite_gradients(self) -> int:
        """Worlds x steps whose gradient had an infinite or NaN entry and was set to zero, since construction
        (the sum of :attr:`nonfinite_gradient_steps`; reading it synchronises)."""
        return int(self.nonfinite_gradient_steps.sum())

    # ------------------------------------------------------------------------------------------- step
    def step(self, joint_q, joint_qd, control: Control, params) -> StepOutput:
        """One env step (``substeps`` physics substeps); differentiable w.r.t. every tensor input.
        ``params``: the named per-world parameters (:meth:`default_params`)."""
        n = joint_q.shape[0]
        if n != self.num_worlds:
            raise ValueError(f"joint_q has {n} worlds, the simulator was built for {self.num_worlds}")
        ext = control.object_wrench
        if ext is None:
            if self._no_wrench is None:
                self._no_wrench = self._zeros(n, 6)  # read only: the trajectory copies its inputs
            ext = self._no_wrench
        self.check_params(params)
        return self.output_type(SimStep.apply(self, joint_q, joint_qd, control.tau, control.q_target, control.kp,
                                              control.kd, self.pack_params(params), ext))

    def _replay(self, inputs: list[torch.Tensor]) -> list[torch.Tensor]:
        """Gradient-free step on one persistent trajectory (no saved intermediates)."""
        if self._fast is None:
            self._fast = self.new_trajectory(save=False)
        self._fast.load(inputs[0], inputs[1], inputs[2:])
        self._fast.forward()
        return self._fast.outputs()

    def _take_trajectory(self) -> tuple[TapeTrajectory, int]:
        """A taped trajectory from the pool and its lease: hand both back with :meth:`_return_trajectory`
        after the backward pass, or when the step's graph is dropped without one."""
        traj = self._pool.pop() if self._pool else self.new_trajectory(save=True)
        traj.lease += 1
        return traj, traj.lease

    def _return_trajectory(self, traj: TapeTrajectory, lease: int) -> None:
        if traj.lease == lease:  # not returned already for this lease (backward, then the graph's release)
            traj.lease += 1
            self._pool.append(traj)


def _clip_outlier_worlds(sim: HandSimulator, grads: list[torch.Tensor | None]) -> list[torch.Tensor | None]:
    """Scale down every gradient row of a world whose state adjoint is more than ``sim.adjoint_clip`` times
    the median over worlds (scale-free: nothing happens while the worlds' adjoints are alike).

    Worlds are independent, so a world's adjoint only carries its own future rewards; in stiff contact
    it can grow by orders of magnitude over a few steps while the others stay put (measured on the claw:
    median 2e-2, a few worlds 1e2-1e6), and one such world then sets the clipped direction of the whole
    batch. Capping it keeps that world's direction and the others' signal."""
    state = torch.cat([grads[0], grads[1]], dim=-1).norm(dim=-1)
    limit = sim.adjoint_clip * state.median()
    scale = torch.where(state > limit, limit / state.clamp_min(torch.finfo(state.dtype).tiny), torch.ones_like(state))
    sim.clipped_adjoint_steps += scale < 1  # on the device: no host synchronisation in the backward pass
    return [None if g is None else g * scale.view(-1, *([1] * (g.dim() - 1))) for g in grads]


def _zero_nonfinite(sim: HandSimulator, grads: list[torch.Tensor | None]) -> list[torch.Tensor | None]:
    """The gradients with every row (world) that holds an infinite or NaN entry set to zero, counted in
    :attr:`HandSimulator.nonfinite_gradient_steps` (and, on CPU, warned about): a world whose adjoint overflowed in stiff contact, or whose state
    blew up (the env resets it), must not poison the batch's gradient, and its finite entries are no more
    trustworthy than the others. The other worlds' rows are returned unchanged (as copies: the trajectory's
    buffers are reused)."""
    present = [g for g in grads if g is not None]
    bad = torch.zeros(sim.num_worlds, dtype=torch.bool, device=sim.torch_device)
    for g in present:
        bad |= ~torch.isfinite(g.reshape(g.shape[0], -1)).all(-1)
    sim.nonfinite_gradient_steps += bad  # on the device: no host synchronisation in the backward pass
    if sim.device.is_cpu and bool(bad.any()):  # a free read on the host; on a GPU the trainer reads the counts
        warnings.warn(f"{int(bad.sum())} of {sim.num_worlds} worlds had a non-finite gradient this step (their "
                      "adjoint overflowed, or their state blew up); it was set to zero", RuntimeWarning, stacklevel=2)
    zero = torch.zeros((), dtype=present[0].dtype, device=present[0].device) if present else None
    return [None if g is None else torch.where(bad.view(-1, *([1] * (g.dim() - 1))), zero, g) for g in grads]


class SimStep(torch.autograd.Function):
    """One env step as an autograd Function for any :class:`HandSimulator`: when an input needs a gradient,
    forward runs on a pooled trajectory that keeps the step's substeps and the intermediates the reverse pass
    replays, and backward runs the kernels' adjoints over it in reverse, then returns it to the pool (no tape,
    no trajectory and no gradient buffers otherwise). Inputs: ``sim, joint_q, joint_qd, tau, q_target, kp, kd,
    params, object_wrench``; outputs as the simulator's :attr:`~HandSimulator.output_type`."""

    @staticmethod
    def forward(ctx, sim: HandSimulator, *inputs):
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
        sim = ctx.sim
        needed = list(ctx.needs_input_grad[1:])
        if sim.adjoint_clip is not None:
            needed[:2] = [True, True]  # the clip measures each world by its state adjoint
        grads = _zero_nonfinite(sim, ctx.traj.backward(grad_outputs, needed))  # copies: the buffers are reused
        sim._return_trajectory(ctx.traj, ctx.lease)
        ctx.traj = None
        if sim.adjoint_clip is not None:
            grads = _clip_outlier_worlds(sim, grads)
        return (None, *[g if need else None for g, need in zip(grads, ctx.needs_input_grad[1:])])
