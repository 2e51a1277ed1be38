"""Pose-only demonstrations (``task.demo``): read, checked, resampled and followed by the tasks."""

import numpy as np
import pytest
import torch

from dexmots_rl.envs import make_env
from dexmots_rl.envs.demos import part_torque, read_demo, resample
from dexmots_rl.trajectories import TrajectoryFormatError


def _ramp(rows=31, dt=1 / 30, end=0.3):
    """A minimum-jerk move to ``end`` over ``rows`` rows, then held for 10 rows."""
    s = np.concatenate([np.linspace(0.0, 1.0, rows), np.ones(10)])
    return {"dt": dt, "joint_q": (end * (10 * s**3 - 15 * s**4 + 6 * s**5))[:, None]}


def test_resample_keeps_the_motion():
    rows = resample(read_demo(_ramp()), 1 / 60)
    assert rows["joint_q"].shape == (81, 1)
    assert torch.allclose(rows["joint_q"][::2], torch.as_tensor(_ramp()["joint_q"]))


@pytest.mark.parametrize("task,kwargs", [("operate", {"object": "spray_bottle_a"}), ("screw_claw", {})])
def test_a_task_follows_the_demonstration(tmp_path, task, kwargs):
    """The goal is the demonstration's last row; the reference's rows are the demonstration at the control
    step, with the force the nominal part needs for that motion."""
    path = tmp_path / "demo.npz"
    np.savez(path, **_ramp())
    env = make_env(task, num_envs=2, demo=str(path), seed=0, raw=True, **kwargs)
    td = env.reset()
    assert torch.allclose(td["task", "goal"], torch.tensor(0.3, dtype=td["task", "goal"].dtype))
    steps = torch.arange(81).expand(2, -1)
    ref = env.reference(td, steps)
    expected = resample(read_demo(_ramp()), env.sim.dt)["joint_q"].to(ref["joint_q"].dtype)
    assert torch.allclose(ref["joint_q"][0], expected, atol=1e-6)
    hold = part_torque(torch.zeros(1), torch.tensor([0.3]), [torch.as_tensor(v) for v in env._nominal])
    assert torch.allclose(ref["joint_torque"][0, -1].double(), hold.double(), atol=1e-6)
    angle, torque = env.joint_reference(td, steps)
    assert torch.equal(angle, ref["joint_q"]) and torch.equal(torque, ref["joint_torque"])
    rollout = make_env(task, num_envs=2, demo=str(path), seed=0, **kwargs).rollout(3)
    assert torch.isfinite(rollout["next", "reward"]).all()


@pytest.mark.parametrize("field,value,words", [
    ("dt", None, "'dt' is missing"),
    ("dt", -0.1, "'dt' must be a positive"),
    ("joint_q", None, "'joint_q' is missing"),
    ("joint_q", np.zeros((31, 2)), "'joint_q' must have 1 column"),
    ("joint_q", np.full((31, 1), np.nan), "'joint_q' contains non-finite"),
    ("pos", np.zeros((30, 3)), "'pos' has 30 rows"),
    ("quat", np.zeros((41, 4)), "'quat' has zero-length"),
    ("speed", np.zeros(41), "unknown field 'speed'"),
])
def test_a_bad_demonstration_names_its_field(tmp_path, field, value, words):
    data = _ramp()
    if value is None:
        data.pop(field)
    else:
        data[field] = value
    path = tmp_path / "demo.npz"
    np.savez(path, **data)
    with pytest.raises(TrajectoryFormatError, match=words):
        make_env("operate", num_envs=2, demo=str(path), seed=0)


def test_demo_and_references_are_exclusive(tmp_path):
    path = tmp_path / "demo.npz"
    np.savez(path, **_ramp())
    with pytest.raises(ValueError, match="task.demo and task.references"):
        make_env("screw_claw", num_envs=2, demo=str(path), references=str(path))
    with pytest.raises(ValueError, match="does not follow pose-only demonstrations"):
        make_env("repose_cube", num_envs=2, demo=str(path))
