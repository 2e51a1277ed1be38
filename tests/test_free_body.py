"""Free-floating object dynamics: ballistic fall and torque-free spin (no contact)."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch

from dexmots_rl.sim import Simulator, load_scene

ASSET = Path(__file__).parent / "assets" / "free_box.xml"


@pytest.fixture(scope="module")
def sim():
    return Simulator(load_scene(ASSET), num_worlds=2, dtype=torch.float64, substeps=10)


def _run(sim, q, qd, steps):
    params = sim.default_params()
    for _ in range(steps):
        out = sim.step(q, qd, sim.zero_control(), params)
        q, qd = out.joint_q, out.joint_qd
    return q, qd


def test_free_fall_matches_symplectic_euler(sim):
    q, qd = sim.initial_state()
    assert torch.allclose(q[0, 1:4], torch.tensor([2.0, 0.0, 1.0], dtype=torch.float64))
    steps = 50
    q, qd = _run(sim, q, qd, steps)
    n, h, g = steps * sim.substeps, sim.sub_dt, 9.81
    expected_z = 1.0 - g * h * h * n * (n + 1) / 2  # semi-implicit Euler, exact for constant gravity
    assert q[0, 3].item() == pytest.approx(expected_z, abs=1e-9)
    assert qd[0, 3].item() == pytest.approx(-g * h * n, abs=1e-9)
    assert torch.allclose(q[:, 1:3], torch.tensor([2.0, 0.0], dtype=torch.float64).expand(2, 2))


def test_torque_free_spin_keeps_angular_momentum(sim):
    q, qd = sim.initial_state()
    w0 = np.array([1.0, 2.0, 3.0])
    qd[:, 4:7] = torch.as_tensor(w0)
    q, qd = _run(sim, q, qd, 50)
    quat = q[0, 4:8].numpy()
    assert np.linalg.norm(quat) == pytest.approx(1.0, abs=1e-9)
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, quat)
    rot = rot.reshape(3, 3)
    inertia = sim.scene.object_inertia
    momentum = rot @ inertia @ rot.T @ qd[0, 4:7].numpy()
    np.testing.assert_allclose(momentum, inertia @ w0, rtol=2e-2)
    assert not np.allclose(quat, [1.0, 0.0, 0.0, 0.0])  # it did rotate
