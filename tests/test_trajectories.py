"""PoseWrenchTrajectory file format / indexing, and finite-difference wrenches against an analytic free body."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest
import torch

from dexmots_rl.quaternions import quat_multiply, quat_to_matrix
from dexmots_rl.trajectories import PoseWrenchTrajectory, TrajectoryFormatError, load_pose_demo, wrenches_from_poses


def make_traj(T: int = 7, K: int = 1, dtype: torch.dtype = torch.float32) -> PoseWrenchTrajectory:
    g = torch.Generator().manual_seed(0)
    quat = torch.randn(T, 4, generator=g, dtype=dtype)
    quat = quat / quat.norm(dim=-1, keepdim=True)
    return PoseWrenchTrajectory(
        torch.randn(T, 3, generator=g, dtype=dtype),
        quat,
        torch.randn(T, 6, generator=g, dtype=dtype),
        dt=0.05,
        joint_q=torch.randn(T, K, generator=g, dtype=dtype),
        joint_torque=torch.randn(T, K, generator=g, dtype=dtype),
    )


# ------------------------------------------------------------------------------------------ basic structure
def test_properties_and_shapes():
    traj = make_traj(T=7, K=1)
    assert traj.horizon == 7 and len(traj) == 7 and traj.num_joints == 1
    assert traj.dt == 0.05
    assert traj.poses.shape == (7, 7)
    assert torch.equal(traj.poses[:, :3], traj.pos) and torch.equal(traj.poses[:, 3:], traj.quat)
    assert traj.td.batch_size == torch.Size([7])
    assert set(traj.td.keys()) == {"pos", "quat", "joint_q", "wrench", "joint_torque"}


def test_no_articulation_defaults_to_k0():
    q = torch.tensor([[1.0, 0, 0, 0]] * 3)
    traj = PoseWrenchTrajectory(torch.zeros(3, 3), q, torch.zeros(3, 6), dt=0.1)
    assert traj.joint_q.shape == (3, 0) and traj.joint_torque.shape == (3, 0)


def test_at_clamps():
    traj = make_traj(T=5)
    assert torch.equal(traj.at(2)["pos"], traj.pos[2])
    assert torch.equal(traj.at(100)["pos"], traj.pos[4])
    batched = traj.at(torch.tensor([0, 4, 9]))
    assert batched.batch_size == torch.Size([3])
    assert torch.equal(batched["quat"], traj.quat[[0, 4, 4]])
    with pytest.raises(IndexError):
        traj.at(-1)


def test_slice_padding_and_shapes():
    traj = make_traj(T=5, K=2)
    inner = traj.slice(1, 3)
    assert isinstance(inner, PoseWrenchTrajectory) and inner.horizon == 3 and inner.dt == traj.dt
    assert torch.equal(inner.pos, traj.pos[1:4])
    padded = traj.slice(3, 6)
    assert padded.horizon == 6
    assert padded.joint_q.shape == (6, 2) and padded.wrench.shape == (6, 6) and padded.poses.shape == (6, 7)
    assert torch.equal(padded.wrench[:2], traj.wrench[3:5])
    for k in range(2, 6):  # everything past the end repeats the last step
        assert torch.equal(padded.td[k]["pos"], traj.pos[-1])
        assert torch.equal(padded.td[k]["joint_torque"], traj.joint_torque[-1])
    beyond = traj.slice(10, 2)
    assert torch.equal(beyond.quat, traj.quat[[4, 4]])
    win = traj.window(torch.tensor([0, 3]), 4)
    assert win.batch_size == torch.Size([2, 4])
    assert torch.equal(win["pos"][1], traj.pos[[3, 4, 4, 4]])
    with pytest.raises(ValueError):
        traj.slice(0, 0)


def test_to_device_keeps_values():
    traj = make_traj()
    assert traj.to("cpu") is traj
    moved = traj.to("meta")
    assert moved.device == torch.device("meta") and moved.horizon == traj.horizon and moved.dt == traj.dt


# ------------------------------------------------------------------------------------------ save / load
def test_round_trip_exact(tmp_path):
    for dtype, K in ((torch.float32, 1), (torch.float64, 0), (torch.float64, 3)):
        traj = make_traj(T=9, K=K, dtype=dtype)
        path = tmp_path / f"plan_{K}.pt"
        traj.save(path)
        back = PoseWrenchTrajectory.load(path)
        assert back.dt == traj.dt
        for key in ("pos", "quat", "joint_q", "wrench", "joint_torque"):
            assert back.td[key].dtype == dtype
            assert torch.equal(back.td[key], traj.td[key]), key


def test_file_is_a_plain_dict(tmp_path):
    path = tmp_path / "plan.pt"
    make_traj().save(path)
    data = torch.load(path, weights_only=True)
    assert type(data) is dict
    assert data["format"] == "dexmots-trajectory" and data["version"] == 2 and type(data["dt"]) is float


def test_atomic_write_leaves_no_temp_files(tmp_path):
    path = tmp_path / "plan.pt"
    make_traj().save(path)
    make_traj(T=3).save(path)  # overwrite
    assert os.listdir(tmp_path) == ["plan.pt"]
    assert PoseWrenchTrajectory.load(path).horizon == 3


def test_failed_save_keeps_old_file(tmp_path, monkeypatch):
    path = tmp_path / "plan.pt"
    good = make_traj(T=4)
    good.save(path)
    before = path.read_bytes()
    real_save = torch.save

    def broken_save(obj, f, *args, **kwargs):
        f.write(b"PK\x03\x04 partial garbage")  # some bytes hit the disk before the failure
        raise OSError("disk full")

    monkeypatch.setattr(torch, "save", broken_save)
    with pytest.raises(OSError, match="disk full"):
        make_traj(T=8).save(path)
    monkeypatch.setattr(torch, "save", real_save)
    assert path.read_bytes() == before
    assert os.listdir(tmp_path) == ["plan.pt"]
    assert torch.equal(PoseWrenchTrajectory.load(path).pos, good.pos)


def _good_dict(T: int = 4, K: int = 1) -> dict:
    return make_traj(T=T, K=K).state_dict()


def _write(tmp_path, data) -> str:
    path = tmp_path / "bad.pt"
    torch.save(data, path)
    return path


def _unnormalised(d):
    d["quat"] = d["quat"] * 1.01
    return d


BAD_CASES = {
    # id: (mutation of a good dict, substring the message must contain)
    "wrong_format": (lambda d: {**d, "format": "something-else"}, "'format'"),
    "missing_format": (lambda d: {k: v for k, v in d.items() if k != "format"}, "'format'"),
    "not_a_dict": (lambda d: [d["pos"]], "'format'"),
    "bad_version": (lambda d: {**d, "version": 3}, "'version'"),
    "missing_version": (lambda d: {k: v for k, v in d.items() if k != "version"}, "'version'"),
    "missing_dt": (lambda d: {k: v for k, v in d.items() if k != "dt"}, "'dt'"),
    "dt_zero": (lambda d: {**d, "dt": 0.0}, "'dt'"),
    "dt_negative": (lambda d: {**d, "dt": -0.1}, "'dt'"),
    "dt_nan": (lambda d: {**d, "dt": float("nan")}, "'dt'"),
    "dt_inf": (lambda d: {**d, "dt": float("inf")}, "'dt'"),
    "dt_string": (lambda d: {**d, "dt": "0.1"}, "'dt'"),
    "missing_pos": (lambda d: {k: v for k, v in d.items() if k != "pos"}, "'pos'"),
    "missing_quat": (lambda d: {k: v for k, v in d.items() if k != "quat"}, "'quat'"),
    "missing_joint_q": (lambda d: {k: v for k, v in d.items() if k != "joint_q"}, "'joint_q'"),
    "missing_wrench": (lambda d: {k: v for k, v in d.items() if k != "wrench"}, "'wrench'"),
    "missing_joint_torque": (lambda d: {k: v for k, v in d.items() if k != "joint_torque"}, "'joint_torque'"),
    "pos_int_dtype": (lambda d: {**d, "pos": d["pos"].long()}, "'pos'"),
    "wrench_bool_dtype": (lambda d: {**d, "wrench": d["wrench"] > 0}, "'wrench'"),
    "pos_not_tensor": (lambda d: {**d, "pos": d["pos"].tolist()}, "'pos'"),
    "pos_wrong_width": (lambda d: {**d, "pos": torch.zeros(4, 2)}, "'pos'"),
    "pos_1d": (lambda d: {**d, "pos": torch.zeros(12)}, "'pos'"),
    "quat_wrong_width": (lambda d: {**d, "quat": d["quat"][:, :3]}, "'quat'"),
    "wrench_wrong_width": (lambda d: {**d, "wrench": torch.zeros(4, 3)}, "'wrench'"),
    "mismatched_T": (lambda d: {**d, "wrench": torch.zeros(5, 6)}, "'wrench'"),
    "mismatched_T_quat": (lambda d: {**d, "quat": d["quat"][:3]}, "'quat'"),
    "joint_K_mismatch": (lambda d: {**d, "joint_torque": torch.zeros(4, 2)}, "'joint_torque'"),
    "empty_T": (lambda d: {**d, **{k: d[k][:0] for k in ("pos", "quat", "joint_q", "wrench", "joint_torque")}},
                "'pos'"),
    "pos_nan": (lambda d: {**d, "pos": d["pos"].index_fill(0, torch.tensor([1]), float("nan"))}, "'pos'"),
    "wrench_inf": (lambda d: {**d, "wrench": d["wrench"].index_fill(0, torch.tensor([2]), float("inf"))},
                   "'wrench'"),
    "joint_q_nan": (lambda d: {**d, "joint_q": torch.full_like(d["joint_q"], float("nan"))}, "'joint_q'"),
    "quat_not_unit": (_unnormalised, "'quat'"),
    "quat_zero": (lambda d: {**d, "quat": torch.zeros_like(d["quat"])}, "'quat'"),
}


@pytest.mark.parametrize("case", sorted(BAD_CASES))
def test_malformed_file_names_field(tmp_path, case):
    mutate, needle = BAD_CASES[case]
    path = _write(tmp_path, mutate(_good_dict()))
    with pytest.raises(TrajectoryFormatError) as info:
        PoseWrenchTrajectory.load(path)
    assert needle in str(info.value), str(info.value)
    assert isinstance(info.value, ValueError)


def test_missing_file(tmp_path):
    with pytest.raises(TrajectoryFormatError, match="not found"):
        PoseWrenchTrajectory.load(tmp_path / "nope.pt")


@pytest.mark.parametrize("keep", [0, 10, 200, -30])
def test_truncated_or_corrupted_file(tmp_path, keep):
    good = tmp_path / "good.pt"
    make_traj().save(good)
    raw = good.read_bytes()
    bad = tmp_path / "bad.pt"
    bad.write_bytes(raw[:keep] if keep >= 0 else raw[:keep])
    with pytest.raises(TrajectoryFormatError, match="truncated or corrupted"):
        PoseWrenchTrajectory.load(bad)


def test_pickled_class_is_rejected(tmp_path):
    # weights_only=True must refuse arbitrary objects rather than execute them
    path = tmp_path / "obj.pt"
    torch.save({"format": "dexmots-trajectory", "obj": make_traj()}, path)
    with pytest.raises(TrajectoryFormatError, match="truncated or corrupted"):
        PoseWrenchTrajectory.load(path)


def test_constructor_validates_too():
    q = torch.tensor([[1.0, 0, 0, 0]] * 3)
    with pytest.raises(TrajectoryFormatError, match="'quat'"):
        PoseWrenchTrajectory(torch.zeros(3, 3), 2 * q, torch.zeros(3, 6), dt=0.1)
    with pytest.raises(TrajectoryFormatError, match="'dt'"):
        PoseWrenchTrajectory(torch.zeros(3, 3), q, torch.zeros(3, 6), dt=0)
    with pytest.raises(TrajectoryFormatError, match="'wrench'"):
        PoseWrenchTrajectory(torch.zeros(3, 3), q, torch.zeros(2, 6), dt=0.1)
    with pytest.raises(TrajectoryFormatError, match="'joint_torque'"):
        PoseWrenchTrajectory(torch.zeros(3, 3), q, torch.zeros(3, 6), dt=0.1,
                             joint_q=torch.zeros(3, 1), joint_torque=torch.zeros(3, 2))


# ------------------------------------------------------------------------------------------ finite differences
MASS = 1.7
INERTIA = torch.tensor([[0.09, 0.01, 0.0], [0.01, 0.14, -0.02], [0.0, -0.02, 0.21]], dtype=torch.float64)
FORCE = torch.tensor([1.5, -0.7, 2.2], dtype=torch.float64)  # constant, world frame
BODY_TORQUE = torch.tensor([0.05, -0.12, 0.08], dtype=torch.float64)  # constant in the body frame


def _free_body_derivative(state: torch.Tensor) -> torch.Tensor:
    # state = [x(3), v(3), q(4, wxyz), w_body(3)]; Newton–Euler in the body frame for rotation
    v, q, wb = state[3:6], state[6:10], state[10:13]
    qdot = 0.5 * quat_multiply(q, torch.cat([wb.new_zeros(1), wb]))
    wdot = torch.linalg.solve(INERTIA, BODY_TORQUE - torch.linalg.cross(wb, INERTIA @ wb))
    return torch.cat([v, FORCE / MASS, qdot, wdot])


def simulate_free_body(T: int, dt: float, substeps: int = 200) -> tuple[torch.Tensor, torch.Tensor]:
    """RK4 in float64 with ``substeps`` steps per sample; returns sampled pos [T,3], quat [T,4]."""
    q0 = torch.tensor([0.9, 0.2, -0.3, 0.25], dtype=torch.float64)
    state = torch.cat([
        torch.tensor([0.1, -0.2, 0.3, 0.4, 0.0, -0.5], dtype=torch.float64),
        q0 / q0.norm(),
        torch.tensor([1.2, -0.8, 2.0], dtype=torch.float64),  # tumbling, so the gyroscopic term matters
    ])
    h = dt / substeps
    out = [state.clone()]
    for _ in range(T - 1):
        for _ in range(substeps):
            k1 = _free_body_derivative(state)
            k2 = _free_body_derivative(state + 0.5 * h * k1)
            k3 = _free_body_derivative(state + 0.5 * h * k2)
            k4 = _free_body_derivative(state + h * k3)
            state = state + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            state[6:10] = state[6:10] / state[6:10].norm()
        out.append(state.clone())
    s = torch.stack(out)
    return s[:, :3], s[:, 6:10]


def _fd_errors(T: int, dt: float) -> tuple[float, float, float]:
    pos, quat = simulate_free_body(T, dt)
    w = wrenches_from_poses(pos, quat, dt, MASS, INERTIA)
    assert w.shape == (T, 6) and w.dtype == torch.float64
    true_torque = quat_to_matrix(quat) @ BODY_TORQUE  # the body-fixed torque seen in the world frame
    f_err = (w[1:-1, :3] - FORCE).abs().max().item()
    t_err = (w[1:-1, 3:] - true_torque[1:-1]).abs().max().item()
    t_end_err = (w[[0, -1], 3:] - true_torque[[0, -1]]).abs().max().item()
    return f_err, t_err, t_end_err


def test_fd_wrench_matches_free_body():
    T, dt = 30, 0.01
    f_err, t_err, t_end_err = _fd_errors(T, dt)
    # positions are exactly quadratic under a constant force, so the second difference is exact up to rounding
    # (x ~ 1, divided by dt² = 1e-4 → ~1e-12 relative)
    assert f_err < 1e-8 * FORCE.abs().max().item() / dt**2
    # interior torque is second order: error ≈ C·dt² with C ~ |I|·|d³ω/dt³| ≈ 0.1 → ~1e-5 at dt = 0.01
    # (measured 7.7e-6; the order itself is checked below), so 1e-3 of the torque scale leaves ample margin
    torque_scale = BODY_TORQUE.abs().max().item()
    assert t_err < 1e-3 * torque_scale, t_err
    # the end steps reuse the neighbour's α (first order, error ≈ |I·dα/dt|·dt, measured 9e-3): looser bound
    assert t_end_err < 0.2 * torque_scale, t_end_err


def test_fd_torque_is_second_order():
    # halving dt must cut the interior torque error by ≈4 (second-order scheme); 3 leaves room for rounding
    _, coarse, _ = _fd_errors(16, 0.02)
    _, fine, _ = _fd_errors(31, 0.01)
    assert coarse / fine > 3.0, (coarse, fine)


def test_quaternion_sign_flips_do_not_break_omega():
    T, dt = 20, 0.01
    pos, quat = simulate_free_body(T, dt, substeps=20)
    reference = wrenches_from_poses(pos, quat, dt, MASS, INERTIA)
    signs = torch.ones(T, 1, dtype=torch.float64)
    signs[1::2] = -1.0  # q and −q alternate, as happens with per-frame mocap solvers
    signs[7:10] = -1.0
    flipped = wrenches_from_poses(pos, quat * signs, dt, MASS, INERTIA)
    assert torch.allclose(flipped, reference, atol=1e-9, rtol=0)
    demo = load_pose_demo(pos.numpy(), (quat * signs).numpy(), dt, MASS, INERTIA.numpy())
    assert torch.allclose(demo.wrench, reference, atol=1e-9, rtol=0)


def test_large_rotation_per_step_uses_short_way():
    # 170° per step about z: the relative quaternion has w = cos(85°) > 0; the −q representative must not turn
    # it into a 190° rotation the other way
    dt, rate = 0.1, math.radians(170) / 0.1
    angles = torch.arange(5, dtype=torch.float64) * rate * dt
    quat = torch.stack([torch.cos(angles / 2), 0 * angles, 0 * angles, torch.sin(angles / 2)], -1)
    quat[2] = -quat[2]
    from dexmots_rl.trajectories import angular_velocities

    omega, alpha = angular_velocities(quat, dt)
    assert torch.allclose(omega[:, 2], torch.full((5,), rate, dtype=torch.float64))
    assert torch.allclose(alpha, torch.zeros_like(alpha), atol=1e-9)


def test_load_pose_demo_normalises_and_validates():
    T, dt = 12, 0.02
    pos, quat = simulate_free_body(T, dt, substeps=10)
    demo = load_pose_demo(pos.numpy(), 3.0 * quat.numpy(), dt, MASS, INERTIA.numpy(), joint_q=np.zeros(T))
    assert isinstance(demo, PoseWrenchTrajectory)
    assert demo.horizon == T and demo.dt == dt and demo.joint_q.shape == (T, 1)
    assert torch.allclose(demo.quat.norm(dim=-1), torch.ones(T, dtype=torch.float64))
    assert torch.equal(demo.joint_torque, torch.zeros(T, 1, dtype=torch.float64))
    with pytest.raises(TrajectoryFormatError, match="'quat'"):
        load_pose_demo(pos, torch.zeros(T, 4, dtype=torch.float64), dt, MASS, INERTIA)
    with pytest.raises(TrajectoryFormatError, match="'pos'"):
        load_pose_demo(pos[:, :2], quat, dt, MASS, INERTIA)
    with pytest.raises(TrajectoryFormatError, match="'dt'"):
        load_pose_demo(pos, quat, -1.0, MASS, INERTIA)
    with pytest.raises(TrajectoryFormatError, match="'joint_q'"):
        load_pose_demo(pos, quat, dt, MASS, INERTIA, joint_q=np.zeros((T + 1, 1)))


def test_short_demos():
    q = torch.tensor([[1.0, 0, 0, 0]], dtype=torch.float64)
    assert wrenches_from_poses(torch.zeros(1, 3, dtype=torch.float64), q, 0.1, 1.0, torch.eye(3)).shape == (1, 6)
    two = wrenches_from_poses(torch.tensor([[0.0, 0, 0], [1.0, 0, 0]]), q.repeat(2, 1).float(), 0.1, 1.0,
                              torch.eye(3))
    assert torch.equal(two, torch.zeros(2, 6))
