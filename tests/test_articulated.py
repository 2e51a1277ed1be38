"""The Allegro hand with an articulated library object on a table (sim/articulated.py)."""

import tempfile
from pathlib import Path

import numpy as np
import pytest
import torch

from dexmots_rl.assets.hand_scene import hand_object_scene_xml
from dexmots_rl.assets.objects import load_object
from dexmots_rl.sim import load_scene
from dexmots_rl.sim.articulated import ArticulatedScene, ArticulatedSimulator

# a sample of the library: a free base with a hinge, a fixed base with a slide, a free base lying flat
OBJECTS = ["spray_bottle_a", "drawer_a", "scissors_a"]


def _scene(name):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scene.xml"
        path.write_text(hand_object_scene_xml(load_object(name), tmp))
        return load_scene(path)


def _closing(sim, index_flex=1.2):
    """Position control toward a pose that curls the index and middle fingers."""
    ctrl = sim.zero_control()
    n, nu = sim.num_worlds, sim.nu
    target = torch.zeros(n, nu, dtype=sim.dtype)
    target[:, [1, 2, 5, 6]] = index_flex
    ctrl.q_target, ctrl.kp, ctrl.kd = target, torch.full((n, nu), 3.0, dtype=sim.dtype), torch.full((n, nu), 0.1, dtype=sim.dtype)
    return ctrl


@pytest.mark.parametrize("name", OBJECTS)
def test_hand_and_object_step(name):
    """The scene loads as a hand plus an object tree, steps finitely, the closing fingers touch the object, and
    the object's joint stays within its range (plus the stop's give)."""
    scene = _scene(name)
    assert isinstance(scene, ArticulatedScene)
    sim = ArticulatedSimulator(scene, 2)
    q, qd = sim.initial_state()
    params, ctrl = sim.default_params(), _closing(sim)
    touched = 0.0
    with torch.no_grad():
        for _ in range(40):
            out = sim.step(q, qd, ctrl, params)
            q, qd = out.joint_q, out.joint_qd
            touched = max(touched, float(out.contact_force.max()))
            assert torch.isfinite(q).all() and torch.isfinite(qd).all()
    assert touched > 0.05
    lo, hi = scene.tree.joint_range[0]
    joint = q[:, -1]
    assert (joint > lo - 0.05 * (hi - lo)).all() and (joint < hi + 0.05 * (hi - lo)).all()
    pose, tips = sim.observe(q)
    assert pose.shape == (2, sim.nu + scene.tree.num_bodies, 7) and tips.shape == (2, 4, 3)


def test_gradient_through_finger_contact_matches_finite_differences():
    """d(object and hand state after one step)/d(position targets), in float64 through finger-object contact
    and the table, against central differences."""
    scene = _scene("spray_bottle_a")
    sim = ArticulatedSimulator(scene, 1, dtype=torch.float64)
    q, qd = sim.initial_state()
    params, ctrl = sim.default_params(), _closing(sim)
    with torch.no_grad():  # into contact
        for _ in range(8):
            out = sim.step(q, qd, ctrl, params)
            q, qd = out.joint_q, out.joint_qd
    assert float(out.contact_force[0]) > 0.05
    weights = torch.randn(sim.nv, generator=torch.Generator().manual_seed(0), dtype=torch.float64)

    def loss(target):
        c = _closing(sim)
        c.q_target = target
        o = sim.step(q, qd, c, params)
        return (o.joint_qd[0] * weights).sum() + o.fingertips.sum() + o.wrench.sum() * 1e-2

    target = ctrl.q_target.clone().requires_grad_(True)
    loss(target).backward()
    grad = target.grad[0].numpy()
    eps = 1e-6
    fd = np.zeros(sim.nu)
    with torch.no_grad():
        for i in range(sim.nu):
            plus, minus = ctrl.q_target.clone(), ctrl.q_target.clone()
            plus[0, i] += eps
            minus[0, i] -= eps
            fd[i] = (loss(plus) - loss(minus)).item() / (2 * eps)
    assert np.abs(fd).max() > 1e-3
    np.testing.assert_allclose(grad, fd, rtol=1e-4, atol=1e-6 * np.abs(fd).max())


def test_steps_in_flight_keep_their_own_intermediates():
    """Two chained steps differentiated at once (two pooled trajectories in flight, sharing adjoint buffers) give
    the gradient of the chain of single steps, and a gradient-free step in between changes nothing."""
    sim = ArticulatedSimulator(_scene("spray_bottle_a"), 2, dtype=torch.float64)
    q, qd = sim.initial_state()
    params, ctrl = sim.default_params(), _closing(sim)
    with torch.no_grad():  # into contact
        for _ in range(8):
            out = sim.step(q, qd, ctrl, params)
            q, qd = out.joint_q, out.joint_qd
    weights = torch.randn(sim.nq, generator=torch.Generator().manual_seed(1), dtype=torch.float64)

    def closing(target):
        c = _closing(sim)
        c.q_target = target
        return c

    target = ctrl.q_target.clone().requires_grad_(True)
    first = sim.step(q, qd, closing(target), params)
    with torch.no_grad():
        sim.step(first.joint_q, first.joint_qd, ctrl, params)
    second = sim.step(first.joint_q, first.joint_qd, closing(target), params)
    (second.joint_q * weights).sum().backward()
    together = target.grad.clone()

    # the same chain, one step at a time: d/dtarget through step 2 directly, and through step 1's state
    q1 = first.joint_q.detach().requires_grad_(True)
    qd1 = first.joint_qd.detach().requires_grad_(True)
    target2 = ctrl.q_target.clone().requires_grad_(True)
    (sim.step(q1, qd1, closing(target2), params).joint_q * weights).sum().backward()
    target1 = ctrl.q_target.clone().requires_grad_(True)
    again = sim.step(q, qd, closing(target1), params)
    ((again.joint_q * q1.grad).sum() + (again.joint_qd * qd1.grad).sum()).backward()
    assert target2.grad.abs().max() > 0 and target1.grad.abs().max() > 0
    torch.testing.assert_close(together, target1.grad + target2.grad, rtol=1e-12, atol=1e-14)
