"""Rigid-body dynamics of the warp core: MuJoCo as the oracle, plus behaviour checks on the claw.

The oracle scene (tests/assets/chain3d.xml) has 3D finger chains with hinge and slide joints, tilted axes,
offset inertias, gravity with x/y components and a tilted hinge object, so every term of the mass matrix
and of the bias forces (gravity, Coriolis/centrifugal) is exercised. With one float64 substep of 1e-7 s,
``(qd_out - qd) / dt`` is the simulator's joint acceleration, compared with MuJoCo's ``qacc`` after
``mj_forward`` with every constraint disabled (no contacts or limits are active in these states).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from simutil import CHAIN3D, CLAW, CLAW_CONTACT_Q, CLAW_OPEN_Q, batch_state, claw_params, mujoco_forward, mujoco_model, torque

# (seed, moving): random states with q in +-0.08 (inside the slide joint's +-0.1 range) and qd in +-2
ORACLE_STATES = [(0, False), (1, False), (2, True), (3, True), (4, True)]


def _random_state(seed: int, nq: int, moving: bool):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-0.08, 0.08, nq)
    qd = rng.uniform(-2.0, 2.0, nq) if moving else np.zeros(nq)
    return q, qd


def _sim_accelerations(sim, q, qd, tau):
    qt, qdt = batch_state(sim, q, qd)
    out = sim.step(qt, qdt, torque(tau), sim.default_params())
    return ((out.joint_qd - qdt) / sim.dt).numpy()


@pytest.fixture(scope="module")
def chain_mj():
    return mujoco_model(CHAIN3D)


@pytest.mark.parametrize("seed,moving", ORACLE_STATES)
def test_chain3d_acceleration_matches_mujoco(chain_sim, chain_mj, seed, moving):
    sim = chain_sim
    q, qd = _random_state(seed, sim.nq, moving)
    tau = torch.from_numpy(np.random.default_rng(100 + seed).uniform(-0.5, 0.5, sim.nu)).expand(sim.num_worlds, -1)
    acc = _sim_accelerations(sim, q, qd, tau.clone())[0]
    qacc, _, _, _ = mujoco_forward(chain_mj, q, qd, tau[0].numpy())
    np.testing.assert_allclose(acc, qacc, rtol=1e-8, atol=1e-8 * np.abs(qacc).max())


@pytest.mark.parametrize("seed", [0, 3])
def test_chain3d_mass_matrix_matches_mujoco(chain_sim, chain_mj, seed):
    """Unit torques on each hand dof give the columns of M^-1 (the hand block; fingers are independent)."""
    sim = chain_sim
    assert sim.num_worlds == sim.nu + 1
    q, qd = _random_state(seed, sim.nq, moving=True)
    tau = torch.zeros(sim.num_worlds, sim.nu, dtype=torch.float64)
    tau[1:] = torch.eye(sim.nu, dtype=torch.float64)
    acc = _sim_accelerations(sim, q, qd, tau)
    minv_sim = (acc[1:, : sim.nu] - acc[0, : sim.nu]).T  # column j: response to a unit torque on dof j
    _, M, _, _ = mujoco_forward(chain_mj, q, qd)
    minv_mj = np.linalg.inv(M)[: sim.nu, : sim.nu]
    np.testing.assert_allclose(minv_sim, minv_mj, rtol=1e-8, atol=1e-8 * np.abs(minv_mj).max())
    # the hand torques must not reach the object
    np.testing.assert_allclose(acc[1:, sim.nu :], acc[:1, sim.nu :].repeat(sim.nu, 0), rtol=0, atol=1e-6)


@pytest.mark.parametrize("seed,moving", ORACLE_STATES)
def test_chain3d_bias_forces_match_mujoco(chain_sim, chain_mj, seed, moving):
    """Without torque, M qacc = -bias: gravity alone at rest, plus Coriolis/centrifugal when moving."""
    sim = chain_sim
    q, qd = _random_state(seed, sim.nq, moving)
    acc = _sim_accelerations(sim, q, qd, torch.zeros(sim.num_worlds, sim.nu, dtype=torch.float64))[0]
    _, M, bias, _ = mujoco_forward(chain_mj, q, qd)
    np.testing.assert_allclose(-M @ acc, bias, rtol=1e-8, atol=1e-8 * np.abs(bias).max())


def test_chain3d_velocity_terms_are_not_trivial(chain_sim, chain_mj):
    """Guard for the oracle itself: the moving states really exercise velocity-product forces."""
    q, qd = _random_state(3, chain_sim.nq, moving=True)
    _, _, bias_moving, _ = mujoco_forward(chain_mj, q, qd)
    _, _, bias_rest, _ = mujoco_forward(chain_mj, q, np.zeros_like(qd))
    assert np.abs(bias_moving - bias_rest).max() > 1e-2 * np.abs(bias_rest).max()


@pytest.mark.parametrize("seed", [0, 2])
def test_chain3d_kinematics_match_mujoco(chain_sim, chain_mj, seed):
    import mujoco

    sim = chain_sim
    q, qd = _random_state(seed, sim.nq, moving=False)
    q = q * 10  # kinematics has no range restriction: use larger angles
    pose, tips = sim.observe(batch_state(sim, q)[0])
    _, _, _, d = mujoco_forward(chain_mj, q, qd)
    for b, name in enumerate(sim.scene.body_names):
        bid = mujoco.mj_name2id(chain_mj, mujoco.mjtObj.mjOBJ_BODY, name)
        np.testing.assert_allclose(pose[0, b, :3].numpy(), d.xpos[bid], atol=1e-10, err_msg=name)
        quat = pose[0, b, 3:].numpy()
        sign = np.sign(quat @ d.xquat[bid])
        np.testing.assert_allclose(sign * quat, d.xquat[bid], atol=1e-10, err_msg=name)
    for f, site in enumerate(["a_tip", "b_tip"]):
        sid = mujoco.mj_name2id(chain_mj, mujoco.mjtObj.mjOBJ_SITE, site)
        np.testing.assert_allclose(tips[0, f].numpy(), d.site_xpos[sid], atol=1e-10, err_msg=site)


# ------------------------------------------------------------------------------------ the claw scene
@pytest.fixture(scope="module")
def claw_mj():
    return mujoco_model(CLAW)


def test_claw_free_acceleration_matches_mujoco(make_claw_sim, claw_mj):
    """Open fingers (no contact, inside the limits): damping + armature + inertia as in MuJoCo.

    The knob's Coulomb friction is a constraint in MuJoCo (disabled here), so it is zeroed in params."""
    sim = make_claw_sim(1, substeps=1, dt=1e-7)
    q = np.array(CLAW_OPEN_Q) + np.array([0.1, -0.2, -0.05, 0.3, 0.7])
    qd = np.array([1.5, -2.0, -1.0, 2.5, 3.0])
    tau = torch.tensor([[20.0, -10.0, 5.0, 40.0]], dtype=torch.float64)
    params = torch.tensor([[0.5, 0.0]], dtype=torch.float64)
    qt, qdt = batch_state(sim, q, qd)
    out = sim.step(qt, qdt, torque(tau), claw_params(params))
    acc = ((out.joint_qd - qdt) / sim.dt)[0].numpy()
    qacc, _, _, _ = mujoco_forward(claw_mj, q, qd, tau[0].numpy())
    # damping is integrated implicitly: (M + dt D) qdd differs from M qdd by ~dt * D / M ~ 1e-7 relative
    np.testing.assert_allclose(acc, qacc, rtol=1e-6, atol=1e-6 * np.abs(qacc).max())
    assert float(out.contact_force.abs().max()) == 0.0


def test_claw_torque_accelerates_its_joint(make_claw_sim):
    """A positive (negative) torque on one joint from rest speeds that joint up positively (negatively)."""
    sim = make_claw_sim(9)
    q, qd = batch_state(sim, CLAW_OPEN_Q)
    tau = torch.zeros(9, 4, dtype=torch.float64)
    for j in range(4):
        tau[j, j], tau[4 + j, j] = 30.0, -30.0
    out = sim.step(q, qd, torque(tau), sim.default_params())
    for j in range(4):
        assert out.joint_qd[j, j] > 0.1, j
        assert out.joint_qd[4 + j, j] < -0.1, j
        assert out.joint_q[j, j] > q[j, j] and out.joint_q[4 + j, j] < q[4 + j, j], j
    # the last world has no torque: at rest inside the limits and out of contact nothing moves
    assert float(out.joint_qd[8].abs().max()) < 1e-12
    assert float(out.contact_force.abs().max()) == 0.0


def test_claw_pd_drive_saturates_at_the_motor_effort(make_claw_sim, claw_scene):
    """A stiff target far away pushes no harder than the motor can (|gear| * ctrlrange = 150 N m),
    while a mild one stays (almost) linear."""
    from dexmots_rl.sim import Control

    effort = torch.as_tensor(claw_scene.actuator_effort)
    torch.testing.assert_close(effort, torch.full((4,), 150.0, dtype=torch.float64))
    sim = make_claw_sim(3)
    q, qd = batch_state(sim, CLAW_OPEN_Q)
    z = torch.zeros(3, 4, dtype=torch.float64)
    far = q[:, :4] + torch.tensor([[5.0, 0, 0, 0], [0.01, 0, 0, 0], [0, 0, 0, 0]], dtype=torch.float64)
    kp = torch.zeros(3, 4, dtype=torch.float64)
    kp[:2, 0] = 1e5  # only joint 0 is driven; world 2 uses torque control
    tau = torch.zeros(3, 4, dtype=torch.float64)
    tau[2, 0] = 150.0  # the motor at full effort, torque control
    out = sim.step(q, qd, Control(tau, far, kp.clone(), z.clone()), sim.default_params())
    saturated, mild, full = out.joint_qd[:, 0]
    # 5 rad at kp 1e5 would be 5e5 N m unsaturated: it moves the joint like the motor's full torque
    torch.testing.assert_close(saturated, full, rtol=0.02, atol=0.0)
    # 0.01 rad at kp 1e5 asks 1e3 N m at first but the joint closes the gap within the step: slower
    assert 0.0 < mild < full


def test_claw_kinetic_energy_decays_without_torque(make_claw_sim, claw_mj):
    """Planar claw, gravity along the joint axes, no contact: joint damping only removes energy."""
    sim = make_claw_sim(1)
    q, qd = batch_state(sim, CLAW_OPEN_Q, [1.0, -1.0, -0.5, 1.5, 2.0])
    tau = torch.zeros(1, 4, dtype=torch.float64)
    energies = []
    for _ in range(12):
        _, M, _, _ = mujoco_forward(claw_mj, q[0].numpy(), qd[0].numpy())
        v = qd[0].numpy()
        energies.append(0.5 * v @ M @ v)
        out = sim.step(q, qd, torque(tau), sim.default_params())
        q, qd = out.joint_q, out.joint_qd
        assert float(out.contact_force.abs().max()) == 0.0
    energies = np.array(energies)
    assert np.all(np.diff(energies) < 0), energies
    assert energies[-1] < 0.9 * energies[0]


@pytest.mark.parametrize("q0", [CLAW_OPEN_Q, CLAW_CONTACT_Q], ids=["open", "contact"])
def test_claw_mirror_symmetry(make_claw_sim, q0):
    """The claw and the octagonal knob are symmetric under y -> -y: a mirrored state and mirrored torques
    stay mirrored (left joints = -right joints) and the knob gets no net torque, with or without contact."""
    sim = make_claw_sim(1)
    q, qd = batch_state(sim, q0, [-0.3, -0.2, 0.3, 0.2, 0.0])
    tau = torch.tensor([[-15.0, -25.0, 15.0, 25.0]], dtype=torch.float64)  # closing on the knob
    peak_force = 0.0
    for _ in range(6):
        out = sim.step(q, qd, torque(tau), sim.default_params())
        q, qd = out.joint_q, out.joint_qd
        peak_force = max(peak_force, float(out.contact_force[0]))
    assert torch.allclose(q[:, 2:4], -q[:, 0:2], rtol=0, atol=1e-9)
    assert torch.allclose(qd[:, 2:4], -qd[:, 0:2], rtol=0, atol=1e-7)
    assert float(q[0, 4].abs()) < 1e-9
    tips = out.fingertips[0]
    assert torch.allclose(tips[1] * torch.tensor([1.0, -1.0, 1.0], dtype=torch.float64), tips[0], atol=1e-9)
    if q0 == CLAW_CONTACT_Q:
        assert peak_force > 10.0  # the symmetric case really is in contact
    else:
        assert peak_force == 0.0


# (joint, violation): outward/inward past a limit, chosen so the fingers stay clear of the knob
LIMIT_CASES = [(0, +0.1), (1, +0.1), (1, -0.1), (2, -0.1), (3, +0.1), (3, -0.1)]


def test_claw_joint_limits_push_back(make_claw_sim, claw_scene):
    sim = make_claw_sim(len(LIMIT_CASES) + 1)
    q, qd = batch_state(sim, CLAW_OPEN_Q)
    lower, upper = claw_scene.dof_lower, claw_scene.dof_upper
    for w, (j, over) in enumerate(LIMIT_CASES):
        q[w, j] = upper[j] + over if over > 0 else lower[j] + over
    tau = torch.zeros(sim.num_worlds, 4, dtype=torch.float64)
    out = sim.step(q, qd, torque(tau), sim.default_params())
    assert float(out.contact_force.abs().max()) == 0.0
    for w, (j, over) in enumerate(LIMIT_CASES):
        v = float(out.joint_qd[w, j])
        assert v * over < 0 and abs(v) > 0.1, (j, over, v)  # pushed back towards the range
    # a world inside every limit (last one) feels no limit force
    assert float(out.joint_qd[-1].abs().max()) < 1e-12


def test_claw_joint_limit_holds_against_full_torque(make_claw_sim, claw_scene):
    """Full motor torque (gear 150) into the right proximal upper limit: the joint stops just past it."""
    sim = make_claw_sim(1)
    q, qd = batch_state(sim, (1.4, -0.5, -1.2, 0.5, 0.0))
    tau = torch.tensor([[150.0, 0.0, 0.0, 0.0]], dtype=torch.float64)
    upper = claw_scene.dof_upper[0]
    peak = -np.inf
    for _ in range(40):
        out = sim.step(q, qd, torque(tau), sim.default_params())
        q, qd = out.joint_q, out.joint_qd
        peak = max(peak, float(q[0, 0]))
    # without the limit the joint would have turned by several radians in 40 steps (0.67 s at ~60 rad/s^2)
    assert upper < peak < upper + 0.2
    assert abs(float(q[0, 0]) - upper) < 0.2


@pytest.mark.parametrize("taped", [False, True], ids=["fast_path", "taped_path"])
def test_worlds_are_independent(make_claw_sim, taped):
    """A world's step does not depend on the batch it is in (80 worlds are split into CPU-thread blocks)."""
    n = 80
    gen = torch.Generator().manual_seed(4)
    base = torch.tensor([CLAW_OPEN_Q, CLAW_CONTACT_Q], dtype=torch.float64)[torch.arange(n) % 2]
    q = base + 0.05 * torch.rand(n, 5, generator=gen, dtype=torch.float64)
    qd = 0.5 * (2 * torch.rand(n, 5, generator=gen, dtype=torch.float64) - 1)
    tau = 30 * (2 * torch.rand(n, 4, generator=gen, dtype=torch.float64) - 1)
    params = torch.tensor([[0.5, 0.3]], dtype=torch.float64).expand(n, 2).contiguous()
    big = make_claw_sim(n)
    out = big.step(q, qd, torque(tau.clone().requires_grad_(taped)), claw_params(params))
    one = make_claw_sim(1)
    for w in [0, 1, 38, 39, 40, 41, 79]:
        ref = one.step(q[w : w + 1], qd[w : w + 1], torque(tau[w : w + 1]), claw_params(params[w : w + 1]))
        for name, a, b in zip(out.names, out, ref):
            assert torch.equal(a[w : w + 1].detach(), b), (w, name)
    assert float(out.contact_force[1::2].detach().min()) > 0.0  # the odd worlds are in contact


def test_cpu_threads_setting(monkeypatch):
    """DEXMOTS_CPU_THREADS caps the world blocks a step is split into; a bad value names the variable."""
    import warp as wp

    from dexmots_rl.sim._stepper import world_blocks

    cpu = wp.get_device("cpu")
    monkeypatch.setenv("DEXMOTS_CPU_THREADS", "1")
    assert world_blocks(256, cpu) == [(0, 256)]
    monkeypatch.setenv("DEXMOTS_CPU_THREADS", "4")
    assert len(world_blocks(256, cpu)) == 4 and world_blocks(256, cpu)[-1] == (192, 256)
    monkeypatch.setenv("DEXMOTS_CPU_THREADS", "zero")
    with pytest.raises(ValueError, match="DEXMOTS_CPU_THREADS"):
        world_blocks(256, cpu)


def test_claw_mirrored_turning_states_stay_mirrored():
    """test_claw_mirror_symmetry's states are their own mirror images; here two worlds hold an asymmetric state
    (knob turned, random velocities and torques) and its mirror image (left and right fingers swapped with their
    angles negated, the knob's angle negated). Stepped in contact while the knob turns, they stay mirror images
    to the bit, so the physics favours neither turning direction (the claw's policies without the mirror that
    learnt one direction only did not learn it from the physics)."""
    from dexmots_rl.apps.bench_setup import bench_task
    from dexmots_rl.envs import task_contact, task_scene
    from dexmots_rl.sim import Control, Simulator

    scene, poses = task_scene("screw_claw"), bench_task("screw_claw")
    sim = Simulator(scene, 2, dtype=torch.float64, contact=task_contact("screw_claw"))
    order = [2, 3, 0, 1, 4]  # right proximal, right distal, left proximal, left distal, knob

    def mirror(x):
        return -x[..., order]

    g = torch.Generator().manual_seed(0)
    q0 = torch.tensor(poses.touch_q, dtype=torch.float64)
    q0[4] = 0.1
    qd0 = 0.3 * torch.randn(5, generator=g, dtype=torch.float64)
    q, qd = torch.stack([q0, mirror(q0)]), torch.stack([qd0, mirror(qd0)])
    gear = torch.as_tensor(scene.actuator_gear, dtype=torch.float64)
    close = torch.tensor([*poses.close_action, 0.0], dtype=torch.float64)
    touched = 0.0
    for _ in range(10):
        a = close + torch.cat([0.3 * (2 * torch.rand(4, generator=g, dtype=torch.float64) - 1), torch.zeros(1)])
        tau = (torch.stack([a, mirror(a)])[:, :4] * gear).contiguous()
        zero = torch.zeros_like(tau)
        out = sim.step(q, qd, Control(tau, zero, zero, zero), sim.default_params())
        q, qd = out.joint_q, out.joint_qd
        touched += float(out.contact_force[0])
        torch.testing.assert_close(q[1], mirror(q[0]), rtol=0, atol=1e-12)
        torch.testing.assert_close(qd[1], mirror(qd[0]), rtol=0, atol=1e-12)
        torch.testing.assert_close(out.contact_force[1], out.contact_force[0], rtol=0, atol=1e-9)
    assert touched > 0.0 and abs(float(q[0, 4]) - 0.1) > 0.01  # in contact, and the knob turned
