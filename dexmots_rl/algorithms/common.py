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
* :func:`batch_metrics`, :class:`CollectorLoop` — every method's loop end (:class:`~.loop.TrainingLoop`) fed
  by a torchrl ``Collector``: a batch's row, its collection timed apart, the normaliser synced into the
  deployable policy, SAC's replay buffer in the checkpoint.
"""

from __future__ import annotations

import time
import warnings

import torch
from tensordict import TensorDict
from tensordict.nn import AddStateIndependentNormalScale, NormalParamExtractor, TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.envs import ClipTransform, RewardSum
from torchrl.envs.transforms.vecnorm import VecNormV2
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal

from ..envs import make_env
from .checkpoint import CheckpointError
from .loop import TrainingLoop
from .rundir import RunDirectory

__all__ = ["CollectorLoop", "ObsNorm", "RunningObsNorm", "batch_metrics", "deployable_policy", "load_replay_buffer",
           "make_train_env", "mlp", "policy_from_data", "replay_buffer_state", "sync_obs_norm", "tanh_gaussian_actor"]

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


def batch_metrics(data) -> dict:
    """A collected batch's ``[worlds, time]`` entries of its ``metrics.jsonl`` row: the mean step reward,
    ``episode_success`` (the success flag at the last step of the episodes that ended in the batch; NaN when
    none did) and ``episode_reward`` (their return), and the mean of each reward term."""
    nxt = data.get("next")
    done = nxt.get("done").squeeze(-1)
    ended = int(done.sum())
    row = {
        "reward": float(nxt.get("reward").mean()),
        "episodes": ended,
        "episode_success": float(nxt.get("success").squeeze(-1)[done].float().mean()) if ended else float("nan"),
        "episode_reward": float(nxt.get("episode_reward").squeeze(-1)[done].mean()) if ended else float("nan"),
    }
    if "reward_terms" in nxt.keys():
        for name, value in nxt.get("reward_terms").items():
            row[f"reward_{name}"] = float(value.mean())
    return row


class CollectorLoop(TrainingLoop):
    """:class:`~.loop.TrainingLoop` for the methods a torchrl ``Collector`` feeds (PPO, SAC, PGDM).

    The trainer iterates :meth:`batches` (the collector's batches, their collection timed apart, until the
    loop is done), counts ``counters["iteration"]`` and ``counters["env_steps"]`` itself and ends each
    iteration with :meth:`end_batch`: the row is :func:`batch_metrics` + the method's statistics + the
    iteration's CPU and wall seconds spent collecting and learning (``collect_*`` / ``learn_*``). The
    deployable ``policy`` gets the normaliser's statistics before it is saved or evaluated; a checkpoint also
    holds ``replay_buffer`` (SAC's), which :meth:`start` refills on resume.
    """

    def __init__(self, run: RunDirectory, env, policy, vecnorm, iterations: int, modules: dict, optimizers: dict,
                 counters: dict | None = None, replay_buffer=None):
        super().__init__(run, env, iterations, modules, optimizers, policy, counters=counters)
        self.vecnorm, self.replay_buffer, self.collector = vecnorm, replay_buffer, None
        self._collected = (0.0, 0.0)  # the last batch's collection (CPU s, wall s)
        self._last = (self.counters["cpu_s"], self.counters["wall_clock_s"])  # training time at the last row

    def frames_left(self, frames_per_batch: int) -> int:
        """The frames the collector still has to collect: up to ``stop_after`` or the schedule's end."""
        return max(0, self.stop_at - self.counters["iteration"]) * frames_per_batch

    def start(self, collector) -> None:
        """Call once ``collector`` (None: nothing left to collect) is built: building it resets the worlds,
        which draws from the RNG streams and updates the normaliser. A fresh run keeps all that; a resumed
        one goes on from its checkpoint (:meth:`.TrainingLoop.start`, and the replay buffer)."""
        self.collector = collector
        start = self.run.start
        if self.replay_buffer is not None and start is not None:
            if "replay_buffer" not in start:
                raise CheckpointError(f"resume={self.cfg.resume}: the checkpoint holds no replay buffer (written "
                                      "before SAC runs could resume); start a new run")
            load_replay_buffer(self.replay_buffer, start["replay_buffer"])
        if collector is None:
            super().start(None)  # the modules and optimisers only: there are no worlds to go on with
            return
        carrier = self.current_worlds()
        worlds = super().start(carrier)
        if worlds is not carrier:
            carrier.update_(worlds)
            collector.update_policy_weights_()

    def current_worlds(self) -> TensorDict | None:
        # torchrl keeps the worlds' current TensorDict there between batches (not always the same object)
        return None if self.collector is None else self.collector._carrier

    def batches(self, collector):
        """``collector``'s batches until the loop is done, each one's collection measured apart from the
        learning that follows it (the rows' ``collect_cpu_s`` / ``learn_cpu_s``: ``dexmots-bench baselines``)."""
        if collector is None:
            return
        batches = iter(collector)
        while not self.done:
            cpu, wall = time.process_time(), time.perf_counter()
            data = next(batches, None)
            if data is None:
                return
            self._collected = (time.process_time() - cpu, time.perf_counter() - wall)
            yield data

    def end_batch(self, data, stats: dict) -> bool:
        """:meth:`.TrainingLoop.end_iteration` of the collected batch ``data`` with the method's ``stats``."""
        return self.end_iteration({**batch_metrics(data), **stats})

    def _timing(self) -> dict:
        counters = self.counters
        (collect_cpu, collect_wall), (last_cpu, last_wall) = self._collected, self._last
        self._last = (counters["cpu_s"], counters["wall_clock_s"])
        # learning: the rest of the iteration since the last row (the method's updates, this loop's bookkeeping)
        timing = {"collect_cpu_s": collect_cpu, "collect_wall_s": collect_wall,
                  "learn_cpu_s": max(0.0, counters["cpu_s"] - last_cpu - collect_cpu),
                  "learn_wall_s": max(0.0, counters["wall_clock_s"] - last_wall - collect_wall)}
        return {k: round(v, 4) for k, v in timing.items()}

    def sync_policy(self) -> None:
        sync_obs_norm(self.policy, self.vecnorm)

    def _resume_state(self) -> dict:
        state = super()._resume_state()
        if self.replay_buffer is not None:
            state["replay_buffer"] = replay_buffer_state(self.replay_buffer)
        return state

    def finish(self, **extra) -> dict:
        """Close the collector (None: there was nothing left to collect), then :meth:`.TrainingLoop.finish`."""
        if self.collector is not None:
            self.collector.shutdown()
        return super().finish(**extra)
