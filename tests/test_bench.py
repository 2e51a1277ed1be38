"""dexmots-bench throughput, grad (AD vs finite differences, growth statistics) and train over seeds, on tiny
configurations."""

from __future__ import annotations

import math

import pytest

from dexmots_rl.apps.bench import build_parser, format_table, run
from dexmots_rl.envs import list_tasks


RATES = ("fwd", "fwdbwd", "mujoco")


@pytest.mark.parametrize("task", ["screw_claw", "spray_bottle"])  # a knob scene and a tool scene
def test_throughput_bench_reports_every_rate_in_contact(task):
    result = run(["throughput", "--task", task, "--num-envs", "2", "--min-time", "0.05",
                  "--settle-steps", "20", "--chunk-steps", "2", "--quiet"])
    (row,) = result["rows"]
    assert result["task"] == task and result["threads"] >= 1 and result["mujoco_threads"] >= 1
    assert row["num_envs"] == 2 and row["contact_fraction"] == 1.0 and row["mujoco_contact_fraction"] == 1.0
    for key in [f"{r}_steps_per_{clock}" for r in RATES for clock in ("s", "cpu_s")] + ["taped_fwd_ms", "reverse_ms"]:
        assert math.isfinite(row[key]) and row[key] > 0, key
    assert row["fwd_steps_per_s"] > row["fwdbwd_steps_per_s"]  # the backward pass is not free
    assert row["fwdbwd_cost"] == pytest.approx(row["fwd_steps_per_s"] / row["fwdbwd_steps_per_s"])
    assert row["fwdbwd_cost_per_cpu_s"] == pytest.approx(row["fwd_steps_per_cpu_s"] / row["fwdbwd_steps_per_cpu_s"])
    assert row["ratio_vs_mujoco"] == pytest.approx(row["fwd_steps_per_s"] / row["mujoco_steps_per_s"])
    assert row["ratio_vs_mujoco_per_cpu_s"] == pytest.approx(row["fwd_steps_per_cpu_s"] / row["mujoco_steps_per_cpu_s"])
    assert ("object" in result) == (task == "spray_bottle")


@pytest.mark.parametrize("task", list_tasks())
def test_throughput_bench_takes_every_registered_task(task):
    args = build_parser().parse_args(["throughput", "--task", task])
    assert args.task == task and not args.all


def test_throughput_bench_all_runs_every_registered_task_into_one_table(monkeypatch):
    from dexmots_rl.apps import bench_throughput

    def one_task(task, **options):  # the rows of one task, as run_throughput returns them
        return {"task": task, "device": "cpu", "dt": 0.001, "substeps": options["substeps"], "obs": options["obs"],
                "threads": 1, "mujoco_threads": 2, "rows": [{"num_envs": n, "fwd_steps_per_s": 1.0}
                                                            for n in options["num_envs"]]}

    monkeypatch.setattr(bench_throughput, "run_throughput", one_task)
    result = run(["throughput", "--all", "--num-envs", "2", "4", "--substeps", "8", "--quiet"])
    assert result["tasks"] == list_tasks() and result["substeps"] == 8
    assert [(r["task"], r["num_envs"]) for r in result["rows"]] == [(t, n) for t in list_tasks() for n in (2, 4)]
    assert all(r["object"] is None for r in result["rows"])  # one_task names none
    assert format_table(result).splitlines()[1].split()[:4] == ["task", "object", "dt", "num_envs"]


@pytest.mark.slow  # the benchmark at full size
def test_grad_bench_rows_agree_with_finite_differences():
    result = run(["grad", "--task", "screw_claw", "--horizons", "1", "4", "--draws", "2", "--num-entries", "4",
                  "--quiet"])
    rows = result["rows"]
    assert [(r["loss_kind"], r["horizon"], r["contact"]) for r in rows] == [
        (kind, h, c) for kind in ("pose", "velocity") for h in (1, 4) for c in (True, False)]
    for row in rows:
        assert row["draws"] == 2
        assert row["median_rel_err"] < 1e-4, row
        assert row["grad_growth_max"] >= row["grad_growth"] >= 1.0 - 1e-12
        assert math.isfinite(row["growth_per_step"]) and row["growth_per_step"] > 0
        assert (row["contact_fraction"] > 0) == row["contact"], row
    # one step: the only action is the last one
    assert all(r["grad_growth"] == 1.0 for r in rows if r["horizon"] == 1)
    assert result["goals_met"]["median_rel_err_with_contact"]
    assert "grad_growth_at_longest_horizon" in result["goals_met"]
    assert "goal grad_growth_at_longest_horizon" in format_table(result)


@pytest.mark.slow  # the tool scenes' float64 builds
@pytest.mark.parametrize("task, object_name, free_base", [("spray_bottle", None, True), ("operate", "drawer_a", False)])
def test_grad_bench_on_a_tool_task_agrees_through_contact(task, object_name, free_base):
    """The articulated scenes: from a squeezed pre-grasp (contact on every step) and from the hand extended
    clear (none), a free base's pose in the loss."""
    from dexmots_rl.apps.bench_setup import bench_tasks, grad_bench_tasks

    assert "spray_bottle" in grad_bench_tasks() and "spray_bottle" not in bench_tasks()  # no throughput poses
    argv = ["grad", "--task", task, "--horizons", "1", "2", "--draws", "1", "--num-entries", "4", "--quiet"]
    result = run(argv + (["--object", object_name] if object_name else []))
    assert result["free_base"] == free_base and result["object"] == (object_name or "spray_bottle_a")
    assert (result["base_tolerance"] is not None) == free_base
    assert len(result["rows"]) == 8
    for row in result["rows"]:
        assert row["median_rel_err"] < 1e-4 and row["max_rel_err"] < 1e-2, row
        assert row["grad_norm"] > 0, row
        assert (row["contact_fraction"] == 1.0) if row["contact"] else (row["contact_fraction"] == 0.0), row
    assert result["goals_met"]["median_rel_err_with_contact"]


def test_train_bench_over_seeds_reports_each_run_and_the_spread(tmp_path):
    tiny = ["task.num_envs=4", "algo.horizon=4", "algo.critic_iterations=2", "algo.critic_minibatches=2",
            "algo.hidden=[16]", "eval.episodes=4", "task.max_episode_steps=6", "algo.iterations=1"]
    result = run(["train", "--task", "screw_claw", "--algo", "shac", "--seeds", "0", "1", "--run-dir",
                  str(tmp_path), "--quiet", *tiny])
    runs = result["runs"]
    assert [r["seed"] for r in runs] == [0, 1] and result["seeds"] == [0, 1]
    for r in runs:
        assert (tmp_path / f"seed{r['seed']}" / "metrics.jsonl").exists()
        assert r["env_steps"] == 4 * 4
    rates = [r["success_rate"] for r in runs]
    assert result["success_rate"] == pytest.approx(sum(rates) / 2)
    assert result["success_rate_std"] == pytest.approx(abs(rates[0] - rates[1]) / math.sqrt(2))
    assert {"task", "algo", "success_rate", "wall_clock_s", "env_steps"} <= set(result)


@pytest.mark.parametrize("task", list_tasks())
def test_train_bench_takes_every_registered_task(task):
    args = build_parser().parse_args(["train", "--task", task, "--seed", "1", "algo.iterations=1"])
    assert (args.task, args.seed, args.overrides) == (task, 1, ["algo.iterations=1"])


def test_pipeline_bench_reports_rollout_and_collector_against_the_kernels():
    result = run(["pipeline", "--task", "screw_claw", "--num-envs", "4", "--steps", "3", "--min-time", "0.05",
                  "--quiet"])
    (row,) = result["rows"]
    for key in ("kernel_steps_per_s", "rollout_steps_per_s", "collector_steps_per_s"):
        assert math.isfinite(row[key]) and row[key] > 0, key
    assert row["rollout_fraction"] == pytest.approx(row["rollout_steps_per_s"] / row["kernel_steps_per_s"])
    assert row["collector_fraction"] == pytest.approx(row["collector_steps_per_s"] / row["kernel_steps_per_s"])


# one method times both loops in the fast set; PPO's pair (its own and torchrl's, ~3x SAC's CPU here) in the slow one
@pytest.mark.parametrize("methods", [["sac"], pytest.param(["ppo", "sac"], marks=pytest.mark.slow)], ids=" ".join)
def test_baselines_bench_times_our_loops_and_torchrls_on_the_same_env(methods):
    result = run(["baselines", "--num-envs", "4", "--iterations", "2", "--methods", *methods, "--quiet",
                  "algo.hidden=[16]", "sac:algo.batch_size=8", "task.max_episode_steps=6"])
    assert [r["method"] for r in result["rows"]] == methods
    for row in result["rows"]:
        for who in ("ours", "reference"):
            for key in ("env_steps_per_cpu_s", "updates_per_cpu_s", "env_steps_per_wall_s", "updates_per_wall_s"):
                assert math.isfinite(row[f"{who}_{key}"]) and row[f"{who}_{key}"] > 0, (row["method"], who, key)
        assert row["ratio_updates_per_cpu_s"] == pytest.approx(row["ours_updates_per_cpu_s"]
                                                               / row["reference_updates_per_cpu_s"])


def test_baselines_bench_rates_leave_out_the_warm_up_and_count_only_learning_iterations():
    from dexmots_rl.apps.bench_baselines import rates

    row = {"collect_cpu_s": 1.0, "collect_wall_s": 2.0, "learn_cpu_s": 0.5, "learn_wall_s": 1.0}
    rows = [{**row, "env_steps": 999, "updates": 999, "collect_cpu_s": 100.0},  # warm-up: left out
            {**row, "env_steps": 10, "updates": 0, "learn_cpu_s": 9.0},          # random frames: no updates
            {**row, "env_steps": 10, "updates": 4}]
    out = rates(rows)
    assert out["env_steps_per_cpu_s"] == 10.0 and out["env_steps_per_wall_s"] == 5.0
    assert out["updates_per_cpu_s"] == 8.0 and out["updates_per_wall_s"] == 4.0
