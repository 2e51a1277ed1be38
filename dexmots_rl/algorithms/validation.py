"""Up-front checks of a training run's config: every key of every algorithm's ``algo`` section and the run
keys, each error naming the key (``algo.<key>``), before any env is built or any file is written.

Each key has a type annotation and a rule (:func:`dexmots_rl.envs.fields.rule`), checked by the same
:func:`~dexmots_rl.envs.fields.check_value` that checks every task config field: type, finiteness, range.
A key in ``configs/algo/*.yaml`` without an entry in :data:`ALGO_FIELDS` fails the test suite.

Example:
    >>> from omegaconf import OmegaConf
    >>> cfg = OmegaConf.create({"algo": {"name": "shac", "gamma": 2.0}})
    >>> try:
    ...     validate_run_config(cfg)
    ... except ValueError as e:
    ...     print(e)
    algo.gamma must be a finite number > 0 and <= 1, got 2.0
"""

from __future__ import annotations

from typing import Any, Optional

from ..envs.fields import check_value, rule

__all__ = ["ALGO_ADDED_WITH_THE_OLD_BEHAVIOUR", "ALGO_FIELDS", "RUN_FIELDS", "validate_run_config"]

_POSITIVE = rule(gt=0)
_NON_NEGATIVE = rule(ge=0)
_SHARE = rule(ge=0, le=1)
_WIDTHS = (tuple[int, ...], _POSITIVE)  # MLP hidden-layer widths
_ACTIVATIONS = rule(choices=("tanh", "relu", "elu"))

#: ``algo`` keys added after runs were saved -> the value that is what those runs did: a saved config without
#: one is today's config with that value (dexmots-table reuses such a finished run, and runs again one whose
#: spec sets another value)
ALGO_ADDED_WITH_THE_OLD_BEHAVIOUR: dict[str, Any] = {"num_envs": None, "init_stiffness": 0.0,
                                                     "horizon_clip_target": None, "horizon_clip_lr": 20.0}

#: key -> (type, rule) of every algorithm's ``algo`` keys; a key absent from a config is skipped (e.g. AHAC-only
#: keys under SHAC); keys shared by several methods mean the same everywhere
ALGO_FIELDS: dict[str, tuple[Any, Optional[dict]]] = {
    "name": (str, None),
    # SHAC / AHAC
    "iterations": (int, _POSITIVE),
    "num_envs": (Optional[int], _POSITIVE),
    "horizon": (int, _POSITIVE),
    "gamma": (float, rule(gt=0, le=1)),
    "lmbda": (float, _SHARE),
    "actor_lr": (float, _POSITIVE),
    "critic_lr": (float, _POSITIVE),
    "betas": (tuple[float, float], rule(ge=0, lt=1)),
    "lr_decay": (str, rule(choices=("linear", "constant"))),
    "critic_iterations": (int, _POSITIVE),
    "critic_minibatches": (int, _POSITIVE),
    "target_alpha": (float, _SHARE),
    "grad_norm": (float, _POSITIVE),
    "skip_grad_norm": (float, _POSITIVE),
    "hidden": _WIDTHS,
    "critic_hidden": (Optional[tuple[int, ...]], _POSITIVE),
    "layer_norm": (bool, None),
    "init_log_std": (float, rule(ge=-20, le=5)),
    "init_stiffness": (float, rule(gt=-1, lt=1)),
    "adjoint_clip": (Optional[float], rule(ge=1)),
    "horizon_min": (int, _POSITIVE),
    "horizon_max": (int, _POSITIVE),
    "contact_threshold": (float, _POSITIVE),
    "dual_lr": (float, _POSITIVE),
    "horizon_clip_target": (Optional[float], rule(ge=0, lt=1)),
    "horizon_clip_lr": (float, _POSITIVE),
    "truncate": (bool, None),
    "keep_best": (bool, None),
    "best_window": (int, _POSITIVE),
    "rollback_drop": (Optional[float], rule(gt=0, le=1)),
    "smooth_temporal": (float, _NON_NEGATIVE),
    "smooth_spatial": (float, _NON_NEGATIVE),
    "smooth_sigma": (float, _POSITIVE),
    "smooth_clip_target": (Optional[float], rule(ge=0, lt=1)),
    "smooth_dual_lr": (float, _POSITIVE),
    # PPO / PGDM / SAC
    "total_frames": (float, rule(ge=1)),
    "frames_per_batch": (int, _POSITIVE),
    "epochs": (int, _POSITIVE),
    "minibatch_size": (int, _POSITIVE),
    "lr": (float, _POSITIVE),
    "anneal_lr": (bool, None),
    "max_grad_norm": (float, _POSITIVE),
    "reward_scale": (float, _POSITIVE),
    "clip_epsilon": (float, _POSITIVE),
    "entropy_coeff": (float, _NON_NEGATIVE),
    "critic_coeff": (float, _POSITIVE),
    "loss_critic_type": (str, rule(choices=("l2", "smooth_l1", "l1"))),
    "normalize_advantage": (bool, None),
    "activation": (str, _ACTIVATIONS),
    "obs_norm_decay": (float, rule(gt=0, le=1)),
    "obs_clip": (float, _POSITIVE),
    "init_random_frames": (float, _NON_NEGATIVE),
    "utd_ratio": (float, _POSITIVE),
    "batch_size": (int, _POSITIVE),
    "buffer_size": (float, rule(ge=1)),
    "tau": (float, rule(gt=0, le=1)),
    "alpha_lr": (float, _POSITIVE),
    "alpha_init": (float, _POSITIVE),
    # PGDM's TCDM observation and reward
    "target_offsets": (tuple[int, ...], _POSITIVE),
    "time_frequencies": (tuple[float, ...], _POSITIVE),
    "tracking_scale": (float, _POSITIVE),
    "tracking_sharpness": (float, _POSITIVE),
    "rotation_weight": (float, _NON_NEGATIVE),
    "lift_bonus": (float, _NON_NEGATIVE),
    "lift_height": (float, _NON_NEGATIVE),
    "termination_distance": (float, _POSITIVE),
    "warm_start": (bool, None),
    # MPC
    "candidates": (int, _POSITIVE),
    "knots": (int, _POSITIVE),
    "interpolation": (str, rule(choices=("zero", "linear"))),
    "noise": (float, _NON_NEGATIVE),
    "initial_plan": (str, rule(choices=("hold", "zero"))),
    "refine_steps": (int, _NON_NEGATIVE),
    "refine_lr": (float, _POSITIVE),
    "refine_optimizer": (str, rule(choices=("adam", "sgd"))),
}

#: dotted run key -> (type, rule)
RUN_FIELDS: dict[str, tuple[Any, Optional[dict]]] = {
    "seed": (int, _NON_NEGATIVE),
    "checkpoint_every": (int, _POSITIVE),
    "stop_after": (Optional[int], _POSITIVE),
    "logger": (str, rule(choices=("csv", "tensorboard"))),
    "progress": (bool, None),
    "overwrite": (bool, None),
    "torch_threads": (Optional[int], _POSITIVE),
    "eval.episodes": (int, _POSITIVE),
    "eval.every": (int, _NON_NEGATIVE),
    "eval.curve_episodes": (Optional[int], _POSITIVE),
    "eval.seed": (int, rule()),
    "eval.record": (bool, None),
    "budget.wall_clock_s": (Optional[float], _POSITIVE),
    "budget.env_steps": (Optional[int], _POSITIVE),
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


def _check(cfg, fields: dict, prefix: str) -> None:
    for key, (annotation, key_rule) in fields.items():
        value = _plain(_get(cfg, f"{prefix}{key}"))
        if value is not _MISSING:
            check_value(f"{prefix}{key}", value, annotation, key_rule)


def _check_device(device) -> None:
    from ..sim import check_device

    try:
        check_device(str(device))
    except RuntimeError:  # torch's "Expected one of cpu, cuda, ... device type"
        raise ValueError(f"device must be 'cpu' or 'cuda[:index]', got {device!r}") from None


def validate_run_config(cfg) -> None:
    """``ValueError`` naming the first bad key of ``cfg``'s ``algo`` section or run keys (a DictConfig or
    mapping, as composed by ``dexmots-train``), a bad ``task.<field>`` (the task's typed config) or a device this
    machine lacks. Cross-field rules: AHAC's horizon bounds."""
    if _get(cfg, "algo") is not _MISSING:
        _check(cfg, ALGO_FIELDS, "algo.")
    _check(cfg, RUN_FIELDS, "")
    if _get(cfg, "device") is not _MISSING:
        _check_device(_get(cfg, "device"))
    task = _get(cfg, "task")
    if task is not _MISSING and task is not None and "name" in task:  # what make_env will check, checked now
        from ..envs.config import config_from_dict
        from ..envs.registry import task_entry

        config_from_dict(task_entry(task["name"]).config_class, _plain(task))
    algo = _get(cfg, "algo")
    if algo is not _MISSING and _get(cfg, "algo.name") == "ahac":
        lo, hi, h0 = (_get(cfg, f"algo.{k}") for k in ("horizon_min", "horizon_max", "horizon"))
        if _MISSING not in (lo, hi, h0) and not lo <= h0 <= hi:
            raise ValueError(f"algo.horizon must lie in [algo.horizon_min, algo.horizon_max] = [{lo}, {hi}], got {h0}")
