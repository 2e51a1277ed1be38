"""Planning an articulated object's operated joint through the object simulator (optimize_joint_torques)."""

import pytest
import torch

from dexmots_rl.envs import make_env
from dexmots_rl.trajectories.joint_planner import optimize_joint_torques


@pytest.mark.slow  # a plan through the simulator, then a task following it
@pytest.mark.parametrize("name,joint,goal", [("drawer_a", "drawer", 0.03), ("spray_bottle_a", "trigger", 0.15)])
def test_the_plan_tracks_the_ramp_and_a_task_follows_it(name, joint, goal):
    """A slide (fixed base) and a sprung hinge (free base, held): the planned force brings the joint to the goal
    and the plan is a reference the operate task reads (goal: its last row)."""
    plan = optimize_joint_torques(name, joint, 0.0, goal, steps=6, iterations=60, progress=False)
    traj = plan.trajectory
    assert plan.final_error < 0.5 * plan.initial_error
    assert abs(float(traj.joint_q[-1, 0]) - goal) < 0.2 * goal
    assert traj.horizon == 7 and torch.isfinite(traj.joint_torque).all()
    env = make_env("operate", object=name, num_envs=2, references=[traj], seed=0, raw=True, differentiable=False)
    td = env.reset()
    assert torch.allclose(td["task", "goal"], traj.joint_q[-1].to(td["task", "goal"].dtype))


def test_a_joint_that_is_not_there_is_named():
    with pytest.raises(ValueError, match="joint 'lid' is not a joint"):
        optimize_joint_torques("drawer_a", "lid", 0.0, 0.05, steps=2, iterations=1, progress=False)


def test_dexmots_plan_writes_a_tool_tasks_plan(tmp_path):
    """dexmots-plan on an articulated task plans its operated joint; the file is a reference the task reads."""
    from dexmots_rl.apps.plan import main

    out = tmp_path / "drawer.pt"
    main(["--task", "drawer", "--goal", "0.03", "--steps", "3", "--iterations", "2", "--friction", "0.5", "--out",
          str(out)])
    env = make_env("drawer", num_envs=2, references=str(out), seed=0, raw=True, differentiable=False)
    assert env.reference_bank.batch_size == (1, 4)


@pytest.mark.parametrize("task, goal", [("stapler", 5.0), ("drawer", -0.01)])
def test_dexmots_plan_refuses_a_goal_outside_the_joints_range_naming_it(tmp_path, task, goal):
    from dexmots_rl.apps.plan import main
    from dexmots_rl.assets.objects import load_object
    from dexmots_rl.envs import task_config, task_scene

    config, tree = task_config(task), task_scene(task).tree
    lo, hi = tree.joint_range[tree.joint_names.index(config.joint or load_object(config.object).operated_joint)]
    out = tmp_path / "plan.pt"
    with pytest.raises(SystemExit, match=rf"^dexmots-plan: --goal {goal:g} is outside the range of joint "
                                         rf"'\w+': \[{lo:g}, {hi:g}\] (rad|m) \({task}'s operated joint\)$"):
        main(["--task", task, "--goal", str(goal), "--steps", "2", "--iterations", "1", "--out", str(out)])
    assert not out.exists()


def test_a_start_outside_the_range_is_named():
    with pytest.raises(ValueError, match=r"start 0.5 is outside the range of joint 'drawer': \[0, 0.\d+\] m"):
        optimize_joint_torques("drawer_a", "drawer", 0.5, 0.05, steps=2, iterations=1, progress=False)
