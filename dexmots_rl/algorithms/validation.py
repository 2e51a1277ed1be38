"""Up-front checks of a training run's config: every numeric field of ``algo`` and the run keys, each
error naming the key, before any env is built or any file is written.

Example:
    >>> from omegaconf import OmegaConf
    >>> cfg = OmegaConf.create({"algo": {"name": "shac", "gamma": 2.0}})
    >>> try:
    ...     validate_run_config(cfg)
    ... except ValueError as e:
    ...     print(e)
    algo.gamma must be in (0, 1], got 2.0
"""

from __future__ import annotations

import math
from typing import Any

__all__ = ["validate_run_config"]


def _number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _integer(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


# key -> (check, what a valid value is); a key absent from the config is skipped (e.g. AHAC-only keys)
_ALGO_RULES = {
    "iterations": (lambda v: _integer(v) and v > 0, "a positive integer"),
    "horizon": (lambda v: _integer(v) and v > 0, "a positive integer"),
    "gamma": (lambda v: _number(v) and 0 < v <= 1, "in (0, 1]"),
    "lmbda": (lambda v: _number(v) and 0 <= v <= 1, "in [0, 1]"),
    "actor_lr": (lambda v: _number(v) and v > 0, "a positive finite number"),
    "critic_lr": (lambda v: _number(v) and v > 0, "a positive finite number"),
    "betas": (lambda v: len(v) == 2 and all(_number(b) and 0 <= b < 1 for b in v), "two numbers in [0, 1)"),
    "lr_decay": (lambda v: v in ("linear", "constant"), "'linear' or 'constant'"),
    "critic_iterations": (lambda v: _integer(v) and v > 0, "a positive integer"),
    "critic_minibatches": (lambda v: _integer(v) and v > 0, "a positive integer"),
    "target_alpha": (lambda v: _number(v) and 0 <= v <= 1, "in [0, 1]"),
    "grad_norm": (lambda v: _number(v) and v > 0, "a positive finite number"),
    "skip_grad_norm": (lambda v: _number(v) and v > 0, "a positive finite number"),
    "hidden": (lambda v: len(v) > 0 and all(_integer(h) and h > 0 for h in v), "a non-empty list of positive integers"),
    "critic_hidden": (lambda v: v is None or (len(v) > 0 and all(_integer(h) and h > 0 for h in v)),
                      "null or a non-empty list of positive integers"),
    "layer_norm": (lambda v: isinstance(v, bool), "true or false"),
    "init_log_std": (lambda v: _number(v) and -20 <= v <= 5, "a finite number in [-20, 5]"),
    "adjoint_clip": (lambda v: v is None or (_number(v) and v >= 1), "null or a number >= 1"),
    "horizon_min": (lambda v: _integer(v) and v > 0, "a positive integer"),
    "horizon_max": (lambda v: _integer(v) and v > 0, "a positive integer"),
    "contact_threshold": (lambda v: _number(v) and v > 0, "a positive finite number"),
    "dual_lr": (lambda v: _number(v) and v > 0, "a positive finite number"),
    "truncate": (lambda v: isinstance(v, bool), "true or false"),
    "keep_best": (lambda v: isinstance(v, bool), "true or false"),
    "best_window": (lambda v: _integer(v) and v > 0, "a positive integer"),
    "rollback_drop": (lambda v: v is None or (_number(v) and 0 < v <= 1), "null or a number in (0, 1]"),
    "smooth_temporal": (lambda v: _number(v) and v >= 0, "a non-negative finite number"),
    "smooth_spatial": (lambda v: _number(v) and v >= 0, "a non-negative finite number"),
    "smooth_sigma": (lambda v: _number(v) and v > 0, "a positive finite number"),
    "smooth_clip_target": (lambda v: v is None or (_number(v) and 0 <= v < 1), "null or a share in [0, 1)"),
    "smooth_dual_lr": (lambda v: _number(v) and v > 0, "a positive finite number"),
}

_RUN_RULES = {
    "seed": (lambda v: _integer(v) and v >= 0, "a non-negative integer"),
    "checkpoint_every": (lambda v: _integer(v) and v > 0, "a positive integer"),
    "stop_after": (lambda v: v is None or (_integer(v) and v > 0), "null or a positive integer"),
    "logger": (lambda v: v in ("csv", "tensorboard"), "'csv' or 'tensorboard'"),
    "progress": (lambda v: isinstance(v, bool), "true or false"),
    "overwrite": (lambda v: isinstance(v, bool), "true or false"),
    "eval.episodes": (lambda v: _integer(v) and v > 0, "a positive integer"),
    "eval.every": (lambda v: _integer(v) and v >= 0, "a non-negative integer (0: only at the end)"),
    "eval.curve_episodes": (lambda v: v is None or (_integer(v) and v > 0), "null or a positive integer"),
    "eval.seed": (lambda v: _integer(v), "an integer"),
    "budget.wall_clock_s": (lambda v: v is None or (_number(v) and v > 0), "null or a positive number of seconds"),
    "budget.env_steps": (lambda v: v is None or (_integer(v) and v > 0), "null or a positive integer"),
    "eval.record": (lambda v: isinstance(v, bool), "true or false"),
}


def _get(cfg, dotted: str):
    node = cfg
    for part in dotted.split("."):
        if node is None or part not in node:
            return _MISSING
        node = node[part]
    return node


_MISSING = object()


def _plain(v):
    from omegaconf import DictConfig, ListConfig, OmegaConf

    return OmegaConf.to_container(v, resolve=True) if isinstance(v, (DictConfig, ListConfig)) else v


def _check(cfg, rules: dict, prefix: str) -> None:
    for key, (ok, what) in rules.items():
        value = _plain(_get(cfg, f"{prefix}{key}"))
        if value is _MISSING:
            continue
        try:
            good = ok(value)
        except TypeError:
            good = False
        if not good:
            raise ValueError(f"{prefix}{key} must be {what}, got {value!r}")


def validate_run_config(cfg) -> None:
    """``ValueError`` naming the first bad key of ``cfg``'s ``algo`` section or run keys (a DictConfig or
    mapping, as composed by ``dexmots-train``). Cross-field rules: AHAC's horizon bounds."""
    if _get(cfg, "algo") is not _MISSING:
        _check(cfg, _ALGO_RULES, "algo.")
    _check(cfg, _RUN_RULES, "")
    algo = _get(cfg, "algo")
    if algo is not _MISSING and _get(cfg, "algo.name") == "ahac":
        lo, hi, h0 = (_get(cfg, f"algo.{k}") for k in ("horizon_min", "horizon_max", "horizon"))
        if _MISSING not in (lo, hi, h0) and not lo <= h0 <= hi:
            raise ValueError(f"algo.horizon must lie in [algo.horizon_min, algo.horizon_max] = [{lo}, {hi}], got {h0}")
