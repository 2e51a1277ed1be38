"""dexmots-bench sysid-loop: record on the truth, identify from a wrong nominal model, train on each model and
evaluate every policy on the truth (tiny sizes: one training iteration, a few episodes)."""

from __future__ import annotations

import json

import pytest
import yaml

from dexmots_rl.apps.bench import main as bench_main, run as bench


@pytest.mark.slow  # three training runs (one iteration each)
def test_the_loop_identifies_trains_on_each_model_and_evaluates_on_the_truth(tmp_path, capsys):
    out = tmp_path / "loop"
    result = bench(["sysid-loop", "--truth", "joint_damping=0.8", "joint_friction=0.6", "--record-worlds", "2",
                    "--record-steps", "32", "--sysid-iterations", "15", "--method", "gn", "--episodes", "2",
                    "--out-dir", str(out), "-q", "algo.iterations=1", "task.num_envs=2", "eval.episodes=1",
                    "algo.horizon=4", "algo.horizon_min=4"])
    models = result["models"]
    assert models["nominal"] == {"joint_damping": 0.4, "joint_friction": 0.3}
    # identified from the x0.5 nominal on the truth's recording
    for name, value in models["truth"].items():
        assert models["identified"][name] == pytest.approx(value, rel=0.01), models
    assert [r["model"] for r in result["rows"]] == ["truth", "nominal", "identified"]
    for row in result["rows"]:
        # each policy was trained on its own model's file ...
        trained_on = yaml.safe_load((out / f"{row['model']}_seed0" / "config.yaml").read_text())["task"]
        assert json.loads(open(trained_on["object_params"]).read())["params"] == pytest.approx(models[row["model"]])
        assert 0.0 <= row["success_on_truth"] <= 1.0
    # ... and the table says how far the identified model's policy is from the truth's
    gap = 100 * (result["mean_success_on_truth"]["truth"] - result["mean_success_on_truth"]["identified"])
    assert result["identified_gap_points"] == pytest.approx(gap) and result["goal_met"] == (gap <= 5.0)


@pytest.mark.parametrize("argv, message", [
    (["--truth", "joint_mass=1.0"], "--truth joint_mass=1.0: task 'screw_claw'.s object has no parameter"),
    (["--truth", "joint_damping=0"], "--truth joint_damping=0.0: must be positive"),
    (["--nominal-scale", "1"], "--nominal-scale must be positive and not 1"),
])
def test_bad_input_is_one_error_before_any_file(tmp_path, argv, message):
    out = tmp_path / "loop"
    with pytest.raises(SystemExit, match=f"^dexmots-bench: {message}"):
        bench_main(["sysid-loop", "--out-dir", str(out), *argv])
    assert not out.exists()


@pytest.mark.parametrize("result", [{"interrupted": "SIGTERM", "iteration": 140, "run_dir": "runs/x"}, {}])
def test_a_training_stopped_before_its_evaluation_is_one_line_saying_how_to_continue(monkeypatch, result):
    """A signal (or stop_after) ends a benchmark's training before its final evaluation: one line naming the run
    and the resume command, not a KeyError from the missing success rate."""
    import argparse

    from dexmots_rl.apps import bench_setup, train

    monkeypatch.setattr(train, "run", lambda cfg: dict(result))
    args = argparse.Namespace(task="screw_claw", algo="ahac", device="cpu", overrides=[])
    with pytest.raises(SystemExit, match=r"^dexmots-bench: the training in runs/x stopped( at iteration 140)? before "
                                         r"its evaluation .*dexmots-train resume=runs/x"):
        bench_setup.train_one(args, 0, "runs/x")
