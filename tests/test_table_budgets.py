"""dexmots-table's per-task budgets (``task_budgets``): the same budget for every method of a task, part of each
run's identity, stated per task in table.md, bad entries failing naming the field; and the ``suite`` preset's
spec (every paper and tool task, every method) composes, is valid and fits its stated hours (no training)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from dexmots_rl.apps import table
from dexmots_rl.apps.table_spec import SweepSpecError
from dexmots_rl.apps.table_writer import budget_text, read_csv
from dexmots_rl.apps.train import CONFIG_DIR


def _table_cfg(sweep: Path, *overrides, preset: str = "small"):
    with initialize_config_dir(config_dir=str(CONFIG_DIR / "table"), version_base="1.3"):
        return compose("config", overrides=[f"preset={preset}", f"sweep_dir={sweep}", "launcher=basic",
                                            "threads_per_job=1", "progress=false", "methods=[dexmots,ppo]",
                                            "seeds=[0]", "action_ablation.tasks=[]", *overrides])


TWO_TASKS = ("tasks=[screw_claw,allegro_rotate]",)


@pytest.fixture
def fake_trainer(monkeypatch):
    """A train_job that leaves what a trainer leaves (config.yaml, metrics.json) and records each run's budget."""
    launched = []

    def train_job(cfg):
        run_dir = Path(cfg.run_dir)
        run_dir.mkdir(parents=True, exist_ok=True)
        (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
        budget = {"wall_clock_s": cfg.budget.wall_clock_s, "env_steps": cfg.budget.env_steps,
                  "stopped_by": "wall_clock_s"}
        (run_dir / "metrics.json").write_text(json.dumps({
            "task": cfg.task.name, "algo": cfg.algo.name, "success_rate": 0.5, "episodes": 10, "env_steps": 100,
            "train_wall_clock_s": 1.0, "budget": budget}))
        launched.append((cfg.task.name, cfg.algo.name, cfg.budget.wall_clock_s, cfg.budget.env_steps))
        return {}

    monkeypatch.setattr(table, "train_job", train_job)
    return launched


def test_a_task_budget_applies_to_every_method_of_that_task_alone(tmp_path, fake_trainer):
    sweep = tmp_path / "sweep"
    result = table.run_table(_table_cfg(sweep, *TWO_TASKS, "+task_budgets.allegro_rotate.wall_clock_s=300"))
    assert sorted(fake_trainer) == [("allegro_rotate", "ahac", 300, None), ("allegro_rotate", "ppo", 300, None),
                                    ("screw_claw", "ahac", 150, None), ("screw_claw", "ppo", 150, None)]
    lines = result["table"].splitlines()
    assert "| Environment | Ours | PPO | Budget |" in lines
    assert "| Screw-top (Claw) | 50.0 | 50.0 | 150 s |" in lines
    assert "| Screw-top (Allegro) | 50.0 | 50.0 | 300 s |" in lines
    assert "| Average | 50.0 | 50.0 |  |" in lines
    assert "stated per task (Budget column" in result["table"] and "Warning" not in result["table"]
    csv = {(r["task"], r["method"]): r["budget_wall_clock_s"] for r in read_csv(sweep / "runs.csv")}
    assert csv[("allegro_rotate", "ppo")] == 300 and csv[("screw_claw", "ppo")] == 150


def test_a_changed_task_budget_reruns_that_task_only(tmp_path, fake_trainer):
    sweep = tmp_path / "sweep"
    table.run_table(_table_cfg(sweep, *TWO_TASKS, "+task_budgets.allegro_rotate.wall_clock_s=300"))
    fake_trainer.clear()
    result = table.run_table(_table_cfg(sweep, *TWO_TASKS, "+task_budgets.allegro_rotate.env_steps=5000"))
    # the task's entry is its whole budget: wall_clock_s not given is null, not the sweep's 150 s
    assert sorted(fake_trainer) == [("allegro_rotate", "ahac", None, 5000), ("allegro_rotate", "ppo", None, 5000)]
    assert (result["skipped"], result["launched"]) == (2, 2)
    assert "| Screw-top (Allegro) | 50.0 | 50.0 | 5,000 env steps |" in result["table"].splitlines()


def test_equal_budgets_keep_the_single_budget_sentence(tmp_path, fake_trainer):
    result = table.run_table(_table_cfg(tmp_path / "sweep", *TWO_TASKS,
                                        "+task_budgets.allegro_rotate.wall_clock_s=150"))
    assert "Budget per run: 150 s of training wall-clock (evaluations excluded)" in result["table"]
    assert "| Environment | Ours | PPO |" in result["table"].splitlines()  # no Budget column


@pytest.mark.parametrize("overrides, message", [
    (["+task_budgets.screw_claw.wall_clock_s=-1"], "task_budgets.screw_claw.wall_clock_s must be null or a "
                                                      "positive number"),
    (["+task_budgets.screw_claw.env_steps=1.5"], "task_budgets.screw_claw.env_steps must be null or a positive"),
    (["+task_budgets.screw_claw.seconds=5"], "task_budgets.screw_claw takes wall_clock_s, env_steps, cpu_s"),
    (["+task_budgets.screw_claw.cpu_s=0"], "task_budgets.screw_claw.cpu_s must be null or a positive number"),
    (["+task_budgets.nope.wall_clock_s=5"], "task_budgets: unknown task 'nope'"),
    (["~task_budgets", "+task_budgets=[screw_claw]"], "task_budgets must map task names"),
])
def test_a_bad_task_budget_fails_naming_the_field(tmp_path, monkeypatch, overrides, message):
    monkeypatch.setattr(table, "train_job", lambda cfg: pytest.fail("a bad spec must not launch anything"))
    with pytest.raises(SweepSpecError) as info:
        table.run_table(_table_cfg(tmp_path / "sweep", "tasks=[screw_claw]", *overrides))
    assert message in str(info.value)
    assert not (tmp_path / "sweep" / "runs").exists()


def _row(task, wall_clock_s, stopped_by="wall_clock_s"):
    return {"task": task, "status": "finished", "stopped_by": stopped_by, "budget_wall_clock_s": wall_clock_s,
            "budget_env_steps": None}


def test_the_mixed_budget_warning_works_per_task():
    budgets = {"a": {"wall_clock_s": 100, "env_steps": None}, "b": {"wall_clock_s": 200, "env_steps": None}}
    assert "Warning" not in budget_text(budgets, [_row("a", 100), _row("b", 200), _row("b", None, "no_training")])
    text = budget_text(budgets, [_row("a", 100), _row("b", 200), _row("b", 150)])
    assert "the finished runs of b (2) had different budgets within the task" in text
    one = {"a": budgets["a"], "b": budgets["a"]}  # one budget for all tasks: any difference warns, as before
    assert "had 2 different budgets" in budget_text(one, [_row("a", 100), _row("b", 200)])


# The suite preset's sizing model (configs/table/preset/suite.yaml gives the measurements behind each figure):
# seconds on one core of the 2-core machine, n_jobs=2 runs at once.
STARTUP_S = 10            # process start, imports, env and policy construction
FINAL_EVAL_S = {"screw_claw": 3, "allegro_rotate": 5, "repose_cube": 8}  # 100 episodes; tool tasks: TOOL_EVAL_S
TOOL_EVAL_S = 6
CURVE_EVALS = 15          # periodic evaluations per trained run (eval.every: ~10-20 within a budget)
MPC_S_PER_EPISODE_CANDIDATE = {"screw_claw": 0.1, "allegro_rotate": 0.3, "repose_cube": 1.65}  # tools: TOOL_MPC_S
TOOL_MPC_S = 1.5
SUITE_HOURS = 8.0


def _run_seconds(identity: dict) -> float:
    """One run's wall-clock by the sizing model, from its composed dexmots-train config."""
    task, algo, ev = identity["task"]["name"], identity["algo"], identity["eval"]
    if algo["name"] == "mpc":  # trains nothing: plans through its evaluation episodes, cost ~ worlds x candidates
        return STARTUP_S + MPC_S_PER_EPISODE_CANDIDATE.get(task, TOOL_MPC_S) * ev["episodes"] * algo["candidates"]
    final = FINAL_EVAL_S.get(task, TOOL_EVAL_S) * ev["episodes"] / 100
    curve = CURVE_EVALS * FINAL_EVAL_S.get(task, TOOL_EVAL_S) * (ev["curve_episodes"] or ev["episodes"]) / 100
    return identity["budget"]["cpu_s"] + STARTUP_S + final + curve


def test_the_suite_preset_is_valid_and_fits_its_hours(tmp_path):
    from dexmots_rl import envs
    from dexmots_rl.algorithms.registry import list_algorithms
    from dexmots_rl.algorithms.validation import validate_run_config
    from dexmots_rl.apps.table_spec import run_identity, sweep_spec

    with initialize_config_dir(config_dir=str(CONFIG_DIR / "table"), version_base="1.3"):
        cfg = compose("config", overrides=["preset=suite", f"sweep_dir={tmp_path / 'suite'}"])
    registered = envs.list_tasks()
    spec = sweep_spec(cfg, list_algorithms(), registered, {t: envs.task_config(t).action for t in registered})
    assert spec.tasks == tuple(cfg.paper_tasks) and not spec.notes  # every paper and tool task, all registered
    assert [m.name for m in spec.methods] == list(cfg.method_catalog)  # every method, each algo exists
    assert spec.seeds == (0, 1, 2) and cfg.n_jobs == 2 and spec.ablation_tasks == ("screw_claw",)  # and Fig. 3b
    assert set(spec.task_budgets) == set(spec.tasks)  # a stated budget per task, CPU time (sized for 2 cores)
    assert all(b["cpu_s"] > 0 and b["wall_clock_s"] is None and b["env_steps"] is None
               for b in spec.task_budgets.values())
    runs = spec.runs(threads=1)
    assert sum(r.experiment == "table" for r in runs) == len(spec.tasks) * len(spec.methods) * 3
    loader, master = table._train_multirun_config(cfg, spec.sweep_dir)
    seconds = 0.0
    for run in runs:
        if run.seed != 0:  # the seeds' configs differ in the seed alone: composed once, counted for each
            continue
        composed = loader.load_sweep_config(master, list(run.overrides))
        validate_run_config(composed)
        identity = run_identity(composed)
        assert identity["eval"]["episodes"] == 100
        assert run.algo != "mpc" or identity["algo"]["horizon"] == 30  # the horizon MPC's rates were measured at
        assert identity["budget"]["cpu_s"] == spec.task_budgets[run.task]["cpu_s"]
        seconds += len(spec.seeds) * _run_seconds(identity)
    hours = seconds / cfg.n_jobs / 3600
    assert 0.8 * SUITE_HOURS <= hours <= SUITE_HOURS, f"the suite is sized at {hours:.2f} h"
