"""PPO baseline (``dexmots-train algo=ppo``): torchrl's ``ClipPPOLoss`` on the task env, no simulator gradients.

    dexmots-train algo=ppo                                   # screw_claw as SHAC/AHAC train it
    dexmots-train algo=ppo task.goal=pose                    # the paper's PPO without trajectory conditioning
    dexmots-train algo=ppo task=screw_claw algo.total_frames=2e6 seed=1

One iteration (CleanRL / torchrl ``sota-implementations/ppo`` style): the ``Collector`` steps ``num_envs``
worlds of ``make_env(task, differentiable=False)`` (observation normalised by ``VecNorm``) for
``frames_per_batch`` frames under the sampled policy -> for each of ``epochs`` epochs: GAE advantages with
the current critic, then Adam steps on shuffled minibatches of the clipped PPO objective + critic loss
(gradient norm clipped) -> learning rate annealed linearly. The run directory is :mod:`.shac`'s:
``metrics.jsonl`` per iteration, ``checkpoints/last.pt`` (``dexmots-eval`` reloads it), ``metrics.json``
with the final deterministic evaluation.

A method that is PPO with another observation, reward, start or initialisation (PGDM, :mod:`.pgdm`) passes
a :class:`PPOVariant` to :func:`build` / :func:`train` instead of copying the loop.
"""

from __future__ import annotations

import logging
import math
import sys
import time
from dataclasses import dataclass
from typing import Callable, Optional

import torch
from omegaconf import DictConfig
from torchrl.collectors import Collector
from torchrl.envs.utils import ExplorationType
from torchrl.modules import ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from ..progress import progress_bar
from .budget import RunBudget
from .common import RunWriter, batch_metrics, deployable_policy, make_train_env, mlp, sync_obs_norm, \
    tanh_gaussian_actor

__all__ = ["PLAIN_PPO", "PPOVariant", "build", "train"]

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


def train(cfg: DictConfig, variant: PPOVariant = PLAIN_PPO) -> dict:
    """Train a PPO run; returns the final metrics dict (also written to ``metrics.json``)."""
    a = cfg.algo
    writer = RunWriter(cfg)
    env, vecnorm, actor, critic, gae, loss, optimizer = build(cfg, variant)
    front = None if variant.policy_observation is None else variant.policy_observation(env)
    policy = deployable_policy(actor, env.observation_spec["observation"].shape[-1], a.obs_clip, observation=front)
    frames_per_batch = a.frames_per_batch
    iterations = max(1, math.ceil(float(a.total_frames) / frames_per_batch))
    # the collector runs the sampled policy (exploration RANDOM) and resets the worlds that are done
    collector = Collector(env, actor, frames_per_batch=frames_per_batch, total_frames=iterations * frames_per_batch,
                          device=cfg.device, exploration_type=ExplorationType.RANDOM,
                          auto_register_policy_transforms=False)
    counters = {"iteration": 0, "env_steps": 0, "wall_clock_s": 0.0}
    bar = progress_bar(total=iterations, desc=f"{a.name} {cfg.task.name}", disable=not cfg.progress, file=sys.stderr)
    budget, stopped_by = RunBudget.from_config(cfg), None
    t_start = time.perf_counter()
    for data in collector:
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
                group["lr"] = a.lr * (1.0 - budget.progress(counters, counters["iteration"] / iterations))
        collector.update_policy_weights_()  # single process: the collector already holds this actor

        counters["env_steps"] += data.numel()
        counters["wall_clock_s"] = time.perf_counter() - t_start
        row = {**batch_metrics(data, counters), **{k: v / max(updates, 1) for k, v in stats.items()},
               "lr": optimizer.param_groups[0]["lr"], "policy_std": float(data.get("scale").mean())}
        if variant.reward_key != "reward":  # "reward" stays the task's (comparable across methods)
            row[variant.reward_key] = float(data.get(("next", variant.reward_key)).mean())
        writer.log(row)
        bar.update(1)
        bar.set_postfix(fps=f"{row['env_steps'] / max(row['wall_clock_s'], 1e-9):.0f}",
                        reward=f"{row['reward']:.3f}", success=f"{row['episode_success']:.2f}")
        stopped_by = budget.reached(counters)
        last = counters["iteration"] == iterations or stopped_by is not None
        evaluate_now = cfg.eval.every and counters["iteration"] % cfg.eval.every == 0 and not last
        if last or counters["iteration"] % cfg.checkpoint_every == 0 or evaluate_now:
            sync_obs_norm(policy, vecnorm)
            writer.checkpoint(counters, {"policy": policy, "critic": critic, "vecnorm": vecnorm},
                              {"optimizer": optimizer})
            if evaluate_now:
                t_eval = time.perf_counter()
                writer.evaluate(policy, counters, final=False)
                t_start += time.perf_counter() - t_eval  # evaluation is not training time (the budget's clock)
        if stopped_by is not None:
            break
    bar.close()
    collector.shutdown()
    sync_obs_norm(policy, vecnorm)
    return writer.evaluate(policy, counters, budget=budget.record(stopped_by))
