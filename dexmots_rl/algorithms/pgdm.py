"""PGDM baseline (``dexmots-train algo=pgdm``): Dasari et al.'s exemplar-object-trajectory PPO, as the paper's
Table 2 runs it — our PPO (:mod:`.ppo`, torchrl's ``ClipPPOLoss`` unchanged) with PGDM's observation,
reward, start and initialisation.

    dexmots-train algo=pgdm task=screw_claw
    dexmots-train algo=pgdm task=stapler budget.wall_clock_s=600

What PGDM changes (everything else, the evaluation included, is the task's and PPO's):

* **Observation** (:class:`PGDMObservation`, the training env's transform; the same features rebuilt in front of
  the deployable policy by :func:`policy_observation`, so ``dexmots-eval`` runs it on the plain task env):
  proprioception (hand joint positions and velocities, fingertip positions: our PPO's), the object's state
  (an articulated part's angles and rates, and a tool's base pose, pos + wxyz quat; a free body's pos + wxyz
  quat and its 6 velocities), the reference object coordinates at ``t + k`` for ``k`` in
  ``algo.target_offsets`` (1, 5, 10: the task's own reference, :meth:`~dexmots_rl.envs.base.DexEnv.goal_window`,
  the one the ``pose_traj`` goals read), then ``sin(τ f)`` for ``f`` in ``algo.time_frequencies`` (1, 4, 6, 8)
  and the same cosines, τ = step / episode length. Width: ``2 nu + 3 F + (2 K [+ 7] | 13) + len(offsets) D +
  2 len(frequencies)`` (K: the part's joints as the task observes them; D: the reference's coordinates per
  step, ``goal_window_widths``). On a mirrored task (``task.mirror``) the worlds with a negative goal see these
  features reflected, as the task's own observation is.
* **Reward** (:func:`tracking_reward`), what the critic and the advantages see (``"pgdm_reward"``; the logged
  ``"reward"`` stays the task's): ``10 exp(-50 (‖p - p̄‖ + 0.1 θ(q, q̄) / π)) + 2.5 [lifted]`` against the
  reference at the current step. An articulated object's pose error is its tracked part's, in the units of
  its joint: a hinged part turns about the hinge axis, so its frame's position error is 0 and its rotation
  angle is exactly ``|θ - θ̄|``; a sliding part (a pump's head, a drawer) moves along the axis, so its
  position error is ``|x - x̄|`` in m and its rotation 0. The tracked part is the task's operated joint
  (``joint_index``; a knob task's knob). A tool with a base adds the base's error against the reference,
  which holds the base where it stood: its shift (m) to the position error and its tilt (rad) to the
  rotation error (the task's ``base_motion``; zeros for a base fixed to the world), so knocking a tool over
  costs PGDM reward as it fails the task. The lift bonus (reference and object both ≥ 2 cm above the
  reference's start height) and the early termination (object ≥ 0.25 m from its reference) only exist for
  free objects.
* **Start**: nothing changes. The tool tasks (spray_bottle, scissors, stapler, ...: library objects free on
  the table) start from their object's pre-grasps (``task.initial="pregrasp"``), the knob tasks from their
  grasp (``task.initial="grasp"``): the starts DexMOTS uses (the paper gives PGDM DexMOTS's grasp and no CEM
  step).
* **Warm start** (:func:`warm_start_actor`): the actor's output bias makes the initial mean action the one
  whose joint targets are the mean start pose (``position`` / ``vi``; the ``vi`` stiffness half at 0, the
  geometric mean of its range), log σ₀ = ``algo.init_log_std`` = -1.6. The start pose is the mean of the
  task's start poses (a task drawing one of several pre-grasps gets their mean: PGDM had one per task).
"""

from __future__ import annotations

import logging
import math

import torch
from omegaconf import DictConfig
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import nn
from torchrl.data import Composite, Unbounded

from ..envs.mirror import SignedPermutation, reflect_mirrored, sized
from ..envs.transforms import StateTransform
from ..quaternions import quat_angle
from ..sim import SLIDE
from . import ppo
from .common import policy_from_data

__all__ = ["PGDMFeatures", "PGDMObservation", "PGDMPolicyObservation", "build", "load_policy", "pgdm_variant",
           "policy_observation", "start_action", "tracking_reward", "train", "warm_start_actor"]

log = logging.getLogger(__name__)

WARM_START_SAMPLES = 256  # start poses averaged for the warm start (a task may draw among several pre-grasps)
WARM_START_CLIP = 0.95  # |initial mean action| at most this: a start at a joint limit would need atanh(±1) = ±inf


def tracking_reward(pos_error: torch.Tensor, rot_error: torch.Tensor, lifted: torch.Tensor | None = None,
                    scale: float = 10.0, sharpness: float = 50.0, rot_weight: float = 0.1,
                    lift_bonus: float = 2.5) -> torch.Tensor:
    """PGDM's object-tracking reward ``scale exp(-sharpness (pos_error + rot_weight rot_error / π)) +
    lift_bonus lifted`` (``pos_error`` in m, ``rot_error`` in rad, ``lifted`` bool or None).

    Example:
        >>> import math, torch
        >>> tracking_reward(torch.tensor([0.0]), torch.tensor([0.0])).item()
        10.0
        >>> round(tracking_reward(torch.tensor([0.01]), torch.tensor([math.pi])).item(), 4)  # 10 e^-5.5
        0.0409
    """
    reward = scale * torch.exp(-sharpness * (pos_error + rot_weight * rot_error / math.pi))
    return reward if lifted is None else reward + lift_bonus * lifted.to(reward.dtype)


class PGDMFeatures:
    """PGDM's observation, its reward and its early termination on the entries a task env writes (see the
    module docstring); ``task_env``: a :class:`~dexmots_rl.envs.base.DexEnv` of the task (any number of
    worlds: it lends its reference and its sizes). ``algo``: the ``algo`` section (offsets, frequencies and
    the reward's constants)."""

    def __init__(self, task_env, algo):
        scene, spec = task_env.scene, task_env.observation_spec
        self.articulated, self.nu, self.num_fingers = bool(scene.articulated), scene.num_hand_dofs, scene.num_fingers
        self.coords = task_env.goal_window_widths()[0]  # the reference's object coordinates per step
        # the object's state as the task env writes it: a part's angles and rates (and, for a tool, its base's
        # pose: a free base must be held), or a free body's pose and velocities
        self.object_keys = [("object", "q") if self.articulated else ("object", "pose"), ("object", "qd")]
        if self.articulated and ("object", "base_pose") in spec.keys(True, True):
            self.object_keys.append(("object", "base_pose"))
        object_state = sum(spec[key].shape[-1] for key in self.object_keys)
        self.episode_steps = task_env.max_episode_steps
        # a bound method, not the env: the env is an nn.Module and must not become a submodule of a policy
        self._window = task_env.goal_window
        self.offsets = [int(k) for k in algo["target_offsets"]]
        self.frequencies = [float(f) for f in algo["time_frequencies"]]
        self.reward_constants = {k: float(algo[k]) for k in ("tracking_scale", "tracking_sharpness",
                                                             "rotation_weight", "lift_bonus")}
        self.lift_height, self.far = float(algo["lift_height"]), float(algo["termination_distance"])
        self.width = (2 * self.nu + 3 * self.num_fingers + object_state + len(self.offsets) * self.coords
                      + 2 * len(self.frequencies))
        self.reflection = self._reflection(task_env) if task_env.config.mirror else None
        # the tracked part of an articulated object (its column of ("object", "q")), whether it slides (its
        # error is then a position, in m), and the base's (shift m, tilt rad) from where it stood; bound
        # methods and plain values, not the env (an nn.Module must not become a submodule of a policy)
        self.part = getattr(task_env, "joint_index", None) if self.articulated else None  # None: a knob task's
        self.slides = bool(self.part is not None and scene.tree.joint_kind[self.part] == SLIDE)
        self._base_motion = getattr(task_env, "base_motion", None) if self.part is not None else None

    def _reflection(self, task_env) -> SignedPermutation:
        """The observation's reflection for a mirrored task (``task.mirror``): the task's per-entry maps; the
        reference targets reflect as its goal error's window does; the time features do not change."""
        maps, _ = task_env.mirror_maps()
        targets = sized(maps["goal_error"], len(self.offsets) * self.coords, "the reference targets")
        return SignedPermutation.concat([
            maps[("hand", "q")], maps[("hand", "qd")], maps[("fingertips", "pos")],
            *[maps[key] for key in self.object_keys], targets, SignedPermutation.identity(2 * len(self.frequencies))])

    def targets(self, td: TensorDictBase, offsets) -> torch.Tensor:
        """The reference object coordinates at ``step + offsets`` [N, len(offsets), D]."""
        step = td.get(("task", "step"))
        steps = step + torch.as_tensor(list(offsets), dtype=step.dtype, device=step.device)
        return self._window(td, steps, False)

    def observation(self, td: TensorDictBase) -> torch.Tensor:
        """The policy input [N, width] (unnormalised)."""
        obj = [td.get(key) for key in self.object_keys]
        dtype = obj[0].dtype
        tau = td.get(("task", "step")).to(dtype) / self.episode_steps  # [N, 1]
        freqs = torch.as_tensor(self.frequencies, dtype=dtype, device=tau.device)
        parts = [td.get(("hand", "q")), td.get(("hand", "qd")), td.get(("fingertips", "pos")).flatten(1), *obj,
                 self.targets(td, self.offsets).to(dtype).flatten(1),
                 torch.sin(tau * freqs), torch.cos(tau * freqs)]
        obs = torch.cat(parts, -1)
        # a mirrored task's worlds with a negative goal act in the mirror, so they must also see it
        return obs if self.reflection is None else reflect_mirrored(td, obs, self.reflection)

    def errors(self, td: TensorDictBase) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """``(position error [N, 1] m, rotation error [N, 1] rad, lifted [N, 1] or None)`` of the object
        against the reference at the current step."""
        if self.articulated:  # the tracked part's joint error, plus a base's motion (module docstring)
            q = td.get(("object", "q"))
            q = q if self.part is None else q[:, self.part:self.part + 1]
            error = (q - self.targets(td, [0])[:, 0].to(q.dtype)).norm(dim=-1, keepdim=True)
            zero = torch.zeros_like(error)
            pos_error, rot_error = (error, zero) if self.slides else (zero, error)
            if self._base_motion is not None:
                shift, tilt = self._base_motion(td)
                pos_error, rot_error = pos_error + shift.to(q.dtype), rot_error + tilt.to(q.dtype)
            return pos_error, rot_error, None
        pose = td.get(("object", "pose"))
        ref = self.targets(td, [0])[:, 0].to(pose.dtype)
        start_z = self._window(td, torch.zeros_like(td.get(("task", "step"))), False)[:, 0, 2:3].to(pose.dtype)
        lifted = (ref[:, 2:3] - start_z >= self.lift_height) & (pose[:, 2:3] - start_z >= self.lift_height)
        pos_error = (pose[:, :3] - ref[:, :3]).norm(dim=-1, keepdim=True)
        return pos_error, quat_angle(pose[:, 3:], ref[:, 3:]), lifted

    def reward_and_far(self, td: TensorDictBase) -> tuple[torch.Tensor, torch.Tensor]:
        """``(PGDM reward [N, 1], too far from the reference [N, 1] bool)``; never too far for a hinged part."""
        pos_error, rot_error, lifted = self.errors(td)
        c = self.reward_constants
        reward = tracking_reward(pos_error, rot_error, lifted, scale=c["tracking_scale"],
                                 sharpness=c["tracking_sharpness"], rot_weight=c["rotation_weight"],
                                 lift_bonus=c["lift_bonus"])
        return reward, (pos_error >= self.far) & (not self.articulated)


class PGDMObservation(StateTransform):
    """The training env's transform: ``"observation"`` replaced by PGDM's, ``"pgdm_reward"`` written after
    each step, and worlds whose free object is ``termination_distance`` from its reference terminated."""

    def __init__(self, algo):
        super().__init__(in_keys=[("task", "step")], out_keys=["observation", "pgdm_reward"])
        self.algo = algo
        self._features = None

    @property
    def features(self) -> PGDMFeatures:
        if self._features is None:  # the parent env is only known once the transform is appended
            self._features = PGDMFeatures(self.parent.base_env, self.algo)
        return self._features

    def _call(self, td: TensorDictBase) -> TensorDictBase:
        td.set("observation", self.features.observation(td))
        if "pgdm_reward" not in td.keys():  # a reset: no step, no reward
            td.set("pgdm_reward", torch.zeros_like(td.get(("task", "step")), dtype=td.get("observation").dtype))
        return td

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        reward, far = self.features.reward_and_far(next_tensordict)
        next_tensordict.set("pgdm_reward", reward)
        if bool(far.any()):
            next_tensordict.set("terminated", next_tensordict.get("terminated") | far)
            next_tensordict.set("done", next_tensordict.get("done") | far)
        return self._call(next_tensordict)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        old = observation_spec["observation"]
        lead = old.shape[:-1]
        observation_spec["observation"] = Unbounded(shape=(*lead, self.features.width), dtype=old.dtype,
                                                    device=old.device)
        observation_spec["pgdm_reward"] = Unbounded(shape=(*lead, 1), dtype=old.dtype, device=old.device)
        return observation_spec


class PGDMPolicyObservation(TensorDictModuleBase):
    """The deployable policy's first module: writes PGDM's ``"observation"`` from the plain task env's entries."""

    def __init__(self, features: PGDMFeatures):
        super().__init__()
        self.features, self.width = features, features.width
        self.in_keys = [("hand", "q"), ("hand", "qd"), ("fingertips", "pos"), ("object", "q"), ("object", "pose"),
                        ("object", "qd"), ("task", "step"), ("task", "goal"), ("task", "ref_index"),
                        *[key for key in features.object_keys if key == ("object", "base_pose")]]
        self.out_keys = ["observation"]

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        return tensordict.set("observation", self.features.observation(tensordict))


def policy_observation(algo, env) -> PGDMPolicyObservation:
    """The module rebuilding PGDM's observation on ``env`` (a task env, transformed or not) for ``algo``."""
    return PGDMPolicyObservation(PGDMFeatures(getattr(env, "base_env", env), algo))


def start_action(env) -> torch.Tensor | None:
    """The action [action_dim] whose joint targets are the task's mean start pose (``vi``: stiffness half 0),
    clipped to ±``WARM_START_CLIP``; None for ``torque`` actions (no pose to aim at: mean 0, as PPO)."""
    base = getattr(env, "base_env", env)
    if base.action_type == "torque":
        return None
    state = base.get_rng_state()  # drawing start poses must not move the training's random stream
    try:
        hand = base.sample_initial(WARM_START_SAMPLES)["joint_q"][:, : base.scene.num_hand_dofs].mean(0)
    finally:
        base.set_rng_state(state)
    action = base.actions.actions_for_targets(hand)
    if base.action_type == "vi":
        action = torch.cat([action, torch.zeros_like(action)])
    return action.clamp(-WARM_START_CLIP, WARM_START_CLIP)


@torch.no_grad()
def warm_start_actor(actor, env) -> None:
    """Set the bias of ``actor``'s output layer (the loc half) so its deterministic action, ``tanh(loc)``
    mapped to the action bounds, is :func:`start_action` while the small last-layer weights keep the
    observation's share ~0.01 (the log-std is the actor's ``init_log_std``)."""
    target = start_action(env)
    if target is None:
        log.info("pgdm: torque actions, no pose warm start (initial mean action 0)")
        return
    spec = env.action_spec_unbatched
    low, high = spec.space.low.to(target), spec.space.high.to(target)
    last = [m for m in actor.modules() if isinstance(m, nn.Linear)][-1]
    unit = (2.0 * (target - low) / (high - low) - 1.0).clamp(-WARM_START_CLIP, WARM_START_CLIP)
    last.bias[: target.numel()] = torch.atanh(unit).to(last.bias)


def _check(algo) -> None:
    """``ValueError`` naming the first bad PGDM field of ``algo``."""
    offsets, freqs = algo.get("target_offsets"), algo.get("time_frequencies")
    if not offsets or not all(isinstance(k, int) and not isinstance(k, bool) and k >= 0 for k in offsets):
        raise ValueError(f"algo.target_offsets must be a non-empty list of integers >= 0, got {offsets!r}")
    if not freqs or not all(isinstance(f, (int, float)) and not isinstance(f, bool) and math.isfinite(f)
                            for f in freqs):
        raise ValueError(f"algo.time_frequencies must be a non-empty list of numbers, got {freqs!r}")
    for name in ("tracking_scale", "tracking_sharpness", "rotation_weight", "lift_bonus", "lift_height",
                 "termination_distance"):
        value = algo.get(name)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
            raise ValueError(f"algo.{name} must be a finite number >= 0, got {value!r}")
    if not isinstance(algo.get("warm_start"), bool):
        raise ValueError(f"algo.warm_start must be true or false, got {algo.get('warm_start')!r}")


def pgdm_variant(algo) -> ppo.PPOVariant:
    """The :class:`~.ppo.PPOVariant` that makes our PPO PGDM (checks ``algo``'s PGDM fields first)."""
    _check(algo)
    return ppo.PPOVariant(env_transforms=lambda: [PGDMObservation(algo)],
                          policy_observation=lambda env: policy_observation(algo, env),
                          init_actor=warm_start_actor if algo.warm_start else None, reward_key="pgdm_reward")


def build(cfg: DictConfig):
    """:func:`.ppo.build` with PGDM's env transform and warm start (the same tuple)."""
    return ppo.build(cfg, pgdm_variant(cfg.algo))


def train(cfg: DictConfig, overrides: list[str] | None = None) -> dict:
    """Train a PGDM run (:func:`.ppo.train`); returns the final metrics dict (``metrics.json``)."""
    return ppo.train(cfg, overrides, pgdm_variant)


def load_policy(data: dict, env):
    """The deployable policy of a PGDM checkpoint ``data`` on the plain task ``env``: PGDM's observation
    (rebuilt from the checkpoint's ``algo`` section and ``env``'s task), the normaliser and the actor."""
    return policy_from_data(data, env, observation=policy_observation(data["config"]["algo"], env))
