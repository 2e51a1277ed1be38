"""One identification: a method's run, then what the data says about its answer.

At the answer the Gauss-Newton matrix ``H = J^T J`` (the Jacobian of the training residuals w.r.t. the
unconstrained coordinates: log values of positive parameters) gives the covariance ``s^2 H^-1`` (``s^2`` the
residual variance, sum of squares over ``m - p``), mapped to the parameters' own units, and its condition
number; the eigenvectors of ``H`` whose eigenvalue is below ``1 / max_condition`` of the largest are the
directions the data cannot tell apart, named by the parameters that dominate them. (With ``free_starts`` the
Jacobian is taken from the recorded starts, the start offsets held: the covariance then leaves out their share.) The held-out segments'
replay error (the RMS residual in noise units, and per coordinate kind in metres and radians) is measured with
the initial guess and with the answer.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from .optimize import run_method
from .problem import ShootingProblem

__all__ = ["Identification", "identify", "replay_error"]


@dataclasses.dataclass
class Identification:
    """What :func:`identify` found; ``history``: the method's records (:mod:`.optimize`)."""

    method: str
    names: tuple[str, ...]
    initial: dict
    values: dict
    std: dict  # one standard deviation per parameter, its own units
    correlation: np.ndarray  # [P, P]
    condition_number: float
    unidentifiable: list[str]  # parameters dominating the directions the data cannot tell apart
    train_error: dict  # replay error on the training segments at the initial guess and at the answer
    validation_error: dict  # the same on the held-out segments
    history: list[dict]
    truth: dict | None = None  # the values the data was made with, where it says them

    def relative_errors(self) -> dict | None:
        if not self.truth:
            return None
        return {n: abs(self.values[n] - self.truth[n]) / max(abs(self.truth[n]), 1e-12) for n in self.names}

    def summary(self) -> dict:
        out = {k: getattr(self, k) for k in ("method", "initial", "values", "std", "condition_number",
                                             "unidentifiable", "train_error", "validation_error", "truth")}
        out["names"] = list(self.names)
        out["relative_error"] = self.relative_errors()
        last = self.history[-1]
        out["cost"] = {k: last[k] for k in ("forward_steps", "backward_steps", "cpu_seconds")}
        out["iterations"] = len(self.history) - 1
        return out


def replay_error(problem: ShootingProblem, z, index) -> dict:
    """RMS residual of segments ``index`` with shared parameters ``z``: ``"rms"`` in noise units, and per coordinate
    kind in its units (``"position_m"``, ``"angle_rad"``, ``"quaternion"``)."""
    index = np.asarray(index)
    with torch.no_grad():
        zt = torch.as_tensor(np.asarray(z, dtype=np.float64), dtype=problem.dtype).expand(len(index), -1)
        r = problem.residuals(zt, index)
    physical = (r * problem.scales).numpy()
    kinds = np.array(problem.kinds)
    unit = {"position": "position_m", "angle": "angle_rad", "quaternion": "quaternion"}
    out = {"rms": float(r.square().mean().sqrt())}
    for kind in sorted(set(kinds)):
        out[unit[kind]] = float(np.sqrt(np.mean(physical[..., kinds == kind] ** 2)))
    return out


def _uncertainty(problem: ShootingProblem, z: np.ndarray, jacobian: str, max_condition: float):
    r, jac = problem.jacobian(z, jacobian)
    m, p = jac.shape
    hess = jac.T @ jac
    eigvals, eigvecs = np.linalg.eigh(hess)
    top = max(float(eigvals[-1]), 1e-300)
    condition = float(top / eigvals[0]) if eigvals[0] > 0 else float("inf")
    weak = [i for i in range(p) if eigvals[i] < top / max_condition]
    unidentifiable = sorted({problem.space.names[j] for i in weak for j in range(p) if abs(eigvecs[j, i]) > 0.3})
    s2 = float(r @ r) / max(m - p, 1)
    cov_z = s2 * np.linalg.pinv(hess)
    values = problem.space.values_np(z)
    scale = np.where(problem.space.log, values, 1.0)  # d value / d z
    cov = cov_z * np.outer(scale, scale)
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    corr = cov / np.maximum(np.outer(std, std), 1e-300)
    return std, corr, condition, unidentifiable


def identify(problem: ShootingProblem, method: str = "lbfgs", iterations: int = 30, seed: int = 0,
             max_condition: float = 1e6) -> Identification:
    """Identify ``problem``'s parameters with ``method`` (:data:`~.optimize.METHODS`) in at most ``iterations``
    iterations (generations for CMA-ES); see the module docstring."""
    z0 = problem.space.to_z(problem.space.initial)
    history = run_method(problem, method, iterations, z0=z0, seed=seed)
    best = min(history, key=lambda h: h["loss"])
    z = best["z"]
    std, corr, condition, weak = _uncertainty(problem, z, "fd" if method in ("fd-gn", "cmaes") else "ad",
                                              max_condition)
    names = problem.space.names
    values = problem.space.values_np(z)
    recorded = [problem.traj.params.get(n) for n in names]
    truth = None  # only when one value made all of the data (a randomised recording has one per world)
    if all(v is not None and np.ptp(v) <= 1e-9 * np.abs(v).max() for v in recorded):
        truth = {n: float(v.flat[0]) for n, v in zip(names, recorded)}
    return Identification(
        method=method, names=names, initial=dict(zip(names, map(float, problem.space.initial))),
        values=dict(zip(names, map(float, values))), std=dict(zip(names, map(float, std))), correlation=corr,
        condition_number=condition, unidentifiable=weak,
        train_error={"initial": replay_error(problem, z0, problem.train_index),
                     "identified": replay_error(problem, z, problem.train_index)},
        validation_error={"initial": replay_error(problem, z0, problem.val_index),
                          "identified": replay_error(problem, z, problem.val_index)} if len(problem.val_index)
        else {},
        history=history, truth=truth)
