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


@pytest.mark.parametrize("name", ["spray_bottle_a", "scissors_a"])
def test_bang_bang_fingers_inject_no_energy(name):
    """Random full-torque actions held for 3 steps strike the object; its kinetic + potential energy gain never
    exceeds the work the motors have done (sum of torque x joint travel) plus what the hand's links can release
    by falling (their weight over 0.2 m). That bound is loose (the motors' ~50 J over 2 s go mostly into the
    joints' damping), so the base's speed and spin are also bounded: strikes measured 0.8-1 m/s and 16-25 rad/s;
    a contact that injects energy flings objects at hundreds of rad/s."""
    scene = _scene(name)
    n = 8
    sim = ArticulatedSimulator(scene, n)
    q, qd = sim.initial_state()
    params = sim.default_params()
    tree, nu = scene.tree, sim.nu
    gear = torch.as_tensor(scene.actuator_gear, dtype=torch.float32)
    release = float(np.sum(scene.link_mass)) * 9.81 * 0.2
    mass, inertia = float(tree.mass[0]), torch.as_tensor(tree.inertia[0], dtype=torch.float32)
    com_local = torch.as_tensor(tree.com[0], dtype=torch.float32)

    def energy(q, qd):
        w, x, y, z = q[:, nu + 3], q[:, nu + 4], q[:, nu + 5], q[:, nu + 6]
        R = torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                         2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                         2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1).view(-1, 3, 3)
        com = q[:, nu:nu + 3] + R @ com_local
        omega = qd[:, nu + 3:nu + 6]
        v = qd[:, nu:nu + 3] + torch.cross(omega, com - q[:, nu:nu + 3], dim=-1)
        spin = (omega * ((R @ inertia @ R.transpose(1, 2)) @ omega[..., None])[..., 0]).sum(-1)
        return 0.5 * mass * (v ** 2).sum(-1) + 0.5 * spin + mass * 9.81 * com[:, 2]

    gen = torch.Generator().manual_seed(0)
    e0, work, worst = energy(q, qd), torch.zeros(n), torch.full((n,), -1e9)
    speed = spin = 0.0
    with torch.no_grad():
        for step in range(120):
            if step % 3 == 0:
                action = torch.where(torch.rand(n, nu, generator=gen) < 0.5, -1.0, 1.0)
            ctrl = sim.zero_control()
            ctrl.tau = action * gear
            out = sim.step(q, qd, ctrl, params)
            work += (ctrl.tau * (out.joint_q[:, :nu] - q[:, :nu])).sum(-1)
            q, qd = out.joint_q, out.joint_qd
            worst = torch.maximum(worst, energy(q, qd) - e0 - work.clamp(min=0))
            speed = max(speed, float(qd[:, nu:nu + 3].norm(dim=-1).max()))
            spin = max(spin, float(qd[:, nu + 3:nu + 6].norm(dim=-1).max()))
    assert torch.isfinite(q).all()
    assert speed < 3.0 and spin < 100.0, (speed, spin)
    assert (worst < release + 0.01).all(), (worst, release)


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
