"""dexmots-table reuses a finished run only when its whole config matches the spec's (task, method, action,
seed, budget, every override): a smoke run in the same sweep directory is run again, not reported."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from dexmots_rl.apps import table
from dexmots_rl.apps.train import CONFIG_DIR
from dexmots_rl.apps.table_writer import read_csv


def _table_cfg(sweep: Path, *overrides):
    with initialize_config_dir(config_dir=str(CONFIG_DIR / "table"), version_base="1.3"):
        return compose("config", overrides=[f"sweep_dir={sweep}", "launcher=basic", "threads_per_job=1",
                                            "progress=false", "tasks=[screw_claw]", "methods=[dexmots,ppo]",
                                            "seeds=[0]", "action_ablation.tasks=[]", *overrides])


SMOKE = ("budget.wall_clock_s=2", 'method_overrides.ppo=["algo.total_frames=24"]', 'run_overrides=["algo.hidden=[8]"]')
REAL = ("budget.wall_clock_s=150",)


@pytest.fixture
def fake_trainer(monkeypatch):
    """A train_job that leaves what a trainer leaves: config.yaml (the config it ran), metrics.json."""
    launched = []

    def train_job(cfg):
        run_dir = Path(cfg.run_dir)
        run_dir.mkdir(parents=True, exist_ok=True)
        (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
        success = 0.0 if cfg.budget.wall_clock_s == 2 else 0.9
        (run_dir / "metrics.json").write_text(json.dumps({
            "task": cfg.task.name, "algo": cfg.algo.name, "success_rate": success, "episodes": 10,
            "env_steps": 100, "train_wall_clock_s": 1.0,
            "budget": {"wall_clock_s": cfg.budget.wall_clock_s, "env_steps": None, "stopped_by": "wall_clock_s"}}))
        launched.append((cfg.algo.name, cfg.budget.wall_clock_s))
        return {}

    monkeypatch.setattr(table, "train_job", train_job)
    return launched


def test_a_finished_smoke_run_is_not_reused_by_the_real_spec(tmp_path, fake_trainer):
    sweep = tmp_path / "tables" / "small"
    assert table.run_table(_table_cfg(sweep, *SMOKE))["launched"] == 2
    fake_trainer.clear()
    result = table.run_table(_table_cfg(sweep, *REAL))
    assert sorted(fake_trainer) == [("ahac", 150), ("ppo", 150)]  # both rerun: the budget and overrides differ
    assert (result["skipped"], result["launched"]) == (0, 2)
    assert "0.0" not in result["table"].split("\n")[4]  # Ours / PPO from the real runs, not the smoke runs'
    assert {r["success"] for r in read_csv(sweep / "runs.csv")} == {0.9}


@pytest.mark.parametrize("changed", ["seeds=[0]", 'method_overrides.ppo=["algo.total_frames=48"]',
                                     'run_overrides=["algo.hidden=[16]"]',
                                     '+task_overrides.screw_claw=["task.mirror=false"]'])
def test_any_part_of_the_spec_decides(tmp_path, fake_trainer, changed):
    sweep = tmp_path / "sweep"
    table.run_table(_table_cfg(sweep, *SMOKE))
    fake_trainer.clear()
    rerun = table.run_table(_table_cfg(sweep, *SMOKE, changed))["launched"]
    assert rerun == (0 if changed == "seeds=[0]" else 1 if "ppo" in changed else 2)


def test_a_run_without_its_config_is_not_finished(tmp_path, fake_trainer):
    sweep = tmp_path / "sweep"
    table.run_table(_table_cfg(sweep, *SMOKE))
    (sweep / "runs" / "screw_claw" / "ppo" / "vi" / "seed0" / "config.yaml").unlink()
    fake_trainer.clear()
    assert table.run_table(_table_cfg(sweep, *SMOKE))["launched"] == 1 and fake_trainer == [("ppo", 2)]


def test_a_run_saved_before_a_task_field_was_added_is_still_finished(tmp_path, fake_trainer):
    spec = ("tasks=[pump_dispenser]", "methods=[ppo]", *REAL)
    table.run_table(_table_cfg(tmp_path, *spec))
    saved = tmp_path / "runs" / "pump_dispenser" / "ppo" / "vi" / "seed0" / "config.yaml"
    config = OmegaConf.load(saved)
    del config.task["urdf"]  # what a run made before task.urdf existed saved
    saved.write_text(OmegaConf.to_yaml(config))
    result = table.run_table(_table_cfg(tmp_path, *spec))
    assert (result["launched"], result["skipped"]) == (0, 1)


def test_a_run_saved_before_an_algo_field_was_added_is_still_finished_at_that_fields_old_value(tmp_path,
                                                                                               fake_trainer):
    spec = ("methods=[dexmots]", *REAL)
    table.run_table(_table_cfg(tmp_path, *spec))
    saved = tmp_path / "runs" / "screw_claw" / "dexmots" / "vi" / "seed0" / "config.yaml"
    config = OmegaConf.load(saved)
    for key in ("init_stiffness", "horizon_clip_target", "horizon_clip_lr", "num_envs"):
        del config.algo[key]  # what an AHAC run made before these keys existed saved
    saved.write_text(OmegaConf.to_yaml(config))
    result = table.run_table(_table_cfg(tmp_path, *spec))
    assert (result["launched"], result["skipped"]) == (0, 1)
    # a spec that sets one of them to another value than those runs had is another config: run again
    result = table.run_table(_table_cfg(tmp_path, *spec, 'run_overrides=["algo.init_stiffness=0.9"]'))
    assert (result["launched"], result["skipped"]) == (1, 0)
