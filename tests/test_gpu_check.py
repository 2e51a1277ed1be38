"""dexmots-bench gpu (scripts/gpu_check.sh) end to end on CPU at tiny sizes, so the GPU check never rots."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "gpu_check.sh"


@pytest.mark.slow  # every benchmark of the script, a tool scene among them
def test_gpu_check_script_runs_end_to_end_on_cpu_and_writes_every_figure(tmp_path):
    out = tmp_path / "gpu_check.json"
    env = dict(os.environ, PYTHON=sys.executable, PYTHONPATH=str(SCRIPT.parents[1]))
    done = subprocess.run(["bash", str(SCRIPT), "--device", "cpu", "--out", str(out), "--tasks", "screw_claw", "spray_bottle",
                  "--num-envs", "2", "--rgb-envs", "2", "--min-time", "0.02", "--pipeline-steps", "2",
                  "--grad-horizon", "2", "--grad-draws", "1", "--agree-steps", "5", "--agree-envs", "2",
                  "--train-envs", "4", "--train-seconds", "2", "--eval-episodes", "2", "--compile-jobs", "1",
                  "--run-dir", str(tmp_path / "run"), "--quiet",
                  "algo.horizon=4", "algo.horizon_min=4", "algo.critic_iterations=2", "algo.critic_minibatches=2", "algo.hidden=[16]",
                  "task.max_episode_steps=6"], env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads(done.stdout)  # the same figures on stdout
    written = json.loads(out.read_text())
    assert set(written) >= {"machine", "compile", "throughput", "pipeline", "grad", "agreement", "train", "goals",
                            "goals_met", "seconds"}
    assert written["machine"]["warp"] and written["machine"]["device"] == "cpu"
    assert all(part["ok"] for part in written["compile"])
    rows = {(t["task"], t["obs"]): t["rows"] for t in written["throughput"]}
    assert set(rows) == {(task, obs) for task in ("screw_claw", "spray_bottle") for obs in ("state", "rgb")}
    for task_rows in rows.values():
        for row in task_rows:
            assert row["fwd_steps_per_s"] > 0 and row["fwdbwd_steps_per_s"] > 0 and row["mujoco_steps_per_s"] is None
    assert all(r["rollout_steps_per_s"] > 0 for p in written["pipeline"] for r in p["rows"])
    assert all(r["median_rel_err"] < 1e-4 for r in written["grad"]["rows"] if r["contact"])
    assert written["agreement"]["agree"] and written["agreement"]["max_abs_diff"] == 0.0  # CPU against itself
    train = written["train"]
    assert 0.0 <= train["success_rate"] <= 1.0 and train["wall_clock_s"] < 30 and train["env_steps"] > 0
    assert set(written["goals_met"]) >= {"screw_claw_fwd_steps_per_s", "spray_bottle_fwd_steps_per_s",
                                         "rgb_steps_per_s", "ahac_screw_claw_success"}
    assert all(math.isfinite(s) for s in written["seconds"].values())
    assert result["train"]["success_rate"] == train["success_rate"]


def test_gpu_check_without_a_gpu_is_one_clear_error():
    import pytest
    import torch

    from dexmots_rl.apps import bench

    if torch.cuda.is_available():
        pytest.skip("this machine has a GPU")
    with pytest.raises(SystemExit, match="device 'cuda' is not available"):
        bench.main(["gpu", "--device", "cuda"])
