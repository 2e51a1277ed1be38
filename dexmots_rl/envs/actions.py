"""Action spaces: map a policy action in [-1, 1] to the simulator's joint-space drive.

* ``"torque"``: ``tau = a * gear`` (the MJCF motor gear per joint).
* ``"position"``: PD targets spanning the joint range, ``q* = lower + (a + 1) / 2 * (upper - lower)``
  (or, when the task names a ``center`` pose, piecewise linear: a = -1, 0, +1 give lower, center, upper),
  stiffness ``kp = stiffness_frequency^2 * I0`` per joint (``I0``: joint-space inertia at q = 0) and
  critical damping ``kd = 2 sqrt(kp * I0)``; the simulator integrates both terms implicitly.
* ``"vi"`` (variable impedance): ``2 nu`` entries. The first ``nu`` are PD targets mapped like
  ``"position"``; the last ``nu`` choose each joint's stiffness per step, log-linearly between
  ``kp_min = (f / 4)^2 I0`` (a = -1) and ``kp_max = (2 f)^2 I0`` (a = +1), ``f = stiffness_frequency``
  (rad/s): ``kp = kp_min (kp_max / kp_min)^((a + 1) / 2)``, so a = 0 gives the geometric mean ``f^2 I0 / 2``.
  The bounds put the joint's natural frequency ``sqrt(kp / I0)`` in ``[f / 4, 2 f]``; log-linear
  spacing spends the action range evenly on each octave of that frequency instead of crowding the soft end.
  Damping follows the same critical rule ``kd = 2 sqrt(kp I0)`` so no gain setting rings or over-damps.

Actions are clamped to [-1, 1]; non-finite actions are rejected (see :func:`validate_action`).
"""

from __future__ import annotations

import math

import torch

from ..sim import Control, HandSimulator

__all__ = ["ACTION_TYPES", "ActionMap", "validate_action"]

ACTION_TYPES = ("torque", "position", "vi")


def validate_action(action: torch.Tensor, num_envs: int, action_dim: int, values: bool = True) -> None:
    """Raise ``ValueError`` naming the ``action`` field when its shape, dtype or (``values``: reading them
    on the host) values are wrong."""
    if not isinstance(action, torch.Tensor):
        raise ValueError(f"action must be a torch.Tensor, got {type(action).__name__}")
    if not action.is_floating_point():
        raise ValueError(f"action must be a floating-point tensor, got dtype {action.dtype}")
    if tuple(action.shape) != (num_envs, action_dim):
        raise ValueError(f"action has shape {tuple(action.shape)}, expected ({num_envs}, {action_dim})")
    if values and not bool(torch.isfinite(action).all()):
        bad = (~torch.isfinite(action)).any(-1).nonzero().flatten().tolist()
        raise ValueError(f"action contains NaN or inf (worlds {bad[:8]}); non-finite actions are rejected")


class ActionMap:
    """Turns clamped policy actions into a :class:`~dexmots_rl.sim.Control` (differentiably).

    ``action_dim`` is the policy action width: ``nu`` for ``"torque"``/``"position"``, ``2 nu`` for ``"vi"``.

    Example:
        >>> import torch
        >>> from types import SimpleNamespace
        >>> from dexmots_rl.sim import load_scene
        >>> from dexmots_rl.assets import asset_path
        >>> scene = load_scene(asset_path("claw_screw.xml"))
        >>> sim = SimpleNamespace(scene=scene, num_worlds=2, nu=scene.num_hand_dofs,
        ...                       dtype=torch.float64, torch_device=torch.device("cpu"))
        >>> vi = ActionMap(sim, "vi")
        >>> vi.action_dim, tuple(vi(torch.zeros(2, vi.action_dim)).kp.shape)
        (8, (2, 4))
    """

    def __init__(self, sim: HandSimulator, kind: str = "torque", stiffness_frequency: float = 20.0, center=None):
        if kind not in ACTION_TYPES:
            raise ValueError(f"action type {kind!r} is unknown; known: {', '.join(ACTION_TYPES)}")
        self.kind, self.num_worlds, self.nu = kind, sim.num_worlds, sim.nu
        self.action_dim = 2 * sim.nu if kind == "vi" else sim.nu
        scene = sim.scene

        def t(x):
            return torch.as_tensor(x, dtype=sim.dtype, device=sim.torch_device)

        self.gear = t(scene.actuator_gear)
        finite = scene.dof_limited
        self.lower = t(scene.dof_lower * finite - math.pi * (1 - finite))
        self.upper = t(scene.dof_upper * finite + math.pi * (1 - finite))
        # the joint targets of a = 0: mid-range, or the task's default pose (a palm-up hand whose mid-range
        # pose is far from the cube would otherwise start every policy with its fingers off the object)
        self._mid_center = center is None
        self.center = 0.5 * (self.lower + self.upper) if center is None else t(center)
        if self.center.shape != self.lower.shape or not bool(
                ((self.center > self.lower) & (self.center < self.upper)).all()):
            raise ValueError(f"action center must be {self.nu} joint angles strictly inside the joint limits, "
                             f"got {tuple(center) if center is not None else None}")
        inertia0 = t(scene.dof_inertia0)
        self.kp = stiffness_frequency**2 * inertia0
        self.kd = 2.0 * torch.sqrt(self.kp * inertia0)
        # "vi" bounds; kd is written via sqrt(kp I0) = (f/4) 8^u I0 (u in [0, 1]), which equals the
        # critical rule exactly but has no sqrt, so its gradient stays finite even where I0 = 0
        self.inertia0 = inertia0
        self.kp_min = (stiffness_frequency / 4.0) ** 2 * inertia0
        self.kp_max = (2.0 * stiffness_frequency) ** 2 * inertia0
        self._kd_min = 2.0 * (stiffness_frequency / 4.0) * inertia0
        self._log_ratio = math.log(64.0)  # kp_max / kp_min = (2 f / (f / 4))^2, the same for every joint
        self._zeros = torch.zeros(sim.num_worlds, sim.nu, dtype=sim.dtype, device=sim.torch_device)

    def targets(self, a: torch.Tensor) -> torch.Tensor:
        """Joint targets spanning the joint range for actions ``a`` in [-1, 1] (-1: lower, 0: center,
        +1: upper)."""
        if self._mid_center:  # the symmetric map, written as before so mid-centred tasks keep their numerics
            return self.lower + 0.5 * (a + 1.0) * (self.upper - self.lower)
        return self.center + a * torch.where(a < 0, self.center - self.lower, self.upper - self.center)

    def actions_for_targets(self, q: torch.Tensor) -> torch.Tensor:
        """The inverse of :meth:`targets`: the actions in [-1, 1] whose joint targets are ``q``."""
        if self._mid_center:
            return 2.0 * (q - self.lower) / (self.upper - self.lower) - 1.0
        return (q - self.center) / torch.where(q < self.center, self.center - self.lower, self.upper - self.center)

    def mean_actions(self, stiffness: float = 0.0) -> torch.Tensor:
        """``[action_dim]`` actions holding every PD target at its centre and, for ``"vi"``, every joint's
        stiffness action at ``stiffness`` (in [-1, 1]; other action spaces have no stiffness channel)."""
        if not -1.0 <= stiffness <= 1.0:
            raise ValueError(f"stiffness must be in [-1, 1], got {stiffness!r}")
        a = torch.zeros(self.action_dim, dtype=self.lower.dtype, device=self.lower.device)
        if self.kind == "vi":
            a[self.nu:] = stiffness
        return a

    def stiffness(self, s: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(kp, kd)`` for stiffness actions ``s`` in [-1, 1]: log-linear kp, critically damped kd."""
        u = 0.5 * (s + 1.0)
        kp = self.kp_min * torch.exp(self._log_ratio * u)
        kd = self._kd_min * torch.exp(0.5 * self._log_ratio * u)
        return kp, kd

    def __call__(self, action: torch.Tensor) -> Control:
        if action.shape[-1] != self.action_dim:
            raise ValueError(f"action has {action.shape[-1]} entries per world, the {self.kind!r} action "
                             f"space expects {self.action_dim}")
        a = action.clamp(-1.0, 1.0)
        z = self._zeros[: a.shape[0]]
        if self.kind == "torque":
            return Control(tau=a * self.gear, q_target=z, kp=z, kd=z)
        if self.kind == "vi":
            kp, kd = self.stiffness(a[..., self.nu:])
            return Control(tau=z, q_target=self.targets(a[..., : self.nu]), kp=kp, kd=kd)
        return Control(tau=z, q_target=self.targets(a), kp=self.kp.expand_as(a), kd=self.kd.expand_as(a))
