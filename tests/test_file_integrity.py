"""Files under bad input: checksummed checkpoints and plans, sane reference plans, dexmots-plan argument checks,
atomic writes at the umask's mode, strict JSON, stale temp files, one-line errors on a full disk."""

from __future__ import annotations

import errno
import json
import os
import stat

import pytest
import torch

from dexmots_rl.algorithms.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from dexmots_rl.atomic import atomic_write, atomic_write_json, clean_stale_temps, dumps_json
from dexmots_rl.trajectories import PoseWrenchTrajectory, TrajectoryFormatError

MARK = torch.arange(256, dtype=torch.float32) * 1.2345 + 7.0  # distinctive bytes to find in the file


def _flip_bit_in(path, needle: bytes, at: int, bit: int = 3) -> None:
    raw = bytearray(path.read_bytes())
    start = raw.find(needle)
    assert start >= 0, "tensor bytes not found in the file"
    raw[start + at] ^= 1 << bit
    path.write_bytes(bytes(raw))


def _plan(T=5, joint_q=None):
    quat = torch.tensor([[1.0, 0.0, 0.0, 0.0]] * T)
    return PoseWrenchTrajectory(torch.zeros(T, 3), quat, torch.zeros(T, 6), dt=0.1,
                                joint_q=torch.linspace(0, 1, T).reshape(T, 1) if joint_q is None else joint_q)


@pytest.mark.parametrize("at", [0, 513, 1023])
def test_bit_flip_in_a_checkpoint_tensor_is_one_clear_error(tmp_path, at):
    path = tmp_path / "last.pt"
    save_checkpoint(path, {"task": "screw_claw", "algo": "shac", "iteration": 1, "modules": {"actor": {"w": MARK}}})
    assert torch.equal(load_checkpoint(path)["modules"]["actor"]["w"], MARK)
    _flip_bit_in(path, MARK.numpy().tobytes(), at)
    with pytest.raises(CheckpointError, match="checksum") as err:
        load_checkpoint(path)
    assert str(path) in str(err.value)


def test_checkpoint_without_its_checksum_is_refused(tmp_path):
    path = tmp_path / "last.pt"
    save_checkpoint(path, {"task": "screw_claw", "iteration": 1})
    data = torch.load(path, weights_only=True)
    del data["sha256"]
    torch.save(data, path)
    with pytest.raises(CheckpointError, match="checksum"):
        load_checkpoint(path)


@pytest.mark.parametrize("field, at", [("joint_q", 1), ("pos", 0)])
def test_bit_flip_in_a_plan_tensor_is_one_clear_error(tmp_path, field, at):
    T = 64
    values = torch.linspace(0.25, 0.75, T * 3).reshape(T, 3)
    plan = (_plan(T, joint_q=values[:, :1].clone()) if field == "joint_q" else
            PoseWrenchTrajectory(values, torch.tensor([[1.0, 0, 0, 0]] * T), torch.zeros(T, 6), dt=0.1))
    path = tmp_path / "plan.pt"
    plan.save(path)
    _flip_bit_in(path, getattr(plan, field).numpy().tobytes(), at * 4 + 1, bit=0)  # a mantissa bit: still valid
    with pytest.raises(TrajectoryFormatError, match="checksum") as err:
        PoseWrenchTrajectory.load(path)
    assert str(path) in str(err.value)


def test_legacy_version_1_plan_still_loads(tmp_path):
    data = _plan().state_dict()
    data = {**{k: v for k, v in data.items() if k != "sha256"}, "version": 1}
    torch.save(data, tmp_path / "old.pt")
    assert PoseWrenchTrajectory.load(tmp_path / "old.pt").horizon == 5


@pytest.mark.parametrize("angle", [3.46e8, -101.0])
def test_make_env_rejects_absurd_reference_plans(tmp_path, angle):
    from dexmots_rl.envs import make_env

    joint_q = torch.zeros(5, 1)
    joint_q[3] = angle
    _plan(joint_q=joint_q).save(tmp_path / "bad.pt")
    with pytest.raises(ValueError, match="joint_q"):
        make_env("screw_claw", num_envs=1, references=str(tmp_path / "bad.pt"), raw=True)


@pytest.mark.parametrize("args, option", [
    (["--goal", "1e9"], "--goal"), (["--goal", "nan"], "--goal"), (["--goal", "1", "--friction", "-1"], "--friction"),
    (["--goal", "1", "--damping", "inf"], "--damping"), (["--goal", "1", "--steps", "0"], "--steps"),
    (["--goal", "1", "--lr", "nan"], "--lr"), (["--goal", "1", "--start=-1e9"], "--start"),
])
def test_plan_cli_rejects_bad_values_with_one_line_and_writes_nothing(tmp_path, args, option):
    from dexmots_rl.apps.plan import main

    out = tmp_path / "plans"
    with pytest.raises(SystemExit) as err:
        main([*args, "--out", str(out)])
    msg = str(err.value.code)
    assert msg.startswith("dexmots-plan:") and option in msg and "\n" not in msg
    assert not out.exists()


def test_plan_cli_refuses_an_articulated_tool_task_with_one_line(tmp_path):
    from dexmots_rl.apps.plan import main

    out = tmp_path / "plan.pt"
    with pytest.raises(SystemExit) as err:
        main(["--task", "stapler", "--goal", "0.2", "--out", str(out)])
    msg = str(err.value.code)
    assert msg.startswith("dexmots-plan: --task 'stapler' operates an articulated object") and "\n" not in msg
    assert "optimize_joint_torques" in msg and not out.exists()


def test_atomic_writes_get_the_umask_default_mode(tmp_path):
    old = os.umask(0o022)
    try:
        atomic_write(tmp_path / "a.bin", lambda f: f.write(b"x"))
        save_checkpoint(tmp_path / "c.pt", {"iteration": 0})
        _plan().save(tmp_path / "p.pt")
        os.umask(0o027)
        atomic_write(tmp_path / "b.bin", lambda f: f.write(b"x"))
    finally:
        os.umask(old)
    for name in ("a.bin", "c.pt", "p.pt"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == 0o644, name
    assert stat.S_IMODE((tmp_path / "b.bin").stat().st_mode) == 0o640


def test_json_outputs_are_strict_json(tmp_path):
    row = {"success": float("nan"), "x": [1.0, float("inf")], "n": 3}
    assert json.loads(dumps_json(row)) == {"success": None, "x": [1.0, None], "n": 3}
    atomic_write_json(tmp_path / "m.json", row)
    text = (tmp_path / "m.json").read_text()
    assert "NaN" not in text and "Infinity" not in text
    json.loads(text, parse_constant=lambda c: pytest.fail(f"bare {c}"))


def test_stale_temp_files_are_cleaned(tmp_path):
    (tmp_path / ".last.pt.abc123.tmp").write_bytes(b"")
    (tmp_path / "last.pt").write_bytes(b"keep")
    removed = clean_stale_temps(tmp_path)
    assert [p.name for p in removed] == [".last.pt.abc123.tmp"]
    assert sorted(os.listdir(tmp_path)) == ["last.pt"]


def test_full_disk_is_a_one_line_error_from_the_console_scripts(tmp_path, monkeypatch):
    import dexmots_rl.apps.eval as eval_app

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "eval.json"))

    monkeypatch.setattr(eval_app, "_run", full)
    with pytest.raises(SystemExit) as err:
        eval_app.main([str(tmp_path)])
    msg = str(err.value.code)
    assert msg.startswith("dexmots-eval: no space left on device") and "\n" not in msg
