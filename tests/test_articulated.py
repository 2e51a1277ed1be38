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


def test_palm_pushes_the_object():
    """A bottle whose top is 3 mm inside the palm is pushed down by it (compared with the same scene without palm
    contact; the fingers' contact is switched off, as the bottle also overlaps them there)."""
    import dataclasses

    from dexmots_rl.sim import ContactParams

    scene = _scene("spray_bottle_a")
    assert len(scene.palm[0]) == 1
    palm_pos, palm_rot, palm_half = (np.asarray(a)[0] for a in scene.palm)
    bottom = palm_pos[2] - np.abs(palm_rot[2]) @ palm_half  # the palm box's lowest z
    top = max(float(p[2] + r) for p, r in zip(scene.tree.sample_pos[0], scene.tree.sample_radius[0]) if r >= 0)
    speeds = []
    for palm in (scene.palm, tuple(np.zeros((0, *np.shape(a)[1:])) for a in scene.palm)):
        sim = ArticulatedSimulator(dataclasses.replace(scene, palm=palm), 1, contact=ContactParams(stiffness=0.0))
        q, qd = sim.initial_state()
        q[0, sim.nu:sim.nu + 3] = torch.tensor([palm_pos[0], palm_pos[1], bottom + 0.003 - top])
        out = sim.step(q, qd, sim.zero_control(), sim.default_params())
        speeds.append(out.joint_qd[0, sim.nu:sim.nu + 3])
    assert speeds[0][2] < speeds[1][2] - 0.05  # pushed down, beyond gravity's share
