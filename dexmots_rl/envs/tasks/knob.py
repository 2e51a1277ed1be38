"""Turning a knob on a hinge by a goal angle: the config, reference, reward and success every knob task shares.

A task (``screw_claw``, ``allegro_rotate``) subclasses :class:`KnobTurnConfig` and :class:`KnobTurnEnv`
and adds its hand's start poses (:meth:`KnobTurnEnv.start_pose`), bench poses and MJCF.

Per episode: the goal angle is drawn with magnitude in ``goal_range`` and a random direction; the knob's
joint damping and Coulomb friction are drawn from ``damping_range`` / ``friction_range`` (the paper's
"object joint friction is unknown and randomized per episode"). Success: ``|theta - theta_goal| <
success_threshold``; evaluation reads it at the last step of the episode.

Reference (what the policy tracks, paper §4): without a plan bank, the knob angle ramps linearly from 0
to the goal over ``ramp_steps`` env steps and then holds; the reference torque about the hinge is the
one the *nominal* knob (the MJCF's damping, friction and spring, not the episode's randomised ones: the
plan does not know them) needs for that motion, ``d ω + f tanh(ω / 0.05)`` during the ramp and 0 after,
plus ``k (θ̄ - θ_rest)`` for a sprung part;
``reference_torque="episode"`` computes it with the episode's drawn damping and friction instead (the
policy is told how hard the knob is to turn, while its pose-only goal modes still are not). With
``references=`` (plans from ``dexmots-plan``) each world follows one planned trajectory instead and its
goal is that plan's final angle.

Reward (paper Eq. 1–3, terms under ``("reward_terms", name)``):
``λ_pose exp(-|θ - θ̄_k| / pose_scale) + λ_wrench exp(-|τ - τ̄_k| / torque_scale) - λ_act ‖w ⊙ a‖
+ λ_f Σ_i exp(-‖x_fi - x_o‖ / fingertip_scale)`` with k the step counter, τ the contact torque about the
hinge axis and w the distal-weighted joint weights (stiffness actions of ``"vi"`` are not penalised).
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import torch
from tensordict import TensorDict

from ..base import DexEnv
from ...trajectories import PoseWrenchTrajectory
from ..config import TaskConfig, rule
from ..demos import demo_trajectory, part_torque
from ..references import lookup
from ..rewards import action_penalty, angle_tracking_reward, distal_weighted_joint_weights, fingertip_reward

__all__ = ["KnobTurnConfig", "KnobTurnEnv", "PARAM_BREAKDOWNS", "REFERENCE_TORQUES"]

REFERENCE_TORQUES = ("nominal", "episode")  # whose knob the reference torque is computed for
# dexmots-eval breakdowns by the knob joint's randomised parameters (every knob-like task draws them)
PARAM_BREAKDOWNS = {"friction": ("sim", "params", "joint_friction"), "damping": ("sim", "params", "joint_damping")}
RANGE = rule(ge=0, ordered=True)  # a (low, high) pair of non-negative numbers


@dataclasses.dataclass
class KnobTurnConfig(TaskConfig):
    """Fields of every knob-turning task (defaults: the claw's; each task sets its own)."""

    # the start pose: one of the task's initial_choices
    initial: str = dataclasses.field(default="grasp", metadata=rule(choices="initial_choices"))
    initial_choices: ClassVar[tuple[str, ...]] = ("grasp",)  # the start poses the task's env knows
    # |goal angle| (rad), random sign
    goal_range: tuple[float, float] = dataclasses.field(default=(math.pi / 4, math.pi / 2), metadata=RANGE)
    # knob joint damping (N m s/rad), drawn per episode
    damping_range: tuple[float, float] = dataclasses.field(default=(0.3, 0.7), metadata=RANGE)
    # knob joint Coulomb friction (N m), drawn per episode
    friction_range: tuple[float, float] = dataclasses.field(default=(0.2, 1.0), metadata=RANGE)
    joint_noise: float = dataclasses.field(default=0.05, metadata=rule(ge=0))  # rad: uniform noise on the start pose
    success_threshold: float = 0.1  # rad: |theta - goal| at the episode end (the paper's epsilon_task)
    ramp_steps: int = 25  # analytic reference: the angle ramps to the goal over this many steps
    pose_scale: float = 0.5  # rad: r_pose = exp(-|theta - ref| / pose_scale)
    torque_scale: float = 5.0  # N m: r_wrench = exp(-|tau - ref| / torque_scale)
    fingertip_scale: float = 1.0  # m: r_f = sum_i exp(-|x_fi - x_o| / fingertip_scale)
    # nominal | episode: the reference torque for the MJCF's knob or this one
    reference_torque: str = dataclasses.field(default="nominal", metadata=rule(choices=REFERENCE_TORQUES))


class KnobTurnEnv(DexEnv):
    """A hand and a knob on one hinge; subclasses give :meth:`start_pose` and the scene."""

    reward_terms = ("pose", "wrench", "action", "fingertip")
    # dexmots-eval: success by quartiles of each; the signed goal's lower two quartiles turn the knob one way and
    # the upper two the other, so a policy that learnt one direction only shows as 0 % / 100 % halves
    breakdowns = {**PARAM_BREAKDOWNS, "goal": ("task", "goal")}

    def __init__(self, config: KnobTurnConfig, **kwargs):
        super().__init__(config, **kwargs)
        c = self.config
        self.goal_range, self.success_threshold, self.ramp_steps = c.goal_range, c.success_threshold, c.ramp_steps
        self.coeffs, self.pose_scale, self.torque_scale = c.reward, c.pose_scale, c.torque_scale
        self._open_pose = torch.as_tensor(self.start_pose(), dtype=self.dtype, device=self.device)
        scene = self.sim.scene

        def t(x):
            return torch.as_tensor(x, dtype=self.dtype, device=self.device)

        self._lower, self._upper = t(scene.dof_lower), t(scene.dof_upper)
        self._axis = t(scene.object_base_rot @ scene.object_axis)
        self._knob_pos = t(scene.object_base_pos)
        # the reference's model of the knob: the MJCF's, or the identified values (task.object_params)
        # (damping, friction, stiffness, rest): the scene's parameters in their order
        self._nominal = tuple(self.identified_params.get(name, value) for name, value in
                              scene.default_param_values().items())
        weights = distal_weighted_joint_weights(scene.joints_per_finger, scene.num_fingers, dtype=self.dtype,
                                                device=self.device)
        self._act_weights = torch.cat([weights, torch.zeros_like(weights)]) if c.action == "vi" else weights

    def start_pose(self) -> tuple[float, ...]:
        """The hand's joint positions at the start of an episode (``config.initial``)."""
        raise NotImplementedError

    def _param_ranges(self) -> dict:
        return {"joint_damping": self.config.damping_range, "joint_friction": self.config.friction_range}

    def sample_start(self, n: int) -> torch.Tensor:
        """The hand's start poses of ``n`` episodes [n, nu], before the joint noise: :meth:`start_pose`."""
        return self._open_pose.expand(n, -1)

    def sample_goal(self, n: int) -> torch.Tensor:
        """Goal angles of ``n`` episodes [n, 1]: magnitude in ``goal_range``, random sign."""
        sign = torch.where(self._rand(n, 1) < 0.5, -1.0, 1.0).to(self.dtype)
        return sign * self._uniform(n, self.goal_range)

    def sample_initial(self, n: int) -> dict:
        noise = self.config.joint_noise * (2 * self._rand(n, self.sim.nu) - 1)
        hand = torch.minimum(torch.maximum(self.sample_start(n) + noise, self._lower), self._upper)
        rest = torch.full((n, 1), float(self.sim.scene.object_q0[0]), dtype=self.dtype, device=self.device)
        q = torch.cat([hand, rest], -1)
        goal = self.sample_goal(n)
        ref_index = self.sample_ref_index(n)
        if self.reference_bank is not None:
            goal = self.reference_bank["joint_q"][ref_index.squeeze(-1), -1]
        return {
            "joint_q": q,
            "joint_qd": torch.zeros(n, self.sim.nv, dtype=self.dtype, device=self.device),
            "params": self.sample_params(n),
            "goal": goal,
            "ref_index": ref_index,
        }

    def joint_reference(self, td, steps: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(angle, torque)`` of the reference at env steps ``steps`` [N, H], each [N, H, 1]: the lean path
        the reward and the goal window use every step (no TensorDict)."""
        if self.reference_bank is not None:
            ref = lookup(self.reference_bank, td[("task", "ref_index")], steps)
            return ref["joint_q"], ref["joint_torque"]
        goal = td[("task", "goal")]  # [N, 1]
        frac = (steps.to(self.dtype) / self.ramp_steps).clamp(max=1.0).unsqueeze(-1)  # [N, H, 1]
        angle = goal.unsqueeze(1) * frac
        speed = goal.unsqueeze(1) / (self.ramp_steps * self.sim.dt)
        moving = ((steps >= 1) & (steps <= self.ramp_steps)).unsqueeze(-1)
        damping, friction, stiffness, rest = self._nominal
        if self.config.reference_torque == "episode":
            damping, friction, stiffness, rest = (td[("sim", "params", name)].to(self.dtype)[:, None]  # [N, 1, 1]
                                                  for name in ("joint_damping", "joint_friction", "joint_stiffness",
                                                               "joint_rest"))
        # a sprung part is held against its spring; a knob's stiffness is 0
        return angle, part_torque(torch.where(moving, speed, 0.0), angle, (damping, friction, stiffness, rest))

    def demo_reference(self, demo: dict):
        """The knob turning as demonstrated, about its hinge where it stands (the pose follows the angle)."""
        traj = demo_trajectory(demo, self.sim.dt, self.sim.scene.object_base_pos, (1.0, 0.0, 0.0, 0.0),
                               self._nominal)
        half = 0.5 * traj.joint_q
        axis = self._axis.to(torch.float64).cpu()
        quat = torch.cat([torch.cos(half), torch.sin(half) * axis], -1)
        wrench = torch.cat([torch.zeros_like(traj.pos), traj.joint_torque * axis], -1)
        return PoseWrenchTrajectory(traj.pos, quat, wrench, traj.dt, joint_q=traj.joint_q,
                                    joint_torque=traj.joint_torque)

    def reference(self, td, steps: torch.Tensor) -> TensorDict:
        if self.reference_bank is not None:
            return lookup(self.reference_bank, td[("task", "ref_index")], steps)
        angle, torque = self.joint_reference(td, steps)
        half = 0.5 * angle
        quat = torch.cat([torch.cos(half), torch.sin(half) * self._axis], -1)
        pose = torch.cat([self._knob_pos.expand(*angle.shape[:2], 3), quat], -1)
        wrench = torch.cat([torch.zeros_like(pose[..., :3]), torque * self._axis], -1)
        return TensorDict({"pose": pose, "joint_q": angle, "wrench": wrench, "joint_torque": torque},
                          batch_size=steps.shape)

    def goal_window(self, td, steps: torch.Tensor, with_wrench: bool) -> torch.Tensor:
        angle, torque = self.joint_reference(td, steps)
        return torch.cat([angle, torque], -1) if with_wrench else angle

    def achieved_goal(self, obs: dict) -> torch.Tensor:
        return obs[("object", "q")]

    def task_reward(self, obs: dict, task: dict, action: torch.Tensor) -> tuple[torch.Tensor, dict]:
        ref_angle, ref_torque = self.joint_reference(task, task[("task", "step")])
        angle = obs[("object", "q")]
        axial = (obs[("object", "wrench")][:, 3:] * self._axis).sum(-1, keepdim=True)
        terms = {
            "pose": angle_tracking_reward(angle, ref_angle[:, 0], self.pose_scale),
            "wrench": angle_tracking_reward(axial, ref_torque[:, 0], self.torque_scale),
            "action": action_penalty(action.to(self.dtype), self._act_weights),
            "fingertip": fingertip_reward(obs[("fingertips", "pos")], obs[("object", "pose")][:, :3],
                                          self.config.fingertip_scale),
        }
        c = self.coeffs
        total = (c.lambda_pose * terms["pose"] + c.lambda_wrench * terms["wrench"] + c.lambda_act * terms["action"]
                 + c.lambda_f * terms["fingertip"])
        return total, terms

    def task_success(self, obs: dict, goal: torch.Tensor) -> torch.Tensor:
        return (obs[("object", "q")] - goal).abs() < self.success_threshold


