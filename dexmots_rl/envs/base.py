"""DexEnv: a functional, batched torchrl ``EnvBase`` over the warp simulator.

The full physical state of every world travels in the TensorDict under ``"sim"``
(``("sim", "joint_q")``, ``("sim", "joint_qd")``, and the named physical parameters under
``("sim", "params", name)``, e.g. ``"joint_damping"``), so a step is a pure function of its input
TensorDict. With ``differentiable=True`` gradients flow from anything computed on the output
(rewards, observations) back to the actions and the input state through :class:`~dexmots_rl.sim.SimStep`.

Task modules subclass :class:`DexEnv` and implement its abstract hooks (:meth:`sample_initial`,
:meth:`reference`, :meth:`achieved_goal`, :meth:`task_reward`, :meth:`task_success`);
:func:`~dexmots_rl.envs.registry.register_task` refuses a class that lacks one, naming it.

The task's final goal is carried under ``("task", "goal")`` (what the env reads back); ``"desired_goal"``
is written for the policy (the final goal by default; the goal-conditioning transforms replace it with
the reference window) and never read back. Reward terms are written under ``("reward_terms", name)``.
"""

from __future__ import annotations

from abc import abstractmethod
import logging
from contextlib import contextmanager

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from ..sim import SceneModel, check_device, compile_scene, make_simulator
from .actions import ActionMap, validate_action
from .mirror import action_reflection, reflect_mirrored
from .demos import demo_path, read_demo
from .fields import check_value, rule
from .object_params import read_object_params
from .references import load_reference_bank

__all__ = ["DexEnv", "MAX_JOINT_SPEED", "GRADIENT_COUNTS", "ScriptedPolicy"]

log = logging.getLogger(__name__)

MAX_JOINT_SPEED = 1.0e3  # rad/s (m/s); a world faster than this has blown up and is reset
# per world, int64 [N, 1]: blow-ups reset so far, and (since the env was built) backward steps whose adjoint
# adjoint_clip capped and whose non-finite gradient was zeroed (the simulator counts those in its backward pass)
GRADIENT_COUNTS = (("info", "clipped_adjoints"), ("info", "nonfinite_gradients"))
INFO_COUNTS = (("info", "sim_failures"), *GRADIENT_COUNTS)


class DexEnv(EnvBase):
    """Base class: specs, functional step/reset, blow-up handling. See the task modules.

    A task subclass sets ``asset`` (its MJCF in :mod:`dexmots_rl.assets`), implements the abstract hooks
    and is registered with its config class (:func:`~dexmots_rl.envs.registry.register_task`); it is
    built from a config: ``TaskEnv(config, num_envs=...)`` (``make_env`` does this).

    ``sync_free`` (on a CUDA device always; settable, the tests set it on CPU): the step, reward, reset and
    observation never read a tensor's value on the host (no ``.item()``, no Python branch on a tensor), so
    a GPU step never waits for the GPU. Its costs: every step draws the fresh state a blown-up world would
    be reset to (on CPU it is drawn only when a world blew up), and a non-finite action is not rejected
    with an error; it blows its world up, which is reset and counted like any other blow-up.
    """

    batch_locked = True
    asset: str = ""
    # evaluation breakdowns: name -> key of a per-episode value, or a function (env, first-step TensorDict [N])
    # -> [N] values; dexmots-eval reports success by its quartiles
    breakdowns: dict = {}
    # names of a categorical breakdown's values (name -> [label of value 0, 1, ...]), e.g. each object variant's
    breakdown_labels: dict = {}
    # other success tests dexmots-eval reports as success_rate_<name> (e.g. an original code's looser test): name ->
    # function (env, achieved_goal [N, G], goal [N, G]) -> [N] bool at the episode end; a terminated episode fails
    extra_success: dict = {}
    # BenchPoses for dexmots-bench throughput / grad (None: the task is not benchmarked, unless it builds its
    # poses per scene by overriding bench_poses: then the gradient benchmark runs it)
    bench = None
    contact_params = None  # the scene's ContactParams (None: the defaults, sized for the claw)
    plan_problem = None  # PlanProblem for dexmots-bench plan
    action_center = None  # hand joint targets of the zero position/vi action (None: mid-range of each joint)

    @classmethod
    def asset_path(cls):
        from ..assets import asset_path

        return asset_path(cls.asset)

    @classmethod
    def task_scene(cls, config):
        """The scene this task simulates for ``config`` (default: its MJCF, :attr:`asset`)."""
        from ..sim import load_scene

        return load_scene(cls.asset_path())

    def __init__(
        self,
        config,
        num_envs: int | None = None,
        device: str | torch.device = "cpu",
        differentiable: bool = True,
        seed: int | None = None,
        dtype: torch.dtype = torch.float32,
        adjoint_clip: float | None = None,
        contact=None,
        scene: SceneModel | None = None,
    ):
        self.config = config.validate()
        if config.mirror and self.mirror_maps() is None:
            raise ValueError(f"task.mirror: task {config.name!r} is not mirror-symmetric (it declares no mirror)")
        # what __reduce__ rebuilds from: the simulator holds warp (ctypes) arrays that cannot be pickled
        self._init_kwargs = dict(config=config, num_envs=num_envs, device=device, differentiable=differentiable,
                                 seed=seed, dtype=dtype, adjoint_clip=adjoint_clip, contact=contact, scene=scene)
        # any whole number (a numpy integer too), as a Python int
        num_envs = check_value("num_envs", config.num_envs if num_envs is None else num_envs, int, rule(gt=0))
        device = check_device(device)
        super().__init__(device=device, batch_size=torch.Size([num_envs]))
        if scene is None:
            scene = self.task_scene(config)
        self.sim = make_simulator(scene, num_worlds=num_envs, device=device, dtype=dtype, substeps=config.substeps,
                                  contact=self.contact_params if contact is None else contact,
                                  adjoint_clip=adjoint_clip)
        self.sync_free = device.type == "cuda"  # see the class docstring
        self.num_envs, self.differentiable, self.max_episode_steps = num_envs, differentiable, config.max_episode_steps
        self.dtype = dtype
        self.param_ranges = self._param_ranges()
        # the identified values (task.object_params) replace the draw of the parameters they name
        known = tuple(name for name in scene.param_names if name != "variant")
        self.identified_params = ({} if config.object_params is None
                                  else read_object_params(config.object_params, known))
        if config.demo is not None and config.references is not None:
            raise ValueError("task.demo and task.references both given: a task follows one reference")
        self._bank = (None if config.references is None
                      else load_reference_bank(config.references, dtype, device, dt=self.sim.dt))
        # a demonstration is read (and checked) now, and turned into the task's reference once the task's own
        # fields exist (the first use of reference_bank; make_env makes that use before returning)
        self._demo = None if config.demo is None else read_demo(demo_path(config.name, config.demo))
        self.actions = ActionMap(self.sim, config.action, center=self.action_center)
        self.action_type = config.action
        self._make_specs()
        self.generator = torch.Generator(device=device)
        self._set_seed(seed if seed is not None else int(torch.empty((), dtype=torch.int64).random_().item()))

    def gradient_counts(self) -> TensorDict:
        """The simulator's per-world gradient counters as of now, by key (:data:`GRADIENT_COUNTS`, each int64
        [N, 1]): the backward steps whose adjoint ``adjoint_clip`` capped, and those whose non-finite gradient was
        set to zero, since the env was built. Every step's and reset's TensorDict carries them; a trainer reads
        them around its backward pass (no host synchronisation here)."""
        sim = self.sim
        return TensorDict({GRADIENT_COUNTS[0]: sim.clipped_adjoint_steps.unsqueeze(-1).clone(),
                           GRADIENT_COUNTS[1]: sim.nonfinite_gradient_steps.unsqueeze(-1).clone()},
                          batch_size=[self.num_envs], device=self.device)

    @contextmanager
    def counting_gradients(self):
        """Count the gradient events of a backward pass: ``with env.counting_gradients() as counted:
        loss.backward()`` fills ``counted`` on leaving the block with each :data:`GRADIENT_COUNTS` key's per-world
        increase (int64 [N, 1]). The counts grow while the backward runs, after the rollout's TensorDicts were
        written, so a trainer reads them around its backward rather than from a step's keys."""
        before, counted = self.gradient_counts(), TensorDict({}, batch_size=[self.num_envs], device=self.device)
        yield counted
        counted.update(self.gradient_counts() - before)

    def get_rng_state(self) -> torch.Tensor:
        """The state of the worlds' random stream (what resets draw: starts, goals, physical parameters), a
        ``torch.ByteTensor`` to save beside ``torch.get_rng_state()`` and give back to :meth:`set_rng_state`."""
        return self.generator.get_state()

    def set_rng_state(self, state: torch.Tensor) -> None:
        """Continue the worlds' random stream from ``state`` (one :meth:`get_rng_state` returned)."""
        if not (isinstance(state, torch.Tensor) and state.dtype == torch.uint8
                and state.shape == self.generator.get_state().shape):
            got = (f"{state.dtype} {tuple(state.shape)}" if isinstance(state, torch.Tensor)
                   else type(state).__name__)
            raise ValueError(f"rng state: expected the uint8 tensor of shape {tuple(self.generator.get_state().shape)} "
                             f"that get_rng_state returns, got {got}")
        self.generator.set_state(state)

    @property
    def scene(self):
        """The scene this env simulates (:class:`~dexmots_rl.sim.SceneModel` or
        :class:`~dexmots_rl.sim.ArticulatedScene`): names, sizes, the object's description."""
        return self.sim.scene

    @property
    def dt(self) -> float:
        """Simulated seconds per env step."""
        return self.sim.dt

    def load_kernels(self) -> None:
        """Compile, or load from warp's kernel cache, the kernels that step this env (forward and adjoint: one
        module holds both) now instead of at the first step, so that whoever times the steps (a training budget)
        does not count a cold cache's compile. A kernel that does not compile is logged; its first launch raises
        the compiler's error."""
        sim = self.sim
        device = "cuda" if str(sim.device).startswith("cuda") else "cpu"
        for row in compile_scene(sim.scene, device=device, arch=None, dtypes=(sim.dtype,), contact=sim.contact,
                                 render=False):
            if not row["ok"]:
                log.warning("kernel %s did not compile: %s", row["kernel"], row["error"])

    def bench_poses(self):
        """The :class:`~dexmots_rl.envs.BenchPoses` of this env's scene (default: the class's ``bench``)."""
        return self.bench

    def _param_ranges(self) -> dict[str, tuple[float, float]]:
        """Per-episode randomisation of the scene's named parameters, ``{name: (low, high)}`` (the task
        config's ranges); a parameter not named keeps the MJCF's value."""
        return {}

    # ------------------------------------------------------------------------------------------ specs
    def _obs_shapes(self) -> dict:
        s, sim = self.sim.scene, self.sim
        return {
            ("hand", "q"): (sim.nu,),
            ("hand", "qd"): (sim.nu,),
            ("object", "pose"): (7,),
            ("object", "q"): (s.object_nq if s.articulated else 0,),
            ("object", "qd"): (s.object_nv,),
            ("object", "wrench"): (6,),
            ("object", "contact_force"): (1,),
            ("fingertips", "pos"): (s.num_fingers, 3),
            "achieved_goal": (self.goal_dim,),
            "desired_goal": (self.goal_dim,),
            ("task", "goal"): (self.goal_dim,),
            ("sim", "joint_q"): (sim.nq,),
            ("sim", "joint_qd"): (sim.nv,),
            ("sim", "body_pose"): (sim.num_bodies, 7),
            **{("sim", "params", name): (1,) for name in sim.scene.param_names},
        }

    def _make_specs(self):
        n, dev, dt = self.num_envs, self.device, self.dtype
        obs = Composite(shape=(n,), device=dev)
        for key, shape in self._obs_shapes().items():
            obs[key] = Unbounded(shape=(n, *shape), dtype=dt, device=dev)
        for name in self.reward_terms:
            obs[("reward_terms", name)] = Unbounded(shape=(n, 1), dtype=dt, device=dev)
        obs[("task", "step")] = Unbounded(shape=(n, 1), dtype=torch.int64, device=dev)
        obs[("task", "ref_index")] = Unbounded(shape=(n, 1), dtype=torch.int64, device=dev)
        for key in INFO_COUNTS:
            obs[key] = Unbounded(shape=(n, 1), dtype=torch.int64, device=dev)
        obs["success"] = Categorical(2, shape=(n, 1), dtype=torch.bool, device=dev)
        self.observation_spec = obs
        self.action_spec = Bounded(-1.0, 1.0, shape=(n, self.actions.action_dim), dtype=dt, device=dev)
        self.reward_spec = Unbounded(shape=(n, 1), dtype=dt, device=dev)
        self.full_done_spec = Composite(
            done=Categorical(2, shape=(n, 1), dtype=torch.bool, device=dev),
            terminated=Categorical(2, shape=(n, 1), dtype=torch.bool, device=dev),
            truncated=Categorical(2, shape=(n, 1), dtype=torch.bool, device=dev),
            shape=(n,),
            device=dev,
        )

    # -------------------------------------------------------------------------------------- task API
    goal_dim = 1
    reward_terms: tuple[str, ...] = ()

    @abstractmethod
    def sample_initial(self, n: int) -> dict:
        """Initial ``joint_q``, ``joint_qd``, ``params``, ``goal`` and ``ref_index`` [n, 1] (int64) for ``n``
        worlds (use self.generator)."""

    @abstractmethod
    def reference(self, td: TensorDictBase, steps: torch.Tensor) -> TensorDictBase:
        """The object-centric reference at env steps ``steps`` [N, H] of each world's plan: a TensorDict
        [N, H] with ``"pose"`` [7], ``"joint_q"`` [K], ``"wrench"`` [6] and ``"joint_torque"`` [K]; ``td``
        holds the worlds' ``("task", ...)`` and ``("sim", ...)`` entries."""

    @property
    def reference_bank(self) -> TensorDict | None:
        """The plans (``task.references``) or the demonstration (``task.demo``) the worlds follow, a TensorDict
        [M, T] (:mod:`dexmots_rl.envs.references`); None: the task's analytic reference."""
        if self._demo is not None:
            self._bank = load_reference_bank([self.demo_reference(self._demo)], self.dtype, self.device)
            self._demo = None
        return self._bank

    def demo_reference(self, demo: dict):
        """The :class:`~dexmots_rl.trajectories.PoseWrenchTrajectory` this task follows for a pose-only
        demonstration (:func:`~dexmots_rl.envs.demos.read_demo`'s dict); tasks that can follow one override it."""
        raise ValueError(f"task.demo: task {self.config.name!r} does not follow pose-only demonstrations")

    @abstractmethod
    def achieved_goal(self, obs: dict) -> torch.Tensor:
        """[N, goal_dim] the goal coordinates the object has reached (compared with ``("task", "goal")``)."""

    def goal_window(self, td: TensorDictBase, steps: torch.Tensor, with_wrench: bool) -> torch.Tensor:
        """The goal-conditioning window [N, H, D (+ W)]: the reference's object coordinates at ``steps``
        [N, H] (the articulation angles, or pos + wxyz quat of a free body), then, ``with_wrench``, the
        generalised force (articulation) or force + torque (free body). Built from :meth:`reference`;
        tasks override it with a path that builds no TensorDict (it runs every step)."""
        ref = self.reference(td, steps)
        articulated = self.sim.scene.articulated
        parts = [ref["joint_q"] if articulated else ref["pose"]]
        if with_wrench:
            parts.append(ref["joint_torque"] if articulated else ref["wrench"])
        return torch.cat(parts, -1)

    def goal_window_widths(self) -> tuple[int, int]:
        """``(D, W)``: per reference step, the object coordinates and the wrench entries :meth:`goal_window`
        writes (an articulation's angles and generalised forces, or a free body's pose and force + torque)."""
        scene = self.sim.scene
        return (scene.object_nq, scene.object_nv) if scene.articulated else (7, 6)

    def mirror_maps(self):
        """``(maps, action)`` of a mirror-symmetric task (:mod:`..mirror`): the reflection of each policy entry
        ``{key: SignedPermutation}`` and of the action, under which the task is itself with the goal negated;
        ``None`` (the default): the task has no such symmetry and ``task.mirror`` is refused."""
        return None

    def scripted_action(self, td: TensorDictBase) -> torch.Tensor:
        """A hand-written controller's torque-space action [N, nu] for the state in ``td`` (smoke runs,
        recordings and plots); tasks without one raise ``NotImplementedError``."""
        raise NotImplementedError(f"{type(self).__name__} has no scripted controller")

    @abstractmethod
    def task_reward(self, obs: dict, task: dict, action: torch.Tensor) -> tuple[torch.Tensor, dict]:
        """``(reward [N, 1], {term name: [N, 1]})`` after a step; ``task`` holds ``("task", ...)`` entries
        (goal, the step counter after the step, ref_index) and the ``("sim", "params", name)`` entries."""

    @abstractmethod
    def task_success(self, obs: dict, goal: torch.Tensor) -> torch.Tensor:
        """[N, 1] bool: worlds whose object meets the task's success test for ``goal`` [N, goal_dim]."""

    def goal_error(self, achieved: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """[...] the error the success threshold is compared with, for ``achieved_goal`` and goal tensors
        [..., goal_dim] (dexmots-eval's mean final error). Default: the Euclidean distance (the angle error of
        a 1-D articulation); a free body's task returns its rotation angle."""
        return (achieved - goal).norm(dim=-1)

    def task_terminated(self, obs: dict) -> torch.Tensor:
        """[N, 1] bool: worlds whose episode ends early after this step (e.g. a dropped object); none by
        default. A simulation blow-up terminates a world regardless."""
        return torch.zeros(self.num_envs, 1, dtype=torch.bool, device=self.device)

    # ------------------------------------------------------------------------------------ pickling
    def __reduce__(self):
        """Pickle / deepcopy as "rebuild from the constructor arguments": the copy gets a fresh simulator
        (warp arrays and kernels are not picklable) and the same generator state, so it continues the
        same random stream. Worker processes (spawn) and ``copy.deepcopy`` both go through this."""
        return _rebuild_env, (type(self), self._init_kwargs, self.get_rng_state())

    # ------------------------------------------------------------------------------------ internals
    def _set_seed(self, seed: int | None):
        seed = check_value("seed", seed, int, rule())  # int() took 1.7 as 1
        self.generator.manual_seed(seed % (2**63))
        self._seed = seed

    def _rand(self, *shape) -> torch.Tensor:
        return torch.rand(*shape, generator=self.generator, device=self.device, dtype=self.dtype)

    def _uniform(self, n: int, lo_hi: tuple[float, float]) -> torch.Tensor:
        lo, hi = lo_hi
        return lo + (hi - lo) * self._rand(n, 1)

    def sample_params(self, n: int) -> dict[str, torch.Tensor]:
        """Per-episode physical parameters ``{name: [n, 1]}``: uniform in :attr:`param_ranges` (seeded by
        the env's generator), the MJCF's value for the others."""
        out = {}
        for name, value in self.sim.default_param_values().items():
            rng = self.param_ranges.get(name)
            out[name] = (self._uniform(n, rng) if rng is not None
                         else torch.full((n, 1), value, dtype=self.dtype, device=self.device))
        return out

    def sample_ref_index(self, n: int) -> torch.Tensor:
        """Which plan of the reference bank each world follows this episode (0 without a bank)."""
        if self.reference_bank is None:
            return torch.zeros(n, 1, dtype=torch.int64, device=self.device)
        m = self.reference_bank.batch_size[0]
        return torch.randint(0, m, (n, 1), generator=self.generator, device=self.device)

    def _observe(self, q, qd, params, goal, wrench, contact_force, body_pose, tips, *step_extras) -> dict:
        """The observation dict of a state and a step's outputs; ``step_extras``: what a scene's step adds to
        :class:`~dexmots_rl.sim.StepOutput` (an articulated object's ``joint_wrench``; nothing at reset), read by
        the task that simulates such a scene."""
        nu = self.sim.nu
        obs = {
            ("hand", "q"): q[:, :nu],
            ("hand", "qd"): qd[:, :nu],
            ("object", "pose"): body_pose[:, -1],
            ("object", "q"): q[:, nu:] if self.sim.scene.articulated else q[:, :0],
            ("object", "qd"): qd[:, nu:],
            ("object", "wrench"): wrench,
            ("object", "contact_force"): contact_force.unsqueeze(-1),
            ("fingertips", "pos"): tips,
            ("sim", "joint_q"): q,
            ("sim", "joint_qd"): qd,
            ("sim", "body_pose"): body_pose,
            **{("sim", "params", name): value for name, value in params.items()},
            ("task", "goal"): goal,
            "desired_goal": goal,
        }
        obs["achieved_goal"] = self.achieved_goal(obs)
        return obs

    def _initial_obs(self) -> dict:
        init = self.sample_initial(self.num_envs)
        for name, value in self.identified_params.items():
            init["params"][name] = torch.full_like(init["params"][name], value)
        pose, tips = self.sim.observe(init["joint_q"], init["joint_qd"], init["params"])
        zeros6 = torch.zeros(self.num_envs, 6, dtype=self.dtype, device=self.device)
        zeros = torch.zeros(self.num_envs, dtype=self.dtype, device=self.device)
        obs = self._observe(init["joint_q"], init["joint_qd"], init["params"], init["goal"], zeros6, zeros, pose, tips)
        obs[("task", "ref_index")] = init["ref_index"]
        return obs

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        obs = self._initial_obs()
        n = self.num_envs
        step = torch.zeros(n, 1, dtype=torch.int64, device=self.device)
        failures = torch.zeros(n, 1, dtype=torch.int64, device=self.device)
        mask = None
        if tensordict is not None and "_reset" in tensordict.keys():
            mask = tensordict.get("_reset").reshape(n, 1)
        if mask is not None and (self.sync_free or not bool(mask.all())):
            # partial reset: keep every entry of the worlds that are not reset
            for key in list(obs):
                old = tensordict.get(key, None)
                if old is not None:
                    m = mask.reshape(n, *([1] * (obs[key].dim() - 1)))
                    obs[key] = torch.where(m, obs[key], old)
            old_step = tensordict.get(("task", "step"), None)
            if old_step is not None:
                step = torch.where(mask, step, old_step)
        if tensordict is not None and ("info", "sim_failures") in tensordict.keys(True):
            failures = tensordict.get(("info", "sim_failures"))
        out = TensorDict(obs, batch_size=[n], device=self.device)
        out.set(("task", "step"), step)
        out.set(("info", "sim_failures"), failures)
        out.update(self.gradient_counts())
        for name in self.reward_terms:
            zero = torch.zeros(n, 1, dtype=self.dtype, device=self.device)
            old = tensordict.get(("reward_terms", name), None) if mask is not None else None
            # a partial reset zeroes the reset worlds' terms only: the kept worlds keep their last step's
            out.set(("reward_terms", name), zero if old is None else torch.where(mask, zero, old))
        out.set("success", self.task_success(obs, obs[("task", "goal")]))
        false = torch.zeros(n, 1, dtype=torch.bool, device=self.device)
        out.update({"done": false, "terminated": false.clone(), "truncated": false.clone()})
        return out

    def _state_keys(self) -> list:
        """The entries a step reads from its input TensorDict (besides ``"action"``)."""
        return [("sim", "joint_q"), ("sim", "joint_qd"), *(("sim", "params", name) for name in self.sim.scene.param_names),
                ("task", "goal"), ("task", "step"), ("task", "ref_index"), ("info", "sim_failures")]

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict.get("action", None)
        if action is None:
            raise KeyError("env.step: the input TensorDict has no 'action'")
        validate_action(action, self.num_envs, self.actions.action_dim, values=not self.sync_free)
        present = tensordict.keys(True)
        missing = [key for key in self._state_keys() if key not in present]
        if missing:
            # the step is a pure function of the TensorDict: without the state there is nothing to step
            raise KeyError(f"env.step: the input TensorDict lacks the state entry {missing[0]!r} (and "
                           f"{len(missing) - 1} more); step the TensorDict returned by env.reset() / env.step()")
        # the physics clamps to [-1, 1] (ActionMap); the reward must see the same action, or a huge
        # action would be penalised for force the hand never applied (and |a| = 1e19 overflowed the
        # norm). Clamping here gives zero gradient outside the box, exactly like the physics.
        action = action.clamp(-1.0, 1.0)
        q = tensordict.get(("sim", "joint_q"))
        qd = tensordict.get(("sim", "joint_qd"))
        params = {name: tensordict.get(("sim", "params", name)) for name in self.sim.scene.param_names}
        goal = tensordict.get(("task", "goal"))
        step = tensordict.get(("task", "step")) + 1
        task = {("task", "goal"): goal, ("task", "step"): step, ("task", "ref_index"): tensordict.get(("task", "ref_index")),
                **{("sim", "params", name): value for name, value in params.items()}}
        if not self.differentiable:
            q, qd, action = q.detach(), qd.detach(), action.detach()
            params = {name: value.detach() for name, value in params.items()}
        with torch.set_grad_enabled(self.differentiable and torch.is_grad_enabled()):
            out = self.sim.step(q, qd, self.actions(action.to(self.dtype)), params)
            # out[6:]: what an articulated object's step adds (joint_wrench)
            obs = self._observe(out.joint_q, out.joint_qd, params, goal, out.wrench, out.contact_force,
                                out.body_pose, out.fingertips, *out[6:])
            obs[("task", "ref_index")] = task[("task", "ref_index")]
            reward, terms = self.task_reward(obs, task, action)
            obs.update({("reward_terms", name): terms[name] for name in self.reward_terms})
        failures = tensordict.get(("info", "sim_failures")).clone()
        blown = ~(torch.isfinite(out.joint_q).all(-1, keepdim=True) & torch.isfinite(out.joint_qd).all(-1, keepdim=True))
        blown |= out.joint_qd.detach().abs().amax(-1, keepdim=True).nan_to_num(float("inf")) > MAX_JOINT_SPEED
        # a world whose object went through the table or far past a stop has left the physics, however slow it is
        blown |= self.sim.outside_physics(out.joint_q.detach(), out.body_pose.detach(), params).unsqueeze(-1)
        if self.sync_free or bool(blown.any()):
            # reset the worlds that blew up so that no NaN reaches the batch; count them
            fresh = self._initial_obs()
            fresh.update({("reward_terms", name): torch.zeros_like(terms[name]) for name in self.reward_terms})
            for key in list(obs):
                m = blown.reshape(-1, *([1] * (obs[key].dim() - 1)))
                obs[key] = torch.where(m, fresh[key], obs[key])
            reward = torch.where(blown, torch.zeros_like(reward), reward)
            step = torch.where(blown, torch.zeros_like(step), step)
            failures = failures + blown.long()
        truncated = step >= self.max_episode_steps
        terminated = blown | self.task_terminated(obs)
        next_td = TensorDict(obs, batch_size=[self.num_envs], device=self.device)
        next_td.update({
            "reward": reward,
            ("task", "step"): step,
            ("info", "sim_failures"): failures,
            **self.gradient_counts(),
            # a world that ends by termination (a dropped cube, a blow-up) has failed, whatever the task's test says
            "success": self.task_success(obs, obs[("task", "goal")]) & ~terminated,
            "terminated": terminated,
            "truncated": truncated,
            "done": terminated | truncated,
        })
        return next_td


def _rebuild_env(cls, kwargs: dict, generator_state: torch.Tensor) -> DexEnv:
    env = cls(**kwargs)
    env.set_rng_state(generator_state)
    return env


class ScriptedPolicy(TensorDictModuleBase):
    """The task's scripted controller (:meth:`DexEnv.scripted_action`) as a torchrl policy module for the env
    ``make_env`` builds around ``env``; the env must use the ``"torque"`` action space. The controller acts in
    the real scene, so on a mirrored task (``task.mirror``) the mirrored worlds' actions are reflected for
    the env to reflect back."""

    def __init__(self, env: DexEnv):
        super().__init__()
        if env.action_type != "torque":
            raise ValueError(f"the scripted controller acts in torque space; the env uses action={env.action_type!r} "
                             "(build it with action='torque')")
        self.env, self.reflection = env, action_reflection(env)
        self.in_keys, self.out_keys = [("task", "goal"), ("sim", "joint_q")], ["action"]

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = self.env.scripted_action(tensordict).to(self.env.dtype)
        if self.reflection is not None:
            action = reflect_mirrored(tensordict, action, self.reflection)
        return tensordict.set("action", action)
