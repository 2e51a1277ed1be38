"""Every task config field and every algorithm key is checked from its type annotation and range: a wrong
type, a null, a NaN or an infinity, or a value out of range is one ``ValueError`` naming ``task.<field>`` /
``algo.<key>``, and the console script prints it as one line."""

from __future__ import annotations

import dataclasses
import os
import re
import subprocess
import sys
import typing
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from dexmots_rl.algorithms.validation import ALGO_FIELDS, validate_run_config
from dexmots_rl.apps.train import CONFIG_DIR, run as train
from dexmots_rl.envs import list_tasks, task_config
from dexmots_rl.envs.fields import field_rules

NAN, INF = float("nan"), float("inf")


def _bad_values(annotation, rule) -> list:
    """Values that break ``annotation`` / ``rule``: wrong types, null, non-finite and out-of-range numbers."""
    optional = type(None) in typing.get_args(annotation)
    if optional:
        annotation = next(a for a in typing.get_args(annotation) if a is not type(None))
    rule = (rule or {}).get("check", rule or {})
    rule = {k: v for k, v in rule.items() if v is not None and v is not False}  # the bounds that apply
    out = [] if optional else [None]
    if annotation is bool:
        return out + ["abc", 1, 0.0]
    if annotation in (int, float):
        out += ["abc", [1], NAN, INF, -INF, True]
        low = rule.get("gt", rule.get("ge", 0 if not rule else None))
        if low is not None:
            out.append(low - 1)
        if rule.get("gt", 0 if not rule else None) is not None:
            out.append(rule.get("gt", 0))
        if rule.get("le") is not None:
            out.append(rule["le"] + 1)
        if annotation is int:
            out.append(2.5)
        return out
    if annotation is str:
        return out + [5, ""] + (["no-such-choice"] if rule.get("choices") else [])
    if typing.get_origin(annotation) is tuple:
        out += ["abc", 5, [], [NAN, 1.0], [1.0, INF], [-1.0, 1.0], ["abc", 1.0]]
        if rule.get("ordered"):
            out.append([0.2, 0.1])
        if typing.get_args(annotation)[-1] is not Ellipsis:
            out.append([0.1] * (len(typing.get_args(annotation)) + 1))
        return out
    if dataclasses.is_dataclass(annotation):
        name = dataclasses.fields(annotation)[0].name
        nullable = type(None) in typing.get_args(typing.get_type_hints(annotation)[name])  # None is then valid
        return out + [5, "abc", [1.0], {"no_such_key": 1.0}, {name: NAN}, {name: -1.0}, {name: "abc"}] + (
            [] if nullable else [{name: None}])
    raise AssertionError(f"no bad values for {annotation!r}")


def _task_cases():
    for task in list_tasks():
        for field, (annotation, rule) in field_rules(type(task_config(task))).items():
            if field == "name":
                continue
            for value in _bad_values(annotation, rule):
                yield pytest.param(task, field, value, id=f"{task}-{field}-{value!r}")


@pytest.mark.parametrize("task, field, value", list(_task_cases()))
def test_every_task_field_rejects_bad_values_naming_the_field(task, field, value):
    with pytest.raises(ValueError, match=rf"^task\.{field}\b"):
        task_config(task, **{field: value})


@pytest.mark.parametrize("task", list_tasks())
def test_every_task_default_config_is_valid(task):
    cfg = task_config(task)
    same = {f.name: getattr(cfg, f.name) for f in dataclasses.fields(cfg) if f.name != "name"}
    assert task_config(task, **same) == cfg


@pytest.mark.parametrize("field, value", [
    ("joint_noise", "abc"), ("success_threshold", None), ("ramp_steps", NAN), ("success_threshold", INF),
    ("torque_scale", "abc"), ("pose_scale", None), ("fingertip_scale", "abc"), ("reward", 5), ("num_envs", 0),
    ("goal_range", (0.5, 0.1)), ("damping_range", (-1.0, 1.0)),
])
def test_reported_bad_task_values(field, value):
    with pytest.raises(ValueError, match=rf"^task\.{field} must be"):
        task_config("screw_claw", **{field: value})


def test_valid_values_are_normalised():
    cfg = task_config("screw_claw", goal_range=[0.1, 0.2], joint_noise=0, reward={"lambda_act": 0})
    assert cfg.goal_range == (0.1, 0.2) and isinstance(cfg.joint_noise, float) and cfg.reward.lambda_act == 0.0
    assert cfg.reward.lambda_pose == task_config("screw_claw").reward.lambda_pose  # the other keys kept


# --- algorithm keys ---------------------------------------------------------------------------------------------

ALGOS = sorted(p.stem for p in (CONFIG_DIR / "algo").glob("*.yaml"))


def _algo_cfg(algo: str, *overrides: str):
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return compose("config", overrides=[f"algo={algo}", *overrides])


@pytest.mark.parametrize("algo", ALGOS)
def test_every_algorithm_key_has_a_type_and_rule(algo):
    cfg = _algo_cfg(algo)
    missing = [k for k in cfg.algo if k not in ALGO_FIELDS]
    assert not missing, f"algo={algo}: keys without an entry in ALGO_FIELDS: {missing}"
    validate_run_config(cfg)  # its defaults pass


def _algo_cases():
    for algo in ALGOS:
        keys = [k for k in _algo_cfg(algo).algo if k != "name"]
        for key in keys:
            for value in _bad_values(*ALGO_FIELDS[key]):
                yield pytest.param(algo, key, value, id=f"{algo}-{key}-{value!r}")


@pytest.fixture(scope="module")
def algo_configs():
    return {algo: OmegaConf.to_container(_algo_cfg(algo)) for algo in ALGOS}


@pytest.mark.parametrize("algo, key, value", list(_algo_cases()))
def test_every_algorithm_key_rejects_bad_values_naming_the_key(algo_configs, algo, key, value):
    cfg = OmegaConf.create(algo_configs[algo])
    cfg.algo[key] = value
    with pytest.raises(ValueError, match=rf"^algo\.{key}\b"):
        validate_run_config(cfg)


@pytest.mark.parametrize("algo, override, key", [
    ("ppo", "algo.epochs=0", "algo.epochs"), ("ppo", "algo.total_frames=-1", "algo.total_frames"),
    ("ppo", "algo.clip_epsilon=nan", "algo.clip_epsilon"), ("sac", "algo.utd_ratio=-1", "algo.utd_ratio"),
    ("ppo", "algo.minibatch_size=0", "algo.minibatch_size"), ("sac", "algo.batch_size=0", "algo.batch_size"),
    ("ppo", "algo.frames_per_batch=0", "algo.frames_per_batch"), ("pgdm", "algo.hidden=[]", "algo.hidden"),
    ("mpc", "algo.candidates=0", "algo.candidates"),
])
def test_reported_bad_algorithm_values_fail_before_any_work(tmp_path, algo, override, key):
    run_dir = tmp_path / "run"
    with pytest.raises(ValueError, match=re.escape(key)):
        train(_algo_cfg(algo, f"run_dir={run_dir}", override))
    assert not run_dir.exists()


@pytest.mark.parametrize("algo", ALGOS)
def test_a_key_no_config_declares_fails_before_any_work_naming_the_known_ones(tmp_path, algo):
    """hydra's advice for an unknown key, ``+algo.<key>=...``, composes it silently: the trainer refuses it."""
    run_dir = tmp_path / "run"
    known = ", ".join(sorted(_algo_cfg(algo).algo))
    with pytest.raises(ValueError, match=re.escape(f"algo.itrations: no such key in algo={algo} (a '+' adds none "
                                                   f"either); its keys: {known}")):
        train(_algo_cfg(algo, f"run_dir={run_dir}", "+algo.itrations=3"))
    assert not run_dir.exists()


@pytest.mark.parametrize("override, message", [
    ("+algo.horizon=3", "algo.horizon: no such key in algo=sac"),  # another method's key
    ("+eval.episode=3", "eval.episode: no such key in eval (a '+' adds none either); its keys: curve_episodes,"),
    ("+budget.cpu=3", "budget.cpu: no such key in budget"),
    ("+sed=3", "sed: no such key in the config"),
])
def test_unknown_keys_of_every_section_fail(tmp_path, override, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        train(_algo_cfg("sac", f"run_dir={tmp_path / 'run'}", override))
    assert not (tmp_path / "run").exists()


# each case starts a process (imports alone are seconds of CPU): the fast set runs one, every section's in the slow
@pytest.mark.parametrize("override, key", [
    pytest.param("algo.clip_epsilon=nan", "algo.clip_epsilon", marks=pytest.mark.slow),
    pytest.param("task.ramp_steps=0", "task.ramp_steps", marks=pytest.mark.slow),
    ("+algo.clip_epsilom=0.1", "algo.clip_epsilom")])
def test_cli_prints_one_line_naming_the_key(tmp_path, override, key):
    root = Path(__file__).resolve().parents[1]
    proc = subprocess.run([sys.executable, "-m", "dexmots_rl.apps.train", "algo=ppo", f"run_dir={tmp_path / 'run'}",
                           override], capture_output=True, text=True, cwd=tmp_path, timeout=300,
                          env={**os.environ, "PYTHONPATH": str(root)})
    assert proc.returncode != 0
    lines = [line for line in proc.stderr.splitlines() if line.strip() and "Warp CUDA warning" not in line]
    assert len(lines) == 1 and key in lines[0], proc.stderr
    assert not (tmp_path / "run").exists()
