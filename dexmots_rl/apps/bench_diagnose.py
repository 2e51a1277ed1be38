"""``dexmots-bench diagnose``: what the gradient through the simulator tells a task's policy, and which actions the
policy tries, measured on short rollouts of the differentiable env (the env SHAC / AHAC train on).

    dexmots-bench diagnose --task jar --json                                   # the untrained policy
    dexmots-bench diagnose --run runs/jar_ahac_seed0 --json                    # a run's policy (its checkpoint)
    dexmots-bench diagnose --task jar --horizons 1 4 16 32 --num-envs 4 --pairs 32 --start-steps 40 --json

The policy is a run's (its last checkpoint, any method that saves one), or, without ``--run`` or when the run
kept no checkpoint (an archived run), the initial policy training starts from (the run's or the task's default
config, its seed); ``--zero-mean`` uses zero pre-tanh means instead. From ``--num-envs`` start states (resets,
then ``--start-steps`` steps of the policy's mean action), each copied into ``2 --pairs`` worlds, the policy's
mean ``u_t`` (pre-tanh) along its noise-free rollout is fixed, and every world takes the actions
``a_t = tanh(u_t + s * e_t)`` for ``H`` steps, ``s`` the policy's exploration scale. The return
``R = sum_t gamma^t r_t`` (until an episode ends) is differentiated with respect to every action
(open loop: the figures are the simulator's and the reward's, not the network's):

* ``grad_first_median`` / ``_p90``: ``|dR/da_0|`` over the worlds (the first action's effect through ``H`` steps),
  and ``grad_all_*``: ``|dR/da_{0..H-1}|``; ``grad_growth_total`` = median ``|dR/da_0|`` at the longest horizon /
  at the shortest, ``growth_per_step`` its (H_max - H_min)-th root (a return summing H bounded rewards grows at most
  ~H_max / H_min without any amplification by the dynamics), and ``growth_per_step_in_rollout``: exp of the slope of
  ``log |dR/da_t|`` against steps to go at the longest horizon (``bench_grad``'s definition; 1.0: no growth).
* ``capped_share``: world-steps whose adjoint the cap (``algo.adjoint_clip``, the run's) scaled down, over all
  world-steps; ``nonfinite_share``: those whose gradient was not finite (set to zero): the env's own counters.
* First-order against zeroth-order gradient of the smoothed return ``J(u_0) = E[R]`` with respect to the first
  mean ``u_0``: FO = mean of ``dR/du_0``; ZO = mean over antithetic pairs (``e_0`` and ``-e_0``, later noise
  shared) of ``(R+ - R-) e_0 / (2 s)``. Both estimate the same gradient; ``fo_zo_cosine`` and
  ``fo_zo_norm_ratio`` (``|FO| / |ZO|``) say whether the first-order gradient follows the smoothed return.
  A finite sample bounds the cosine even for an exact gradient: ``zo_self_cosine`` is the cosine between the ZO
  estimates of the two halves of the pairs, and ``cosine_ceiling = sqrt(2 c / (1 + c))`` what an exact FO would
  reach (Spearman-Brown); ``fo_self_cosine`` likewise for FO (low: its variance, not its bias, dominates).
  Medians over the start states.
* ``exploration``: per action entry, the share of sampled actions within 0.05 of +1 and of -1; for ``vi``
  actions, per stiffness channel the share at its stiff end (> 0.95), the share of its range it visits
  (``coverage``: of 10 equal bins, those holding >= 1 % of the steps) and the share of steps with two or more
  channels at the stiff end at once.
* ``training_log`` (a run directory with ``metrics.jsonl``): the share of capped adjoints, the gradient norm
  and the horizon along training (quartiles over iterations), as the run logged them.
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import torch
from omegaconf import OmegaConf
from torchrl.envs.utils import step_mdp

from .bench_grad import growth_per_step

__all__ = ["NEAR_BOUND", "adjoint_clip_option", "diagnose", "fo_zo_agreement", "load_policy_source",
           "training_log_summary"]

log = logging.getLogger(__name__)

NEAR_BOUND = 0.05  # an action within this of +-1 is at the end of its range (the stiff end of a vi channel)
COVERAGE_BINS = 10
COVERAGE_MIN_SHARE = 0.01


def adjoint_clip_option(text: str) -> float | str | None:
    """``--adjoint-clip``: ``"run"``, ``"none"`` (exact gradients) or a number >= 1."""
    if text in ("run", "none"):
        return None if text == "none" else text
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not value >= 1.0:
        raise ValueError(f"--adjoint-clip must be 'run', 'none' or a number >= 1, got {text!r}")
    return value


def _quantiles(x: torch.Tensor) -> dict:
    x = x.double().flatten()
    return {"median": float(x.median()), "p90": float(torch.quantile(x, 0.9))}


def _initial_config(task: str):
    """dexmots-train's composed config for ``task`` (its default method)."""
    from hydra import compose, initialize_config_dir

    from .train import CONFIG_DIR

    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return compose("config", overrides=[f"task={task}"])


def load_policy_source(task: str | None, run: str | None, zero_mean: bool) -> tuple[dict, dict, object, dict]:
    """``(task config, algo config, policy or None, description)`` of what is diagnosed; the policy maps a
    TensorDict with ``"observation"`` to one with ``"loc"`` and ``"scale"`` (pre-tanh)."""
    from ..algorithms.checkpoint import load_checkpoint
    from ..algorithms.networks import make_networks
    from ..algorithms.registry import policy_from_checkpoint
    from ..algorithms.shac import initial_action
    from ..envs import make_env

    source = {"run": run}
    data = None
    if run is not None:
        path = Path(run)
        if not path.exists():
            raise ValueError(f"--run {run}: no such run directory or checkpoint")
        checkpoint = path if path.is_file() else path / "checkpoints" / "last.pt"
        if checkpoint.is_file():
            data = load_checkpoint(checkpoint)
            cfg = OmegaConf.create(data["config"])
        elif (path / "config.yaml").is_file():
            cfg = OmegaConf.load(path / "config.yaml")
        else:
            raise ValueError(f"--run {run}: neither a checkpoint (checkpoints/last.pt) nor a config.yaml")
        if task is not None and task != cfg.task.name:
            raise ValueError(f"--task {task}: the run {run} trained task {cfg.task.name!r}")
    else:
        if task is None:
            raise ValueError("--task: give a registered task (or --run)")
        cfg = _initial_config(task)
    task_cfg, algo = OmegaConf.to_container(cfg.task, resolve=True), OmegaConf.to_container(cfg.algo, resolve=True)
    if zero_mean:
        source.update(policy="zero-mean", checkpoint=None)
        return task_cfg, algo, None, source
    if data is not None:
        policy, _ = policy_from_checkpoint(checkpoint)
        source.update(policy=f"{data.get('algo')} checkpoint", checkpoint=str(checkpoint),
                      iteration=data.get("counters", {}).get("iteration"))
        return task_cfg, algo, policy, source
    env = make_env(task_cfg, num_envs=1, differentiable=False, seed=0)
    torch.manual_seed(cfg.seed)  # the initial networks of the run (or of a fresh one)
    actor, _, _ = make_networks(env.observation_spec["observation"].shape[-1], env.action_spec.shape[-1],
                                tuple(algo["hidden"]), algo["init_log_std"], layer_norm=algo.get("layer_norm", True),
                                critic_hidden=None, init_action=initial_action(env, algo))
    source.update(policy=f"initial ({algo['name']}, seed {cfg.seed})", checkpoint=None)
    if run is not None:
        log.warning("diagnose: %s holds no checkpoint; the initial policy of its config is diagnosed", run)
    return task_cfg, algo, actor, source


def _mean_and_scale(policy, td, action_dim: int, log_std: float) -> tuple[torch.Tensor, torch.Tensor]:
    if policy is None:
        shape = (td.batch_size[0], action_dim)
        return torch.zeros(shape, dtype=torch.float32), torch.full(shape, math.exp(log_std), dtype=torch.float32)
    out = policy(td.clone())
    return out.get("loc").detach(), out.get("scale").detach()


def _cosine(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return (a * b).sum(-1) / (a.norm(dim=-1) * b.norm(dim=-1)).clamp_min(1e-30)


def fo_zo_agreement(fo: torch.Tensor, ret: torch.Tensor, noise: torch.Tensor, scale: torch.Tensor) -> dict:
    """First- against zeroth-order estimates of the smoothed return's gradient, per start state.

    ``fo`` [B, K, 2, D]: ``dR/du`` of each world (pair k, sign + then -); ``ret`` [B, K, 2]: the returns;
    ``noise`` [B, K, D]: ``e`` of the + world (the - world took ``-e``); ``scale`` [B, D]: ``s``. Returns the
    medians over the B states (module docstring)."""
    pairs = ret.shape[1]
    zo_pair = (ret[:, :, 0] - ret[:, :, 1]).unsqueeze(-1) * noise / (2 * scale.unsqueeze(1))  # [B, K, D]
    fo_pair = fo.mean(2)
    zo, fo_mean = zo_pair.mean(1), fo_pair.mean(1)
    half = pairs // 2
    zo_self = _cosine(zo_pair[:, :half].mean(1), zo_pair[:, half:].mean(1))
    fo_self = _cosine(fo_pair[:, :half].mean(1), fo_pair[:, half:].mean(1))
    ceiling = torch.sqrt((2 * zo_self / (1 + zo_self)).clamp_min(0.0))
    ratio = fo_mean.norm(dim=-1) / zo.norm(dim=-1).clamp_min(1e-30)
    return {"fo_zo_cosine": float(_cosine(fo_mean, zo).median()), "fo_zo_norm_ratio": float(ratio.median()),
            "zo_self_cosine": float(zo_self.median()), "fo_self_cosine": float(fo_self.median()),
            "cosine_ceiling": float(ceiling.median()), "fo_norm": float(fo_mean.norm(dim=-1).median()),
            "zo_norm": float(zo.norm(dim=-1).median())}


def _groups_share_leader(td, starts: int, group: int):
    """Every world of a group of ``group`` consecutive worlds takes its first world's state."""
    return td.apply(lambda x: x.reshape(starts, group, *x.shape[1:])[:, :1].expand(starts, group, *x.shape[1:])
                    .reshape(x.shape).clone())


def _rollout(env, start, means, scale, noise, gamma: float):
    """Steps ``env`` from ``start`` with ``a_t = tanh(means[t] + scale * noise[t])`` (leaves with gradients);
    returns (discounted return [W] with the graph, actions [H, W, D])."""
    td, ret, alive = start.clone(), 0.0, torch.ones(start.batch_size[0])
    actions = []
    for t in range(len(noise)):
        action = torch.tanh(means[t] + scale * noise[t]).detach().requires_grad_(True)
        actions.append(action)
        td = env.step(td.set("action", action))
        reward = td.get(("next", "reward")).squeeze(-1)
        ret = ret + gamma ** t * alive * torch.nan_to_num(reward)
        alive = alive * (~td.get(("next", "done")).squeeze(-1)).float()
        td = step_mdp(td)
    return ret, actions


def _exploration(actions: torch.Tensor, nu: int, vi: bool, names: list[str]) -> dict:
    """Where the sampled actions ``[..., D]`` lie in their range (module docstring)."""
    a = actions.reshape(-1, actions.shape[-1]).double()
    near_high, near_low = (a > 1 - NEAR_BOUND).double().mean(0), (a < -1 + NEAR_BOUND).double().mean(0)
    out = {"action_names": names, "share_near_plus_one": near_high.tolist(), "share_near_minus_one": near_low.tolist(),
           "share_any_entry_at_a_bound": float(((a > 1 - NEAR_BOUND) | (a < -1 + NEAR_BOUND)).any(-1).double().mean())}
    if vi:
        stiff = a[:, nu:]
        at_stiff = stiff > 1 - NEAR_BOUND
        bins = ((stiff + 1) / 2 * COVERAGE_BINS).long().clamp(0, COVERAGE_BINS - 1)
        counts = torch.stack([(bins == i).double().mean(0) for i in range(COVERAGE_BINS)])  # [bins, nu]
        out.update(stiffness_share_at_stiff_end=at_stiff.double().mean(0).tolist(),
                   stiffness_coverage=(counts >= COVERAGE_MIN_SHARE).double().mean(0).tolist(),
                   stiffness_median=stiff.median(0).values.tolist(),
                   share_two_or_more_channels_stiff=float((at_stiff.sum(-1) >= 2).double().mean()))
    return out


def training_log_summary(run_dir: Path) -> dict | None:
    """Quartiles over the iterations of a run's ``metrics.jsonl`` (None without one)."""
    path = run_dir / "metrics.jsonl"
    if not path.is_file():
        return None
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    rows = [r for r in rows if "env_steps" in r]  # training rows (evaluation rows lack it)
    if not rows:
        return None
    out = {"iterations_logged": len(rows), "last_iteration": rows[-1]["iteration"]}
    for key in ("clip_share", "grad_norm", "horizon", "episode_success", "ahac_contact"):
        values = torch.tensor([float(r[key]) for r in rows if r.get(key) is not None], dtype=torch.float64)
        values = values[torch.isfinite(values)]
        if len(values):
            q = torch.quantile(values, torch.tensor([0.25, 0.5, 0.75], dtype=torch.float64)).tolist()
            out[key] = {"q25": q[0], "median": q[1], "q75": q[2], "max": float(values.max())}
    for key in ("skipped_updates", "clipped_adjoints", "nonfinite_gradients"):
        if key in rows[-1]:
            out[key] = rows[-1][key]
    metrics = run_dir / "metrics.json"
    if metrics.is_file():
        out["eval_success_rate"] = json.loads(metrics.read_text()).get("success_rate")
    return out


def diagnose(task: str | None = None, run: str | None = None, horizons=(1, 4, 16, 32), num_envs: int = 4,
             pairs: int = 32, start_steps: int = 0, seed: int = 0, zero_mean: bool = False,
             adjoint_clip: float | str | None = "run", device: str = "cpu") -> dict:
    """The diagnosis ``dexmots-bench diagnose`` prints (module docstring). ``adjoint_clip``: ``"run"`` (the run's
    or the default config's ``algo.adjoint_clip``), a number, or None (exact gradients)."""
    from ..envs import GRADIENT_COUNTS, make_env

    horizons = sorted(set(int(h) for h in horizons))
    if not horizons or horizons[0] < 1:
        raise ValueError(f"--horizons must be positive integers, got {horizons}")
    if pairs < 2:
        raise ValueError(f"--pairs must be >= 2 (its two halves give the ZO noise ceiling), got {pairs}")
    if num_envs < 1 or start_steps < 0:
        raise ValueError(f"--num-envs must be >= 1 and --start-steps >= 0, got {num_envs} and {start_steps}")
    task_cfg, algo, policy, source = load_policy_source(task, run, zero_mean)
    clip = algo.get("adjoint_clip") if adjoint_clip == "run" else adjoint_clip
    gamma = float(algo.get("gamma", 0.99))
    group, worlds = 2 * pairs, num_envs * 2 * pairs
    env = make_env(task_cfg, num_envs=worlds, differentiable=True, seed=seed, device=device, adjoint_clip=clip)
    base = env.base_env
    nu, dim = base.scene.num_hand_dofs, env.action_spec.shape[-1]
    vi = base.action_type == "vi"
    joints = list(base.scene.joint_names[:nu])
    names = [f"target:{j}" for j in joints] + [f"stiffness:{j}" for j in joints] if vi else joints
    log.info("diagnose: %s, %d start states x %d worlds, horizons %s, adjoint_clip %s", task_cfg["name"], num_envs,
             group, horizons, clip)
    with torch.no_grad():
        td = _groups_share_leader(env.reset(), num_envs, group)
        for _ in range(start_steps):
            mean, _ = _mean_and_scale(policy, td, dim, algo["init_log_std"])
            td = step_mdp(env.step(td.set("action", torch.tanh(mean))))
        start = td.clone()
        means, scales = [], None
        for _ in range(horizons[-1]):  # the policy's mean along its noise-free rollout (one per start state)
            mean, scale = _mean_and_scale(policy, td, dim, algo["init_log_std"])
            mean = mean.reshape(num_envs, group, dim)[:, :1].expand(num_envs, group, dim).reshape(worlds, dim)
            means.append(mean)
            scales = scale.reshape(num_envs, group, dim)[:, 0] if scales is None else scales
            td = step_mdp(env.step(td.set("action", torch.tanh(mean))))
    scale_w = scales.unsqueeze(1).expand(num_envs, group, dim).reshape(worlds, dim)
    generator = torch.Generator().manual_seed(seed)
    rows, exploration = [], None
    for horizon in horizons:
        noise = torch.randn(horizon, num_envs, pairs, 1, dim, generator=generator).expand(-1, -1, -1, 2, -1).clone()
        noise[0, :, :, 1] *= -1  # antithetic first step; later steps' noise shared within a pair
        noise = noise.reshape(horizon, worlds, dim)
        ret, actions = _rollout(env, start, means, scale_w, noise, gamma)
        with env.counting_gradients() as counted:
            ret.sum().backward()
        capped, nonfinite = (int(counted[key].sum()) for key in GRADIENT_COUNTS)
        grads = torch.stack([a.grad for a in actions])  # [H, W, D]
        first = grads[0].norm(dim=-1)
        per_step = grads.norm(dim=-1).median(1).values.double().clamp_min(1e-30)  # [H]
        fo = grads[0] * (1 - actions[0].detach() ** 2)  # dR/du_0 through the tanh
        agreement = fo_zo_agreement(fo.reshape(num_envs, pairs, 2, dim), ret.detach().reshape(num_envs, pairs, 2),
                                    noise[0].reshape(num_envs, pairs, 2, dim)[:, :, 0], scales)
        row = {"horizon": horizon, "return_median": float(ret.detach().median()),
               **{f"grad_first_{k}": v for k, v in _quantiles(first).items()},
               **{f"grad_all_{k}": v for k, v in _quantiles(grads.permute(1, 0, 2).flatten(1).norm(dim=-1)).items()},
               "capped_share": capped / (worlds * horizon), "nonfinite_share": nonfinite / (worlds * horizon),
               **agreement}
        if horizon > 1:
            row["growth_per_step_in_rollout"] = float(growth_per_step(per_step))
        rows.append(row)
        log.info("diagnose: %s", row)
        exploration = torch.stack([a.detach() for a in actions])
    result = {"task": task_cfg["name"], "action": base.action_type, "source": source, "adjoint_clip": clip,
              "gamma": gamma, "num_envs": num_envs, "pairs": pairs, "worlds": worlds, "start_steps": start_steps,
              "seed": seed, "exploration_scale_median": float(scales.median()), "rows": rows}
    if len(rows) > 1 and rows[-1]["horizon"] > rows[0]["horizon"]:
        ratio = rows[-1]["grad_first_median"] / max(rows[0]["grad_first_median"], 1e-30)
        result["grad_growth_total"] = ratio
        result["growth_per_step"] = ratio ** (1.0 / (rows[-1]["horizon"] - rows[0]["horizon"]))
    result["exploration"] = _exploration(exploration, nu, vi, names)
    if run is not None and Path(run).is_dir():
        result["training_log"] = training_log_summary(Path(run))
    return result
