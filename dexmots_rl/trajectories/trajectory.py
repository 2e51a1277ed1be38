"""Object-centric task plans: the object's pose, articulation and net wrench per time step.

A :class:`PoseWrenchTrajectory` is what the policy is conditioned on (paper §4): for every step t = 0..T-1 the
object's base pose, its articulation coordinates and the net wrench that should act on it.

File format (version 2)
-----------------------
One ``.pt`` file written by :func:`torch.save` holding a *plain* dict, so it loads with
``torch.load(weights_only=True)`` and never unpickles classes:

=================  ===================================================================
key                value
=================  ===================================================================
``format``         the string ``"dexmots-trajectory"``
``version``        the int ``2`` (version 1, the same without ``sha256``, is still read)
``sha256``         :func:`~dexmots_rl.integrity.payload_digest` of all other entries, verified on load
``dt``             python float > 0, seconds between steps
``pos``            float tensor [T, 3], object base position (world frame)
``quat``           float tensor [T, 4], unit quaternion, **wxyz** (MuJoCo order)
``joint_q``        float tensor [T, K], articulation coordinates (K may be 0)
``wrench``         float tensor [T, 6], net force (3) then torque (3), world frame
``joint_torque``   float tensor [T, K], net generalised force on each articulation DoF
=================  ===================================================================

Writes are atomic (temp file in the same directory, fsync, ``os.replace``), so a crash mid-save never leaves a
half-written plan where a good one was. Unknown extra keys are ignored, which leaves room for metadata.

Example:
    >>> import torch, tempfile, os
    >>> T = 5
    >>> quat = torch.tensor([1.0, 0.0, 0.0, 0.0]).repeat(T, 1)
    >>> traj = PoseWrenchTrajectory(torch.zeros(T, 3), quat, torch.zeros(T, 6), dt=0.1)
    >>> traj.horizon, traj.poses.shape
    (5, torch.Size([5, 7]))
    >>> traj.slice(3, 4).horizon   # padded with the last step
    4
    >>> path = os.path.join(tempfile.mkdtemp(), "plan.pt")
    >>> traj.save(path)
    >>> torch.equal(PoseWrenchTrajectory.load(path).pos, traj.pos)
    True
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDict

from ..atomic import atomic_torch_save
from ..integrity import CHECKSUM_KEY, checksum_problem, load_failure, with_checksum

__all__ = [
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "FIELDS",
    "PoseWrenchTrajectory",
    "TrajectoryFormatError",
    "validate_trajectory_fields",
]

logger = logging.getLogger(__name__)

FORMAT_NAME = "dexmots-trajectory"
FORMAT_VERSION = 2
_READABLE_VERSIONS = (1, 2)  # 1: before checksums
#: Tensor fields of a trajectory, in file order.
FIELDS = ("pos", "quat", "joint_q", "wrench", "joint_torque")
#: Fixed trailing sizes; ``None`` means the articulation size K shared by joint_q and joint_torque.
_WIDTHS: dict[str, int | None] = {"pos": 3, "quat": 4, "joint_q": None, "wrench": 6, "joint_torque": None}
QUAT_NORM_TOL = 1e-3


class TrajectoryFormatError(ValueError):
    """A trajectory file or constructor argument is malformed; the message names the offending field."""


def _check_dt(dt: Any) -> float:
    # bool is an int subclass; True as a time step is certainly a bug
    if isinstance(dt, torch.Tensor) and dt.numel() == 1 and dt.is_floating_point():
        dt = dt.item()
    if isinstance(dt, bool) or not isinstance(dt, (int, float)):
        raise TrajectoryFormatError(f"field 'dt' must be a positive finite number, got {type(dt).__name__}")
    dt = float(dt)
    if not (math.isfinite(dt) and dt > 0.0):
        raise TrajectoryFormatError(f"field 'dt' must be a positive finite number, got {dt!r}")
    return dt


def validate_trajectory_fields(fields: Mapping[str, Any], dt: Any) -> tuple[int, int, float]:
    """Check every field of a trajectory; return ``(T, K, dt)`` or raise :class:`TrajectoryFormatError`.

    The one validation routine shared by the constructor and :meth:`PoseWrenchTrajectory.load`.

    Example:
        >>> import torch
        >>> f = {"pos": torch.zeros(2, 3), "quat": torch.tensor([[1.0, 0, 0, 0]] * 2),
        ...      "joint_q": torch.zeros(2, 1), "wrench": torch.zeros(2, 6), "joint_torque": torch.zeros(2, 1)}
        >>> validate_trajectory_fields(f, 0.01)
        (2, 1, 0.01)
    """
    dt = _check_dt(dt)
    for name in FIELDS:
        if name not in fields or fields[name] is None:
            raise TrajectoryFormatError(f"missing field {name!r}")
        value = fields[name]
        if not isinstance(value, torch.Tensor):
            raise TrajectoryFormatError(f"field {name!r} must be a tensor, got {type(value).__name__}")
        if not value.is_floating_point():
            raise TrajectoryFormatError(f"field {name!r} must have a floating dtype, got {value.dtype}")
        if value.ndim != 2:
            raise TrajectoryFormatError(f"field {name!r} must be 2-D [T, n], got shape {tuple(value.shape)}")
        width = _WIDTHS[name]
        if width is not None and value.shape[1] != width:
            raise TrajectoryFormatError(f"field {name!r} must have shape [T, {width}], got {tuple(value.shape)}")
    T = fields["pos"].shape[0]
    if T < 1:
        raise TrajectoryFormatError("field 'pos' has T=0 steps; a trajectory needs at least one")
    for name in FIELDS[1:]:
        if fields[name].shape[0] != T:
            raise TrajectoryFormatError(
                f"field {name!r} has {fields[name].shape[0]} steps but 'pos' has {T} (mismatched T)"
            )
    K = fields["joint_q"].shape[1]
    if fields["joint_torque"].shape[1] != K:
        raise TrajectoryFormatError(
            f"field 'joint_torque' has K={fields['joint_torque'].shape[1]} but 'joint_q' has K={K}"
        )
    for name in FIELDS:
        if not bool(torch.isfinite(fields[name]).all()):
            raise TrajectoryFormatError(f"field {name!r} contains non-finite values")
    norm_err = (torch.linalg.vector_norm(fields["quat"], dim=-1) - 1.0).abs()
    if bool((norm_err > QUAT_NORM_TOL).any()):
        bad = int(torch.argmax(norm_err))
        raise TrajectoryFormatError(
            f"field 'quat' is not unit norm at step {bad} (|‖q‖−1| = {float(norm_err[bad]):.3g} > {QUAT_NORM_TOL})"
        )
    return T, K, dt


class PoseWrenchTrajectory:
    """Per-step object pose (pos + wxyz quat), articulation ``joint_q``, net ``wrench`` and ``joint_torque``.

    Backed by a :class:`~tensordict.TensorDict` with ``batch_size=[T]`` and keys :data:`FIELDS`.
    ``joint_q`` / ``joint_torque`` default to ``[T, 0]`` (no articulation); ``joint_torque`` defaults to zeros
    shaped like ``joint_q``.

    Example:
        >>> import torch
        >>> quat = torch.tensor([[1.0, 0.0, 0.0, 0.0]] * 3)
        >>> traj = PoseWrenchTrajectory(torch.zeros(3, 3), quat, torch.zeros(3, 6), dt=0.05,
        ...                             joint_q=torch.tensor([[0.0], [0.1], [0.2]]))
        >>> traj.at(10)["joint_q"]   # clamped to the last step
        tensor([0.2000])
    """

    def __init__(
        self,
        pos: torch.Tensor,
        quat: torch.Tensor,
        wrench: torch.Tensor,
        dt: float,
        joint_q: torch.Tensor | None = None,
        joint_torque: torch.Tensor | None = None,
    ) -> None:
        if joint_q is None and isinstance(pos, torch.Tensor) and pos.ndim >= 1:
            joint_q = pos.new_zeros(pos.shape[0], 0)
        if joint_torque is None and isinstance(joint_q, torch.Tensor):
            joint_torque = torch.zeros_like(joint_q)
        fields = {"pos": pos, "quat": quat, "joint_q": joint_q, "wrench": wrench, "joint_torque": joint_torque}
        T, _, dt = validate_trajectory_fields(fields, dt)
        devices = {v.device for v in fields.values()}
        if len(devices) != 1:
            raise TrajectoryFormatError(f"all fields must be on one device, got {sorted(map(str, devices))}")
        self._td = TensorDict(fields, batch_size=[T], device=pos.device)
        self._dt = dt

    @classmethod
    def _from_td(cls, td: TensorDict, dt: float) -> PoseWrenchTrajectory:
        # internal: derived from an already validated trajectory, skip re-validation (and GPU syncs)
        obj = cls.__new__(cls)
        obj._td = td
        obj._dt = dt
        return obj

    # ---------------------------------------------------------------- accessors
    @property
    def td(self) -> TensorDict:
        """The backing TensorDict, ``batch_size=[T]``."""
        return self._td

    @property
    def horizon(self) -> int:
        """Number of steps T."""
        return int(self._td.batch_size[0])

    @property
    def dt(self) -> float:
        """Seconds between consecutive steps."""
        return self._dt

    @property
    def num_joints(self) -> int:
        """Articulation size K (0 for a free rigid object)."""
        return int(self._td["joint_q"].shape[-1])

    @property
    def device(self) -> torch.device:
        return self._td.device

    pos = property(lambda self: self._td["pos"], doc="Positions [T, 3].")
    quat = property(lambda self: self._td["quat"], doc="Unit quaternions [T, 4], wxyz.")
    joint_q = property(lambda self: self._td["joint_q"], doc="Articulation coordinates [T, K].")
    wrench = property(lambda self: self._td["wrench"], doc="Net force+torque [T, 6], world frame.")
    joint_torque = property(lambda self: self._td["joint_torque"], doc="Articulation generalised forces [T, K].")

    @property
    def poses(self) -> torch.Tensor:
        """Position and quaternion concatenated, [T, 7] (the envs' ``("object","pose")`` layout)."""
        return torch.cat([self._td["pos"], self._td["quat"]], dim=-1)

    def __len__(self) -> int:
        return self.horizon

    def __repr__(self) -> str:
        return f"PoseWrenchTrajectory(T={self.horizon}, K={self.num_joints}, dt={self._dt}, device={self.device})"

    # ---------------------------------------------------------------- indexing
    def _clamped(self, t: int | torch.Tensor) -> int | torch.Tensor:
        if isinstance(t, torch.Tensor):
            if bool((t < 0).any()):
                raise IndexError("trajectory step indices must be >= 0")
            return t.clamp(max=self.horizon - 1).to(device=self.device, dtype=torch.long)
        if t < 0:
            raise IndexError(f"trajectory step index must be >= 0, got {t}")
        return min(int(t), self.horizon - 1)

    def at(self, t: int | torch.Tensor) -> TensorDict:
        """Step ``t`` (clamped to the last step): a TensorDict with batch [] for an int, [N] for a tensor [N]."""
        return self._td[self._clamped(t)]

    def slice(self, t0: int, H: int) -> PoseWrenchTrajectory:
        """The H steps from ``t0`` as a trajectory, repeating the last step past the end (goal windows)."""
        if H < 1:
            raise ValueError(f"slice length H must be >= 1, got {H}")
        if t0 < 0:
            raise IndexError(f"slice start must be >= 0, got {t0}")
        idx = self._clamped(torch.arange(int(t0), int(t0) + H, device=self.device))
        return PoseWrenchTrajectory._from_td(self._td[idx], self._dt)

    def window(self, t: torch.Tensor, H: int) -> TensorDict:
        """Batched :meth:`slice`: for start steps ``t`` [N] a TensorDict [N, H] of goal windows."""
        if H < 1:
            raise ValueError(f"window length H must be >= 1, got {H}")
        t = torch.as_tensor(t, device=self.device).reshape(-1, 1)
        return self._td[self._clamped(t + torch.arange(H, device=self.device))]

    def to(self, device: torch.device | str) -> PoseWrenchTrajectory:
        """A copy on ``device`` (``self`` if already there)."""
        if torch.device(device) == self.device:
            return self
        return PoseWrenchTrajectory._from_td(self._td.to(device), self._dt)

    # ---------------------------------------------------------------- file I/O
    def state_dict(self) -> dict[str, Any]:
        """The plain dict written to disk (format documented in the module docstring); tensors on CPU."""
        out: dict[str, Any] = {"format": FORMAT_NAME, "version": FORMAT_VERSION, "dt": float(self._dt)}
        for name in FIELDS:
            out[name] = self._td[name].detach().to("cpu").contiguous()
        return with_checksum(out)

    def save(self, path: str | os.PathLike) -> None:
        """Write atomically: a temp file beside ``path``, fsync, then ``os.replace`` over the target."""
        atomic_torch_save(self.state_dict(), path)

    @classmethod
    def from_state_dict(cls, data: Any, source: str = "<dict>") -> PoseWrenchTrajectory:
        """Validate a loaded plain dict and build the trajectory; errors name the bad field."""
        if not isinstance(data, Mapping) or data.get("format") != FORMAT_NAME:
            raise TrajectoryFormatError(f"{source}: field 'format' is not {FORMAT_NAME!r}; not a dexmots trajectory")
        version = data.get("version")
        if version not in _READABLE_VERSIONS or isinstance(version, bool):
            raise TrajectoryFormatError(
                f"{source}: field 'version' = {version!r} is unsupported (this reader handles "
                f"{', '.join(map(str, _READABLE_VERSIONS))})"
            )
        if "dt" not in data:
            raise TrajectoryFormatError(f"{source}: missing field 'dt'")
        fields = {name: data.get(name) for name in FIELDS}
        try:
            validate_trajectory_fields(fields, data["dt"])
            # fields first (their errors name the field), then the checksum catches what still looks valid
            problem = checksum_problem(data) if version >= 2 else None
            if problem is not None:
                raise TrajectoryFormatError(f"field {CHECKSUM_KEY!r}: the plan {problem}")
            return cls(fields["pos"], fields["quat"], fields["wrench"], data["dt"],
                       joint_q=fields["joint_q"], joint_torque=fields["joint_torque"])
        except TrajectoryFormatError as err:
            raise TrajectoryFormatError(f"{source}: {err}") from None

    @classmethod
    def load(cls, path: str | os.PathLike, map_location: torch.device | str | None = "cpu") -> PoseWrenchTrajectory:
        """Read and validate a trajectory file; raises :class:`TrajectoryFormatError` on any problem."""
        path = Path(path)
        if not path.is_file():
            raise TrajectoryFormatError(f"{path}: file not found")
        try:
            data = torch.load(path, map_location=map_location, weights_only=True)
        except Exception as err:  # torch raises many types for a bad archive (RuntimeError, EOFError, pickle…)
            raise TrajectoryFormatError(
                f"{path}: file is truncated or corrupted ({load_failure(err)})"
            ) from None
        return cls.from_state_dict(data, source=str(path))
