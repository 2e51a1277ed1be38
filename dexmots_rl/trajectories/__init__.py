"""Object-centric task plans: pose + wrench trajectories, their file format, and finite-difference wrenches.

Example:
    >>> import torch
    >>> from dexmots_rl.trajectories import PoseWrenchTrajectory
    >>> q = torch.tensor([[1.0, 0.0, 0.0, 0.0]] * 2)
    >>> PoseWrenchTrajectory(torch.zeros(2, 3), q, torch.zeros(2, 6), dt=0.1).horizon
    2
"""

from __future__ import annotations

from .finite_differences import angular_velocities, load_pose_demo, wrenches_from_poses
from .planner import PlanResult, interpolate_reference, optimize_wrenches
from .trajectory import (
    FIELDS,
    FORMAT_NAME,
    FORMAT_VERSION,
    PoseWrenchTrajectory,
    TrajectoryFormatError,
    validate_trajectory_fields,
)

__all__ = [
    "FIELDS",
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "PlanResult",
    "PoseWrenchTrajectory",
    "TrajectoryFormatError",
    "angular_velocities",
    "interpolate_reference",
    "load_pose_demo",
    "optimize_wrenches",
    "validate_trajectory_fields",
    "wrenches_from_poses",
]
