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
collapse of training success (``algo.keep_best``, :mod:`.best_policy`). The run directory every method
writes (:class:`~.rundir.RunDirectory`) gets the resolved config, torchrl logger output, ``metrics.jsonl``
(one line per iteration), checkpoints and, at the end, ``metrics.json`` with the final evaluation
(:mod:`.evaluation`).
"""

from __future__ import annotations

import logging
import signal
import sys
import threading
import warnings

import torch
from omegaconf import DictConfig
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.objectives import SoftUpdate

from ..progress import progress_bar
from ..envs import GRADIENT_COUNTS, make_env
from ..objectives import AdaptiveHorizon, PolicySmoothnessLoss, SHACLoss, next_rollout_start
from .best_policy import BestPolicy
from .checkpoint import restore_rng_states, rng_states
from .budget import RunBudget, TrainingClock
from .distributed import Distributed
from .networks import make_networks
from .rundir import RunDirectory

__all__ = ["build", "load_policy", "train"]

log = logging.getLogger(__name__)


def build(cfg: DictConfig, rank: int = 0):
    """Env, networks, loss, optimisers and the target updater of a run."""
    torch.manual_seed(cfg.seed + rank)
    env = make_env(cfg.task, differentiable=True, seed=cfg.seed + 1000 * rank, device=cfg.device,
                   adjoint_clip=cfg.algo.get("adjoint_clip"))
    obs_dim = env.observation_spec["observation"].shape[-1]
    act_dim = env.action_spec.shape[-1]
    torch.manual_seed(cfg.seed)  # identical initial networks on every rank
    critic_hidden = cfg.algo.get("critic_hidden")
    actor, critic, norm = make_networks(obs_dim, act_dim, tuple(cfg.algo.hidden), cfg.algo.init_log_std,
                                        layer_norm=cfg.algo.layer_norm,
                                        critic_hidden=None if critic_hidden is None else tuple(critic_hidden))
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
                               cfg.algo.dual_lr, horizon_init=cfg.algo.horizon)
    torch.manual_seed(cfg.seed + rank)
    return env, actor, critic, norm, loss, updater, actor_opt, critic_opt, ahac


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
    with RunDirectory(cfg, overrides, main=dist.is_main) as run, _StopOnSignal() as stop:
        return _train(run, dist, stop)


class _StopOnSignal:
    """SIGINT/SIGTERM while training: finish the iteration, checkpoint, return (no traceback); a second
    signal interrupts at once. Only the main thread can install handlers; elsewhere this is a no-op."""

    def __init__(self):
        self.signal, self._old = None, {}

    def _handle(self, signum, frame):
        if self.signal is not None:
            raise KeyboardInterrupt
        self.signal = signal.Signals(signum).name
        log.warning("%s: stopping after this iteration with a checkpoint (again to abort)", self.signal)

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._old[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc):
        for sig, handler in self._old.items():
            signal.signal(sig, handler)


def _train(run: RunDirectory, dist, stop) -> dict:
    cfg, start = run.cfg, run.start
    env, actor, critic, norm, loss, updater, actor_opt, critic_opt, ahac = build(cfg, dist.rank)
    modules = {"actor": actor, "critic": critic, "loss": loss, "norm": norm}
    if ahac is not None:
        modules["ahac"] = ahac
    optimizers = {"actor": actor_opt, "critic": critic_opt}
    smoothness = _smoothness(cfg, actor)
    best = BestPolicy(modules, optimizers, cfg.algo.best_window, cfg.algo.rollback_drop) if cfg.algo.keep_best else None
    counters = {"iteration": 0, "env_steps": 0, "skipped_updates": 0, "clipped_adjoints": 0, "nonfinite_gradients": 0,
                "wall_clock_s": 0.0, "cpu_s": 0.0,
                "smooth_scale": 1.0 if cfg.algo.smooth_clip_target is None else 0.0}
    td = env.reset()
    if start is not None:
        for name, module in modules.items():
            module.load_state_dict(start["modules"][name])
        for name, opt in optimizers.items():
            opt.load_state_dict(start["optimizers"][name])
        counters.update(start["counters"])
        if best is not None and start.get("best") is not None:
            best.load_state_dict(start["best"])
        td = TensorDict.from_dict(start["env_state"], batch_size=td.batch_size)
        restore_rng_states(env, start["rng"])
    iterations = cfg.algo.iterations
    bar = progress_bar(total=iterations, initial=counters["iteration"], desc=f"{cfg.algo.name} {cfg.task.name}",
                       disable=not (cfg.progress and dist.is_main), file=sys.stderr)
    clock = TrainingClock(counters)
    stop_at = min(iterations, cfg.stop_after) if cfg.stop_after else iterations
    budget, stopped_by = RunBudget.from_config(cfg), None
    interrupted = False
    while counters["iteration"] < stop_at and not interrupted and stopped_by is None:
        it = counters["iteration"]
        frac = 1.0 - budget.progress(counters, it / iterations) if cfg.algo.lr_decay == "linear" else 1.0
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
        before = env.base_env.gradient_counts()
        loss_actor.backward()
        # world-steps whose adjoint was capped (adjoint_clip), and whose gradient was not finite (set to zero)
        after = env.base_env.gradient_counts()
        clipped, nonfinite = (int((after[key] - before[key]).sum()) for key in GRADIENT_COUNTS)
        counters["clipped_adjoints"] += clipped
        counters["nonfinite_gradients"] = counters.get("nonfinite_gradients", 0) + nonfinite
        if nonfinite:
            log.warning("iteration %d: %d world-steps of the rollout had a non-finite gradient (set to zero)",
                        counters["iteration"], nonfinite)
        dist.average_gradients(actor.parameters())
        grad_norm = float(torch.nn.utils.clip_grad_norm_(actor.parameters(), cfg.algo.grad_norm))
        # share of world-steps whose adjoint was capped, averaged over ranks: rising shares went with the runs
        # that failed (docs/devnotes.md), and the smoothness penalty's dual follows it
        share = float(dist.mean(torch.tensor(clipped / rollout.numel(), dtype=torch.float64)))
        counters["smooth_scale"] = _smooth_scale(cfg.algo, counters["smooth_scale"], share)
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

        # 5. bookkeeping; every rank sees a signal one rank got, so all stop at the same iteration
        interrupted = bool(dist.sum(torch.tensor([float(stop.signal is not None)])) > 0)
        counters["iteration"] += 1
        counters["env_steps"] += rollout.numel() * dist.world_size
        clock.read(counters)
        # the main rank's clock decides (the others' include its evaluations) and every rank stops with it
        over = budget.reached(counters) if dist.is_main else None
        if dist.sum(torch.tensor([float(over is not None)])) > 0:
            stopped_by = over or "wall_clock_s"
        row = _iteration_metrics(rollout, counters, loss_actor, critic_losses, grad_norm, horizon, dist)
        row["clip_share"] = share
        if ahac is not None:
            row["ahac_contact"] = float(ahac.last_contact)  # the statistic AHAC's dual compares with C-bar
        if smoothness is not None:
            row["smooth_scale"] = counters["smooth_scale"]
        if smooth is not None:
            row["smooth_temporal"] = float(smooth["loss_smooth_temporal"].detach())
            row["smooth_spatial"] = float(smooth["loss_smooth_spatial"].detach())
        if best is not None:  # every rank sees the same (summed) success, so all roll back together
            best.observe(row["episode_success"])
            row["rollbacks"] = best.rollbacks
        bar.update(1)
        bar.set_postfix(fps=f"{row['env_steps'] / max(row['wall_clock_s'], 1e-9):.0f}",
                        reward=f"{row['reward']:.3f}", success=f"{row['episode_success']:.2f}")
        if dist.is_main:
            run.log(row)
            last = counters["iteration"] == stop_at or stopped_by is not None
            if last or interrupted or counters["iteration"] % cfg.checkpoint_every == 0:
                _save(run, counters, modules, optimizers, td, env, best)
            if cfg.eval.every and counters["iteration"] % cfg.eval.every == 0 and not last:
                with clock.paused():  # evaluation is not training time (the budget's clock)
                    run.evaluate(actor, counters, final=False)
    bar.close()
    result = {}
    if interrupted:
        result = {"interrupted": stop.signal or "signal", "iteration": counters["iteration"], "run_dir": str(run.dir)}
    if dist.is_main and (counters["iteration"] == iterations or stopped_by is not None) and not interrupted:
        final_policy = _final_policy(best)
        if final_policy["source"] == "best":  # the checkpoint holds the policy that is evaluated
            _save(run, counters, modules, optimizers, td, env, best)
        result = run.evaluate(actor, counters, budget=budget.record(stopped_by),
                              skipped_updates=counters["skipped_updates"], final_policy=final_policy)
    dist.close()
    return result


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


def _final_policy(best: BestPolicy | None) -> dict:
    """Which policy the final evaluation gets. With rollbacks on, the last one (a collapse was already
    rolled back while training); with ``rollback_drop: null``, the best one when its training success
    beats the last window's."""
    if best is None:
        return {"source": "last"}
    record = {"best_train_success": best.best_score if best.best_iteration is not None else None,
              "best_iteration": best.best_iteration, "rollbacks": best.rollbacks, "source": "last"}
    if best.rollback_drop is None and best.best_iteration is not None and not best.score >= best.best_score:
        best.restore()
        record["source"] = "best"
    return record


def _iteration_metrics(rollout, counters, loss_actor, critic_losses, grad_norm, horizon, dist) -> dict:
    nxt = rollout.get("next")
    done = nxt.get("done").squeeze(-1)
    success = nxt.get("success").squeeze(-1)
    finished = dist.sum(torch.tensor([float(done.sum()), float((success & done).sum())]))
    row = {
        "iteration": counters["iteration"],
        "env_steps": counters["env_steps"],
        "wall_clock_s": round(counters["wall_clock_s"], 3),
        "cpu_s": round(counters.get("cpu_s", 0.0), 3),
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


def _save(run: RunDirectory, counters, modules, optimizers, td, env, best=None) -> None:
    """A checkpoint that resumes bit-identically on CPU: the env's state and both RNG streams too."""
    run.checkpoint(counters, modules, optimizers, env_state=td.detach().to_dict(),
                   rng=rng_states(env),
                   best=best.state_dict() if best is not None else None)


def load_policy(data: dict, env):
    """The actor (with its observation normaliser) of a SHAC / AHAC checkpoint ``data`` on ``env``'s specs."""
    algo = data["config"]["algo"]
    actor, _, norm = make_networks(env.observation_spec["observation"].shape[-1], env.action_spec.shape[-1],
                                   tuple(algo["hidden"]), algo["init_log_std"],
                                   layer_norm=algo.get("layer_norm", False))
    actor.load_state_dict(data["modules"]["actor"])
    norm.load_state_dict(data["modules"]["norm"])
    return actor
