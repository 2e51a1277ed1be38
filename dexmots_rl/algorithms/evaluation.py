"""Evaluation: N episodes of a policy, deterministically, and their success (``dexmots-eval``).

Every episode is one world of a non-differentiable env built from the checkpoint's task config, run for
``max_episode_steps`` steps with the deterministic policy (the tanh of the Gaussian's mean). Success is
the task's success flag at the last step (screw_claw: final |θ − θ*| below 0.1 rad, the paper's ε_task), in an
episode that never terminated (repose_cube: the cube never dropped); the final pose error is
``‖achieved_goal − goal‖`` at the last step; time to success is the first step at which the flag was set,
over the successful episodes. ``success_by_<name>`` breaks the success rate down by quartiles of each
randomised parameter the task names (``DexEnv.breakdowns``, e.g. the knob's joint friction, or repose_cube's
goal angle), or by its values when it takes four or fewer (one per object variant, with its ``label``).

Example:
    >>> from omegaconf import OmegaConf
    >>> from dexmots_rl.algorithms.evaluation import evaluate_policy
    >>> from dexmots_rl.algorithms.networks import make_networks
    >>> task = OmegaConf.create({"name": "screw_claw", "goal": "pose", "action": "position", "max_episode_steps": 5})
    >>> actor, _, _ = make_networks(18, 4, (16,))
    >>> sorted(evaluate_policy(actor, task, episodes=2, seed=0))[:3]
    ['episodes', 'mean_final_error', 'mean_time_to_success_s']
"""

from __future__ import annotations

import logging

import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

from ..envs import make_env

__all__ = ["evaluate_policy", "periodic_episodes"]

log = logging.getLogger(__name__)


@torch.no_grad()
def evaluate_policy(actor, task_cfg, episodes: int = 100, seed: int = 12345, device="cpu", record=None,
                    record_worlds: int = 8, live: bool = False) -> dict:
    """Success rate, mean final error and mean time to success over ``episodes`` deterministic episodes.

    ``record``: an MCAP path; the first ``record_worlds`` episodes are written there (``live``: the file is
    rewritten after every evaluation, for ``dexmots-view --live``; see :mod:`dexmots_rl.recording`)."""
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    env = make_env(task_cfg, num_envs=episodes, differentiable=False, seed=seed, device=device)
    base = env.base_env
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        rollout = env.rollout(base.max_episode_steps, actor, auto_reset=False, break_when_any_done=False,
                              tensordict=env.reset())
    if record is not None:
        _record(task_cfg, rollout, record, record_worlds, live)
    nxt = rollout.get("next")
    success = nxt.get("success").squeeze(-1)  # [N, T]
    final_achieved, final_goal = nxt.get("achieved_goal")[:, -1], nxt.get(("task", "goal"))[:, -1]
    final_error = base.goal_error(final_achieved, final_goal)
    # [N]: no termination (a dropped cube may fall still turned as the goal asks; without a reset its world
    # steps on, and a blown-up world is reset and may succeed from its fresh start): such an episode failed
    kept = ~nxt.get("terminated").squeeze(-1).any(-1)
    won = success[:, -1] & kept
    first = torch.where(success.any(-1), success.float().argmax(-1), torch.full_like(won, -1, dtype=torch.long))
    tts = (first[won] + 1).float() * base.dt
    return {
        "success_rate": float(won.float().mean()),
        "episodes": episodes,
        "mean_final_error": float(final_error.mean()),
        "mean_time_to_success_s": float(tts.mean()) if won.any() else float("nan"),
        "sim_failures": int(nxt.get(("info", "sim_failures"))[:, -1].sum()),
        **{f"success_rate_{name}": float((test(base, final_achieved, final_goal) & kept).float().mean())
           for name, test in base.extra_success.items()},
        # where the misses are, by the task's randomised parameters (e.g. the knob's friction)
        **{f"success_by_{name}": _success_by(_episode_values(base, rollout, key), won,
                                              labels=base.breakdown_labels.get(name))
           for name, key in base.breakdowns.items()},
    }


def periodic_episodes(eval_cfg) -> int:
    """Episodes of an evaluation during training: ``eval.curve_episodes`` (learning curves can be cheaper
    than the final evaluation) or, when null, ``eval.episodes``."""
    return eval_cfg.get("curve_episodes") or eval_cfg.episodes


def _episode_values(env, rollout, key) -> torch.Tensor:
    """[N] per-episode values of a breakdown: a key read at the first step, or ``key(env, first step)``."""
    if callable(key):
        return key(env, rollout[:, 0]).reshape(-1)
    return rollout.get(key)[:, 0].reshape(-1)


def _success_by(values: torch.Tensor, won: torch.Tensor, groups: int = 4, labels=None) -> list[dict]:
    """Success rate in ``groups`` equal-count groups of episodes sorted by ``values`` (quartiles by default), or,
    for a parameter with ``labels`` (a category: value i is ``labels[i]``, e.g. an object variant) or with at
    most ``groups`` distinct values, in one group per value."""
    distinct = values.unique()
    if labels is not None or len(distinct) <= groups:
        rows = []
        for value in distinct:
            mask = values == value
            row = {"low": float(value), "high": float(value), "episodes": int(mask.sum()),
                   "success_rate": float(won[mask].float().mean())}
            rows.append({"label": labels[int(value)], **row} if labels is not None else row)
        return rows
    order = values.argsort()
    return [{"low": float(values[idx].min()), "high": float(values[idx].max()), "episodes": len(idx),
             "success_rate": float(won[idx].float().mean())} for idx in order.chunk(groups)]


_LIVE_RECORDERS: dict = {}


def _record(task_cfg, rollout, path, worlds: int, live: bool) -> None:
    from ..recording import EpisodeRecorder

    worlds = min(worlds, rollout.shape[0])
    # the recorder needs an env of exactly the recorded worlds (scene geometry, references)
    small = make_env(task_cfg, num_envs=worlds, differentiable=False, seed=0)
    if live:  # one recorder per file, so the viewer sees every evaluation as a new episode
        rec = _LIVE_RECORDERS.get(str(path)) or EpisodeRecorder(path, small, live=True)
        _LIVE_RECORDERS[str(path)] = rec
        rec.record_rollout(rollout[:worlds])
        return
    with EpisodeRecorder(path, small) as rec:
        rec.record_rollout(rollout[:worlds])
