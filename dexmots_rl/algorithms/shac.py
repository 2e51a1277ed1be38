"""DexMOTS policy learning with SHAC / AHAC (``dexmots-train algo=shac|ahac``), readable top to bottom.

    dexmots-train                                   # screw_claw, AHAC: the configs' defaults
    dexmots-train task=screw_claw algo=shac seed=1 algo.iterations=100
    dexmots-train resume=runs/screw_claw_ahac_seed0 # continue from the last checkpoint
    torchrun --nproc_per_node 2 -m dexmots_rl.apps.train task.num_envs=32   # data parallel

One iteration: a differentiable rollout of ``horizon`` steps in ``num_envs`` worlds under the sampled
policy -> actor loss (SHAC) -> one clipped Adam step (skipped and counted if the gradient norm is NaN or
huge; worlds whose gradient through the simulator dwarfs the median world's are capped first,
``algo.adjoint_clip``; a policy-smoothness penalty's gradient is added after the clip, ``algo.smooth_*``,
with its weight raised only while the share of capped adjoints is above ``algo.smooth_clip_target``) ->
observation statistics updated outside the graph -> TD(lambda) targets with the target critic on the
detached rollout -> critic minibatch iterations -> polyak update of the target critic -> the episodes
continue from the rollout's last state (graph cut) -> the best policy so far is kept, and restored after a
collapse of training success (``algo.keep_best``, :mod:`.best_policy`). Budget, rollback, progress,
checkpoints and evaluations are the loop's end every method shares (:class:`~.loop.TrainingLoop`). The run
directory every method writes (:class:`~.rundir.RunDirectory`) gets the resolved config, torchrl logger
output, ``metrics.jsonl`` (one line per iteration), checkpoints and, at the end, ``metrics.json`` with the
final evaluation (:mod:`.evaluation`).
"""

from __future__ import annotations

import logging
import warnings

import torch
from omegaconf import DictConfig
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.objectives import SoftUpdate

from ..envs import GRADIENT_COUNTS, make_env
from ..objectives import AdaptiveHorizon, PolicySmoothnessLoss, SHACLoss, next_rollout_start
from .best_policy import BestPolicy
from .distributed import Distributed
from .loop import TrainingLoop
from .networks import make_networks
from .rundir import RunDirectory

__all__ = ["build", "initial_action", "load_policy", "train"]

log = logging.getLogger(__name__)


def build(cfg: DictConfig, rank: int = 0):
    """Env, networks, loss, optimisers and the target updater of a run."""
    torch.manual_seed(cfg.seed + rank)
    env = make_env(cfg.task, num_envs=cfg.algo.get("num_envs"), differentiable=True, seed=cfg.seed + 1000 * rank,
                   device=cfg.device, adjoint_clip=cfg.algo.get("adjoint_clip"))
    obs_dim = env.observation_spec["observation"].shape[-1]
    act_dim = env.action_spec.shape[-1]
    torch.manual_seed(cfg.seed)  # identical initial networks on every rank
    critic_hidden = cfg.algo.get("critic_hidden")
    actor, critic, norm = make_networks(obs_dim, act_dim, tuple(cfg.algo.hidden), cfg.algo.init_log_std,
                                        layer_norm=cfg.algo.layer_norm,
                                        critic_hidden=None if critic_hidden is None else tuple(critic_hidden),
                                        init_action=initial_action(env, cfg.algo))
    loss = SHACLoss(actor_network=actor, critic_network=critic, gamma=cfg.algo.gamma, lmbda=cfg.algo.lmbda)
    loss.make_value_estimator()  # built now, so a checkpoint's state_dict finds it when resuming
    with warnings.catch_warnings():  # torchrl warns for eps < 0.5; SHAC's target critic is updated that fast
        warnings.simplefilter("ignore", UserWarning)
        updater = SoftUpdate(loss, tau=1.0 - cfg.algo.target_alpha)
    betas = tuple(cfg.algo.betas)
    # fused: one kernel per step instead of ~10 ops per parameter (the critic takes 64 steps per iteration)
    actor_opt = torch.optim.Adam(actor.parameters(), lr=cfg.algo.actor_lr, betas=betas, fused=True)
    critic_opt = torch.optim.Adam(critic.parameters(), lr=cfg.algo.critic_lr, betas=betas, fused=True)
    ahac = None
    if cfg.algo.name == "ahac":
        ahac = AdaptiveHorizon(cfg.algo.horizon_min, cfg.algo.horizon_max, cfg.algo.contact_threshold,
                               cfg.algo.dual_lr, horizon_init=cfg.algo.horizon,
                               clip_share_target=cfg.algo.get("horizon_clip_target"),
                               clip_share_lr=cfg.algo.get("horizon_clip_lr", 20.0))
    torch.manual_seed(cfg.seed + rank)
    return env, actor, critic, norm, loss, updater, actor_opt, critic_opt, ahac


def initial_action(env, algo) -> torch.Tensor:
    """The initial policy's mean action on ``env``: PD targets at their centre, ``vi`` stiffness actions at
    ``algo.init_stiffness`` (0: the geometric middle of the stiffness range)."""
    return getattr(env, "base_env", env).actions.mean_actions(algo.get("init_stiffness", 0.0))


def train(cfg: DictConfig, overrides: list[str] | None = None) -> dict:
    """Train (or resume) a run; returns the final metrics dict (also written to ``metrics.json``), ``{}``
    when stopped early by ``stop_after``, or ``{"interrupted": "SIGINT", ...}`` after SIGINT/SIGTERM (a
    checkpoint is saved first).

    Before any work the run directory is opened (:class:`~.rundir.RunDirectory`): the config validated,
    the directory locked, and a fresh run refuses a directory holding another run unless
    ``overwrite=true``. A resume takes the checkpoint's task/algo/seed; ``overrides`` (the command line's,
    from the hydra app) that change them fail, ``None`` compares the whole ``cfg``
    (:func:`.rundir.resume_config`), and log rows past the checkpoint are truncated."""
    dist = Distributed.from_environment()
    with RunDirectory(cfg, overrides, main=dist.is_main) as run:
        return _train(run, dist)


def _train(run: RunDirectory, dist) -> dict:
    cfg = run.cfg
    env, actor, critic, norm, loss, updater, actor_opt, critic_opt, ahac = build(cfg, dist.rank)
    modules = {"actor": actor, "critic": critic, "loss": loss, "norm": norm}
    if ahac is not None:
        modules["ahac"] = ahac
    optimizers = {"actor": actor_opt, "critic": critic_opt}
    smoothness = _smoothness(cfg, actor)
    best = BestPolicy(modules, optimizers, cfg.algo.best_window, cfg.algo.rollback_drop) if cfg.algo.keep_best else None
    counters = {"skipped_updates": 0, "clipped_adjoints": 0, "nonfinite_gradients": 0,
                "smooth_scale": 1.0 if cfg.algo.smooth_clip_target is None else 0.0}
    with TrainingLoop(run, env, cfg.algo.iterations, modules, optimizers, actor, counters=counters, best=best,
                      dist=dist) as loop:
        counters = loop.counters
        td = loop.start(env.reset())  # a resumed run: the checkpoint's networks, worlds and RNG streams
        while not loop.done:
            frac = 1.0 - loop.progress() if cfg.algo.lr_decay == "linear" else 1.0
            for opt, lr in ((actor_opt, cfg.algo.actor_lr), (critic_opt, cfg.algo.critic_lr)):
                for group in opt.param_groups:
                    group["lr"] = lr * frac
            horizon = ahac.horizon if ahac is not None else cfg.algo.horizon

            # 1. differentiable rollout under the sampled policy (normaliser frozen: its buffers are constants)
            with set_exploration_type(ExplorationType.RANDOM):
                rollout = env.rollout(horizon, actor, auto_reset=False, break_when_any_done=False, tensordict=td)
            if ahac is not None:
                ahac.update_from_rollout(rollout)
                if cfg.algo.truncate:
                    rollout = ahac.truncate_rollout(rollout)

            # 2. actor: backpropagate the short-horizon return through the simulator
            actor_opt.zero_grad()
            loss_actor = loss.actor_loss(rollout)
            with env.counting_gradients() as counted:
                loss_actor.backward()
            # world-steps whose adjoint was capped (adjoint_clip), and whose gradient was not finite (set to zero)
            clipped, nonfinite = (int(counted[key].sum()) for key in GRADIENT_COUNTS)
            counters["clipped_adjoints"] += clipped
            counters["nonfinite_gradients"] = counters.get("nonfinite_gradients", 0) + nonfinite
            if nonfinite:
                log.warning("iteration %d: %d world-steps of the rollout had a non-finite gradient (set to zero)",
                            counters["iteration"], nonfinite)
            dist.average_gradients(actor.parameters())
            grad_norm = float(torch.nn.utils.clip_grad_norm_(actor.parameters(), cfg.algo.grad_norm))
            # share of world-steps whose adjoint was capped, averaged over ranks: rising shares went with the
            # runs that failed (docs/devnotes.md), and the smoothness penalty's dual follows it
            share = float(dist.mean(torch.tensor(clipped / rollout.numel(), dtype=torch.float64)))
            counters["smooth_scale"] = _smooth_scale(cfg.algo, counters["smooth_scale"], share)
            if ahac is not None:  # the next rollout's horizon follows the capped share too (horizon_clip_target)
                ahac.update_clip_share(share)
            smooth = None
            if not (grad_norm == grad_norm) or grad_norm > cfg.algo.skip_grad_norm:  # NaN or huge: skip, count
                counters["skipped_updates"] += 1
                actor_opt.zero_grad()
            else:
                if smoothness is not None and counters["smooth_scale"] > 0:  # after the clip, so an exploding
                    smooth = smoothness(rollout)                               # SHAC gradient cannot drown it
                    (counters["smooth_scale"] * (cfg.algo.smooth_temporal * smooth["loss_smooth_temporal"]
                                                 + cfg.algo.smooth_spatial * smooth["loss_smooth_spatial"])).backward()
                    dist.average_gradients(actor.parameters())
                actor_opt.step()

            # 3. observation statistics, outside the graph; 4. critic on the detached rollout
            dist.update_norm(norm, rollout.get("observation"))
            data = loss.critic_targets(rollout).reshape(-1)
            critic_losses = loss.fit_critic(data, critic_opt, cfg.algo.critic_iterations, cfg.algo.critic_minibatches,
                                            on_gradients=lambda: dist.average_gradients(critic.parameters())).tolist()
            updater.step()
            td = next_rollout_start(env, rollout)

            # 5. the iteration's row; the loop's end logs, checkpoints, evaluates, rolls back and stops
            counters["iteration"] += 1
            counters["env_steps"] += rollout.numel() * dist.world_size
            row = _iteration_metrics(rollout, counters, loss_actor, critic_losses, grad_norm, horizon, dist)
            row["clip_share"] = share
            if ahac is not None:
                row["ahac_contact"] = float(ahac.last_contact)  # the statistic AHAC's dual compares with C-bar
            if smoothness is not None:
                row["smooth_scale"] = counters["smooth_scale"]
            if smooth is not None:
                row["smooth_temporal"] = float(smooth["loss_smooth_temporal"].detach())
                row["smooth_spatial"] = float(smooth["loss_smooth_spatial"].detach())
            loop.end_iteration(row, worlds=td)
        return loop.finish(skipped_updates=counters["skipped_updates"])


def _smoothness(cfg, actor) -> PolicySmoothnessLoss | None:
    """The CAPS penalty on the actor's mean action when either weight is positive."""
    if not (cfg.algo.smooth_temporal > 0 or cfg.algo.smooth_spatial > 0):
        return None
    sigma = cfg.algo.smooth_sigma if cfg.algo.smooth_spatial > 0 else 0.0
    return PolicySmoothnessLoss(actor[0], spatial_sigma=sigma)  # actor[0] writes loc (pre-tanh mean)


def _smooth_scale(algo, scale: float, share: float) -> float:
    """The smoothness weights' factor in [0, 1]: 1 without ``smooth_clip_target``; otherwise a dual variable
    that rises while this iteration's clipped-adjoint share is above the target and falls below it. The
    failing runs' share rose from ~0.1 % to 3-10 % as their policies became jumpy, while a fixed penalty
    slowed the runs that learnt (docs/devnotes.md, training), so the penalty acts only in that regime."""
    if algo.smooth_clip_target is None:
        return 1.0
    return min(1.0, max(0.0, scale + algo.smooth_dual_lr * (share - algo.smooth_clip_target)))


def _iteration_metrics(rollout, counters, loss_actor, critic_losses, grad_norm, horizon, dist) -> dict:
    nxt = rollout.get("next")
    done = nxt.get("done").squeeze(-1)
    success = nxt.get("success").squeeze(-1)
    finished = dist.sum(torch.tensor([float(done.sum()), float((success & done).sum())]))
    row = {
        "reward": float(dist.mean(nxt.get("reward").detach().mean())),
        "episode_success": float(finished[1] / finished[0]) if finished[0] > 0 else float("nan"),
        "loss_actor": float(loss_actor.detach()),
        "loss_critic": sum(critic_losses) / max(len(critic_losses), 1),
        "grad_norm": grad_norm,
        "horizon": horizon,
        "skipped_updates": counters["skipped_updates"],
        "clipped_adjoints": counters["clipped_adjoints"],
        "nonfinite_gradients": counters.get("nonfinite_gradients", 0),
        "sim_failures": int(nxt.get(("info", "sim_failures")).sum()),
    }
    if "reward_terms" in nxt.keys():
        for name, value in nxt.get("reward_terms").items():
            row[f"reward_{name}"] = float(value.detach().mean())
    return row


def load_policy(data: dict, env):
    """The actor (with its observation normaliser) of a SHAC / AHAC checkpoint ``data`` on ``env``'s specs."""
    algo = data["config"]["algo"]
    actor, _, norm = make_networks(env.observation_spec["observation"].shape[-1], env.action_spec.shape[-1],
                                   tuple(algo["hidden"]), algo["init_log_std"],
                                   layer_norm=algo.get("layer_norm", False))
    actor.load_state_dict(data["modules"]["actor"])
    norm.load_state_dict(data["modules"]["norm"])
    return actor
