"""dexmots-table: the markdown writer on a known CSV, restart skipping finished runs, spec errors naming the
field, the figures from synthetic run directories, the common training budget, one real tiny sweep."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from dexmots_rl.apps import table
from dexmots_rl.apps.table_spec import SweepSpecError
from dexmots_rl.apps.train import CONFIG_DIR, run as train
from dexmots_rl.apps.table_writer import (action_space_table, machines_text, markdown_table, quoted_table,
                                          read_csv, run_row, time_to_success_table)

KNOWN_CSV = """\
task,method,action,seed,experiment,status,success,episodes,wall_clock_s,env_steps,time_to_90_s,env_steps_to_90,stopped_by,budget_wall_clock_s,budget_env_steps,run_dir
screw_claw,dexmots,vi,0,table,finished,0.97,100,100.0,9000,40.0,3000,wall_clock_s,100,,r/0
screw_claw,dexmots,vi,1,table,finished,0.93,100,100.0,9000,60.0,4000,wall_clock_s,100,,r/1
screw_claw,dexmots,torque,0,action_space,finished,0.10,100,100.0,9000,,,wall_clock_s,100,,r/2
screw_claw,ppo,vi,0,table,finished,0.50,100,100.0,90000,,,wall_clock_s,100,,r/3
screw_claw,ppo,vi,1,table,failed,,,,,,,,,,r/4
allegro_rotate,dexmots,vi,0,table,finished,1.0,100,100.0,5000,20.0,1000,wall_clock_s,100,,r/5
allegro_rotate,dexmots,vi,1,table,finished,0.98,100,100.0,5000,30.0,1500,wall_clock_s,100,,r/6
"""

KNOWN_TABLE = """\
| Environment | Ours | PPO |
|---|---:|---:|
| Screw-top (Claw) | 95.0 ± 2.8 | 50.0 (n=1) |
| Screw-top (Allegro) | 99.0 ± 1.4 | – |
| Average | 97.0 ± 2.1 | – |"""

KNOWN_TIMES = """\
| Environment | Ours | PPO |
|---|---:|---:|
| Screw-top (Claw) | 50 s (2/2) | – (0/1) |
| Screw-top (Allegro) | 25 s (2/2) | – |"""

KNOWN_ACTIONS = """\
| method | torque | vi |
|---|---:|---:|
| Ours | 10: 10.0 | 97 / 93: 95.0 ± 2.8 (50 s, 2/2) |
| PPO | – | 50: 50.0 |"""

TASKS = [("screw_claw", "Screw-top (Claw)"), ("allegro_rotate", "Screw-top (Allegro)")]
METHODS = [("dexmots", "Ours"), ("ppo", "PPO")]


def test_the_writer_renders_a_known_csv_as_table_2(tmp_path):
    (tmp_path / "runs.csv").write_text(KNOWN_CSV)
    rows = read_csv(tmp_path / "runs.csv")
    assert rows[0]["seed"] == 0 and rows[0]["success"] == 0.97 and rows[4]["success"] is None
    assert markdown_table(rows, TASKS, METHODS, seeds=2) == KNOWN_TABLE
    assert time_to_success_table(rows, TASKS, METHODS) == KNOWN_TIMES
    # Fig. 3b in numbers: the table's vi runs count for vi, the failed run for nothing
    assert action_space_table(rows, "screw_claw", METHODS, ["torque", "vi"]) == KNOWN_ACTIONS


def test_the_table_says_which_machines_commits_and_dates_its_runs_had(tmp_path):
    """Each finished run's machine, commit and date come from its metrics.json's provenance into runs.csv, and
    table.md counts them (a sweep resumed on another machine says so)."""
    from types import SimpleNamespace

    rows = []
    for seed, (cpu, commit, date) in enumerate([("AMD EPYC", "aaa1111", "2026-12-05T10:00:00+00:00"),
                                                ("AMD EPYC", "aaa1111", "2026-12-06T09:00:00+00:00"),
                                                ("Intel Xeon", "bbb2222", "2026-12-06T11:00:00+00:00")]):
        run = SimpleNamespace(task="screw_claw", method="dexmots", action="vi", seed=seed, experiment="table",
                              run_dir=tmp_path / f"seed{seed}")
        metrics = {"success_rate": 1.0, "iterations": 0, "provenance": {"cpu": cpu, "cores": 2, "commit": commit,
                                                                        "date": date}}
        rows.append(run_row(run, metrics, "finished"))
    rows.append(run_row(SimpleNamespace(task="screw_claw", method="ppo", action="vi", seed=0, experiment="table",
                                        run_dir=tmp_path / "ppo"), None, "failed"))
    assert rows[2]["machine"] == "Intel Xeon, 2 cores" and rows[2]["date"] == "2026-12-06"
    assert machines_text(rows) == ("Runs by machine: AMD EPYC, 2 cores (2), Intel Xeon, 2 cores (1); commits "
                                   "aaa1111 (2), bbb2222 (1); 2026-12-05 to 2026-12-06.")
    assert machines_text(rows[:1]) == "Runs by machine: AMD EPYC, 2 cores (1); commit aaa1111; 2026-12-05."
    assert machines_text(rows[3:]) is None


def test_the_quoted_paper_table_gives_the_papers_own_average_row(tmp_path):
    """The paper's figures as configs/table/config.yaml quotes them: its five rows average to its Average row
    (80.4 ± 5.0 for DexMOTS ...), so a mistyped figure shows; table.md quotes them under the measured table."""
    from dexmots_rl import envs
    from dexmots_rl.algorithms.registry import list_algorithms
    from dexmots_rl.apps.table_spec import sweep_spec

    with initialize_config_dir(config_dir=str(CONFIG_DIR / "table"), version_base="1.3"):
        cfg = compose("config", overrides=["preset=suite", f"sweep_dir={tmp_path}"])
    registered = envs.list_tasks()
    spec = sweep_spec(cfg, list_algorithms(), registered, {t: envs.task_config(t).action for t in registered})
    tasks = [(t, spec.task_labels[t]) for t in spec.tasks]
    text = quoted_table(spec.paper_table, tasks, [(m.name, m.label) for m in spec.methods])
    lines = text.splitlines()
    assert len(lines) == 2 + 5 + 1  # header, the paper's five rows (not the Allegro knob, not the new tools)
    assert lines[0] == "| Environment | Ours | Ours (pose-only) | MPC | SAC | PPO | PGDM |"
    assert lines[3] == "| Spray Bottle | 89.6 ± 2.9 | 63.4 ± 8.3 | 8.4 ± 4.3 | 47.8 ± 5.8 | 51.8 ± 8.7 | 83.8 ± 4.0 |"
    assert lines[-1] == "| Average | 80.4 ± 5.0 | 69.5 ± 6.1 | 10.8 ± 3.3 | 40.8 ± 7.1 | 46.8 ± 5.8 | 70.3 ± 8.4 |"


def _table_cfg(tmp_path, *overrides):
    with initialize_config_dir(config_dir=str(CONFIG_DIR / "table"), version_base="1.3"):
        return compose("config", overrides=[f"sweep_dir={tmp_path / 'sweep'}", "launcher=basic", "threads_per_job=1",
                                            "progress=false", "tasks=[screw_claw]", "methods=[dexmots,ppo]",
                                            "seeds=[0,1]", "action_ablation.tasks=[]", *overrides])


def _fake_finished(run_dir: Path, task: str, algo: str, success: float, curve=(0.3, 0.95), config=None) -> None:
    """A run directory as a trainer leaves it: its ``config`` (the composed one it was given), training rows,
    periodic evaluations, the final metrics.json."""
    run_dir.mkdir(parents=True, exist_ok=True)
    if config is not None:
        (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(config, resolve=True))
    rows = []
    for i, s in enumerate(curve, start=1):
        rows.append({"iteration": i, "env_steps": 1000 * i, "wall_clock_s": 10.0 * i, "reward": 0.1})
        rows.append({"iteration": i, "eval_success_rate": s, "eval_episodes": 10})
    (run_dir / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    (run_dir / "metrics.json").write_text(json.dumps({
        "task": task, "algo": algo, "success_rate": success, "episodes": 100, "env_steps": 1000 * (len(curve) + 1),
        "train_wall_clock_s": 10.0 * (len(curve) + 1),
        "budget": {"wall_clock_s": 100.0, "env_steps": None, "stopped_by": "wall_clock_s"}}))


def test_a_restarted_sweep_runs_only_what_is_not_finished(tmp_path, monkeypatch):
    launched = []

    def fake_train_job(cfg):
        launched.append((cfg.task.name, cfg.algo.name, cfg.seed, cfg.task.action, cfg.torch_threads))
        assert cfg.overwrite and cfg.budget.wall_clock_s == 150  # the preset's budget, for every run
        _fake_finished(Path(cfg.run_dir), cfg.task.name, cfg.algo.name, 0.5, config=cfg)
        return {}

    monkeypatch.setattr(table, "train_job", fake_train_job)
    assert table.run_table(_table_cfg(tmp_path))["launched"] == 4
    runs = tmp_path / "sweep" / "runs" / "screw_claw"
    (runs / "dexmots" / "vi" / "seed1" / "metrics.json").unlink()  # interrupted before its final evaluation
    (runs / "ppo" / "vi" / "seed0" / "metrics.json").write_text('{"task": "screw_cl')  # torn: not finished
    launched.clear()
    result = table.run_table(_table_cfg(tmp_path))
    assert sorted(launched) == [("screw_claw", "ahac", 1, "vi", 1), ("screw_claw", "ppo", 0, "vi", 1)]
    assert (result["runs"], result["skipped"], result["launched"], result["unfinished"]) == (4, 2, 2, [])
    rows = read_csv(tmp_path / "sweep" / "runs.csv")
    assert [(r["method"], r["seed"], r["status"]) for r in rows] == [
        ("dexmots", 0, "finished"), ("dexmots", 1, "finished"), ("ppo", 0, "finished"), ("ppo", 1, "finished")]
    assert rows[0]["time_to_90_s"] == 20.0 and rows[0]["env_steps_to_90"] == 2000  # the first eval >= 90 %
    # runs.csv names each run relative to the sweep (no path of this machine); read back, a path to its folder
    assert str(tmp_path) not in (tmp_path / "sweep" / "runs.csv").read_text()
    assert rows[0]["run_dir"].resolve() == (runs / "dexmots" / "vi" / "seed0").resolve()
    launched.clear()
    assert table.run_table(_table_cfg(tmp_path))["launched"] == 0 and launched == []
    # report_only: the table of what is finished, launching nothing
    (runs / "ppo" / "vi" / "seed1" / "metrics.json").unlink()
    result = table.run_table(_table_cfg(tmp_path, "report_only=true"))
    assert launched == [] and (result["launched"], result["unfinished"]) == (0, ["screw_claw/ppo/vi/seed1"])
    assert "1 of 4 runs not finished: screw_claw/ppo/vi/seed1" in result["table"]
    # the exit names the missing runs and the command that runs them: the same one without report_only
    command_line = ["preset=suite", "report_only=true", "seeds=[0,1]"]
    assert table.closing_message(result, True, command_line) == (
        "dexmots-table: 1 of 4 runs not finished (screw_claw/ppo/vi/seed1); report_only=true launched none; run "
        "them (finished runs are skipped) with: dexmots-table preset=suite 'seeds=[0,1]'")
    assert table.closing_message(table.run_table(_table_cfg(tmp_path)), False, []) is None  # it ran the missing one


@pytest.mark.parametrize("overrides, message", [
    (["methods=[dexmots,nope]"], "methods: unknown method 'nope'"),
    (["tasks=[screw_claw,nope]"], "tasks: unknown task 'nope'"),
    (["seeds=[]"], "seeds must be a non-empty list"),
    (["+method_catalog.future={label:F,overrides:[\"algo=future\"]}", "methods=[future]"],
     "methods: method 'future' needs algo=future, which dexmots-train does not have yet"),
    (["action_ablation.tasks=[screw_claw]", "action_ablation.actions=[torque,telepathy]"],
     "action_ablation.actions: unknown action 'telepathy'"),
    (["budget.wall_clock_s=-5"], "budget.wall_clock_s must be null or a positive number"),
    (['method_overrides.ppo=["budget.wall_clock_s=5"]'], "method_overrides.ppo: 'budget.wall_clock_s=5' sets budget"),
    (['method_overrides.ppo=["algo.iteratons=1"]'], "run screw_claw/ppo/vi/seed0: Could not override 'algo.iteratons'"),
    (['method_overrides.ppo=["eval.every=-1"]'], "run screw_claw/ppo/vi/seed0: eval.every must be"),
    (["+launcher_params.partishun=gpu"], "launcher_params.partishun: the basic launcher has no field"),
    (["launcher=mpi"], "launcher must be one of"),
    (["paper_table.screw_claw.ppo=[47.4]"], "paper_table.screw_claw.ppo must be [mean, s.d.] in %"),
    (["+paper_table.nope={ppo:[1,2]}"], "paper_table: unknown task 'nope'"),
    (["+seed=[0]"], "seed: no such key in the config (a '+' adds none either); its keys: action_ablation, budget,"),
    (["+budget.cpu=5"], "budget.cpu: no such key in budget"),
    (['method_overrides.ppo=["+algo.iteratons=1"]'], "run screw_claw/ppo/vi/seed0: algo.iteratons: no such key in "
                                                     "algo=ppo (a '+' adds none either); its keys: activation,"),
    (['run_overrides=["+evaluation.episodes=3"]'], "evaluation: no such key in the config"),
])
def test_a_bad_spec_fails_naming_the_field(tmp_path, monkeypatch, overrides, message):
    monkeypatch.setattr(table, "train_job", lambda cfg: pytest.fail("a bad spec must not launch anything"))
    with pytest.raises(SweepSpecError) as info:
        table.run_table(_table_cfg(tmp_path, *overrides))
    assert message in str(info.value)
    assert not (tmp_path / "sweep" / "runs").exists()


@pytest.mark.parametrize("preset", sorted(p.stem for p in (CONFIG_DIR / "table" / "preset").glob("*.yaml")))
def test_every_preset_sets_only_declared_keys(tmp_path, preset):
    from dexmots_rl.apps.config_keys import TABLE_FREE_SECTIONS, declared_config, unknown_keys

    with initialize_config_dir(config_dir=str(CONFIG_DIR / "table"), version_base="1.3"):
        cfg = compose("config", overrides=[f"preset={preset}"])
    assert unknown_keys(cfg, declared_config(str(CONFIG_DIR / "table")), TABLE_FREE_SECTIONS) == []


def _finished_sweep(tmp_path, monkeypatch, finish, *overrides) -> None:
    """A sweep whose every run ``finish(cfg)`` left finished (as a trainer would, config.yaml included)."""
    monkeypatch.setattr(table, "train_job", lambda cfg: finish(cfg) or {})
    table.run_table(_table_cfg(tmp_path, *overrides))
    monkeypatch.setattr(table, "train_job", lambda cfg: pytest.fail("everything is finished"))


def test_the_figures_and_table_come_from_the_run_directories(tmp_path, monkeypatch):
    ablation = ("action_ablation.tasks=[screw_claw]", "action_ablation.methods=[dexmots,ppo]",
                "action_ablation.actions=[torque,vi]")
    _finished_sweep(tmp_path, monkeypatch, lambda cfg: _fake_finished(
        Path(cfg.run_dir), "screw_claw", cfg.algo.name, 0.5 + 0.1 * cfg.seed,
        curve=(0.1 * cfg.seed, 0.5, 0.8 + 0.1 * cfg.seed), config=cfg), *ablation)
    result = table.run_table(_table_cfg(tmp_path, *ablation))
    sweep = tmp_path / "sweep"
    for png in ("curves_screw_claw.png", "action_space_screw_claw.png"):
        assert (sweep / png).stat().st_size > 10_000 and (sweep / png).read_bytes()[:4] == b"\x89PNG"
    assert "| Screw-top (Claw) | 55.0 ± 7.1 | 55.0 ± 7.1 |" in result["table"]
    assert "150 s of training wall-clock" in result["table"] and "wall_clock_s (4)" in result["table"]
    assert (sweep / "table.md").read_text() == result["table"]
    assert "The paper's own Table 2" in result["table"] and "| Screw-top (Claw) | 92.6 ± 6.4 | 47.4 ± 3.8 |" in result["table"]
    assert len(read_csv(sweep / "runs.csv")) == 8


TINY = ["task.num_envs=2", "task.max_episode_steps=6", "eval.episodes=2", "progress=false", "torch_threads=1"]
TINY_PPO = ["algo=ppo", "algo.frames_per_batch=12", "algo.minibatch_size=6", "algo.hidden=[8]"]


def _train_cfg(run_dir, *overrides):
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return compose("config", overrides=[*TINY, f"run_dir={run_dir}", *overrides])


def test_the_time_budget_stops_a_trainer_with_a_final_evaluation(tmp_path):
    result = train(_train_cfg(tmp_path / "ppo", *TINY_PPO, "algo.total_frames=1e7", "budget.wall_clock_s=0.5"))
    metrics = json.loads((tmp_path / "ppo" / "metrics.json").read_text())
    assert metrics["budget"] == {"wall_clock_s": 0.5, "env_steps": None, "cpu_s": None, "stopped_by": "wall_clock_s"}
    assert 0.5 <= result["train_wall_clock_s"] < 30 and result["iterations"] < 1e7 / 12
    assert 0 < result["train_cpu_s"] and "cpu_s" in json.loads((tmp_path / "ppo" / "metrics.jsonl").read_text()
                                                                 .splitlines()[0])
    assert result["episodes"] == 2 and (tmp_path / "ppo" / "checkpoints" / "last.pt").is_file()
    # the env-step budget, on SHAC (2 worlds x horizon 4 = 8 steps per iteration)
    result = train(_train_cfg(tmp_path / "shac", "algo=shac", "algo.horizon=4", "algo.hidden=[8]",
                              "algo.critic_iterations=1", "algo.iterations=1000", "budget.env_steps=20"))
    assert result["iterations"] == 3 and result["env_steps"] == 24
    assert result["budget"]["stopped_by"] == "env_steps"
    # the CPU-time budget (the process's training CPU time, which others' load does not take), on SHAC
    result = train(_train_cfg(tmp_path / "shac_cpu", "algo=shac", "algo.horizon=4", "algo.hidden=[8]",
                              "algo.critic_iterations=1", "algo.iterations=100000", "budget.cpu_s=0.3"))
    assert result["budget"]["stopped_by"] == "cpu_s" and 0.3 <= result["train_cpu_s"] < 30
    assert result["iterations"] < 100000 and result["train_wall_clock_s"] > 0


def test_a_tiny_real_sweep_end_to_end(tmp_path):
    spec = ("methods=[ppo]", "seeds=[0]", "budget.wall_clock_s=null",
            'run_overrides=["task.num_envs=2","task.max_episode_steps=6","eval.episodes=2","eval.every=1",'
            '"eval.curve_episodes=2"]')
    smoke = ('method_overrides.ppo=["algo.total_frames=24","algo.frames_per_batch=12","algo.minibatch_size=6",'
             '"algo.hidden=[8]"]')
    result = table.run_table(_table_cfg(tmp_path, *spec, smoke))
    assert (result["launched"], result["unfinished"]) == (1, [])
    row = read_csv(tmp_path / "sweep" / "runs.csv")[0]
    assert row["status"] == "finished" and row["env_steps"] == 24 and row["stopped_by"] == "schedule"
    # the one run is its task's fewest env steps: read at its end, the final evaluation
    assert row["equal_env_steps"] == 24 and row["success_at_equal_steps"] == row["success"]
    assert table.run_table(_table_cfg(tmp_path, *spec, smoke))["launched"] == 0  # the same spec: finished
    # a longer run in the same sweep directory does not reuse the 2-iteration one: the real trainer's config.yaml
    longer = smoke.replace("total_frames=24", "total_frames=36")
    result = table.run_table(_table_cfg(tmp_path, *spec, longer))
    assert (result["launched"], result["skipped"], result["unfinished"]) == (1, 0, [])
    assert read_csv(tmp_path / "sweep" / "runs.csv")[0]["env_steps"] == 36


def test_learning_rate_schedules_end_with_the_budget():
    from dexmots_rl.algorithms.budget import RunBudget

    counters = {"wall_clock_s": 30.0, "env_steps": 9000}
    assert RunBudget().progress(counters, schedule=0.2) == 0.2  # no budget: the schedule alone
    assert RunBudget(wall_clock_s=60.0).progress(counters, schedule=0.2) == 0.5
    assert RunBudget(wall_clock_s=60.0, env_steps=10000).progress(counters, schedule=0.2) == 0.9
    assert RunBudget(env_steps=5000).progress(counters, schedule=0.2) == 1.0  # past the budget: annealed


def test_a_planner_run_shows_no_training_and_no_budget_warning(tmp_path, monkeypatch):
    def finish(cfg):
        if cfg.algo.name != "mpc":
            return _fake_finished(Path(cfg.run_dir), "screw_claw", "ahac", 0.9, config=cfg)
        mpc = Path(cfg.run_dir)  # as algo=mpc leaves it: one evaluation row, no training
        mpc.mkdir(parents=True, exist_ok=True)
        (mpc / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
        (mpc / "metrics.jsonl").write_text(json.dumps({"iteration": 0, "success_rate": 0.95, "env_steps": 10000,
                                                       "wall_clock_s": 38.0}) + "\n")
        (mpc / "metrics.json").write_text(json.dumps({
            "task": "screw_claw", "algo": "mpc", "success_rate": 0.95, "episodes": 100, "env_steps": 10000,
            "iterations": 0, "train_wall_clock_s": 0.0,
            "budget": {} if cfg.seed == 0 else {"wall_clock_s": None, "env_steps": None, "stopped_by": "no_training"}}))

    _finished_sweep(tmp_path, monkeypatch, finish, "methods=[dexmots,mpc]")
    result = table.run_table(_table_cfg(tmp_path, "methods=[dexmots,mpc]"))
    assert "| Screw-top (Claw) | 20 s (2/2) | no training |" in result["table"]  # not "0 s (2/2)"
    assert "different budgets" not in result["table"] and "no_training (2)" in result["table"]
    rows = read_csv(tmp_path / "sweep" / "runs.csv")
    assert [r["time_to_90_s"] for r in rows if r["method"] == "mpc"] == [None, None]


def test_learning_curves_draw_a_planner_as_a_level():
    from dexmots_rl.viz.table_plots import plot_learning_curves

    trained = [[{"env_steps": 100 * i, "wall_clock_s": 10.0 * i, "success": 0.2 * i} for i in range(1, 5)]] * 2
    planner = [[{"env_steps": 10000, "wall_clock_s": 0.0, "success": s}] for s in (0.4, 0.6)]
    fig = plot_learning_curves({"dexmots": trained, "mpc": planner}, {"dexmots": "Ours", "mpc": "MPC"}, "Claw")
    for ax in fig.axes:
        lines = {line.get_label(): line for line in ax.get_lines()}
        level = lines["MPC (2 seeds, no training)"]
        assert list(level.get_ydata()) == [50.0, 50.0] and level.get_linestyle() == "--"
        assert len(lines["Ours (2 seeds)"].get_xdata()) > 1


def test_the_equal_steps_view_reads_each_run_at_the_fewest_env_steps_of_its_task():
    from dexmots_rl.apps.table_views import add_equal_steps, equal_steps_table, planning_cost, planning_cost_table

    def row(method, seed, env_steps, success, stopped_by="cpu_s"):
        return {"task": "screw_claw", "method": method, "seed": seed, "experiment": "table", "status": "finished",
                "stopped_by": stopped_by, "env_steps": env_steps, "success": success, "run_dir": f"{method}{seed}"}

    def point(env_steps, success, episodes=20):
        return {"env_steps": env_steps, "success": success, "episodes": episodes}

    curves = {  # periodic evaluations, then the final one at the run's last env step
        "dexmots0": [point(5_000, 0.6), point(10_000, 0.9, 100)],
        "dexmots1": [point(4_000, 0.4), point(12_000, 1.0, 100)],
        "ppo0": [point(6_000, 0.1), point(90_000, 0.8, 100)],
        "ppo1": [point(20_000, 0.3), point(80_000, 0.7, 100)],  # none by 10k
    }
    rows = add_equal_steps([row("dexmots", 0, 10_000, 0.9), row("dexmots", 1, 12_000, 1.0),
                            row("ppo", 0, 90_000, 0.8), row("ppo", 1, 80_000, 0.7),
                            row("mpc", 0, 400, 0.5, stopped_by="no_training")], curves.get)
    assert [r.get("success_at_equal_steps") for r in rows] == [0.9, 0.4, 0.1, None, None]
    assert {r.get("equal_env_steps") for r in rows[:4]} == {10_000} and "equal_env_steps" not in rows[4]
    # which evaluation each value is: its env steps and its episodes (the final one's 100, a periodic one's 20)
    assert [r.get("equal_steps_eval_env_steps") for r in rows] == [10_000, 4_000, 6_000, None, None]
    assert [r.get("equal_steps_eval_episodes") for r in rows] == [100, 20, 20, None, None]
    # a planner: its success and its planning CPU per evaluation episode, or that its run did not record it
    rows[4].update(planning_cost({"episodes": 4, "sim_steps": 4_000, "wall_clock_s": 2.0}))
    assert rows[4]["planning_sim_steps_per_episode"] == 1_000 and rows[4]["planning_wall_s_per_episode"] == 0.5
    methods = METHODS + [("mpc", "MPC")]
    assert equal_steps_table(rows, TASKS[:1], methods) == (
        "| Environment | Ours | PPO | MPC | Env steps (the run with the fewest) |\n|---|---:|---:|---:|---:|\n"
        "| Screw-top (Claw) | 65.0 ± 35.4 (at 4.0–10.0k, 20–100 ep) | 10.0 (n=1 of 2; at 6.0k, 20 ep) "
        "| 50.0 (CPU s / episode not recorded) | 10,000 (Ours, seed 0) |")
    assert planning_cost_table(rows, TASKS, "mpc") == (
        "| Environment | success % | sim steps / episode | CPU s / episode | wall s / episode |\n"
        "|---|---:|---:|---:|---:|\n| Screw-top (Claw) | 50.0 | 1,000 | not recorded | 0.50 |")
    rows[4].update(planning_cost({"episodes": 4, "sim_steps": 4_000, "wall_clock_s": 2.0,
                                  "planning_cpu_s_per_episode": 0.4567, "planning_wall_s_per_episode": 0.5}))
    assert "| 50.0 (0.46 CPU s / episode) |" in equal_steps_table(rows, TASKS[:1], methods)


def _fake_planner(run_dir: Path, task: str, success: float, config, cpu_s_per_episode: float | None) -> None:
    """A run directory as ``algo=mpc`` leaves it (one evaluation, no training); ``cpu_s_per_episode`` None: a
    run made before the planning's CPU time was recorded."""
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(config, resolve=True))
    cost = {"sim_steps": 120_000, "sim_steps_per_episode": 1_200, "wall_clock_s": 80.0}
    if cpu_s_per_episode is not None:
        cost.update(planning_cpu_s_per_episode=cpu_s_per_episode, planning_wall_s_per_episode=0.8)
    metrics = {"task": task, "algo": "mpc", "success_rate": success, "episodes": 100, "env_steps": 10_000,
               "iterations": 0, "train_wall_clock_s": 0.0, **cost,
               "budget": {"wall_clock_s": None, "env_steps": None, "cpu_s": None, "stopped_by": "no_training"}}
    (run_dir / "metrics.jsonl").write_text(json.dumps({"iteration": 0, "success_rate": success}) + "\n")
    (run_dir / "metrics.json").write_text(json.dumps(metrics))


def test_the_report_shows_both_views_and_the_planners_cost_from_a_sweep_directory(tmp_path, monkeypatch):
    """A fake sweep: DexMOTS collects 1k env steps per iteration, PPO 10k, so the equal count is DexMOTS's
    final 4k, where PPO has no evaluation yet but its first at 10k; MPC seed 0 was made before its planning
    CPU was recorded, seed 1 after."""
    def finish(cfg):
        run_dir, seed = Path(cfg.run_dir), cfg.seed
        if cfg.algo.name == "mpc":
            return _fake_planner(run_dir, "screw_claw", 0.5 + 0.1 * seed, cfg, None if seed == 0 else 1.25)
        _fake_finished(run_dir, "screw_claw", cfg.algo.name, 0.9, curve=(0.2 + 0.2 * seed, 0.6, 0.7), config=cfg)
        if cfg.algo.name == "ppo":  # ten times the env steps of DexMOTS per iteration
            for name in ("metrics.jsonl", "metrics.json"):
                text = (run_dir / name).read_text()
                (run_dir / name).write_text(text.replace('"env_steps": 1000', '"env_steps": 10000')
                                            .replace('"env_steps": 2000', '"env_steps": 20000')
                                            .replace('"env_steps": 3000', '"env_steps": 30000')
                                            .replace('"env_steps": 4000', '"env_steps": 40000'))

    methods = "methods=[dexmots,ppo,mpc]"
    _finished_sweep(tmp_path, monkeypatch, finish, methods)
    result = table.run_table(_table_cfg(tmp_path, methods, "report_only=true"))
    lines = result["table"].splitlines()
    rows = [line for line in lines if line.startswith("| Screw-top (Claw) |")]
    assert rows[0] == "| Screw-top (Claw) | 90.0 ± 0.0 | 90.0 ± 0.0 | 55.0 ± 7.1 |"  # at equal CPU, as before
    # at DexMOTS's 4,000 env steps: its final evaluations (100 episodes); PPO's last periodic one by then: none
    assert ("| Screw-top (Claw) | 90.0 ± 0.0 (at 4.0k, 100 ep) | – (n=0 of 2) | 55.0 ± 7.1 (1.25 CPU s / episode, n=1 of 2) "
            "| 4,000 (Ours, seed 0) |") in rows
    assert "| Screw-top (Claw) | 55.0 | 1,200 | 1.25 | 0.80 |" in rows  # the planning table: the run that has it
    assert any("not recorded" in line and "before" in line for line in lines)  # says why a cost is missing
    csv_rows = read_csv(tmp_path / "sweep" / "runs.csv")
    dexmots = [r for r in csv_rows if r["method"] == "dexmots"]
    assert [(r["equal_steps_eval_env_steps"], r["equal_steps_eval_episodes"]) for r in dexmots] == [(4000, 100)] * 2
    # a longer PPO count: PPO read at 10k from its first periodic evaluation (10 episodes)
    from dexmots_rl.apps.table_views import add_equal_steps
    from dexmots_rl.apps.table_writer import learning_curve

    ppo = [r for r in csv_rows if r["method"] == "ppo"]
    read = add_equal_steps([{**r, "task": "t"} for r in ppo] + [{**dexmots[0], "task": "t", "env_steps": 15_000}],
                           lambda d: learning_curve(tmp_path / "sweep" / d))
    assert [(r["success_at_equal_steps"], r["equal_steps_eval_env_steps"], r["equal_steps_eval_episodes"])
            for r in read[:2]] == [(0.2, 10_000, 10), (0.4, 10_000, 10)]
