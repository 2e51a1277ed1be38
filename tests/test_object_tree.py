"""The articulated object tree (sim/_object_sim.py) against MuJoCo, on the table, and its gradients."""

import numpy as np
import pytest
import torch

from dexmots_rl.assets.objects import Geom, Joint, ObjectAsset, Part, list_objects, load_object
from dexmots_rl.sim import ObjectSimulator, load_object_tree


def _tree_object(base: str, parts: int) -> ObjectAsset:
    """A free or fixed base with one part on a tilted hinge, or (``parts=3``) three: two hinges in a chain and a
    slide, every axis tilted."""
    chain = (
        Part("slider", (Geom("s", "box", (0.01, 0.01, 0.02), mass=0.04),), parent="body", pos=(-0.02, 0.02, 0.2),
             joint=Joint("pump", "slide", (0, 0.6, 0.8), (-0.1, 0.1), damping=0.0, armature=0.0)),
        Part("tip", (Geom("s2", "sphere", (0.01,), pos=(0.0, 0.02, 0.0), mass=0.02),), parent="trig",
             pos=(0.0, 0.0, -0.04), joint=Joint("tipj", "hinge", (1, 0, 0), (-1, 1), damping=0.0, armature=0.0)),
    )
    return ObjectAsset("probe", "test", (
        Part("body", (Geom("b", "box", (0.03, 0.04, 0.1), pos=(0.01, 0, 0.1), mass=0.3),)),
        Part("trig", (Geom("t", "capsule", (0.008, 0.03), pos=(0, 0.01, -0.02), mass=0.05),), parent="body",
             pos=(0.04, 0, 0.15), quat=(0.9238795, 0, 0.3826834, 0),
             joint=Joint("trigger", "hinge", (0, 1, 0), (-1, 1), anchor=(0.0, 0.0, 0.01), damping=0.0, armature=0.0)),
        *(chain if parts == 3 else ()),
    ), base=base)


# one part: the library objects' tree size, whose float64 builds the gradient tests below share; the three-part
# chain is a float64 build of its own (minutes cold), checked in the slow set
@pytest.mark.parametrize("masses", ["model", "parameters"])
@pytest.mark.parametrize("parts", [1, pytest.param(3, marks=pytest.mark.slow)])
@pytest.mark.parametrize("base", ["free", "fixed"])
def test_accelerations_match_mujoco(base, parts, masses):
    """Mass matrix and bias forces (Coriolis, centrifugal, gravity) through the accelerations of one tiny step
    from a random state, against MuJoCo's qacc (no contact, no joint springs). ``parameters``: every moving
    body's mass parameter ``<body>/mass`` set apart from the model's (each by its own factor) and MuJoCo's
    model given the same masses, the inertias scaled with them."""
    import mujoco

    tree, m = load_object_tree(_tree_object(base, parts))
    factors = dict(zip(tree.moving_bodies, (1.7, 0.6, 2.3, 0.8, 1.3)))
    if masses == "parameters":
        for b, factor in factors.items():
            body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, tree.body_names[b])
            m.body_mass[body] *= factor
            m.body_inertia[body] *= factor
    d = mujoco.MjData(m)
    rng = np.random.default_rng(0)
    qpos = m.qpos0.copy()
    nf = 7 if base == "free" else 0
    if base == "free":
        quat = rng.normal(size=4)
        qpos[:7] = [0.1, 0.2, 1.0, *(quat / np.linalg.norm(quat))]
    qpos[nf:] = rng.uniform(-0.08, 0.08, size=m.nq - nf)
    qvel = rng.normal(size=m.nv)
    d.qpos[:], d.qvel[:] = qpos, qvel
    mujoco.mj_forward(m, d)
    assert d.ncon == 0
    qd = torch.tensor(qvel)[None].clone()
    ref = d.qacc.copy()
    if base == "free":  # MuJoCo's free joint turns at a body-frame angular velocity; ours is in the world frame
        rot = d.xmat[1].reshape(3, 3)
        qd[0, 3:6] = torch.tensor(rot @ qvel[3:6])
        ref[3:6] = rot @ ref[3:6]
    dt = 1e-7
    sim = ObjectSimulator(tree, 1, dtype=torch.float64, substeps=1, sub_dt=dt)
    params = sim.default_params()
    for name in tree.param_names:  # no joint damping, friction or spring (the masses stay the model's)
        if not name.endswith("/mass"):
            params[name] = torch.zeros_like(params[name])
    if masses == "parameters":
        for b, factor in factors.items():
            params[f"{tree.body_names[b]}/mass"] = params[f"{tree.body_names[b]}/mass"] * factor
    _, qd_next = sim.step(torch.tensor(qpos)[None], qd, params)
    acc = ((qd_next - qd) / dt)[0].numpy()
    np.testing.assert_allclose(acc, ref, rtol=1e-5, atol=1e-5 * np.abs(ref).max())


def _settle(name, steps, tilt=0.0, dtype=torch.float32):
    tree, _ = load_object_tree(load_object(name))
    sim = ObjectSimulator(tree, 2, dtype=dtype)
    q, qd = sim.initial_state()
    if tilt:
        q[:, 2] += 0.03
        q[:, 3:7] = torch.tensor([np.cos(tilt / 2), np.sin(tilt / 2), 0.0, 0.0], dtype=dtype)
    q0 = q.clone()
    params = sim.default_params()
    with torch.no_grad():
        for _ in range(steps):
            q, qd = sim.step(q, qd, params)
    return q0, q, qd


def test_free_base_rests_on_the_table():
    """Left alone on the table, a free base stays put: drift < 1 mm in 10 s (600 steps of 1/60 s)."""
    q0, q, qd = _settle("spray_bottle_a", 600)
    assert torch.isfinite(q).all()
    assert (q[:, :3] - q0[:, :3]).norm(dim=-1).max() < 1e-3
    assert qd[:, :6].abs().max() < 1e-2


def test_tilted_base_falls_flat():
    """Released tilted by 0.2 rad (inside its tipping angle) 3 cm above the table, the bottle lands on its bottom."""
    _, q, qd = _settle("spray_bottle_a", 120, tilt=0.2)
    up = torch.tensor([0.0, 0.0, 1.0])
    w, x, y, z = q[:, 3], q[:, 4], q[:, 5], q[:, 6]
    # the base's z axis in the world: its tilt from vertical
    axis_z = torch.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], -1)
    assert torch.arccos((axis_z @ up).clamp(-1, 1)).max() < 0.05
    assert q[:, 2].abs().max() < 2e-3


@pytest.mark.parametrize("name", ["pump_dispenser_a", "stapler_a", "drawer_a"])
def test_gradients_match_finite_differences(name):
    """d(state after one step)/d(state, wrench, joint parameters) in float64, with the base on the table
    (contact and its implicit friction), a slide (the pump, the drawer) and a hinge pushed against its stop."""
    tree, _ = load_object_tree(load_object(name))
    sim = ObjectSimulator(tree, 1, dtype=torch.float64, substeps=8)
    q, qd = sim.initial_state()
    params = sim.default_params()
    # a sideways push on the base, which settles on the table
    wrench = torch.zeros(1, tree.num_bodies, 6, dtype=torch.float64)
    wrench[0, 0, :3] = torch.tensor([0.3, -0.2, -1.0])
    with torch.no_grad():
        for _ in range(20):
            q, qd = sim.step(q, qd, params, wrench)
    # the part 5 mm (or mrad) into its upper stop, moving on
    q[0, -1] = float(tree.joint_range[0, 1]) + 0.005
    qd[0, -1] = 0.1
    weights_q = torch.randn(sim.nq, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    weights_v = torch.randn(sim.nv, generator=torch.Generator().manual_seed(2), dtype=torch.float64)

    def loss(q_in, qd_in, w_in, damping):
        p = params.clone()
        p[f"{tree.joint_names[0]}/damping"] = damping
        q_out, qd_out = sim.step(q_in, qd_in, p, w_in)
        return (q_out * weights_q).sum() + 0.01 * (qd_out * weights_v).sum()

    _assert_gradients_match_central_differences(
        lambda *args: loss(q, *args), [qd, wrench, params[f"{tree.joint_names[0]}/damping"]])


def _assert_gradients_match_central_differences(loss, inputs, eps=1e-6):
    """loss(*inputs)'s gradient w.r.t. every entry of every input against central differences (float64)."""
    inputs = [t.detach().clone().requires_grad_(True) for t in inputs]
    loss(*inputs).backward()
    for k, t in enumerate(inputs):
        fd = np.zeros(t.numel())
        with torch.no_grad():
            for i in range(t.numel()):
                args = [x.detach().clone() for x in inputs]
                args[k].view(-1)[i] += eps
                plus = loss(*args).item()
                args[k].view(-1)[i] -= 2 * eps
                fd[i] = (plus - loss(*args).item()) / (2 * eps)
        np.testing.assert_allclose(t.grad.reshape(-1).numpy(), fd, rtol=1e-4, atol=1e-7 + 1e-6 * np.abs(fd).max())


def test_reused_arrays_give_the_same_rollout_and_gradient():
    """The simulator reuses its substeps' arrays once a step is done with: a rollout's gradient, taken again
    after no-grad steps and a graph dropped without its backward pass, is bit for bit the first one."""
    tree, _ = load_object_tree(load_object("stapler_a"))
    sim = ObjectSimulator(tree, 2, dtype=torch.float64, substeps=4)
    params = sim.default_params()

    def rollout_gradient():
        q, qd = sim.initial_state()
        wrench = torch.full((2, tree.num_bodies, 6), 0.05, dtype=torch.float64, requires_grad=True)
        for _ in range(3):
            q, qd = sim.step(q, qd, params, wrench)
        (q.sum() + qd.square().sum()).backward()
        return q.detach(), wrench.grad

    first = rollout_gradient()
    with torch.no_grad():
        sim.step(*sim.initial_state(), params)
    wrench = torch.zeros(2, tree.num_bodies, 6, dtype=torch.float64, requires_grad=True)
    sim.step(*sim.initial_state(), params, wrench)  # a graph never differentiated
    again = rollout_gradient()
    assert all(torch.equal(a, b) for a, b in zip(first, again)) and first[1].abs().sum() > 0


def test_dropped_object_gains_no_energy():
    """Dropped 5 cm onto the table, the bottle's kinetic plus potential energy never exceeds its initial energy
    (the table's contact, damping and friction only take energy out)."""
    tree, _ = load_object_tree(load_object("spray_bottle_a"))
    sim = ObjectSimulator(tree, 3, dtype=torch.float64)
    q, qd = sim.initial_state()
    q[:, 2] += 0.05
    q[1, 3:7] = torch.tensor([np.cos(0.05), np.sin(0.05), 0.0, 0.0])  # slightly tilted
    qd[2, 3:6] = torch.tensor([2.0, -1.0, 3.0])  # spinning
    mass = float(tree.mass.sum())

    def energy(q, qd):
        # the base's motion dominates (the trigger is light and rests on its stop): m g z + the base's kinetic
        # energy as a rigid body of the total mass
        rot_inertia = torch.tensor(tree.inertia[0], dtype=torch.float64)
        w, x, y, z = q[:, 3], q[:, 4], q[:, 5], q[:, 6]
        R = torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                         2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                         2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1).view(-1, 3, 3)
        com = q[:, :3] + R @ torch.tensor(tree.com[0], dtype=torch.float64)
        v_com = qd[:, :3] + torch.cross(qd[:, 3:6], com - q[:, :3], dim=-1)
        iw = R @ rot_inertia @ R.transpose(1, 2)
        kinetic = 0.5 * tree.mass[0] * (v_com ** 2).sum(-1) + 0.5 * (qd[:, 3:6] * (iw @ qd[:, 3:6, None])[..., 0]).sum(-1)
        return kinetic + mass * 9.81 * com[:, 2]

    e0 = energy(q, qd)
    params = sim.default_params()
    peak = e0.clone()
    with torch.no_grad():
        for _ in range(90):
            q, qd = sim.step(q, qd, params)
            peak = torch.maximum(peak, energy(q, qd))
    assert torch.isfinite(q).all()
    assert (peak - e0 < 0.01 * mass * 9.81 * 0.05).all(), (peak - e0)

HOLD_SECONDS = 1.0
MAX_CREEP = 1e-6  # rad or m over HOLD_SECONDS: a part held by its friction stays put


def _loaded_part(name, num_worlds, loads, substeps=16):
    """The object's part 40 % into its range, its spring off, its joint's friction 2.5 times gravity's largest
    pull plus a load L (the part's weight x 5 cm, or its weight on a slide), and per world an internal couple
    between the part and the base along the joint's axis of ``loads(L, friction, gravity)[w]``.
    Returns the simulator, state, parameters and wrench."""
    import mujoco

    tree, m = load_object_tree(load_object(name))
    sim = ObjectSimulator(tree, num_worlds, dtype=torch.float64, substeps=substeps)
    joint = tree.joint_names[0]
    lo, hi = (float(x) for x in tree.joint_range[0])
    q, qd = sim.initial_state()
    q[:, -1] = lo + 0.4 * (hi - lo)
    d = mujoco.MjData(m)
    d.qpos[:] = q[0].numpy()
    mujoco.mj_forward(m, d)
    axis = torch.tensor(d.xaxis[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, f"object/{joint}")])
    weight = float(tree.mass[1]) * 9.81
    arm = np.asarray(tree.com[1]) - np.asarray(tree.joint_anchor[0])
    slide = tree.joint_kind[0] == 1
    gravity = weight if slide else weight * float(np.linalg.norm(np.cross(arm, tree.joint_axis[0])))
    load = weight * (1.0 if slide else 0.05)  # N, or N m
    friction = 2.5 * (gravity + load)
    params = sim.default_params()
    params[f"{joint}/stiffness"] = torch.zeros_like(params[f"{joint}/stiffness"])
    params[f"{joint}/friction"] = torch.full_like(params[f"{joint}/friction"], friction)
    wrench = torch.zeros(num_worlds, tree.num_bodies, 6, dtype=torch.float64)
    column = slice(0, 3) if slide else slice(3, 6)
    for w, size in enumerate(loads(load, friction, gravity)):
        wrench[w, 1, column] = size * axis
        wrench[w, 0, column] = -size * axis
    return sim, q, qd, params, wrench


@pytest.mark.parametrize("name", [name for name, _ in list_objects()])
def test_friction_holds_a_loaded_part(name):
    """A part held off its stops by its joint's Coulomb friction against gravity and an internal load (below the
    friction either way) does not creep, while a load above the friction moves it. Worlds: +load, -load, then
    1.5 x the friction plus gravity's pull."""
    sim, q, qd, params, wrench = _loaded_part(name, 3, lambda load, friction, gravity: (
        load, -load, 1.5 * friction + gravity))
    start = q[:, -1].clone()
    with torch.no_grad():
        for _ in range(round(HOLD_SECONDS / sim.dt)):
            q, qd = sim.step(q, qd, params, wrench)
    moved = (q[:, -1] - start).abs()
    assert torch.isfinite(q).all()
    assert moved[:2].max() < MAX_CREEP, f"{name}: the held part crept {moved[:2].tolist()}"
    span = float(sim.tree.joint_range[0, 1] - sim.tree.joint_range[0, 0])
    assert moved[2] > 0.05 * span, f"{name}: a load above the friction moved the part only {moved[2]:.2e}"


@pytest.mark.parametrize("name", ["stapler_a", "drawer_a"])
def test_friction_gradients_match_finite_differences(name):
    """d(state after one step)/d(velocity, wrench, joint friction) in float64 where the joint's friction holds
    the part (load 0.5 x its friction), breaks away (1 x: through the blend into sliding) and slides (2 x)."""
    sim, q, qd, params, wrench = _loaded_part(name, 3, lambda load, friction, gravity: (
        0.5 * friction, friction, 2.0 * friction), substeps=8)
    qd[:, -1] = 0.01
    friction = f"{sim.tree.joint_names[0]}/friction"
    weights_q = torch.randn(3, sim.nq, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    weights_v = torch.randn(3, sim.nv, generator=torch.Generator().manual_seed(2), dtype=torch.float64)

    def loss(qd_in, w_in, fric):
        p = params.clone()
        p[friction] = fric
        q_out, qd_out = sim.step(q, qd_in, p, w_in)
        return (q_out * weights_q).sum() + 0.01 * (qd_out * weights_v).sum()

    _assert_gradients_match_central_differences(loss, [qd, wrench, params[friction]])
