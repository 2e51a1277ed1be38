"""Multiple shooting: the object's recorded motion against the simulator's, as residuals of named parameters.

The recording is cut into short segments (``segment_steps`` env steps). Each segment starts from its recorded
state (hand and object, positions and velocities) and is driven by its recorded hand drive; the residuals are
the simulated coordinates (the hand's joints and the object's) minus the recorded ones after every step,
divided by a measurement scale
(``position_scale`` metres for positions and slides, ``angle_scale`` radians for hinges and a base's rotation),
so that one unit of residual is one unit of expected noise. Short segments keep contact's chaos out of the
gradient: an error cannot grow for longer than a segment.

Every evaluation is a batch of worlds of one simulator: world ``b`` replays segment ``index[b]`` with its own
parameter vector, so a batch holds the segments of one candidate (the gradient methods), of a population
(CMA-ES), of perturbed copies (a finite-difference Jacobian) or of one copy per residual (the exact Jacobian in
one reverse pass). Parameters are optimised in unconstrained coordinates ``z``: the logarithm of a positive
quantity (damping, friction, stiffness, mass), the value itself otherwise, both clamped to their bounds.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
import torch

from ..envs import make_env
from ..sim import Control
from .data import CONTROL_FIELDS, Trajectories

__all__ = ["Cost", "ParamSpace", "ShootingProblem", "POSITIVE_KINDS", "coordinate_kinds", "coordinate_scales",
           "is_positive"]

POSITIVE_KINDS = ("damping", "friction", "stiffness", "mass")  # identified through their logarithm
MAX_WORLDS = 2048  # worlds per simulator batch (a longer batch is split)


@dataclasses.dataclass
class Cost:
    """What an identification has spent: simulated world-steps forward and in reverse, and process CPU seconds
    (all threads) since :meth:`start`."""

    forward_steps: int = 0
    backward_steps: int = 0
    cpu_start: float = dataclasses.field(default_factory=time.process_time)

    def start(self) -> None:
        self.forward_steps, self.backward_steps, self.cpu_start = 0, 0, time.process_time()

    @property
    def cpu_seconds(self) -> float:
        return time.process_time() - self.cpu_start

    def snapshot(self) -> dict:
        return {"forward_steps": self.forward_steps, "backward_steps": self.backward_steps,
                "cpu_seconds": self.cpu_seconds}


def coordinate_kinds(sim) -> list[str]:
    """Each state coordinate's kind (the hand's joints, then the object's): ``"position"`` (m: a slide, a base's
    position), ``"quaternion"`` (a free base's wxyz rotation) or ``"angle"`` (rad: a hinge)."""
    from ..sim import SLIDE

    hand = ["position" if k == SLIDE else "angle" for k in sim.scene.joint_type]
    tree = sim.object_tree
    if tree is None:  # one hinged or free object (the knob, the cube)
        return hand + (["angle"] if sim.scene.articulated else ["position"] * 3 + ["quaternion"] * 4)
    base = ["position"] * 3 + ["quaternion"] * 4 if tree.free else []
    return hand + base + ["position" if k == SLIDE else "angle" for k in tree.joint_kind]


def coordinate_scales(kinds: list[str], position: float, angle: float) -> np.ndarray:
    """[D] the scale of each coordinate kind: ``position`` m, ``angle`` rad, a quaternion entry half the angle
    (its components move by half the rotation)."""
    return np.array([{"position": position, "angle": angle, "quaternion": angle / 2}[k] for k in kinds])


def is_positive(name: str) -> bool:
    """A parameter identified through its logarithm: its kind (``joint_damping``, ``<joint>/friction``...) is one
    of :data:`POSITIVE_KINDS`."""
    return name.rsplit("/", 1)[-1].rsplit("_", 1)[-1] in POSITIVE_KINDS


@dataclasses.dataclass
class ParamSpace:
    """The identified parameters: names, which are positive (log coordinates), bounds and the initial guess."""

    names: tuple[str, ...]
    initial: np.ndarray  # [P] physical values
    lower: np.ndarray
    upper: np.ndarray

    @property
    def log(self) -> np.ndarray:
        return np.array([is_positive(n) for n in self.names])

    @classmethod
    def build(cls, names, initial: dict, bounds: dict) -> "ParamSpace":
        names = tuple(names)
        x0 = np.array([float(initial[n]) for n in names])
        lo, hi = np.empty(len(names)), np.empty(len(names))
        for i, name in enumerate(names):
            positive = is_positive(name)
            if positive and not x0[i] > 0:
                raise ValueError(f"parameter {name!r} is positive and identified through its logarithm: its initial "
                                 f"guess must be > 0, got {x0[i]:g} (give init.{name}=<value>)")
            default = (x0[i] / 100.0, x0[i] * 100.0) if positive else (x0[i] - 2.0, x0[i] + 2.0)
            lo[i], hi[i] = bounds.get(name, default)
            if not (lo[i] <= x0[i] <= hi[i]) or (positive and lo[i] <= 0):
                raise ValueError(f"bounds.{name}: ({lo[i]:g}, {hi[i]:g}) must hold the initial guess {x0[i]:g}"
                                 f"{' and be > 0' if positive else ''}")
        return cls(names, x0, lo, hi)

    def to_z(self, x) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        return np.where(self.log, np.log(np.maximum(x, 1e-300)), x)

    def values(self, z: torch.Tensor) -> torch.Tensor:
        """Physical values [..., P] of unconstrained ``z`` [..., P], clamped to the bounds (differentiable)."""
        log = torch.as_tensor(self.log, device=z.device)
        lo, hi = (torch.as_tensor(b, dtype=z.dtype, device=z.device) for b in (self.lower, self.upper))
        return torch.minimum(torch.maximum(torch.where(log, torch.exp(z), z), lo), hi)

    def values_np(self, z) -> np.ndarray:
        return self.values(torch.as_tensor(np.asarray(z, dtype=np.float64))).numpy()


class ShootingProblem:
    """Segments of ``traj`` replayed through the task's simulator; see the module docstring.

    ``names``: the parameters to identify (``("sim", "params", name)`` names of the scene); ``initial`` and
    ``bounds``: per-name initial guesses (default: the scene's nominal value) and ``(low, high)`` bounds;
    ``hand``: the residuals include the hand's joints (default), whose motion against the object carries most of
    what the data says about it (a gripped knob turns with the fingers whatever its friction; the fingers are
    what the friction slows), else only the object's coordinates; ``free_starts``: each training segment's start
    positions are estimated too (errors in variables: a recorded start is a noisy measurement, and in contact a
    start that is off by the noise pushes the whole segment off), each offset charged like a residual (L-BFGS
    only: their gradient comes with the parameters' in the same reverse pass);
    ``validation``: the share of segments held out (chosen by ``seed``); ``max_segments``: at most this many
    segments in all (evenly spaced), to bound the cost. The parameters not identified keep the values the
    recording was made with where it says them, else the scene's nominal values.
    """

    def __init__(self, traj: Trajectories, names, *, segment_steps: int = 8, validation: float = 0.25,
                 seed: int = 0, initial: dict | None = None, bounds: dict | None = None,
                 max_segments: int | None = None, position_scale: float = 1e-3, angle_scale: float = 1e-2,
                 hand: bool = True, free_starts: bool = False, dtype: torch.dtype = torch.float64):
        if segment_steps < 1:
            raise ValueError(f"segment_steps must be a positive integer, got {segment_steps}")
        if not 0.0 <= validation < 1.0:
            raise ValueError(f"validation must be a share in [0, 1), got {validation}")
        env = make_env(traj.task, num_envs=1, raw=True, differentiable=True, dtype=dtype)
        self.env, self.traj, self.dtype, self.steps = env, traj, dtype, segment_steps
        sim = env.sim
        self.first = 0 if hand else sim.nu  # the first state coordinate the residuals compare
        if not math.isclose(traj.dt, sim.dt, rel_tol=1e-6):
            raise ValueError(f"dt: the data's frames are {traj.dt:g} s apart, the task {traj.task['name']!r} steps "
                             f"{sim.dt:g} s (substeps x timestep); record at the task's step")
        nq, nv = traj.joint_q.shape[-1], traj.joint_qd.shape[-1]
        if (nq, nv) != (sim.nq, sim.nv) or traj.control["tau"].shape[-1] != sim.nu:
            raise ValueError(f"{traj.source or 'data'}: states of {nq} positions, {nv} velocities and drives of "
                             f"{traj.control['tau'].shape[-1]} joints; the task {traj.task['name']!r} has {sim.nq}, "
                             f"{sim.nv} and {sim.nu}")
        self.known = tuple(n for n in sim.scene.param_names if n != "variant")
        names = tuple(names)
        unknown = [n for n in names if n not in self.known]
        if unknown or not names:
            raise ValueError(f"unknown parameter {unknown[0] if unknown else '(none given)'!r}; this scene's "
                             f"parameters are: {', '.join(self.known) or 'none'}")
        nominal = sim.default_param_values()
        self.space = ParamSpace.build(names, {**nominal, **(initial or {})}, bounds or {})
        self.nominal = nominal
        self._split(segment_steps, validation, seed, max_segments)
        kinds = coordinate_kinds(sim)
        self.kinds = kinds[self.first:]
        # the start positions free_starts may move (all but a quaternion's entries), and their noise scales
        self.free_starts = free_starts
        self.start_index = torch.as_tensor([i for i, k in enumerate(kinds) if k != "quaternion"], dtype=torch.long)
        self._start_scales = torch.as_tensor(coordinate_scales([kinds[i] for i in self.start_index], position_scale,
                                                               angle_scale), dtype=dtype)
        self.scales = torch.as_tensor(coordinate_scales(self.kinds, position_scale, angle_scale), dtype=dtype)
        self._sims: dict[int, object] = {}
        self.cost = Cost()

    # ------------------------------------------------------------------------------------------ set-up
    def _split(self, steps: int, validation: float, seed: int, max_segments: int | None) -> None:
        starts = self.traj.segment_starts(steps)
        if max_segments is not None and len(starts) > max_segments:
            starts = [starts[i] for i in np.linspace(0, len(starts) - 1, max_segments).round().astype(int)]
        if len(starts) < 2:
            raise ValueError(f"{self.traj.source or 'data'}: {len(starts)} segment(s) of {steps} steps with a drive "
                             "on every step; identification needs at least 2 (record longer, or shorten "
                             "segment_steps)")
        order = np.random.default_rng(seed).permutation(len(starts))
        held = int(round(validation * len(starts))) if validation > 0 else 0
        held = min(max(held, 1 if validation > 0 else 0), len(starts) - 1)
        self.val_index = np.sort(order[:held])
        self.train_index = np.sort(order[held:])
        t, nu, L = self.traj, self.env.sim.nu, steps
        f = np.array([s[0] for s in starts])
        w = np.array([s[1] for s in starts])
        ahead = f[:, None] + np.arange(1, L + 1)[None]  # [S, L] the frames each segment's steps lead to

        def tensor(x):
            return torch.as_tensor(np.ascontiguousarray(x), dtype=self.dtype)

        self.starts = starts
        self.q0, self.qd0 = tensor(t.joint_q[f, w]), tensor(t.joint_qd[f, w])
        self.controls = {k: tensor(t.control[k][ahead, w[:, None]]) for k in CONTROL_FIELDS}  # [S, L, nu]
        self.target = tensor(t.joint_q[ahead, w[:, None]][..., self.first:])  # [S, L, D]
        fixed = {}
        for name in self.env.sim.scene.param_names:
            recorded = t.params.get(name)
            fixed[name] = tensor(recorded[f, w]) if recorded is not None else torch.full(
                (len(starts), 1), float(self.env.sim.default_param_values()[name]), dtype=self.dtype)
        self.fixed = fixed

    @property
    def num_residuals(self) -> int:
        return int(self.target.shape[1] * self.target.shape[2])

    def _sim(self, n: int):
        if n not in self._sims:
            sim = self.env.sim
            self._sims[n] = type(sim)(sim.scene, n, dtype=self.dtype, substeps=sim.substeps, contact=sim.contact)
        return self._sims[n]

    # ------------------------------------------------------------------------------------------ rollouts
    def residuals(self, z: torch.Tensor, index, starts: torch.Tensor | None = None) -> torch.Tensor:
        """[B, L, D] residuals of world ``b`` replaying segment ``index[b]`` with unconstrained parameters
        ``z[b]`` ([B, P]; differentiable w.r.t. ``z``), from its recorded start moved by ``starts[b]`` ([B, K]: the
        start positions' offsets in noise units, :attr:`start_index`; None: the recorded start)."""
        index = torch.as_tensor(np.asarray(index), dtype=torch.long)
        out = []
        for lo in range(0, len(index), MAX_WORLDS):
            chunk = None if starts is None else starts[lo:lo + MAX_WORLDS]
            out.append(self._replay(z[lo:lo + MAX_WORLDS], index[lo:lo + MAX_WORLDS], chunk))
        return torch.cat(out)

    def _replay(self, z: torch.Tensor, index: torch.Tensor, starts: torch.Tensor | None) -> torch.Tensor:
        n, sim = len(index), self._sim(len(index))
        values = self.space.values(z)
        params = {name: value[index] for name, value in self.fixed.items()}
        for i, name in enumerate(self.space.names):
            params[name] = values[:, i:i + 1]
        q, qd = self.q0[index], self.qd0[index]
        if starts is not None:
            q = q + torch.zeros_like(q).index_add(1, self.start_index, starts * self._start_scales)
        preds = []
        for k in range(self.steps):
            control = Control(*(self.controls[c][index, k] for c in CONTROL_FIELDS))
            out = sim.step(q, qd, control, params)
            q, qd = out.joint_q, out.joint_qd
            preds.append(q[:, self.first:])
        self.cost.forward_steps += n * self.steps
        return (torch.stack(preds, 1) - self.target[index]) / self.scales

    def loss(self, z: np.ndarray | torch.Tensor, index=None) -> float:
        """Mean squared residual (noise units) of the shared parameters ``z`` [P] over segments ``index``
        (default: the training segments), without a gradient."""
        index = self.train_index if index is None else index
        with torch.no_grad():
            zt = torch.as_tensor(np.asarray(z, dtype=np.float64), dtype=self.dtype).expand(len(index), -1)
            return float(self.residuals(zt, index).square().mean())

    def losses(self, z_batch: np.ndarray, index=None) -> np.ndarray:
        """[C] mean squared residuals of C candidates ``z_batch`` [C, P], all in one batch of C x S worlds."""
        index = np.asarray(self.train_index if index is None else index)
        c, s = len(z_batch), len(index)
        zt = torch.as_tensor(np.repeat(np.asarray(z_batch, dtype=np.float64), s, axis=0), dtype=self.dtype)
        with torch.no_grad():
            r = self.residuals(zt, np.tile(index, c))
        return r.reshape(c, s, -1).square().mean((1, 2)).numpy()

    def loss_and_grad(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Training objective and its gradient through the simulator (one forward and one reverse pass over the
        training segments). ``x``: the shared ``z`` [P], then, with ``free_starts``, every training segment's start
        offsets (noise units, [S * K]), which the objective also charges as measurements: the sum of squared
        residuals and offsets, over the residuals' count."""
        x = x.detach().clone().requires_grad_(True)
        index, p = self.train_index, len(self.space.names)
        starts = x[p:].view(len(index), -1) if self.free_starts else None
        r = self.residuals(x[:p].expand(len(index), -1), index, starts)
        loss = (r.square().sum() + (0.0 if starts is None else starts.square().sum())) / r.numel()
        loss.backward()
        self.cost.backward_steps += len(index) * self.steps
        return loss.detach(), x.grad.detach()

    @property
    def num_start_variables(self) -> int:
        """Entries of ``x`` after the parameters (:meth:`loss_and_grad`): the training segments' start offsets."""
        return len(self.train_index) * len(self.start_index) if self.free_starts else 0

    def jacobian(self, z: np.ndarray, mode: str = "ad", index=None, eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
        """``(r, J)``: the residual vector [m] of shared ``z`` over segments ``index`` (default: training) and its
        Jacobian [m, P] w.r.t. ``z``. ``"ad"``: exact, one batch holding a copy of each segment per residual of
        it, each copy's own parameters differentiated in one reverse pass; ``"fd"``: forward differences, one
        perturbed copy of each segment per parameter (the finite-difference Gauss-Newton's way)."""
        index = np.asarray(self.train_index if index is None else index)
        s, p, k = len(index), len(z), self.num_residuals
        z = np.asarray(z, dtype=np.float64)
        if mode == "fd":
            batch = np.repeat(z[None], p + 1, 0)
            batch[1:] += eps * np.eye(p)
            zt = torch.as_tensor(np.repeat(batch, s, 0), dtype=self.dtype)
            with torch.no_grad():
                r = self.residuals(zt, np.tile(index, p + 1)).reshape(p + 1, s * k).numpy()
            return r[0], ((r[1:] - r[0]) / eps).T
        if mode != "ad":
            raise ValueError(f"jacobian mode must be 'ad' or 'fd', got {mode!r}")
        zt = torch.as_tensor(np.repeat(z[None], s * k, 0), dtype=self.dtype).requires_grad_(True)
        r = self.residuals(zt, np.repeat(index, k)).reshape(s, k, k)  # [segment, copy, residual]
        own = torch.diagonal(r, dim1=1, dim2=2)  # copy j of a segment answers for its residual j
        own.sum().backward()
        self.cost.backward_steps += s * k * self.steps
        return own.detach().reshape(-1).numpy(), zt.grad.reshape(s * k, p).numpy()
