"""``dexmots-eval``: run N episodes of a trained policy deterministically and report success.

    dexmots-eval runs/screw_claw_ahac_seed0                       # its checkpoints/last.pt, 100 episodes
    dexmots-eval runs/screw_claw_ahac_seed0/checkpoints/last.pt --episodes 200 --out eval.json
    dexmots-eval runs/screw_claw_ahac_seed0 --record eval.mcap      # + dexmots-view eval.mcap

Every episode is one world of a non-differentiable env built from the checkpoint's task config, run for
``max_episode_steps`` steps with the deterministic policy (the tanh of the Gaussian's mean). Success is
the task's success flag at the last step (screw_claw: final |θ − θ*| below 0.1 rad, the paper's ε_task);
the final pose error is ``‖achieved_goal − goal‖`` at the last step; time to success is the first step
at which the flag was set, over the successful episodes.

Example:
    >>> from omegaconf import OmegaConf
    >>> from dexmots_rl.trainers.evaluate import evaluate_policy
    >>> from dexmots_rl.trainers.networks import make_networks
    >>> task = OmegaConf.create({"name": "screw_claw", "goal": "pose", "goal_horizon": 8, "action": "position",
    ...                          "max_episode_steps": 5})
    >>> actor, _, _ = make_networks(18, 4, (16,))
    >>> sorted(evaluate_policy(actor, task, episodes=2, seed=0))[:3]
    ['episodes', 'mean_final_error', 'mean_time_to_success_s']
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

from ..envs import make_env

__all__ = ["TASK_ENV_KEYS", "make_task_env", "evaluate_policy", "policy_from_checkpoint", "main"]

log = logging.getLogger(__name__)

# task config fields that are env keyword arguments (the rest, e.g. num_envs, are the trainer's)
TASK_ENV_KEYS = ("goal", "goal_horizon", "action", "max_episode_steps", "damping_range", "friction_range",
                 "references", "reward", "initial", "ramp_steps", "pose_scale", "torque_scale",
                 "reference_torque")


def make_task_env(task_cfg, num_envs: int, differentiable: bool, seed: int, device="cpu",
                  adjoint_clip: float | None = None):
    """``make_env`` from a task config (hydra ``task`` group); unknown names fail with the field named.
    ``adjoint_clip``: the simulator's outlier-world gradient clip (a training option, :class:`~dexmots_rl.sim.Simulator`)."""
    from omegaconf import OmegaConf

    cfg = OmegaConf.to_container(task_cfg, resolve=True) if not isinstance(task_cfg, dict) else dict(task_cfg)
    kwargs = {k: cfg[k] for k in TASK_ENV_KEYS if cfg.get(k) is not None}
    for key in ("damping_range", "friction_range"):
        if key in kwargs:
            kwargs[key] = tuple(kwargs[key])
    if adjoint_clip is not None:
        kwargs["adjoint_clip"] = adjoint_clip
    return make_env(cfg["name"], num_envs=num_envs, device=device, differentiable=differentiable, seed=seed,
                    **kwargs)


@torch.no_grad()
def evaluate_policy(actor, task_cfg, episodes: int = 100, seed: int = 12345, device="cpu", record=None,
                    record_worlds: int = 8, live: bool = False) -> dict:
    """Success rate, mean final error and mean time to success over ``episodes`` deterministic episodes.

    ``record``: an MCAP path; the first ``record_worlds`` episodes are written there (``live``: the file is
    rewritten after every evaluation, for ``dexmots-view --live``; see :mod:`dexmots_rl.viz`)."""
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    env = make_task_env(task_cfg, episodes, differentiable=False, seed=seed, device=device)
    base = env.base_env
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        rollout = env.rollout(base.max_episode_steps, actor, auto_reset=False, break_when_any_done=False,
                              tensordict=env.reset())
    if record is not None:
        _record(task_cfg, rollout, record, record_worlds, live)
    nxt = rollout.get("next")
    success = nxt.get("success").squeeze(-1)  # [N, T]
    final_error = (nxt.get("achieved_goal")[:, -1] - nxt.get(("task", "goal"))[:, -1]).norm(dim=-1)
    won = success[:, -1]
    first = torch.where(success.any(-1), success.float().argmax(-1), torch.full_like(won, -1, dtype=torch.long))
    tts = (first[won] + 1).float() * base.sim.dt
    return {
        "success_rate": float(won.float().mean()),
        "episodes": episodes,
        "mean_final_error": float(final_error.mean()),
        "mean_time_to_success_s": float(tts.mean()) if won.any() else float("nan"),
        "sim_failures": int(nxt.get(("info", "sim_failures"))[:, -1].sum()),
        # where the misses are: the object's joint friction is the parameter that decides most of them
        "success_by_friction": _success_by(rollout.get(("sim", "params"))[:, 0, 1], won),
    }


def _success_by(values: torch.Tensor, won: torch.Tensor, groups: int = 4) -> list[dict]:
    """Success rate in ``groups`` equal-count groups of episodes sorted by ``values`` (quartiles by default)."""
    order = values.argsort()
    return [{"low": float(values[idx].min()), "high": float(values[idx].max()), "episodes": len(idx),
             "success_rate": float(won[idx].float().mean())} for idx in order.chunk(groups)]


_LIVE_RECORDERS: dict = {}


def _record(task_cfg, rollout, path, worlds: int, live: bool) -> None:
    from ..viz import EpisodeRecorder

    worlds = min(worlds, rollout.shape[0])
    # the recorder needs an env of exactly the recorded worlds (scene geometry, references)
    small = make_task_env(task_cfg, worlds, differentiable=False, seed=0)
    if live:  # one recorder per file, so the viewer sees every evaluation as a new episode
        rec = _LIVE_RECORDERS.get(str(path)) or EpisodeRecorder(path, small, live=True)
        _LIVE_RECORDERS[str(path)] = rec
        rec.record_rollout(rollout[:worlds])
        return
    with EpisodeRecorder(path, small) as rec:
        rec.record_rollout(rollout[:worlds])


def policy_from_checkpoint(path, device="cpu"):
    """``(actor, checkpoint dict)`` rebuilt from a checkpoint file or a run directory."""
    from .checkpoint import latest_checkpoint, load_checkpoint
    from .networks import make_networks

    path = Path(path)
    data = load_checkpoint(latest_checkpoint(path) if path.is_dir() else path)
    cfg = data["config"]
    env = make_task_env(cfg["task"], 1, differentiable=False, seed=0, device=device)
    actor, critic, norm = make_networks(env.observation_spec["observation"].shape[-1], env.action_spec.shape[-1],
                                        tuple(cfg["algo"]["hidden"]), cfg["algo"]["init_log_std"],
                                        layer_norm=cfg["algo"].get("layer_norm", False))
    actor.load_state_dict(data["modules"]["actor"])
    norm.load_state_dict(data["modules"]["norm"])
    return actor, data


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="dexmots-eval", description=__doc__.splitlines()[0])
    p.add_argument("checkpoint", help="a checkpoint file or a run directory")
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--seed", type=int, default=12345)
    p.add_argument("--device", default="cpu")
    p.add_argument("--out", default=None, help="JSON file (default: <run dir>/eval.json)")
    p.add_argument("--record", default=None, help="also write the first --record-worlds episodes to this MCAP file")
    p.add_argument("--record-worlds", type=int, default=8)
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(asctime)s %(message)s")
    from .checkpoint import CheckpointError

    try:
        actor, data = policy_from_checkpoint(args.checkpoint, args.device)
        result = {"task": data["task"], "algo": data["algo"], "iteration": data["iteration"],
                  **evaluate_policy(actor, data["config"]["task"], args.episodes, args.seed, args.device,
                                     record=args.record, record_worlds=args.record_worlds)}
    except (CheckpointError, ValueError) as e:
        raise SystemExit(f"dexmots-eval: {e}") from None
    src = Path(args.checkpoint)
    out = Path(args.out) if args.out else (src if src.is_dir() else src.parent.parent) / "eval.json"
    out.write_text(json.dumps(result, indent=2))
    print(json.dumps(result))


if __name__ == "__main__":
    main()
