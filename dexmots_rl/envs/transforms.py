"""Goal conditioning as torchrl transforms: the three goal representations of the paper's ablation.

:class:`GoalConditioning` writes ``"desired_goal"`` (which the env never reads back: it keeps its own goal
under ``("task", "goal")``) from the task's object-centric reference, indexed by the env's step counter
``("task", "step")`` and each world's plan ``("task", "ref_index")``:

============  ==========================================================  ================
mode          ``"desired_goal"``                                          width
============  ==========================================================  ================
pose          the final goal (the task's goal coordinates)                ``goal_dim``
pose_traj     the reference object coordinates of the next H steps        ``H·D``
pose_wrench   per step of the next H: coordinates, then wrench            ``H·(D + W)``
============  ==========================================================  ================

Object coordinates (``D``) are the articulation angles for an articulated object and pos + wxyz quat
(7) for a free body; the wrench (``W``) is the generalised force on the articulation (K) or the
force + torque (6) on a free body. ``"achieved_goal"`` (the env's) stays the current coordinates.

It also writes ``"goal_error"``: the goal's object coordinates (every step of the window) minus the
current ones (angles for an articulation; for a free body the position difference and the rotation
``q_goal * conj(q)`` as a wxyz quaternion): the network could compute it from the two, but a
goal-relative input spares it learning a subtraction across differently normalised features.
:func:`observation_transform` also assembles the policy input ``"observation"`` (flattened and
concatenated :data:`POLICY_KEYS`) in the same transform.

Example:
    >>> from dexmots_rl.envs import make_env
    >>> env = make_env("screw_claw", num_envs=2, goal="pose_wrench", goal_horizon=4, seed=0)
    >>> env.reset()["desired_goal"].shape
    torch.Size([2, 8])
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.data import Composite, Unbounded
from torchrl.envs import Compose, Transform

from ..quaternions import quat_conjugate, quat_multiply

__all__ = ["GOAL_MODES", "POLICY_KEYS", "GoalConditioning", "StateTransform", "observation_transform"]

GOAL_MODES = ("pose", "pose_traj", "pose_wrench")

# what the default policy input "observation" is assembled from (never read back by the env)
POLICY_KEYS = [
    ("hand", "q"),
    ("hand", "qd"),
    ("object", "q"),
    ("object", "qd"),
    ("fingertips", "pos"),
    "desired_goal",
    "goal_error",
]


class StateTransform(Transform):
    """A transform that computes its outputs from several entries of the whole TensorDict (so it has no
    per-key ``_apply_transform``): ``_call`` serves steps, resets and direct calls alike."""

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        return self._call(td)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return self._call(tensordict_reset)


class GoalConditioning(StateTransform):
    """Write ``"desired_goal"`` for one of :data:`GOAL_MODES` (see the module docstring)."""

    def __init__(self, mode: str = "pose", horizon: int = 8, policy_keys: list | None = None):
        if mode not in GOAL_MODES:
            raise ValueError(f"goal mode {mode!r} is unknown; known: {', '.join(GOAL_MODES)}")
        if not isinstance(horizon, int) or horizon < 1:
            raise ValueError(f"goal_horizon must be a positive integer, got {horizon!r}")
        out_keys = ["desired_goal", "goal_error"] + (["observation"] if policy_keys else [])
        super().__init__(in_keys=[("task", "step"), ("task", "goal")], out_keys=out_keys)
        self.mode, self.horizon = mode, horizon
        # with policy_keys the transform also assembles "observation" (their flattened concatenation) in the
        # same call: one transform per step instead of three (goal, flatten, cat; measured in the pipeline bench)
        self.policy_keys = list(policy_keys or [])

    def _task(self):
        return self.parent.base_env

    def _widths(self) -> tuple[int, int]:
        """Widths of ``"desired_goal"`` and ``"goal_error"``."""
        env = self._task()
        if self.mode == "pose":
            return env.goal_dim, env.goal_dim
        coords, wrench = env.goal_window_widths()
        return self.horizon * (coords + (wrench if self.mode == "pose_wrench" else 0)), self.horizon * coords

    def _goal(self, td: TensorDictBase) -> tuple[torch.Tensor, torch.Tensor]:
        """``(desired_goal, goal_error)`` of a TensorDict holding the env's outputs."""
        achieved = td.get("achieved_goal")
        if self.mode == "pose":
            goal = td.get(("task", "goal"))
            return goal, _coordinate_error(goal, achieved)
        env = self._task()
        steps = td.get(("task", "step")) + torch.arange(1, self.horizon + 1, device=td.device)
        window = env.goal_window(td, steps, self.mode == "pose_wrench").to(achieved.dtype)
        coords = window[..., : achieved.shape[-1]]
        error = _coordinate_error(coords, achieved.unsqueeze(-2))
        return window.flatten(-2), error.flatten(-2)

    def _call(self, td: TensorDictBase) -> TensorDictBase:
        goal, error = self._goal(td)
        td.set("desired_goal", goal)
        td.set("goal_error", error)
        if self.policy_keys:
            batch = td.batch_dims
            td.set("observation", torch.cat([td.get(k).flatten(batch) for k in self.policy_keys], -1))
        return td

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        old = observation_spec["desired_goal"]
        for key, width in zip(("desired_goal", "goal_error"), self._widths()):
            observation_spec[key] = Unbounded(shape=(*old.shape[:-1], width), dtype=old.dtype, device=old.device)
        if self.policy_keys:
            lead = len(old.shape) - 1
            width = sum(int(torch.Size(observation_spec[k].shape[lead:]).numel()) for k in self.policy_keys)
            observation_spec["observation"] = Unbounded(shape=(*old.shape[:-1], width), dtype=old.dtype,
                                                        device=old.device)
        return observation_spec


def _coordinate_error(goal: torch.Tensor, achieved: torch.Tensor) -> torch.Tensor:
    """``goal - achieved`` for articulation angles; for free-body poses (pos + wxyz quat, 7 wide) the
    position difference and the relative rotation ``q_goal * conj(q)``."""
    if goal.shape[-1] != 7:
        return goal - achieved
    achieved = achieved.expand_as(goal)
    rel = quat_multiply(goal[..., 3:], quat_conjugate(achieved[..., 3:]))
    return torch.cat([goal[..., :3] - achieved[..., :3], rel], -1)


def observation_transform(goal: str = "pose", goal_horizon: int = 8, policy_keys: list | None = None) -> Compose:
    """Goal conditioning and the policy input ``"observation"``: ``policy_keys`` (default
    :data:`POLICY_KEYS`) flattened and concatenated, in one transform."""
    return Compose(GoalConditioning(goal, goal_horizon, policy_keys=list(policy_keys or POLICY_KEYS)))
