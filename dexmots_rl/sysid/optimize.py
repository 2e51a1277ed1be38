"""The identification methods, each a loop over a :class:`~.problem.ShootingProblem` that records every iterate.

* ``lbfgs``: L-BFGS (torch's, strong-Wolfe line search) on the training loss and its gradient through the
  simulator: one forward and one reverse pass over the segments per evaluation, whatever the parameter count.
* ``gn``: Levenberg-Marquardt (damped Gauss-Newton) on the exact Jacobian (one batch with a copy of each segment
  per residual, one reverse pass).
* ``fd-gn``: the same with a forward-difference Jacobian (one perturbed copy of the segments per parameter per
  iteration, as ``mujoco.sysid`` does), a reference method.
* ``cmaes``: CMA-ES (Hansen's (mu/mu_w, lambda) with rank-one and rank-mu updates) whose whole population is one
  batch of worlds, a gradient-free reference method.

Each returns a list of records ``{"iteration", "z", "loss", "forward_steps", "backward_steps", "cpu_seconds"}``.
"""

from __future__ import annotations

import logging
import math

import numpy as np
import torch

from .problem import ShootingProblem

__all__ = ["METHODS", "run_method", "lbfgs", "levenberg_marquardt", "cmaes"]

log = logging.getLogger(__name__)

METHODS = ("lbfgs", "gn", "fd-gn", "cmaes")


def _record(problem: ShootingProblem, history: list, z, loss: float) -> None:
    history.append({"iteration": len(history), "z": np.asarray(z, dtype=np.float64).copy(), "loss": float(loss),
                    **problem.cost.snapshot()})
    log.info("iteration %d: loss %.4g (%d steps, %.1f CPU s)", len(history) - 1, loss, problem.cost.forward_steps,
             problem.cost.cpu_seconds)


def lbfgs(problem: ShootingProblem, z0: np.ndarray, iterations: int, tol: float = 1e-10) -> list[dict]:
    """torch's L-BFGS for ``iterations`` iterations (over the parameters and, with the problem's ``free_starts``,
    the segments' start offsets); every evaluation (line-search trials included) is recorded."""
    p = len(z0)
    z = torch.as_tensor(np.concatenate([z0, np.zeros(problem.num_start_variables)]), dtype=problem.dtype)
    z = z.clone().requires_grad_(True)
    opt = torch.optim.LBFGS([z], lr=1.0, max_iter=iterations, max_eval=2 * iterations, history_size=20,
                            line_search_fn="strong_wolfe", tolerance_grad=tol, tolerance_change=tol)
    history: list[dict] = []

    def closure():
        opt.zero_grad()
        loss, grad = problem.loss_and_grad(z)
        z.grad = grad
        _record(problem, history, z.detach().numpy()[:p], float(loss))
        return loss

    opt.step(closure)
    return history


def levenberg_marquardt(problem: ShootingProblem, z0: np.ndarray, iterations: int, jacobian: str = "ad",
                        tol: float = 1e-10) -> list[dict]:
    """Damped Gauss-Newton: solve ``(J^T J + lam diag(J^T J)) dz = -J^T r``; a step that lowers the loss is kept
    and ``lam`` shrinks, else ``lam`` grows and the step is retried from the same Jacobian."""
    z, lam, history = np.asarray(z0, dtype=np.float64).copy(), 1e-3, []
    r, jac = problem.jacobian(z, jacobian)
    loss = float(np.mean(r**2))
    _record(problem, history, z, loss)
    for _ in range(iterations):
        hess, grad = jac.T @ jac, jac.T @ r
        improved = False
        for _ in range(8):
            step = np.linalg.lstsq(hess + lam * np.diag(np.diag(hess) + 1e-12), -grad, rcond=None)[0]
            trial = problem.loss(z + step)
            if trial < loss:
                z, lam, improved = z + step, max(lam / 10.0, 1e-9), True
                break
            lam *= 10.0
        previous, loss = loss, (trial if improved else loss)
        _record(problem, history, z, loss)
        if not improved or previous - loss <= tol * max(1.0, previous):
            break
        r, jac = problem.jacobian(z, jacobian)
    return history


def cmaes(problem: ShootingProblem, z0: np.ndarray, iterations: int, sigma: float = 0.5,
          population: int | None = None, seed: int = 0, tol: float = 1e-10) -> list[dict]:
    """CMA-ES from mean ``z0`` with step ``sigma`` (in log coordinates: 0.5 spans about x0.6 to x1.6); every
    generation is one batch of ``population`` x segments worlds."""
    rng = np.random.default_rng(seed)
    n = len(z0)
    lam = population or 4 + int(3 * math.log(n))
    mu = lam // 2
    weights = np.log(mu + 0.5) - np.log(np.arange(1, mu + 1))
    weights /= weights.sum()
    mu_eff = 1.0 / np.sum(weights**2)
    c_sigma = (mu_eff + 2) / (n + mu_eff + 5)
    d_sigma = 1 + 2 * max(0.0, math.sqrt((mu_eff - 1) / (n + 1)) - 1) + c_sigma
    c_c = (4 + mu_eff / n) / (n + 4 + 2 * mu_eff / n)
    c_1 = 2 / ((n + 1.3) ** 2 + mu_eff)
    c_mu = min(1 - c_1, 2 * (mu_eff - 2 + 1 / mu_eff) / ((n + 2) ** 2 + mu_eff))
    chi_n = math.sqrt(n) * (1 - 1 / (4 * n) + 1 / (21 * n**2))
    mean, cov = np.asarray(z0, dtype=np.float64).copy(), np.eye(n)
    p_sigma, p_c = np.zeros(n), np.zeros(n)
    history: list[dict] = []
    best_z, best = mean.copy(), problem.loss(mean)
    _record(problem, history, best_z, best)
    for gen in range(iterations):
        vals, vecs = np.linalg.eigh(cov)
        root = vecs @ np.diag(np.sqrt(np.maximum(vals, 1e-20))) @ vecs.T
        inv_root = vecs @ np.diag(1 / np.sqrt(np.maximum(vals, 1e-20))) @ vecs.T
        steps = rng.standard_normal((lam, n)) @ root.T
        candidates = mean + sigma * steps
        losses = problem.losses(candidates)
        order = np.argsort(losses)
        if losses[order[0]] < best:
            best, best_z = float(losses[order[0]]), candidates[order[0]].copy()
        chosen = steps[order[:mu]]
        step_mean = weights @ chosen
        mean = mean + sigma * step_mean
        p_sigma = (1 - c_sigma) * p_sigma + math.sqrt(c_sigma * (2 - c_sigma) * mu_eff) * inv_root @ step_mean
        h_sigma = float(np.linalg.norm(p_sigma) / math.sqrt(1 - (1 - c_sigma) ** (2 * (gen + 1))) < (1.4 + 2 / (n + 1))
                        * chi_n)
        p_c = (1 - c_c) * p_c + h_sigma * math.sqrt(c_c * (2 - c_c) * mu_eff) * step_mean
        cov = ((1 - c_1 - c_mu) * cov + c_1 * (np.outer(p_c, p_c) + (1 - h_sigma) * c_c * (2 - c_c) * cov)
               + c_mu * (chosen.T * weights) @ chosen)
        sigma *= math.exp((c_sigma / d_sigma) * (np.linalg.norm(p_sigma) / chi_n - 1))
        _record(problem, history, best_z, best)
        if sigma * math.sqrt(max(vals)) < tol:
            break
    return history


def run_method(problem: ShootingProblem, method: str, iterations: int, z0: np.ndarray | None = None,
               seed: int = 0) -> list[dict]:
    """Run ``method`` (one of :data:`METHODS`) from ``z0`` (default: the problem's initial guess), its cost counted
    from zero."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; the methods are: {', '.join(METHODS)}")
    if problem.free_starts and method != "lbfgs":
        raise ValueError(f"free_starts: only method=lbfgs estimates the segments' start states, not {method!r}")
    z0 = problem.space.to_z(problem.space.initial) if z0 is None else z0
    problem.cost.start()
    if method == "lbfgs":
        return lbfgs(problem, z0, iterations)
    if method == "cmaes":
        return cmaes(problem, z0, iterations, seed=seed)
    return levenberg_marquardt(problem, z0, iterations, "ad" if method == "gn" else "fd")
