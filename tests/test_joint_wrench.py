"""The fingers' generalised contact force on an articulated object's joints (``ArticulatedStepOutput.joint_wrench``):
its physics (at rest it balances the joint's spring) and its gradient through finger contact."""

import dataclasses

import numpy as np
import pytest
import torch

from dexmots_rl.envs.object_pregrasp import operate_pregrasp_path
from dexmots_rl.envs.pregrasp import load_pregrasps
from dexmots_rl.sim import ArticulatedSimulator

from test_articulated import _scene

FLEXION = {"index": [1, 2, 3], "all": [1, 2, 3, 5, 6, 7, 9, 10, 11, 13, 14, 15]}  # joints curled past the pre-grasp


def _pressing(sim, name: str, fingers: str, curl: float = 0.4):
    """The start state (each world one of the object's shipped pre-grasps) and position control curling
    ``fingers`` ``curl`` rad past it, so that they press on the operated part."""
    poses = torch.as_tensor(load_pregrasps(operate_pregrasp_path(name), sim.nu), dtype=sim.dtype)
    q, qd = sim.initial_state()
    q[:, :sim.nu] = poses[torch.arange(sim.num_worlds) % len(poses)]
    ctrl = sim.zero_control()
    target = q[:, :sim.nu].clone()
    target[:, FLEXION[fingers]] += curl
    shape = (sim.num_worlds, sim.nu)
    ctrl.q_target, ctrl.kp, ctrl.kd = target, torch.full(shape, 3.0, dtype=sim.dtype), torch.full(shape, 0.1, dtype=sim.dtype)
    return q, qd, ctrl


# (object, fingers, spring stiffness, spring rest, steps, expected sign): the index pulls the spray bottle's
# trigger up its hinge (free base), the curling fingers push the fixed drawer's handle in along its slide
EQUILIBRIA = [pytest.param(*case, marks=pytest.mark.slow)  # the tool scenes' float64 builds
              for case in (("spray_bottle_a", "index", 0.5, 0.0, 20, 1.0), ("drawer_a", "all", 500.0, 0.04, 60, -1.0))]


@pytest.mark.parametrize("name, fingers, stiffness, rest, steps, sign", EQUILIBRIA)
def test_joint_wrench_balances_the_spring_at_rest(name, fingers, stiffness, rest, steps, sign):
    """Without gravity and joint friction, fingers pressing a sprung part come to rest where their force on the
    joint balances the spring: joint_wrench = k (q - rest), of the sign of the push (N m about the hinge, N along
    the slide)."""
    scene = _scene(name)
    scene = dataclasses.replace(scene, hand={**scene.hand, "gravity": np.zeros(3)})
    sim = ArticulatedSimulator(scene, 2, dtype=torch.float64)
    q, qd, ctrl = _pressing(sim, name, fingers)
    joint = scene.tree.joint_names[0]
    params = sim.default_params()
    params[f"{joint}/friction"].zero_()
    params[f"{joint}/stiffness"].fill_(stiffness)
    params[f"{joint}/rest"].fill_(rest)
    with torch.no_grad():
        for step in range(steps):
            out = sim.step(q, qd, ctrl, params)
            q, qd = out.joint_q, out.joint_qd
            if step == steps - 11:
                earlier = q[:, -1].clone()
    lo, hi = scene.tree.joint_range[0]
    angle = q[:, -1]
    assert ((angle > lo + 0.1 * (hi - lo)) & (angle < hi - 0.1 * (hi - lo))).all()  # off the stops
    # at rest: the part stays within 1 % of its range over the last 10 steps (its velocity under twelve pressing
    # fingers dithers by ~1 cm/s about zero, so the position, not one step's velocity, tells rest)
    assert ((angle - earlier).abs() < 0.01 * (hi - lo)).all()
    spring = stiffness * (angle - rest)
    pushed = out.joint_wrench[:, 0]
    assert out.joint_wrench.shape == (2, 1)
    assert (sign * pushed > 0.2 * stiffness * (hi - lo)).all()  # a firm push of the expected sign
    torch.testing.assert_close(pushed, spring, rtol=0.02, atol=0.0)


@pytest.mark.slow  # the tool scene's float64 build
def test_joint_wrench_gradient_matches_finite_differences():
    """d(joint_wrench after one step)/d(position targets, start state), in float64 through the index finger's
    contact with the spray bottle's trigger, against central differences."""
    sim = ArticulatedSimulator(_scene("spray_bottle_a"), 1, dtype=torch.float64)
    q, qd, ctrl = _pressing(sim, "spray_bottle_a", "index")
    params = sim.default_params()
    with torch.no_grad():  # into contact
        for _ in range(3):
            out = sim.step(q, qd, ctrl, params)
            q, qd = out.joint_q, out.joint_qd
    assert float(out.joint_wrench[0, 0]) > 0.02

    def loss(target, state):
        c = dataclasses.replace(ctrl, q_target=target)
        return sim.step(state, qd, c, params).joint_wrench.sum()

    target, state = ctrl.q_target.clone().requires_grad_(True), q.clone().requires_grad_(True)
    loss(target, state).backward()
    eps = 1e-6

    def central(x, i, other_first):
        plus, minus = x.clone(), x.clone()
        plus[0, i] += eps
        minus[0, i] -= eps
        args = (lambda y: (y, q)) if other_first else (lambda y: (ctrl.q_target, y))
        return (loss(*args(plus)) - loss(*args(minus))).item() / (2 * eps)

    with torch.no_grad():
        fd_target = np.array([central(ctrl.q_target, i, True) for i in range(sim.nu)])
        fd_state = np.array([central(q, i, False) for i in range(sim.nq)])
    for grad, fd in ((target.grad[0].numpy(), fd_target), (state.grad[0].numpy(), fd_state)):
        assert np.abs(fd).max() > 1e-3
        np.testing.assert_allclose(grad, fd, rtol=1e-4, atol=1e-6 * np.abs(fd).max())
