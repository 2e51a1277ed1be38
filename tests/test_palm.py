"""Palm contact: a free cube against the hand's fixed collision box (tests/assets/cube_palm.xml).

The palm box's top face is at z = 0.01 and the cube's half size 0.0325, so a resting cube's centre is at
0.0425 (ours floats ~0.3 mm above it: the relaxed law's force at zero gap; MuJoCo's soft contact sinks a
little instead).
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch

from dexmots_rl.assets import asset_path
from dexmots_rl.sim import Control, Simulator, load_scene

ASSET = Path(__file__).parent / "assets" / "cube_palm.xml"
REST_Z = 0.01 + 0.0325
SECOND = 60  # env steps of 16 substeps of 1/960 s


@pytest.fixture(scope="module")
def scene():
    return load_scene(ASSET)


@pytest.fixture(scope="module")
def sim(scene):
    return Simulator(scene, num_worlds=3, dtype=torch.float64, substeps=16)


def _run(sim, q, qd, steps, wrench=None):
    params = sim.default_params()
    z = torch.zeros(sim.num_worlds, sim.nu, dtype=sim.dtype)
    control = Control(z, z, z, z, wrench)
    heights = []
    for _ in range(steps):
        out = sim.step(q, qd, control, params)
        q, qd = out.joint_q, out.joint_qd
        heights.append(q[:, 3].clone())
    return q, qd, torch.stack(heights)


def _tilt(q, world, angle, axis):
    quat = np.zeros(4)
    mujoco.mju_axisAngle2Quat(quat, np.asarray(axis, dtype=np.float64), angle)
    q[world, 4:8] = torch.as_tensor(quat)


def test_palm_boxes_are_read_only_when_they_collide(scene):
    assert scene.num_palm_boxes == 1
    np.testing.assert_allclose(scene.palm_box_half, [[0.06, 0.06, 0.01]])
    assert scene.object_point_pos.shape == (26, 3) and (scene.object_point_radius == 0).all()
    # the existing scenes have no colliding palm geometry: nothing changes for them
    for name in ("claw_screw.xml", "allegro_knob.xml"):
        other = load_scene(asset_path(name))
        assert other.num_palm_boxes == 0 and len(other.object_point_pos) == 0
    allegro = load_scene(asset_path("allegro_cube.xml"))
    assert allegro.num_palm_boxes == 1 and len(allegro.object_point_pos) == 26


@pytest.mark.slow  # the palm scene's own float64 build
def test_cube_dropped_onto_the_palm_comes_to_rest(sim):
    q, qd = sim.initial_state()  # world 0: flat, 5 mm above the palm
    q[1, 3] += 0.02  # world 1: 2.5 cm above, tilted: lands on an edge and falls flat
    _tilt(q, 1, 0.3, [1.0, 0.5, 0.0])
    q[2, 1] = 0.02  # world 2: off centre, spinning about z
    qd[2, 6] = 3.0
    q, qd, heights = _run(sim, q, qd, 2 * SECOND)
    assert torch.isfinite(q).all()
    for w in range(3):
        assert abs(heights[SECOND - 1, w].item() - REST_Z) < 2e-3, w  # at rest after 1 s
        assert (heights[SECOND:, w] - REST_Z).abs().max().item() < 2e-3, w  # and stays there
        assert (heights[SECOND:, w].max() - heights[SECOND:, w].min()).item() < 2e-4, w
    assert qd[:, :3].abs().max() < 1e-2 and qd[:, 3:].abs().max() < 0.2
    # no drift in the plane for the centred drop, flat orientation for the tilted one
    assert q[0, 1:3].abs().max() < 1e-6
    assert abs(q[1, 1:3]).max() < 0.03  # MuJoCo: (-0.008, 0.011); ours slides a bit farther: (-0.011, 0.026)
    up = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=torch.float64)
    assert 1.0 - abs(float(q[0, 4:8] @ up)) < 1e-9
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, q[1, 4:8].numpy())
    assert np.abs(rot.reshape(3, 3)[2]).max() > 1 - 1e-3  # a face is down (one cube axis vertical again)


@pytest.mark.slow  # the palm scene's own float64 build
def test_cube_beside_the_palm_falls_past_it(sim):
    q, qd = sim.initial_state()
    q[:, 1] = torch.tensor([0.06 + 0.0325 + 0.002, 0.3, -0.2])  # 2 mm clear of the palm's side, far
    steps = 30
    q, qd, heights = _run(sim, q, qd, steps)
    n, h, g = steps * sim.substeps, sim.sub_dt, 9.81
    expected = 0.0475 - g * h * h * n * (n + 1) / 2  # free fall, semi-implicit Euler
    np.testing.assert_allclose(q[:, 3].numpy(), expected, atol=1e-9)
    assert expected < -1.0


@pytest.mark.slow  # the palm scene's own float64 build
def test_palm_contact_gradients_match_finite_differences(sim, scene):
    """d(final height, velocity, orientation) / d(initial object velocity, external wrench) through a
    landing on the palm, H = 3 env steps (48 substeps), AD vs central differences."""
    H, eps = 3, 1e-6
    gen = torch.Generator().manual_seed(3)
    q0, qd0 = sim.initial_state()
    q0 = q0[:1].clone()
    q0[0, 3] = REST_Z + 0.001
    q0[0, 1] = 0.01
    _tilt(q0, 0, 0.05, [0.3, 1.0, 0.0])
    base = torch.cat([torch.tensor([0.05, -0.02, -0.3, 1.0, -2.0, 0.5], dtype=torch.float64),
                      torch.tensor([0.1, 0.05, -0.2, 0.003, -0.002, 0.001], dtype=torch.float64)])
    wq = torch.rand(sim.nq, generator=gen, dtype=torch.float64) * 2 - 1
    wqd = torch.rand(sim.nv, generator=gen, dtype=torch.float64) * 2 - 1

    def loss(x, s):
        n = x.shape[0]
        q = q0.expand(n, -1).clone()
        qd = torch.cat([torch.zeros(n, 1, dtype=torch.float64), x[:, :6]], 1)
        z = torch.zeros(n, s.nu, dtype=torch.float64)
        total = torch.zeros(n, dtype=torch.float64)
        for _ in range(H):
            out = s.step(q, qd, Control(z, z, z, z, x[:, 6:]), s.default_params())
            q, qd = out.joint_q, out.joint_qd
            total = total + (q * wq).sum(-1) + 0.01 * (qd * wqd).sum(-1)
        return total, q

    sim1 = Simulator(scene, num_worlds=1, dtype=torch.float64, substeps=16)
    x = base[None].clone().requires_grad_(True)
    value, q_end = loss(x, sim1)
    (g_ad,) = torch.autograd.grad(value.sum(), x)
    g_ad = g_ad[0]
    dim = base.numel()
    simfd = Simulator(scene, num_worlds=2 * dim, dtype=torch.float64, substeps=16)
    xs = base.repeat(2 * dim, 1)
    idx = torch.arange(dim)
    xs[2 * idx, idx] += eps
    xs[2 * idx + 1, idx] -= eps
    with torch.no_grad():
        lv, _ = loss(xs, simfd)
    g_fd = (lv[0::2] - lv[1::2]) / (2 * eps)
    # the cube did land: without the palm it would be ~ 2.7 cm lower after 50 ms
    assert q_end[0, 3].item() > REST_Z - 0.002
    assert torch.isfinite(g_ad).all()
    rel = float((g_ad - g_fd).norm() / g_fd.norm())
    assert rel < 1e-6, rel
    big = g_fd.abs() > 1e-6 * g_fd.abs().max()
    assert float(((g_ad - g_fd).abs() / g_fd.abs())[big].max()) < 1e-5
    assert (g_ad.abs() > 0).all()


@pytest.mark.slow  # the palm scene's own float64 build
def test_resting_height_agrees_with_mujoco(sim):
    m = mujoco.MjModel.from_xml_path(str(ASSET))
    d = mujoco.MjData(m)
    for _ in range(960):
        mujoco.mj_step(m, d)
    q, qd = sim.initial_state()
    q, qd, _ = _run(sim, q, qd, SECOND)
    ours, theirs = q[0, 3].item(), float(d.qpos[3])
    assert abs(theirs - REST_Z) < 2e-3 and abs(ours - REST_Z) < 2e-3
    assert abs(ours - theirs) < 2e-3, (ours, theirs)
