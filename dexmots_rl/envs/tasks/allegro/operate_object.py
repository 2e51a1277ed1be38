"""``operate``: the Allegro hand operates one joint of any articulated object (a library name or a URDF).

The scene is built from the object (:func:`dexmots_rl.assets.hand_scene.hand_object_scene_xml`): the object
stands on a table with its grasp point under the palm-down hand (a free base must be held, or it is pushed
over; a fixed one cannot move), and is simulated by :class:`~dexmots_rl.sim.ArticulatedSimulator`.

Per episode: the operated joint (``task.joint``, default the object's ``operated_joint``) starts at rest and
its goal is ``rest + goal_fraction (far end - rest)``, the far end being the end of its range farther from
rest (90 % of the travel by default: the original code's goal); every joint's damping, Coulomb friction and
spring stiffness are drawn within ``param_scale`` (relative) of the object's values. The hand starts from one
of the object's pre-grasps (``initial="pregrasp"``, the default: fingertips resting where a person holds the
tool, :mod:`dexmots_rl.envs.object_pregrasp`; the package ships a file per library object, and a URDF's are searched
on first use and kept beside its scene, :mod:`.urdf_object`; ``task.pregrasps`` overrides), or open above the object
(``initial="open"``), with joint noise. Success at the episode end: the joint within
``success_band`` (a fraction of its range) of the goal, and a free base moved less than ``max_base_shift`` and
tilted less than ``max_base_tilt`` from where it stood.

Observations: ``("object", "q")`` / ``("object", "qd")`` are the object's joints (every part's), ``("object",
"pose")`` the operated part's pose and ``("object", "base_pose")`` the base's; the goal is the operated joint's
angle (or position); ``("object", "joint_wrench")`` is the fingers' generalised force on each joint (N m about
a hinge, N along a slide; mean over the step's substeps). Reference: the joint ramps from rest to the goal over
``ramp_steps`` steps, with the torque the object's nominal spring, damping and friction need. Reward: ``λ_pose``
tracking of the reference angle, ``λ_wrench`` tracking of the reference torque by the fingers' force on the
operated joint, ``exp(-|τ - τ̄| / torque_scale)`` (``force_scale`` for a slide), the fingertips' closeness to the
operated part (``λ_f``), the action penalty (``λ_act``), and the base's stillness (``lambda_base``
exp(-shift / max_base_shift - tilt / max_base_tilt)). The wrench term counts only with the pose + wrench goal
(``goal="pose_wrench"``, the default): the pose-only goals (``pose``, ``pose_traj``, the paper's ablation)
neither see nor are rewarded for the reference torque (the term is still reported under ``("reward_terms",
"wrench")``).

Object variants: ``objects`` (library names or URDF paths of one topology, e.g. a class's instances, or
``train`` / ``heldout``: that part of the library split of ``object``'s class) or
``variants`` >= 2 (``variants`` size variants of ``object``: the object itself and ``variants - 1`` with every
size drawn within ``variant_scale`` of its own, seeded by ``variant_seed``; :func:`~dexmots_rl.assets.objects.
sample_variants`) build one scene of K objects (:func:`dexmots_rl.sim.load_variants`). Every reset draws each
world's variant uniformly (the per-world parameter ``("sim", "params", "variant")``), its joint parameters
around that variant's values, and its goal, rest pose, reference law, base pose and pre-grasp from that variant
(an instance's own pre-grasps; size variants start from their instance's, found for its nominal sizes). The
variant index is in the TensorDict's state, not in the policy's observation: a policy sees only the object's
joint state and poses, so it can run on held-out objects whose index it never saw.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import ClassVar, Optional

import torch
from tensordict import TensorDict

from ....quaternions import quat_angle
from ....sim import SLIDE, joint_param_names
from ...base import DexEnv
from ...demos import demo_trajectory, part_torque
from ...object_pregrasp import operate_pregrasp_path
from ...pregrasp import PregraspError, load_pregrasps
from ...references import lookup
from ...registry import register_task
from ...config import TaskConfig, rule
from ...rewards import RewardCoefficients, action_penalty, angle_tracking_reward, distal_weighted_joint_weights, \
    fingertip_reward
from . import hand
from .object_scenes import build_scene, object_names, scene_dir
from .urdf_object import UrdfOptions, cached_pregrasps, urdf_load_options

__all__ = ["OperateObjectConfig", "OperateObjectEnv", "build_scene"]

# rad, in the hand's joint order: task.initial="open", the fingers slightly curled above the object, the thumb opposed
ABOVE_OBJECT = (0.0, 0.3, 0.3, 0.3) * 3 + (0.8, 0.3, 0.3, 0.3)


@dataclasses.dataclass
class OperateObjectConfig(TaskConfig):
    """Fields of ``operate``."""

    name: str = "operate"
    object: str = "spray_bottle_a"  # a library object (dexmots_rl.assets.objects.list_objects) or a .urdf path
    joint: Optional[str] = None  # the operated joint (None: the object's operated_joint)
    urdf: UrdfOptions = dataclasses.field(default_factory=UrdfOptions)  # how a .urdf object is loaded
    initial: str = dataclasses.field(default="pregrasp", metadata=rule(choices="initial_choices"))
    initial_choices: ClassVar[tuple[str, ...]] = ("pregrasp", "open")
    # a pre-grasp file (dexmots-pregrasp --task operate --object ...); None: shipped, or a URDF's cached ones
    pregrasps: Optional[str] = None
    goal_fraction: float = dataclasses.field(default=0.9, metadata=rule(gt=0, le=1))  # of the joint's travel
    success_band: float = dataclasses.field(default=0.1, metadata=rule(gt=0, le=1))  # of the joint's range
    max_base_shift: float = 0.02  # m: a free base moved farther fails
    max_base_tilt: float = 0.2  # rad: a free base tilted more fails
    param_scale: float = dataclasses.field(default=0.3, metadata=rule(ge=0, lt=1))  # relative spread of the draws
    # object variants (see the module docstring): library names or URDF paths of one topology, replacing
    # ``object`` (from Python a list; a comma-separated string from the command line), or size variants of it
    objects: Optional[str] = dataclasses.field(default=None, metadata=rule(objects=True))
    variants: int = dataclasses.field(default=0, metadata=rule(ge=0))  # 0 or 1: the object alone
    variant_scale: float = dataclasses.field(default=0.1, metadata=rule(ge=0, le=0.5))  # relative size spread
    variant_seed: int = dataclasses.field(default=0, metadata=rule(ge=0))  # seeds the size draws (one scene everywhere)
    joint_noise: float = dataclasses.field(default=0.02, metadata=rule(ge=0))  # rad, on the start pose
    ramp_steps: int = 40
    max_episode_steps: int = 150
    pose_scale: float = 0.1  # of the joint's range: r_pose = exp(-|q - ref| / (pose_scale range))
    # r_wrench = exp(-|tau - ref| / scale), tau the fingers' force on the operated joint. The tools' hinges need
    # 0.01 N m (scissors' friction) to 0.26 N m (the stapler's spring at its goal), the torque of a fingertip
    # pressing 0.2-5 N at the 5 cm lever of a trigger or handle: 0.05 N m (1 N at 5 cm) resolves a finger's
    # share, and a hand that gives none of the reference still earns a little and feels the gradient.
    torque_scale: float = dataclasses.field(default=0.05, metadata=rule(gt=0))  # N m (a hinge)
    # the slides need 0.7 N (the drawer's damping) to 2.9 N (the pump's spring held down): 1 N, one fingertip's push
    force_scale: float = dataclasses.field(default=1.0, metadata=rule(gt=0))  # N (a slide)
    fingertip_scale: float = 0.05  # m
    lambda_base: float = dataclasses.field(default=0.5, metadata=rule(ge=0))  # weight of the base's stillness
    reward: RewardCoefficients = dataclasses.field(
        default_factory=lambda: RewardCoefficients(lambda_pose=1.0, lambda_wrench=0.5, lambda_act=0.01, lambda_f=0.5))


def _pose(pos, rot) -> list[float]:
    """pos + wxyz quaternion of a rotation matrix."""
    import mujoco
    import numpy as np

    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.asarray(rot, dtype=np.float64).ravel())
    return [*pos, *quat]


class OperateObjectEnv(DexEnv):
    """The Allegro hand and an articulated object; see the module docstring."""

    contact_params = hand.CONTACT
    reward_terms = ("pose", "wrench", "action", "fingertip", "base")
    breakdowns = {"goal": ("task", "goal")}

    @classmethod
    def asset_path(cls):
        raise ValueError("task 'operate' builds its scene from task.object (operate_object.build_scene)")

    @classmethod
    def task_scene(cls, config):
        return _build(config)[0]

    def __init__(self, config: OperateObjectConfig, scene=None, **kwargs):
        self.object_asset = None
        if scene is None:
            scene, self.object_asset = _build(config)
        tree = scene.tree
        name = config.joint or (self.object_asset.operated_joint if self.object_asset else "") or tree.joint_names[0]
        if name not in tree.joint_names:
            raise ValueError(f"task.joint: {name!r} is not a joint of {config.object!r}; its joints: {tree.joint_names}")
        self.joint_index = tree.joint_names.index(name)
        self.joint_name = name
        self.num_variants = scene.num_variants
        # the objects (library names or URDF paths) the scene's variants are instances of: task.objects', resolved
        self.instance_names = object_names(config.objects, config.object) if config.objects else [config.object]
        super().__init__(config, scene=scene, **kwargs)
        c, dev, dt = self.config, self.device, self.dtype
        # N along a slide, N m about a hinge: the unit of the fingers' force on the operated joint
        self.wrench_scale = c.force_scale if tree.joint_kind[self.joint_index] == SLIDE else c.torque_scale
        lo, hi = (float(v) for v in tree.joint_range[self.joint_index])
        rest = float(tree.q0[7 * tree.free + self.joint_index])
        far = hi if hi - rest >= rest - lo else lo
        self.joint_rest, self.joint_span = rest, hi - lo
        self.goal_value = rest + c.goal_fraction * (far - rest)
        self._open = torch.as_tensor(ABOVE_OBJECT, dtype=dt, device=dev)
        self._lower = torch.as_tensor(scene.dof_lower, dtype=dt, device=dev)
        self._upper = torch.as_tensor(scene.dof_upper, dtype=dt, device=dev)
        self._base0 = torch.as_tensor(tree.q0[:7] if tree.free else _pose(tree.offset_pos[0], tree.offset_rot[0]),
                                      dtype=dt, device=dev)
        j = self.joint_index
        nominal = (tree.joint_damping[j], tree.joint_friction[j], tree.joint_stiffness[j], tree.joint_rest[j])
        # the reference's model of the operated joint: the MJCF's, or the identified values (task.object_params)
        self._nominal = tuple(self.identified_params.get(name, value) for name, value in
                              zip(joint_param_names([tree.joint_names[j]]), nominal))
        if self.num_variants > 1:
            self._variant_values = self._variant_table(scene)
            self.breakdowns = {**self.breakdowns, "variant": ("sim", "params", "variant")}  # dexmots-eval's groups
            self.breakdown_labels = {"variant": (self.instance_names if c.objects else  # dexmots-eval's names
                                                 [c.object] + [f"{c.object}_size{i}" for i in
                                                               range(1, self.num_variants)])}
        weights = distal_weighted_joint_weights(scene.joints_per_finger, scene.num_fingers, dtype=dt, device=dev)
        self._act_weights = torch.cat([weights, torch.zeros_like(weights)]) if c.action == "vi" else weights
        self._pregrasps = None
        if c.initial == "pregrasp":
            # each instance's own pre-grasps (task.objects); size variants start from their instance's
            names = self.instance_names
            self._variant_pregrasps = [self._read_pregrasps(name) for name in names]
            self._pregrasps = self._variant_pregrasps[0]
            if len(names) == 1:
                self._variant_pregrasps *= self.num_variants

    def bench_poses(self):
        """The benchmark poses of this scene: a pre-grasp squeezed, the hand extended clear (:mod:`.operate_bench`)."""
        from .operate_bench import operate_bench_poses

        return operate_bench_poses(self)

    def _read_pregrasps(self, object_name: str) -> torch.Tensor | None:
        """The start poses [K, nu] of ``object_name`` (``task.object`` or one of ``task.objects``):
        ``task.pregrasps``, the library object's shipped file or a URDF's cached one, checked whole; None: a URDF
        for which none was found (the open start)."""
        c, scene = self.config, self.sim.scene
        library = not object_name.lower().endswith(".urdf")
        if c.pregrasps is not None:
            path = Path(c.pregrasps).expanduser()
        elif library:
            path = operate_pregrasp_path(object_name)
        elif c.objects or self.object_asset is None:
            raise PregraspError(f"task.object {object_name!r}: pre-grasps of a URDF among task.objects are not "
                                "searched on first use; write them with dexmots-pregrasp --task operate --object "
                                f"{object_name} and pass task.pregrasps=<file>, or start with task.initial=open")
        else:  # searched once, kept beside the scene
            options = urdf_load_options(c.urdf, c.joint, object_name)
            path = cached_pregrasps(scene, self.object_asset, scene_dir(object_name, options), self.contact_params,
                                    self.joint_name)
            if path is None:  # none found: the open start (urdf_object's docstring)
                return None
        name = self.object_asset.name if self.object_asset is not None else None
        if c.objects:  # one instance of several
            name = object_name if library else None
        poses = load_pregrasps(path, self.sim.nu, "operate", scene.dof_lower[:self.sim.nu],
                               scene.dof_upper[:self.sim.nu], object_name=name)
        return torch.as_tensor(poses, dtype=self.dtype, device=self.device)

    def _variant_table(self, scene) -> dict:
        """Per variant [K, ...]: what :meth:`_per_world` looks up (variant 0's are the attributes themselves)."""
        c, j = self.config, self.joint_index
        rows = {"joint_rest": [], "joint_span": [], "goal_value": [], "_base0": [], "_nominal": []}
        for tree in scene.variant_trees:
            lo, hi = (float(v) for v in tree.joint_range[j])
            rest = float(tree.q0[7 * tree.free + j])
            far = hi if hi - rest >= rest - lo else lo
            rows["joint_rest"].append([rest])
            rows["joint_span"].append([hi - lo])
            rows["goal_value"].append([rest + c.goal_fraction * (far - rest)])
            rows["_base0"].append(list(tree.q0[:7]) if tree.free else _pose(tree.offset_pos[0], tree.offset_rot[0]))
            rows["_nominal"].append([tree.joint_damping[j], tree.joint_friction[j], tree.joint_stiffness[j],
                                     tree.joint_rest[j]])
        table = {k: torch.as_tensor(v, dtype=self.dtype, device=self.device) for k, v in rows.items()}
        table["_nominal"] = tuple(table["_nominal"].T.unsqueeze(-1))  # 4 x [K, 1]
        table["q0"] = torch.as_tensor(scene.variant_q0, dtype=self.dtype, device=self.device)
        table["params"] = {name: torch.as_tensor([[t.default_param_values()[name]] for t in scene.variant_trees],
                                                 dtype=self.dtype, device=self.device)
                           for name in scene.tree.param_names}
        return table

    def world_variant(self, source) -> torch.Tensor:
        """[N] int64: each world's object variant, from ``source``'s ``("sim", "params", "variant")``."""
        return source[("sim", "params", "variant")].reshape(-1).round().long()

    def _per_world(self, name: str, source):
        """Attribute ``name`` of each world's variant ([N, ...] tensors) with K > 1; else the attribute itself."""
        if self.num_variants == 1:
            return getattr(self, name)
        table, variant = self._variant_values[name], self.world_variant(source)
        return tuple(x[variant] for x in table) if isinstance(table, tuple) else table[variant]

    def _param_ranges(self) -> dict:
        s = self.config.param_scale
        return {name: (v * (1 - s), v * (1 + s)) for name, v in self.sim.default_param_values().items()
                if self.sim.tree.randomized(name)}

    def sample_params(self, n: int) -> dict[str, torch.Tensor]:
        """With K > 1 variants: each world's variant (uniform), its joint parameters within ``param_scale`` of
        that variant's (its springs' rest kept); one object: :meth:`DexEnv.sample_params`."""
        if self.num_variants == 1:
            return super().sample_params(n)
        variant = torch.randint(0, self.num_variants, (n,), generator=self.generator, device=self.device)
        s, out = self.config.param_scale, {"variant": variant.to(self.dtype).unsqueeze(-1)}
        for name, values in self._variant_values["params"].items():
            nominal = values[variant]
            out[name] = (nominal * (1 - s + 2 * s * self._rand(n, 1)) if name in self.param_ranges else nominal)
        for name, value in self.sim.default_param_values().items():  # the hand's: every variant's
            if name not in out:
                out[name] = torch.full((n, 1), value, dtype=self.dtype, device=self.device)
        return out

    # ----------------------------------------------------------------------------------- episodes
    def sample_initial(self, n: int) -> dict:
        noise = self.config.joint_noise * (2 * self._rand(n, self.sim.nu) - 1)
        start = self._open
        if self._pregrasps is not None:  # one of the pre-grasps per episode
            pick = self._rand(n)
            start = self._pregrasps[(pick * len(self._pregrasps)).long().clamp(max=len(self._pregrasps) - 1)]
        hand = torch.minimum(torch.maximum(start + noise, self._lower), self._upper)
        obj = torch.as_tensor(self.sim.tree.q0, dtype=self.dtype, device=self.device).expand(n, -1)
        ref_index = self.sample_ref_index(n)
        goal = torch.full((n, 1), self.goal_value, dtype=self.dtype, device=self.device)
        params = self.sample_params(n)
        if self.num_variants > 1:  # each world's variant's rest pose and goal
            variant = params["variant"].reshape(-1).long()
            obj, goal = self._variant_values["q0"][variant], self._variant_values["goal_value"][variant]
            if self._pregrasps is not None:  # the pick among the world's own variant's pre-grasps
                for k, poses in enumerate(self._variant_pregrasps):
                    index = (pick * len(poses)).long().clamp(max=len(poses) - 1)
                    start = torch.where((variant == k).unsqueeze(-1), poses[index], start)
                hand = torch.minimum(torch.maximum(start + noise, self._lower), self._upper)
        if self.reference_bank is not None:  # a plan's or a demonstration's last row
            goal = self.reference_bank["joint_q"][ref_index.squeeze(-1), -1]
        return {
            "joint_q": torch.cat([hand, obj], -1),
            "joint_qd": torch.zeros(n, self.sim.nv, dtype=self.dtype, device=self.device),
            "params": params,
            "goal": goal,
            "ref_index": ref_index,
        }

    # ----------------------------------------------------------------------------------- observations
    def _obs_shapes(self) -> dict:
        shapes = super()._obs_shapes()
        parts = self.sim.tree.num_parts
        shapes.update({("object", "q"): (parts,), ("object", "qd"): (parts,), ("object", "base_pose"): (7,),
                       ("object", "joint_wrench"): (parts,)})
        return shapes

    def _observe(self, q, qd, params, goal, wrench, contact_force, body_pose, tips, joint_wrench=None) -> dict:
        """DexEnv's observation, the object's joints and poses, and ``joint_wrench`` (the step's
        :class:`~dexmots_rl.sim.ArticulatedStepOutput` field; None at reset: no contact yet, zeros)."""
        obs = super()._observe(q, qd, params, goal, wrench, contact_force, body_pose, tips)
        if joint_wrench is None:
            joint_wrench = torch.zeros(q.shape[0], self.sim.tree.num_parts, dtype=self.dtype, device=self.device)
        obs[("object", "joint_wrench")] = joint_wrench
        nu, free = self.sim.nu, self.sim.tree.free
        obs[("object", "q")] = q[:, nu + 7 * free:]
        obs[("object", "qd")] = qd[:, nu + 6 * free:]
        obs[("object", "base_pose")] = body_pose[:, nu]
        obs[("object", "pose")] = body_pose[:, nu + 1 + self.joint_index]
        obs["achieved_goal"] = self.achieved_goal(obs)
        return obs

    def achieved_goal(self, obs: dict) -> torch.Tensor:
        q = obs[("object", "q")]
        if q.shape[-1] != self.sim.tree.num_parts:  # DexEnv's own layout, replaced in _observe
            return q[:, -1:]
        return q[:, self.joint_index: self.joint_index + 1]

    # ----------------------------------------------------------------------------------- reference
    def joint_reference(self, td, steps: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(position, torque)`` of the operated joint's reference at env steps ``steps`` [N, H], each [N, H, 1]."""
        if self.reference_bank is not None:
            ref = lookup(self.reference_bank, td[("task", "ref_index")], steps)
            return ref["joint_q"], ref["joint_torque"]
        goal = td[("task", "goal")]
        rest, nominal = self._per_world("joint_rest", td), self._per_world("_nominal", td)
        if self.num_variants > 1:  # [N, 1, 1]: each world's over the steps
            rest, nominal = rest.unsqueeze(1), tuple(x.unsqueeze(1) for x in nominal)
        frac = (steps.to(self.dtype) / self.config.ramp_steps).clamp(max=1.0).unsqueeze(-1)
        angle = rest + (goal.unsqueeze(1) - rest) * frac
        speed = (goal.unsqueeze(1) - rest) / (self.config.ramp_steps * self.sim.dt)
        moving = ((steps >= 1) & (steps <= self.config.ramp_steps)).unsqueeze(-1)
        return angle, part_torque(torch.where(moving, speed, 0.0), angle, nominal)

    def demo_reference(self, demo: dict):
        """The operated joint moving as demonstrated, the base held where it stands."""
        tree = self.sim.tree
        return demo_trajectory(demo, self.sim.dt, self._base0[:3].double().cpu(), self._base0[3:].double().cpu(),
                               self._nominal, mass=float(tree.mass.sum()), inertia=tree.inertia[0])

    def reference(self, td, steps: torch.Tensor) -> TensorDict:
        if self.reference_bank is not None:
            return lookup(self.reference_bank, td[("task", "ref_index")], steps)
        angle, torque = self.joint_reference(td, steps)
        base0 = self._per_world("_base0", td)
        pose = (base0 if base0.dim() == 1 else base0.unsqueeze(1)).expand(*angle.shape[:2], 7)
        wrench = torch.zeros(*angle.shape[:2], 6, dtype=self.dtype, device=self.device)
        return TensorDict({"pose": pose, "joint_q": angle, "wrench": wrench, "joint_torque": torque},
                          batch_size=steps.shape)

    def goal_window_widths(self) -> tuple[int, int]:
        return 1, 1  # the operated joint's position and torque

    def goal_window(self, td, steps: torch.Tensor, with_wrench: bool) -> torch.Tensor:
        angle, torque = self.joint_reference(td, steps)
        return torch.cat([angle, torque], -1) if with_wrench else angle

    # ----------------------------------------------------------------------------------- reward, success
    def base_motion(self, obs: dict) -> tuple[torch.Tensor, torch.Tensor]:
        """``(shift [N, 1] m, tilt [N, 1] rad)`` of the base from where it stood (zeros for a fixed base)."""
        pose = obs[("object", "base_pose")]
        if not self.sim.tree.free:
            zero = torch.zeros_like(pose[:, :1])
            return zero, zero
        base0 = self._per_world("_base0", obs)
        shift = (pose[:, :3] - base0[..., :3]).norm(dim=-1, keepdim=True)
        return shift, quat_angle(base0[..., 3:].expand_as(pose[:, 3:]), pose[:, 3:])  # finite gradient at 0

    def task_reward(self, obs: dict, task: dict, action: torch.Tensor) -> tuple[torch.Tensor, dict]:
        ref_angle, ref_torque = self.joint_reference(task, task[("task", "step")])
        c = self.config
        shift, tilt = self.base_motion(obs)
        j = self.joint_index
        terms = {
            "pose": angle_tracking_reward(self.achieved_goal(obs), ref_angle[:, 0],
                                          c.pose_scale * self._per_world("joint_span", obs)),
            "wrench": angle_tracking_reward(obs[("object", "joint_wrench")][:, j:j + 1], ref_torque[:, 0],
                                            self.wrench_scale),
            "action": action_penalty(action.to(self.dtype), self._act_weights),
            "fingertip": fingertip_reward(obs[("fingertips", "pos")], obs[("object", "pose")][:, :3],
                                          c.fingertip_scale),
            "base": torch.exp(-shift / c.max_base_shift - tilt / c.max_base_tilt),
        }
        k = c.reward
        # the pose-only goals (the ablation) are not told the reference torque, nor rewarded for it
        lambda_wrench = k.lambda_wrench if c.goal == "pose_wrench" else 0.0
        total = (k.lambda_pose * terms["pose"] + lambda_wrench * terms["wrench"] + k.lambda_act * terms["action"]
                 + k.lambda_f * terms["fingertip"] + c.lambda_base * terms["base"])
        return total, terms

    def task_success(self, obs: dict, goal: torch.Tensor) -> torch.Tensor:
        c = self.config
        shift, tilt = self.base_motion(obs)
        reached = (self.achieved_goal(obs) - goal).abs() < c.success_band * self._per_world("joint_span", obs)
        return reached & (shift < c.max_base_shift) & (tilt < c.max_base_tilt)


def _build(config: OperateObjectConfig):
    if config.objects and config.variants > 1:
        raise ValueError("task.variants: size variants are drawn of task.object; with task.objects give 0")
    return build_scene(config.object, config.objects, config.variants, config.variant_scale, config.variant_seed,
                       config.urdf, config.joint)


register_task("operate", OperateObjectEnv, OperateObjectConfig)
