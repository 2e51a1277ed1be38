"""PPO baseline (``dexmots-train algo=ppo``): torchrl's ``ClipPPOLoss`` on the task env, no simulator gradients.

    dexmots-train algo=ppo                                   # screw_claw as SHAC/AHAC train it
    dexmots-train algo=ppo task.goal=pose                    # the paper's PPO without trajectory conditioning
    dexmots-train algo=ppo task=screw_claw algo.total_frames=2e6 seed=1

One iteration (CleanRL / torchrl ``sota-implementations/ppo`` style): the ``Collector`` steps ``num_envs``
worlds of ``make_env(task, differentiable=False)`` (observation normalised by ``VecNorm``) for
``frames_per_batch`` frames under the sampled policy -> for each of ``epochs`` epochs: GAE advantages with
the current critic, then Adam steps on shuffled minibatches of the clipped PPO objective + critic loss
(gradient norm clipped) -> learning rate annealed linearly -> the loop's end every baseline shares
(:class:`~.common.CollectorLoop`: ``metrics.jsonl`` row, checkpoint ``checkpoints/last.pt`` that
``dexmots-eval`` reloads, periodic evaluations, budget; at the end ``metrics.json`` with the final
deterministic evaluation), in the run directory every method writes (:class:`~.rundir.RunDirectory`).

``resume=<run_dir>`` continues a run from its checkpoint (networks, normaliser, optimiser, counters, the worlds
mid-episode, RNG streams) exactly as the uninterrupted run goes on. A method that is PPO with another observation, reward, start or initialisation
(PGDM, :mod:`.pgdm`) passes a :class:`PPOVariant` to :func:`build` / :func:`train` instead of copying the loop.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Callable, Optional

import torch
from omegaconf import DictConfig
from torchrl.collectors import Collector
from torchrl.envs.utils import ExplorationType
from torchrl.modules import ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from .common import CollectorLoop, deployable_policy, make_train_env, mlp, policy_from_data, tanh_gaussian_actor
from .rundir import RunDirectory

__all__ = ["PLAIN_PPO", "PPOVariant", "build", "load_policy", "train"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PPOVariant:
    """What a method built on this PPO changes; the defaults are plain PPO on the task."""

    #: () -> the transforms appended to the task env before the normalisation (fresh ones per env)
    env_transforms: Callable[[], list] = list
    #: (training env) -> the module the deployable policy runs first, writing ``"observation"`` on the plain
    #: task env as ``env_transforms`` did; None: the task's own ``"observation"``
    policy_observation: Optional[Callable] = None
    #: (actor, training env) -> None: changes the fresh actor's parameters in place (a warm start)
    init_actor: Optional[Callable] = None
    #: the ``("next", key)`` entry the critic and the advantages learn from
    reward_key: str = "reward"


PLAIN_PPO = PPOVariant()


def build(cfg: DictConfig, variant: PPOVariant = PLAIN_PPO):
    """Env (+ its VecNorm), actor, critic, GAE, loss and optimiser of a run."""
    torch.manual_seed(cfg.seed)
    a = cfg.algo
    env, vecnorm = make_train_env(cfg, seed=cfg.seed, norm_decay=a.obs_norm_decay, obs_clip=a.obs_clip,
                                  transforms=variant.env_transforms())
    obs_dim = env.observation_spec["observation"].shape[-1]
    actor = tanh_gaussian_actor(obs_dim, env.action_spec_unbatched, a.hidden, a.activation,
                                init_log_std=a.init_log_std, return_log_prob=True)  # PPO needs the old log-prob
    if variant.init_actor is not None:
        variant.init_actor(actor, env)
    critic = ValueOperator(mlp(obs_dim, 1, a.hidden, a.activation, out_gain=1.0), in_keys=["observation"])
    # separate actor and critic networks (no shared trunk), so the critic coefficient only scales the critic
    gae = GAE(gamma=a.gamma, lmbda=a.lmbda, value_network=critic, average_gae=False)
    gae.set_keys(reward="reward_scaled")  # the critic learns scaled returns (see train); "reward" stays the task's
    loss = ClipPPOLoss(actor, critic, clip_epsilon=a.clip_epsilon, entropy_coeff=a.entropy_coeff,
                       critic_coeff=a.critic_coeff, loss_critic_type=a.loss_critic_type,
                       normalize_advantage=a.normalize_advantage)
    # eps 1e-5: CleanRL's / sota's; fused: one kernel per step (the minibatch loop is Python-bound on CPU)
    optimizer = torch.optim.Adam(loss.parameters(), lr=a.lr, eps=1e-5, fused=True)
    return env, vecnorm, actor, critic, gae, loss, optimizer


def train(cfg: DictConfig, overrides: list[str] | None = None,
          make_variant: Callable[..., PPOVariant] = lambda algo: PLAIN_PPO) -> dict:
    """Train (or resume) a PPO run; returns the final metrics dict (also written to ``metrics.json``), or
    ``{}`` when stopped early by ``stop_after``. ``overrides``: the command line's, which a resume compares
    with its checkpoint; ``make_variant``: ``algo`` section -> the :class:`PPOVariant` (of the config that
    trains: on resume, the checkpoint's)."""
    with RunDirectory(cfg, overrides, resumes=True) as run:
        return _train(run, make_variant(run.cfg.algo))


def _train(run: RunDirectory, variant: PPOVariant) -> dict:
    cfg, a = run.cfg, run.cfg.algo
    env, vecnorm, actor, critic, gae, loss, optimizer = build(cfg, variant)
    front = None if variant.policy_observation is None else variant.policy_observation(env)
    policy = deployable_policy(actor, env.observation_spec["observation"].shape[-1], a.obs_clip, observation=front)
    frames_per_batch = a.frames_per_batch
    iterations = max(1, math.ceil(float(a.total_frames) / frames_per_batch))
    modules, optimizers = {"policy": policy, "critic": critic, "vecnorm": vecnorm}, {"optimizer": optimizer}
    # updates: Adam steps so far (a checkpoint of an older run may lack the count)
    with CollectorLoop(run, env, policy, vecnorm, iterations, modules, optimizers, counters={"updates": 0}) as loop:
        counters = loop.counters
        # the collector runs the sampled policy (exploration RANDOM) and resets the worlds that are done
        frames = loop.frames_left(frames_per_batch)
        collector = Collector(env, actor, frames_per_batch=frames_per_batch, total_frames=frames, device=cfg.device,
                              exploration_type=ExplorationType.RANDOM,
                              auto_register_policy_transforms=False) if frames else None
        loop.start(collector)  # a resumed run continues from its checkpoint
        for data in loop.batches(collector):
            # data: [num_envs, T]; flattened minibatches mix worlds and steps (GAE is computed before flattening)
            stats = {"loss_objective": 0.0, "loss_critic": 0.0, "loss_entropy": 0.0, "grad_norm": 0.0, "kl": 0.0}
            updates = 0
            # screw_claw's returns are ~1e2: scaled, the critic's targets are O(1-10) (rl_games' reward x 0.01)
            data.set(("next", "reward_scaled"), data.get(("next", variant.reward_key)) * a.reward_scale)
            for _ in range(a.epochs):
                with torch.no_grad():  # advantages with the current critic, every epoch (sota's recipe)
                    gae(data)
                flat = data.reshape(-1)
                for idx in torch.randperm(flat.numel()).split(a.minibatch_size):
                    out = loss(flat[idx])
                    total = out["loss_objective"] + out["loss_critic"] + out.get("loss_entropy", torch.zeros(()))
                    optimizer.zero_grad()
                    total.backward()
                    # actor and critic clipped apart: in one global norm the critic's gradient (value errors of
                    # O(returns)) shrank the actor's steps to nothing (tuning run P1, docs/baseline_tuning.md)
                    grad_norm = torch.nn.utils.clip_grad_norm_(actor.parameters(), a.max_grad_norm)
                    torch.nn.utils.clip_grad_norm_(critic.parameters(), a.max_grad_norm)
                    optimizer.step()
                    updates += 1
                    for key in ("loss_objective", "loss_critic", "loss_entropy", "kl_approx"):
                        if key in out.keys():
                            stats["kl" if key == "kl_approx" else key] += float(out[key].detach())
                    stats["grad_norm"] += float(grad_norm)
            # linear learning-rate annealing to 0 over the run (CleanRL's anneal_lr), ending with the budget if that
            # comes first
            counters["iteration"] += 1
            if a.anneal_lr:
                for group in optimizer.param_groups:
                    group["lr"] = a.lr * (1.0 - loop.progress())
            collector.update_policy_weights_()  # single process: the collector already holds this actor
            counters["env_steps"] += data.numel()
            counters["updates"] += updates

            stats = {**{k: v / max(updates, 1) for k, v in stats.items()}, "updates": counters["updates"],
                     "lr": optimizer.param_groups[0]["lr"],
                     "policy_std": float(data.get("scale").mean())}
            if variant.reward_key != "reward":  # "reward" stays the task's (comparable across methods)
                stats[variant.reward_key] = float(data.get(("next", variant.reward_key)).mean())
            loop.end_batch(data, stats)
        return loop.finish()


def load_policy(data: dict, env):
    """The deployable policy (normaliser + actor) of a PPO checkpoint ``data`` on the plain task ``env``."""
    return policy_from_data(data, env)
