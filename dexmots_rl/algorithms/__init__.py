"""Training and evaluation: one readable script per method plus the pieces they share.

* :mod:`.shac` — SHAC / AHAC through the differentiable simulator (``dexmots-train algo=shac|ahac``);
* :mod:`.ppo`, :mod:`.sac` — model-free baselines with torchrl's losses (``dexmots-train algo=ppo|sac``),
  sharing :mod:`.common` (training env with VecNorm, tanh-Gaussian actor, the collector loop's end);
* :mod:`.pgdm` — PGDM (``dexmots-train algo=pgdm``): :mod:`.ppo` with PGDM's observation, object-tracking
  reward and action-bias warm start;
* :mod:`.mpc` — predictive-sampling MPC with gradient refinement, evaluation only (``dexmots-train algo=mpc``);
* :mod:`.registry` — name -> training function, config and policy loader of every method;
* :mod:`.loop` — the end of every learning method's iterations and runs (row, budget, rollback, checkpoints,
  evaluations, signals);
* :mod:`.rundir` — the run directory every method writes (config, metrics, logs, checkpoints, lock, resume);
* :mod:`.networks`, :mod:`.checkpoint`, :mod:`.evaluation`, :mod:`.budget`, :mod:`.best_policy`,
  :mod:`.distributed`, :mod:`.validation` — shared pieces.

Submodules are imported on use, so importing this package does not load the simulator.
"""

from __future__ import annotations

__all__ = ["best_policy", "budget", "checkpoint", "common", "distributed", "evaluation", "loop", "mpc", "networks",
           "pgdm", "ppo", "registry", "rundir", "sac", "shac", "validation"]
