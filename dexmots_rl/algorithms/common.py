"""Pieces the model-free baselines (PPO, SAC, PGDM) share: the training env, the policy, the loop's end.

* :func:`make_train_env` — ``make_env(task, differentiable=False)`` (plus a method's own transforms, e.g.
  PGDM's observation and reward) and torchrl's ``VecNorm`` (new API; :class:`RunningObsNorm`, its variance
  kept >= 0), a clip on ``"observation"`` and an episode-return counter: the env the collector steps.
* :func:`tanh_gaussian_actor` — a ``ProbabilisticActor`` (``TanhNormal`` within the env's action bounds) on an
  MLP; the scale is state-independent (PPO) or a second head (SAC).
* :class:`ObsNorm` / :func:`deployable_policy` — the training env's normalisation frozen into a module in
  front of the actor (after, for PGDM, the module that rebuilds its observation), so the policy runs on the
  *plain* task env (``evaluate_policy``, ``dexmots-eval``).
* :func:`policy_from_data` — that policy rebuilt from a checkpoint (each baseline's loader in
  :mod:`.registry`).
* :func:`batch_metrics`, :class:`CollectorLoop` — what every collector iteration ends with: the
  ``metrics.jsonl`` row, the progress bar, the budget, checkpoints and evaluations through the run's
  :class:`~.rundir.RunDirectory`, and the final evaluation.
"""

from __future__ import annotations

import logging
import sys
import time
import warnings

import torch
from tensordict import TensorDict
from tensordict.nn import AddStateIndependentNormalScale, NormalParamExtractor, TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.envs import ClipTransform, RewardSum
from torchrl.envs.transforms.vecnorm import VecNormV2
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal

from ..progress import progress_bar
from ..envs import make_env
from .budget import RunBudget, TrainingClock
from .checkpoint import CheckpointError, restore_rng_states, rng_states
from .rundir import RunDirectory

__all__ = ["CollectorLoop", "ObsNorm", "RunningObsNorm", "batch_metrics", "deployable_policy", "load_replay_buffer",
           "make_train_env", "mlp", "policy_from_data", "replay_buffer_state", "sync_obs_norm", "tanh_gaussian_actor"]

log = logging.getLogger(__name__)

ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU}


class RunningObsNorm(VecNormV2):
    """torchrl's ``VecNorm`` (new API) whose variance cannot go negative.

    It keeps running means of ``x`` and ``x²`` and takes ``var = E[x²] - E[x]²``. On a feature that does not
    move (a tool's base at rest on the table: its height, its orientation) the two terms are equal up to
    rounding, and once the running mean's bias correction reaches 1 in float32 (``decay ** count`` below
    ~6e-8: ~165k env steps at decay 0.9999) the difference is as often -1e-10 as +1e-10; its square root is
    NaN, and that NaN reaches every world's observation and action. Keeping ``E[x²] >= E[x]²`` after each
    update leaves every other feature's statistics unchanged (bit for bit) and gives a still feature the
    scale ``eps``, as an exactly constant one already had."""

    @torch.no_grad()
    def _stateful_update(self, data):
        super()._stateful_update(data)
        if not self.frozen:
            self._var.apply_(lambda second_moment, mean: torch.maximum(second_moment, mean.square()), self._loc)


def make_train_env(cfg, seed: int, norm_decay: float = 0.9999, obs_clip: float = 10.0, transforms=()):
    """The task env (exactly ``make_env(cfg.task)``, not differentiable), then ``transforms`` (a method's
    own observation / reward, applied before the normalisation), with a running normalisation of
    ``"observation"``, clipped to ±``obs_clip``, and ``"episode_reward"``. Returns ``(env, vecnorm)``."""
    env = make_env(cfg.task, differentiable=False, seed=seed, device=cfg.device)
    for transform in transforms:
        env.append_transform(transform)
    # reduce_batch_dims: the worlds are one batch of samples of the same distribution, not separate streams
    vecnorm = RunningObsNorm(in_keys=["observation"], reduce_batch_dims=True, decay=norm_decay)
    with warnings.catch_warnings():  # "experimental for a batched env": it is what reduce_batch_dims is for
        warnings.filterwarnings("ignore", message=r"Support of \w+ for containers", category=UserWarning)
        env.append_transform(vecnorm)
        env.append_transform(ClipTransform(in_keys=["observation"], low=-obs_clip, high=obs_clip))
        env.append_transform(RewardSum())
        env.observation_spec  # noqa: B018  (built and cached here, where the warning is filtered)
    return env, vecnorm


def mlp(in_features: int, out_features: int, hidden, activation: str, out_gain: float = 1.0) -> MLP:
    """An MLP with orthogonal init (gain √2 on hidden layers, ``out_gain`` on the last), CleanRL's recipe: a
    small ``out_gain`` makes the initial policy mean ~0 and the initial value ~0."""
    net = MLP(in_features=in_features, out_features=out_features, num_cells=list(hidden),
              activation_class=ACTIVATIONS[activation])
    linears = [m for m in net.modules() if isinstance(m, nn.Linear)]
    for i, layer in enumerate(linears):
        nn.init.orthogonal_(layer.weight, out_gain if i == len(linears) - 1 else 2 ** 0.5)
        nn.init.zeros_(layer.bias)
    return net


def tanh_gaussian_actor(obs_dim: int, action_spec, hidden, activation: str = "tanh", state_scale: bool = False,
                        init_log_std: float = 0.0, return_log_prob: bool = False) -> ProbabilisticActor:
    """A tanh-squashed Gaussian policy on ``"observation"`` within ``action_spec``'s bounds.

    ``state_scale``: the network outputs the scale too (SAC; ``scale_lb`` 0.1 as torchrl's sota SAC); else a
    learnt state-independent log-std starting at ``init_log_std`` (PPO)."""
    act_dim = action_spec.shape[-1]
    if state_scale:
        body = nn.Sequential(mlp(obs_dim, 2 * act_dim, hidden, activation, out_gain=0.01),
                             NormalParamExtractor(scale_lb=0.1))
    else:
        body = nn.Sequential(mlp(obs_dim, act_dim, hidden, activation, out_gain=0.01),
                             AddStateIndependentNormalScale(act_dim, init_value=init_log_std))
    module = TensorDictModule(body, in_keys=["observation"], out_keys=["loc", "scale"])
    return ProbabilisticActor(module, in_keys=["loc", "scale"], spec=action_spec, distribution_class=TanhNormal,
                              distribution_kwargs={"low": action_spec.space.low, "high": action_spec.space.high},
                              return_log_prob=return_log_prob)


class ObsNorm(nn.Module):
    """``((x - loc) / scale).clamp(-clip, clip)``: the training env's VecNorm + clip, frozen, as a module."""

    def __init__(self, dim: int, clip: float = 10.0):
        super().__init__()
        self.register_buffer("loc", torch.zeros(dim))
        self.register_buffer("scale", torch.ones(dim))
        self.clip = clip

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return ((x - self.loc) / self.scale).clamp(-self.clip, self.clip)


def deployable_policy(actor, obs_dim: int, obs_clip: float = 10.0, observation=None) -> TensorDictSequential:
    """``actor`` behind an :class:`ObsNorm` that rewrites ``"observation"`` as the training env did, so the
    policy acts on the plain task env (``evaluate_policy``). Keep it current with :func:`sync_obs_norm`.
    ``observation``: a module first writing ``"observation"`` as the training env's own transforms did (a
    method whose observation is not the task's, PGDM), from the entries the plain env writes."""
    norm = TensorDictModule(ObsNorm(obs_dim, obs_clip), in_keys=["observation"], out_keys=["observation"])
    return TensorDictSequential(*([] if observation is None else [observation]), norm, actor)


def _obs_norm(policy: TensorDictSequential) -> ObsNorm:
    return next(m for m in policy.modules() if isinstance(m, ObsNorm))


@torch.no_grad()
def sync_obs_norm(policy: TensorDictSequential, vecnorm) -> None:
    """Copy the training env's current normalisation statistics into ``policy``'s :class:`ObsNorm`."""
    norm = _obs_norm(policy)
    obs_norm = vecnorm.to_observation_norm()  # torchrl's frozen equivalent: loc and scale (already eps-clamped)
    norm.loc.copy_(obs_norm.loc)
    norm.scale.copy_(obs_norm.scale)


def policy_from_data(data: dict, env, state_scale: bool = False, observation=None) -> TensorDictSequential:
    """The normaliser + actor of a baseline's checkpoint ``data`` on the plain task ``env``'s specs, as
    :func:`tanh_gaussian_actor` built it (``state_scale``: SAC's) behind ``observation`` (a method's own
    observation module, PGDM's; None: the task's ``"observation"``)."""
    algo = data["config"]["algo"]
    obs_dim = env.observation_spec["observation"].shape[-1] if observation is None else observation.width
    actor = tanh_gaussian_actor(obs_dim, env.action_spec_unbatched, algo["hidden"], algo["activation"],
                                state_scale=state_scale, init_log_std=algo.get("init_log_std", 0.0))
    policy = deployable_policy(actor, obs_dim, algo.get("obs_clip", 10.0), observation=observation)
    policy.load_state_dict(data["modules"]["policy"])
    return policy


def replay_buffer_state(buffer) -> dict:
    """A replay buffer's filled rows (in storage order, a plain dict of tensors) and its writer's cursor."""
    filled = len(buffer)
    rows = buffer.storage[:filled].exclude("index").to_dict() if filled else {}
    return {"rows": rows, "filled": filled, "writer": dict(buffer.writer.state_dict())}


def load_replay_buffer(buffer, state: dict) -> None:
    """Refill an empty ``buffer`` (of the same capacity) from :func:`replay_buffer_state`."""
    if state["filled"]:
        buffer.extend(TensorDict.from_dict(state["rows"], batch_size=[state["filled"]]))
    buffer.writer.load_state_dict(state["writer"])


def batch_metrics(data, counters: dict) -> dict:
    """The ``metrics.jsonl`` row of a collected batch ``[worlds, time]``: the counters, the mean step reward,
    ``episode_success`` (the success flag at the last step of the episodes that ended in the batch; NaN when
    none did) and ``episode_reward`` (their return), and the mean of each reward term."""
    nxt = data.get("next")
    done = nxt.get("done").squeeze(-1)
    ended = int(done.sum())
    row = {
        "iteration": counters["iteration"],
        "env_steps": counters["env_steps"],
        "wall_clock_s": round(counters["wall_clock_s"], 3),
        "cpu_s": round(counters.get("cpu_s", 0.0), 3),
        "reward": float(nxt.get("reward").mean()),
        "episodes": ended,
        "episode_success": float(nxt.get("success").squeeze(-1)[done].float().mean()) if ended else float("nan"),
        "episode_reward": float(nxt.get("episode_reward").squeeze(-1)[done].mean()) if ended else float("nan"),
    }
    if "reward_terms" in nxt.keys():
        for name, value in nxt.get("reward_terms").items():
            row[f"reward_{name}"] = float(value.mean())
    return row


class CollectorLoop:
    """The end of every collector iteration of PPO, SAC and PGDM, and of their runs.

    The trainer iterates :meth:`batches` (the collector's batches, their collection timed apart) and counts
    ``counters["iteration"]`` and ``counters["env_steps"]`` itself; :meth:`end_iteration`
    then stops the clock for the row, logs the row (:func:`batch_metrics` + the method's statistics + the
    iteration's CPU and wall seconds spent collecting and learning, ``collect_*`` / ``learn_*``),
    checks the budget, writes a checkpoint every ``checkpoint_every`` iterations, at the end and at
    ``stop_after``, runs the periodic evaluations (their time is not training time), and says whether to
    stop. :meth:`finish` closes the collector and writes the final evaluation (``metrics.json``).
    On resume (:attr:`.RunDirectory.start`), the counters continue the checkpoint's and :meth:`start`
    loads the rest of its state (``replay_buffer``: SAC's, saved and restored too).
    """

    def __init__(self, run: RunDirectory, policy, vecnorm, iterations: int, replay_buffer=None):
        self.run, self.cfg, self.policy, self.vecnorm, self.iterations = run, run.cfg, policy, vecnorm, iterations
        self.replay_buffer, self.collector = replay_buffer, None
        self.counters = {"iteration": 0, "env_steps": 0, "wall_clock_s": 0.0, "cpu_s": 0.0}
        if run.start is not None:
            self.counters.update(run.start["counters"])
        self.stop_at = min(iterations, self.cfg.stop_after) if self.cfg.stop_after else iterations
        self.budget, self.stopped_by, self.ended = RunBudget.from_config(self.cfg), None, False
        self.bar = progress_bar(total=iterations, initial=self.counters["iteration"], disable=not self.cfg.progress,
                        desc=f"{self.cfg.algo.name} {self.cfg.task.name}", file=sys.stderr)
        self.clock = TrainingClock(self.counters)
        self._collected = (0.0, 0.0)  # the last batch's collection (CPU s, wall s)
        self._last = (self.counters["cpu_s"], self.counters["wall_clock_s"])  # training time at the last row

    def batches(self, collector):
        """``collector``'s batches (none for ``None``), each one's collection time measured apart from the
        learning that follows it (the rows' ``collect_cpu_s`` / ``learn_cpu_s``: ``dexmots-bench baselines``)."""
        if collector is None:
            return
        batches = iter(collector)
        while True:
            cpu, wall = time.process_time(), time.perf_counter()
            data = next(batches, None)
            if data is None:
                return
            self._collected = (time.process_time() - cpu, time.perf_counter() - wall)
            yield data

    def start(self, collector, modules: dict, optimizers: dict) -> None:
        """Call once ``collector`` (None: nothing left to collect) is built: building it resets the worlds,
        which draws from the RNG streams and updates the normaliser. A fresh run keeps all that; a resumed
        one then takes the checkpoint's state of ``modules`` and ``optimizers`` (the names it saved them
        under), the worlds where training stopped (mid-episode: the collector's next step continues them),
        the replay buffer and both RNG streams, so it goes on exactly as the uninterrupted run."""
        self.collector = collector
        start = self.run.start
        if start is None:
            return
        for name, module in modules.items():
            module.load_state_dict(start["modules"][name])
        for name, optimizer in optimizers.items():
            optimizer.load_state_dict(start["optimizers"][name])
        if self.replay_buffer is not None:
            if "replay_buffer" not in start:
                raise CheckpointError(f"resume={self.cfg.resume}: the checkpoint holds no replay buffer (written "
                                      "before SAC runs could resume); start a new run")
            load_replay_buffer(self.replay_buffer, start["replay_buffer"])
        if collector is None:
            return
        if "env_state" not in start:  # an older checkpoint: the same networks, but the episodes start afresh
            log.warning("resume=%s: the checkpoint predates saved episodes; they start afresh, so the run will "
                        "not be the uninterrupted one", self.cfg.resume)
            torch.set_rng_state(start["rng"]["torch"])
            return
        carrier = collector._carrier  # torchrl keeps the worlds' current TensorDict there between batches
        carrier.update_(TensorDict.from_dict(start["env_state"], batch_size=carrier.batch_size, device=carrier.device))
        collector.update_policy_weights_()
        restore_rng_states(collector.env, start["rng"])

    def _resume_state(self) -> dict:
        """What :meth:`start` needs besides modules and optimizers, for the checkpoint."""
        state = {}
        if self.collector is not None:
            state["env_state"] = self.collector._carrier.detach().to_dict()
            state["rng"] = rng_states(self.collector.env)
        if self.replay_buffer is not None:
            state["replay_buffer"] = replay_buffer_state(self.replay_buffer)
        return state

    def frames_left(self, frames_per_batch: int) -> int:
        """The frames the collector still has to collect: up to ``stop_after`` or the schedule's end."""
        return max(0, self.stop_at - self.counters["iteration"]) * frames_per_batch

    def progress(self) -> float:
        """How far the run is to its end in [0, 1] (its schedule or its budget): linear decays follow it."""
        return self.budget.progress(self.counters, self.counters["iteration"] / self.iterations)

    def end_iteration(self, data, stats: dict, modules: dict, optimizers: dict) -> bool:
        """Log the iteration of the collected batch ``data`` with the method's ``stats``, checkpoint
        ``modules`` (``"policy"``, the deployable policy, is synced with the normaliser first) and
        ``optimizers`` when due, evaluate when due; True when the run is over."""
        counters = self.counters
        self.clock.read(counters)
        (collect_cpu, collect_wall), (last_cpu, last_wall) = self._collected, self._last
        self._last = (counters["cpu_s"], counters["wall_clock_s"])
        # learning: the rest of the iteration since the last row (the method's updates, this loop's bookkeeping)
        timing = {"collect_cpu_s": collect_cpu, "collect_wall_s": collect_wall,
                  "learn_cpu_s": max(0.0, counters["cpu_s"] - last_cpu - collect_cpu),
                  "learn_wall_s": max(0.0, counters["wall_clock_s"] - last_wall - collect_wall)}
        row = {**batch_metrics(data, counters), **stats, **{k: round(v, 4) for k, v in timing.items()}}
        self.run.log(row)
        self.bar.update(1)
        self.bar.set_postfix(fps=f"{row['env_steps'] / max(row['wall_clock_s'], 1e-9):.0f}",
                             reward=f"{row['reward']:.3f}", success=f"{row['episode_success']:.2f}")
        self.stopped_by = self.budget.reached(counters)
        self.ended = counters["iteration"] >= self.iterations or self.stopped_by is not None
        stop = self.ended or counters["iteration"] >= self.stop_at
        evaluate_now = self.cfg.eval.every and counters["iteration"] % self.cfg.eval.every == 0 and not self.ended
        if stop or counters["iteration"] % self.cfg.checkpoint_every == 0 or evaluate_now:
            sync_obs_norm(self.policy, self.vecnorm)
            self.run.checkpoint(counters, modules, optimizers, **self._resume_state())
            if evaluate_now:
                with self.clock.paused():  # evaluation is not training time (the budget's clock)
                    self.run.evaluate(self.policy, counters, final=False)
        return stop

    def finish(self, collector) -> dict:
        """Close the bar and the collector (None: there was nothing left to collect); the final
        evaluation's ``metrics.json`` (returned), or ``{}`` when ``stop_after`` stopped the run first
        (``resume=<run_dir>`` continues it)."""
        self.bar.close()
        if collector is not None:
            collector.shutdown()
        self.ended = self.ended or self.counters["iteration"] >= self.iterations
        if not self.ended:
            return {}
        sync_obs_norm(self.policy, self.vecnorm)
        return self.run.evaluate(self.policy, self.counters, budget=self.budget.record(self.stopped_by))
