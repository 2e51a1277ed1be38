"""SAC baseline (``dexmots-train algo=sac``): torchrl's ``SACLoss`` + a replay buffer, no simulator gradients.

    dexmots-train algo=sac                                   # screw_claw as SHAC/AHAC train it
    dexmots-train algo=sac task.goal=pose algo.utd_ratio=0.25 algo.batch_size=512

One iteration (torchrl ``sota-implementations/sac`` style): the ``Collector`` steps the ``num_envs`` worlds
of ``make_env(task, differentiable=False)`` (observation normalised by ``VecNorm``) for ``frames_per_batch``
frames (uniform random actions for the first ``init_random_frames``) -> the transitions go into a
``TensorDictReplayBuffer`` holding only what ``SACLoss`` reads (:data:`TRANSITION_KEYS`; not the sim state,
reward terms, goals...) -> ``frames_per_batch * utd_ratio`` gradient steps on sampled minibatches (actor,
twin Q and temperature together) with a polyak update of the target Q after each. The normaliser is frozen
once the random frames are in, so the stored observations and the ones the networks see later agree.
The loop ends as every baseline's (:class:`~.common.CollectorLoop`: ``metrics.jsonl``, ``checkpoints/last.pt``
for ``dexmots-eval``, periodic evaluations, budget, ``metrics.json``) in the run directory every method
writes (:class:`~.rundir.RunDirectory`). ``resume=<run_dir>`` continues a run exactly as it would have gone on:
the checkpoint holds the replay buffer's filled rows too (so it grows with them, up to ``buffer_size``).
"""

from __future__ import annotations

import logging
import math

import torch
from omegaconf import DictConfig
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs.utils import ExplorationType
from torchrl.modules import ValueOperator
from torchrl.objectives import SACLoss, SoftUpdate

from .common import CollectorLoop, deployable_policy, make_train_env, mlp, policy_from_data, tanh_gaussian_actor
from .rundir import RunDirectory

__all__ = ["TRANSITION_KEYS", "build", "load_policy", "store_transitions", "train"]

log = logging.getLogger(__name__)

# all SACLoss reads: a 1e6-frame buffer of every key the env writes was ~1.1 GB, of these ~0.4 GB
TRANSITION_KEYS = ("observation", "action", ("next", "observation"), ("next", "reward"), ("next", "done"),
                   ("next", "terminated"))


def build(cfg: DictConfig):
    """Env (+ its VecNorm), actor, twin-Q loss, target updater, optimiser and replay buffer of a run."""
    torch.manual_seed(cfg.seed)
    a = cfg.algo
    env, vecnorm = make_train_env(cfg, seed=cfg.seed, norm_decay=a.obs_norm_decay, obs_clip=a.obs_clip)
    obs_dim = env.observation_spec["observation"].shape[-1]
    action_spec = env.action_spec_unbatched
    actor = tanh_gaussian_actor(obs_dim, action_spec, a.hidden, a.activation, state_scale=True)
    # Q(s, a): torchrl's MLP concatenates its inputs
    qvalue = ValueOperator(mlp(obs_dim + action_spec.shape[-1], 1, a.hidden, a.activation),
                           in_keys=["observation", "action"], out_keys=["state_action_value"])
    loss = SACLoss(actor, qvalue, num_qvalue_nets=2, loss_function="l2", alpha_init=a.alpha_init,
                   target_entropy="auto", delay_qvalue=True)  # target entropy: -action dim
    loss.make_value_estimator(gamma=a.gamma)
    updater = SoftUpdate(loss, tau=a.tau)
    optimizer = torch.optim.Adam([
        {"params": loss.actor_network_params.flatten_keys().values(), "lr": a.actor_lr},
        {"params": loss.qvalue_network_params.flatten_keys().values(), "lr": a.critic_lr},
        {"params": [loss.log_alpha], "lr": a.alpha_lr},
    ], fused=True)  # one kernel per step: SAC is update-bound on CPU
    buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(int(a.buffer_size), device=cfg.device),
                                    batch_size=a.batch_size)
    return env, vecnorm, actor, loss, updater, optimizer, buffer


def store_transitions(buffer: TensorDictReplayBuffer, data) -> None:
    """Add a collected ``[worlds, time]`` batch to ``buffer``, only the :data:`TRANSITION_KEYS`, flattened."""
    buffer.extend(data.select(*TRANSITION_KEYS).reshape(-1))


def train(cfg: DictConfig, overrides: list[str] | None = None) -> dict:
    """Train (or resume) a SAC run; returns the final metrics dict (also written to ``metrics.json``), or
    ``{}`` when stopped early by ``stop_after``. ``overrides``: the command line's, which a resume compares
    with its checkpoint."""
    with RunDirectory(cfg, overrides, resumes=True) as run:
        return _train(run)


def _train(run: RunDirectory) -> dict:
    cfg, a = run.cfg, run.cfg.algo
    env, vecnorm, actor, loss, updater, optimizer, buffer = build(cfg)
    policy = deployable_policy(actor, env.observation_spec["observation"].shape[-1], a.obs_clip)
    frames_per_batch = a.frames_per_batch
    iterations = max(1, math.ceil(float(a.total_frames) / frames_per_batch))
    modules, optimizers = {"policy": policy, "loss": loss, "vecnorm": vecnorm}, {"optimizer": optimizer}
    with CollectorLoop(run, env, policy, vecnorm, iterations, modules, optimizers, counters={"updates": 0},
                       replay_buffer=buffer) as loop:
        counters = loop.counters
        frames = loop.frames_left(frames_per_batch)
        # a resumed run has had some of its random frames already (the collector counts its own frames from 0)
        random_frames = max(0, int(a.init_random_frames) - counters["env_steps"])
        collector = Collector(env, actor, frames_per_batch=frames_per_batch, total_frames=frames,
                              init_random_frames=random_frames, device=cfg.device,
                              exploration_type=ExplorationType.RANDOM,
                              auto_register_policy_transforms=False) if frames else None
        loop.start(collector)  # a resumed run continues from its checkpoint
        if 0 < counters["env_steps"] >= a.init_random_frames:  # resumed past the random frames: frozen, as it was
            vecnorm.freeze()                                      # (VecNorm's state_dict does not hold the flag)
        updates_per_batch = max(1, round(frames_per_batch * a.utd_ratio))
        for data in loop.batches(collector):
            store_transitions(buffer, data)
            counters["iteration"] += 1
            counters["env_steps"] += data.numel()
            stats = {"loss_actor": 0.0, "loss_qvalue": 0.0, "loss_alpha": 0.0}
            learning = counters["env_steps"] >= a.init_random_frames
            if learning:
                if not vecnorm.frozen:  # statistics of the random-action frames, then fixed (see the docstring)
                    vecnorm.freeze()
                for _ in range(updates_per_batch):
                    out = loss(buffer.sample())
                    total = out["loss_actor"] + out["loss_qvalue"] + out["loss_alpha"]
                    optimizer.zero_grad()
                    total.backward()
                    optimizer.step()
                    updater.step()
                    for key in stats:
                        stats[key] += float(out[key].detach())
                counters["updates"] += updates_per_batch
            collector.update_policy_weights_()

            n = updates_per_batch if learning else 1
            stats = {**{k: v / n for k, v in stats.items()}, "alpha": float(loss.log_alpha.detach().exp()),
                     "updates": counters["updates"]}
            loop.end_batch(data, stats)
        return loop.finish()


def load_policy(data: dict, env):
    """The deployable policy (normaliser + actor with its scale head) of a SAC checkpoint ``data`` on the
    plain task ``env``."""
    return policy_from_data(data, env, state_scale=True)
