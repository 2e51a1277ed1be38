"""Pieces the model-free baselines (PPO, SAC, PGDM) share: the training env, the policy, the run directory.

* :func:`make_train_env` — ``make_env(task, differentiable=False)`` (plus a method's own transforms, e.g.
  PGDM's observation and reward) and torchrl's ``VecNorm`` (new API), a clip on ``"observation"`` and an
  episode-return counter: the env the collector steps.
* :func:`tanh_gaussian_actor` — a ``ProbabilisticActor`` (``TanhNormal`` within the env's action bounds) on an
  MLP; the scale is state-independent (PPO) or a second head (SAC).
* :class:`ObsNorm` / :func:`deployable_policy` — the training env's normalisation frozen into a module in
  front of the actor (after, for PGDM, the module that rebuilds its observation), so the policy runs on the
  *plain* task env (``evaluate_policy``, ``dexmots-eval``).
* :func:`policy_from_data` — that policy rebuilt from a checkpoint (``policy_from_checkpoint`` dispatches
  here for ``algo`` in :data:`BASELINES`).
* :func:`batch_metrics`, :class:`RunWriter` — one ``metrics.jsonl`` row per iteration, checkpoints and the final
  ``metrics.json``, with the same names and layout as :mod:`.shac`'s.
"""

from __future__ import annotations

import json
import logging
import warnings
from pathlib import Path

import torch
from omegaconf import OmegaConf
from tensordict.nn import AddStateIndependentNormalScale, NormalParamExtractor, TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.envs import ClipTransform, RewardSum, VecNorm
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal

from ..atomic import atomic_write_json
from ..envs import make_env
from .checkpoint import save_checkpoint
from .evaluation import evaluate_policy, periodic_episodes
from .validation import validate_run_config

__all__ = ["BASELINES", "ObsNorm", "RunWriter", "batch_metrics", "deployable_policy", "make_train_env", "mlp",
           "policy_from_data", "sync_obs_norm", "tanh_gaussian_actor"]

log = logging.getLogger(__name__)

BASELINES = ("ppo", "sac", "pgdm")  # algos whose checkpoints hold a "policy" module built here
ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU}


def make_train_env(cfg, seed: int, norm_decay: float = 0.9999, obs_clip: float = 10.0, transforms=()):
    """The task env (exactly ``make_env(cfg.task)``, not differentiable), then ``transforms`` (a method's
    own observation / reward, applied before the normalisation), with a running normalisation of
    ``"observation"``, clipped to ±``obs_clip``, and ``"episode_reward"``. Returns ``(env, vecnorm)``."""
    env = make_env(cfg.task, differentiable=False, seed=seed, device=cfg.device)
    for transform in transforms:
        env.append_transform(transform)
    # reduce_batch_dims: the worlds are one batch of samples of the same distribution, not separate streams
    vecnorm = VecNorm(in_keys=["observation"], new_api=True, reduce_batch_dims=True, decay=norm_decay)
    with warnings.catch_warnings():  # "experimental for a batched env": it is what reduce_batch_dims is for
        warnings.filterwarnings("ignore", message="Support of VecNormV2", category=UserWarning)
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


def _policy_for(cfg, obs_dim: int, action_spec, observation=None) -> TensorDictSequential:
    algo = cfg["algo"]
    actor = tanh_gaussian_actor(obs_dim, action_spec, algo["hidden"], algo["activation"],
                                state_scale=algo["name"] == "sac", init_log_std=algo.get("init_log_std", 0.0))
    return deployable_policy(actor, obs_dim, algo.get("obs_clip", 10.0), observation=observation)


def policy_from_data(data: dict, env) -> TensorDictSequential:
    """The normaliser + actor of a PPO / SAC / PGDM checkpoint ``data``, on the plain task ``env``'s specs
    (PGDM's observation module is rebuilt from the checkpoint's ``algo`` section and ``env``'s task)."""
    observation, obs_dim = None, env.observation_spec["observation"].shape[-1]
    if data["config"]["algo"]["name"] == "pgdm":
        from .pgdm import policy_observation  # imported on use: pgdm imports this module

        observation = policy_observation(data["config"]["algo"], env)
        obs_dim = observation.width
    policy = _policy_for(data["config"], obs_dim, env.action_spec_unbatched, observation)
    policy.load_state_dict(data["modules"]["policy"])
    return policy


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
        "reward": float(nxt.get("reward").mean()),
        "episodes": ended,
        "episode_success": float(nxt.get("success").squeeze(-1)[done].float().mean()) if ended else float("nan"),
        "episode_reward": float(nxt.get("episode_reward").squeeze(-1)[done].mean()) if ended else float("nan"),
    }
    if "reward_terms" in nxt.keys():
        for name, value in nxt.get("reward_terms").items():
            row[f"reward_{name}"] = float(value.mean())
    return row


class RunWriter:
    """A run directory as :mod:`.shac` writes it: ``config.yaml``, ``metrics.jsonl`` (+ a torchrl logger),
    ``checkpoints/last.pt`` and, after the final evaluation, ``metrics.json``."""

    def __init__(self, cfg):
        if cfg.resume:
            raise ValueError(f"algo {cfg.algo.name!r} does not resume runs (resume={cfg.resume}); start a new run")
        validate_run_config(cfg)
        self.cfg, self.dir = cfg, Path(cfg.run_dir)
        self.dir.mkdir(parents=True, exist_ok=True)
        (self.dir / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
        if cfg.logger not in ("csv", "tensorboard"):
            raise ValueError(f"logger must be 'csv' or 'tensorboard', got {cfg.logger!r}")
        from torchrl.record.loggers import get_logger

        self.logger = get_logger(cfg.logger, logger_name=str(self.dir), experiment_name="logs")

    def log(self, row: dict) -> None:
        with open(self.dir / "metrics.jsonl", "a") as f:
            f.write(json.dumps(row) + "\n")
        for key, value in row.items():
            if key != "iteration" and isinstance(value, (int, float)) and value == value:  # skip NaN
                self.logger.log_scalar(key, value, step=row["iteration"])

    def checkpoint(self, counters: dict, modules: dict, optimizers: dict) -> None:
        """``modules`` must hold ``"policy"`` (:func:`deployable_policy`): what ``dexmots-eval`` rebuilds."""
        save_checkpoint(self.dir / "checkpoints" / "last.pt", {
            "task": self.cfg.task.name,
            "algo": self.cfg.algo.name,
            "config": OmegaConf.to_container(self.cfg, resolve=True),
            "iteration": counters["iteration"],
            "counters": dict(counters),
            "modules": {name: m.state_dict() for name, m in modules.items()},
            "optimizers": {name: o.state_dict() for name, o in optimizers.items()},
        })

    def evaluate(self, policy, counters: dict, final: bool = True, budget: dict | None = None) -> dict:
        """Deterministic evaluation on the plain task env (``eval.curve_episodes`` episodes during training);
        the final one also writes ``metrics.json``, with ``budget`` (:meth:`.budget.RunBudget.record`)."""
        cfg = self.cfg
        rec = {"record": self.dir / "eval.mcap", "live": True} if cfg.eval.record else {}
        episodes = cfg.eval.episodes if final else periodic_episodes(cfg.eval)
        ev = evaluate_policy(policy, cfg.task, episodes, cfg.eval.seed, cfg.device, **rec)
        if not final:
            self.log({"iteration": counters["iteration"],
                      **{f"eval_{k}": v for k, v in ev.items() if isinstance(v, (int, float))}})
            return ev
        return self.write_result(ev, counters, budget=budget)

    def write_result(self, ev: dict, counters: dict, budget: dict | None = None, **extra) -> dict:
        """``metrics.json``: the evaluation ``ev``, the run's counters and ``extra`` entries; returns it."""
        cfg = self.cfg
        result = {"task": cfg.task.name, "algo": cfg.algo.name, **ev, "env_steps": counters["env_steps"],
                  "iterations": counters["iteration"], "train_wall_clock_s": round(counters["wall_clock_s"], 2),
                  "budget": budget or {}, **extra, "run_dir": str(self.dir)}
        atomic_write_json(self.dir / "metrics.json", result)  # a sweep's restart trusts a complete file
        log.info("%s %s: success %.2f after %d env steps, %.0f s", cfg.algo.name, cfg.task.name,
                 ev["success_rate"], counters["env_steps"], counters["wall_clock_s"])
        return result
