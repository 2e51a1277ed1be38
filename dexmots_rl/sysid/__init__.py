"""System identification through contact: estimate an object's named physical parameters from recorded
trajectories by gradients through the differentiable simulator (``dexmots-sysid``).

:func:`load_trajectories` reads an MCAP recording or a ``.npz`` (:mod:`.data`); :class:`ShootingProblem`
replays short segments from their recorded states (:mod:`.problem`); :func:`identify` runs a method
(:mod:`.optimize`: L-BFGS or Gauss-Newton through the simulator, or the finite-difference Gauss-Newton and
CMA-ES references) and returns an :class:`Identification` with the covariance, the Gauss-Newton matrix's
condition number and the held-out replay error; :func:`write_report` writes the text report and plots.
"""

from __future__ import annotations

from .data import CONTROL_FIELDS, Trajectories, load_trajectories, save_npz
from .identify import Identification, identify
from .optimize import METHODS, run_method
from .problem import ParamSpace, ShootingProblem
from .report import write_report
from .synthetic import synthetic_trajectories

__all__ = ["CONTROL_FIELDS", "Identification", "METHODS", "ParamSpace", "ShootingProblem", "Trajectories",
           "identify", "load_trajectories", "run_method", "save_npz", "synthetic_trajectories", "write_report"]
