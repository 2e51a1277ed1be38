"""Wrench planning through the simulator: the object-wrench input, its gradients, and optimize_wrenches."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

from dexmots_rl.sim import Control, ContactParams, Simulator, load_scene
from dexmots_rl.quaternions import slerp
from dexmots_rl.trajectories import PoseWrenchTrajectory, interpolate_reference, optimize_wrenches

from simutil import CLAW

FREE_BOX = Path(__file__).parent / "assets" / "free_box.xml"


def _no_contact_sim(path, n=1, dtype=torch.float64, substeps=4):
    return Simulator(load_scene(path), n, dtype=dtype, substeps=substeps,
                     contact=ContactParams(stiffness=0.0, friction=0.0))


def _push(sim, wrench, params=None):
    q, qd = sim.initial_state()
    z = torch.zeros(sim.num_worlds, sim.nu, dtype=sim.dtype)
    out = sim.step(q, qd, Control(z, z, z, z, object_wrench=wrench), sim.default_params() if params is None else params)
    return out


def test_object_wrench_accelerates_free_body_exactly():
    sim = _no_contact_sim(FREE_BOX)
    force = torch.tensor([[0.3, -0.2, 0.0, 0.0, 0.0, 0.0]], dtype=torch.float64)
    out = _push(sim, force)
    v = out.joint_qd[0, sim.nu:sim.nu + 3]
    expected = force[0, :3] / sim.scene.object_mass * sim.dt + torch.tensor([0, 0, -9.81], dtype=torch.float64) * sim.dt
    torch.testing.assert_close(v, expected, rtol=1e-9, atol=1e-12)
    assert out.wrench.abs().max() == 0  # the reported wrench is the contact wrench only


def test_object_wrench_gradient_matches_finite_differences_on_hinge():
    sim = _no_contact_sim(CLAW)
    axis_torque = torch.tensor([[0.0, 0.0, 0.0, 0.0, 0.1, 0.8]], dtype=torch.float64, requires_grad=True)
    angle = _push(sim, axis_torque).joint_q[0, -1]
    (grad,) = torch.autograd.grad(angle, axis_torque)
    eps = 1e-6
    for c in range(6):
        plus, minus = axis_torque.detach().clone(), axis_torque.detach().clone()
        plus[0, c] += eps
        minus[0, c] -= eps
        fd = (_push(sim, plus).joint_q[0, -1] - _push(sim, minus).joint_q[0, -1]) / (2 * eps)
        assert grad[0, c].item() == pytest.approx(fd.item(), rel=1e-5, abs=1e-10)
    assert grad[0, :5].abs().max() < 1e-12 < grad[0, 5].abs()  # only the axial torque turns a z-hinge


def test_slerp_and_reference_interpolation():
    q0 = torch.tensor([[1.0, 0.0, 0.0, 0.0]], dtype=torch.float64)
    q1 = torch.tensor([[math.cos(0.6), 0.0, math.sin(0.6), 0.0]], dtype=torch.float64)  # 1.2 rad about y
    mid = slerp(q0, q1, torch.tensor([[0.25]], dtype=torch.float64))
    assert 2 * math.acos(mid[0, 0].item()) == pytest.approx(0.3, abs=1e-9)
    start = torch.tensor([[0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0]], dtype=torch.float64)
    goal = torch.tensor([[0.4, 0.0, 1.0, *q1[0].tolist()]], dtype=torch.float64)
    ref = interpolate_reference(start, goal, 4, free_body=True)
    assert ref.shape == (1, 5, 7)
    torch.testing.assert_close(ref[0, :, 0], torch.linspace(0, 0.4, 5, dtype=torch.float64))
    torch.testing.assert_close(ref[0, :, 3:].norm(dim=-1), torch.ones(5, dtype=torch.float64))
    torch.testing.assert_close(ref[0, -1], goal[0])


def test_optimize_wrenches_turns_the_knob_with_friction():
    params = {"joint_damping": 0.5, "joint_friction": 0.8}
    plan = optimize_wrenches(CLAW, start=0.0, goal=0.6, steps=8, iterations=60, lr=1.0, params=params,
                             substeps=4, dt=0.05, progress=False)
    assert plan.initial_error / plan.final_error > 5.0
    assert plan.loss_history[-1] < plan.loss_history[0]
    traj = plan.trajectory
    assert isinstance(traj, PoseWrenchTrajectory) and traj.horizon == 9 and traj.num_joints == 1
    assert abs(traj.joint_q[-1, 0].item() - 0.6) < 0.1
    # a moving knob against 0.8 N·m of Coulomb friction needs more than that torque on average
    assert traj.joint_torque[1:].mean().item() > 0.8
    # the stored wrench is the axial torque (z hinge)
    torch.testing.assert_close(traj.wrench[:, 5], traj.joint_torque[:, 0])


def test_optimize_wrenches_moves_a_free_body():
    scene = load_scene(FREE_BOX)
    start = torch.tensor(scene.object_q0, dtype=torch.float64)
    goal = start.clone()
    goal[0] += 0.05
    goal[3:7] = torch.tensor([math.cos(0.2), 0.0, 0.0, math.sin(0.2)])  # 0.4 rad about z
    plan = optimize_wrenches(scene, start, goal, steps=6, iterations=60, lr=0.5, substeps=4, dt=0.05,
                             dtype=torch.float64, progress=False)
    assert plan.initial_error / plan.final_error > 5.0
    assert plan.trajectory.num_joints == 0
    torch.testing.assert_close(plan.trajectory.quat.norm(dim=-1), torch.ones(7, dtype=torch.float64))


def test_optimize_wrenches_rejects_bad_input():
    with pytest.raises(ValueError, match="scene"):
        optimize_wrenches("screw_claw", 0.0, 1.0, 4, progress=False)  # a task name: the planner takes a scene
    with pytest.raises(ValueError, match="goal"):
        optimize_wrenches(CLAW, 0.0, float("nan"), 4, progress=False)
    with pytest.raises(ValueError, match="steps"):
        optimize_wrenches(CLAW, 0.0, 1.0, 0, progress=False)
    with pytest.raises(ValueError, match="joint_dampnig"):
        optimize_wrenches(CLAW, 0.0, 1.0, 4, params={"joint_dampnig": 1.0}, progress=False)
