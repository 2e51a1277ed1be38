"""dexmots-record and dexmots-rollout work on every task with their defaults (the task's scripted controller
where it has one, random actions elsewhere); asking for a controller a task lacks is one line naming the
options."""

from __future__ import annotations

import json

import pytest

from dexmots_rl.apps import record, rollout
from dexmots_rl.apps._policies import choose_policy, has_scripted_controller
from dexmots_rl.envs import list_tasks


@pytest.mark.parametrize("task", list_tasks())
def test_the_default_policy_exists_for_every_task(task):
    assert choose_policy("auto", task) == ("scripted" if has_scripted_controller(task) else "random")
    assert choose_policy("random", task) == "random"


def test_only_the_claw_has_a_scripted_controller():
    assert [t for t in list_tasks() if has_scripted_controller(t)] == ["screw_claw"]


def test_record_an_allegro_task_with_the_defaults(tmp_path, capsys):
    out = tmp_path / "stapler.mcap"
    record.main(["task=stapler", "num_envs=1", "steps=2", f"out={out}"])
    summary = json.loads(capsys.readouterr().out)
    assert summary["policy"] == "random" and summary["frames"] == 3 and out.stat().st_size > 0


def test_a_missing_controller_is_one_line_naming_the_options(tmp_path):
    with pytest.raises(SystemExit) as err:
        record.main(["task=stapler", "policy=scripted", f"out={tmp_path / 'x.mcap'}"])
    msg = str(err.value.code)
    assert msg.startswith("dexmots-record: task 'stapler' has no scripted controller") and "\n" not in msg
    assert "policy=random" in msg and "checkpoint=" in msg
    assert not (tmp_path / "x.mcap").exists()
    with pytest.raises(SystemExit) as err:
        rollout.main(["--task", "stapler", "--policy", "scripted"])
    assert "--policy random" in str(err.value.code)


def test_rollout_reports_no_success_rate_for_a_controller_that_cannot_reach_the_goal():
    summary = rollout.run(["--task", "screw_claw", "--num-envs", "2", "--steps", "3", "--json"])
    assert summary["policy"] == "scripted" and "scripted_success_rate" not in summary
    assert summary["mean_final_goal_error"] >= 0 and summary["sim_failures"] == 0
