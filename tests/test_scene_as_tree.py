"""The knob and cube scenes read as an object tree (``load_scene(path, articulated=True)``) and stepped by the split
kernels of :class:`~dexmots_rl.sim.ArticulatedSimulator`, against the fused kernel of
:class:`~dexmots_rl.sim.Simulator` (the single-body scenes' own)."""

import numpy as np
import pytest
import torch

from dexmots_rl.apps.bench_setup import bench_task, bench_tasks
from dexmots_rl.envs.registry import task_contact, task_entry
from dexmots_rl.assets import asset_path
from dexmots_rl.sim import ArticulatedScene, AssetError, Control, SceneModel, load_scene, make_simulator

TASKS = bench_tasks()  # the tasks whose object is one hinged or free body
CLAW_XML = asset_path("claw_screw.xml")


def _scenes(task):
    path = task_entry(task).env_class.asset_path()
    contact = task_contact(task)
    return load_scene(path, contact=contact), load_scene(path, contact=contact, articulated=True)


def _sims(task, worlds=2, dtype=torch.float32):
    fused, tree = _scenes(task)
    return [make_simulator(s, num_worlds=worlds, contact=task_contact(task), dtype=dtype) for s in (fused, tree)]


def _torque(sim, action):
    """The motors' torque for ``action`` [N, nu] in [-1, 1]."""
    z = torch.zeros_like(action)
    return Control(action * torch.as_tensor(sim.scene.actuator_gear, dtype=sim.dtype), z, z, z)


@pytest.mark.parametrize("task", TASKS)
def test_single_body_reads_as_a_tree(task):
    """A hinged body is one hinge part on a fixed, massless mount; a free body a free base without parts; the
    joint's and body's values, the initial state and the object's pose are the single-body scene's."""
    fused, scene = _scenes(task)
    assert isinstance(fused, SceneModel) and isinstance(scene, ArticulatedScene)
    tree = scene.tree
    assert (tree.nq, tree.nv) == (fused.object_nq, fused.object_nv)
    np.testing.assert_allclose(scene.object_q0, fused.object_q0)
    assert tree.mass[-1] == pytest.approx(fused.object_mass)
    if fused.articulated:
        assert tree.body_names[1] == "object" and not tree.free and tree.num_parts == 1
        assert tree.mass[0] == 0 and (scene.geoms.kind[0] < 0).all() and len(scene.palm[0]) == 0
        assert (tree.joint_damping[0], tree.joint_friction[0]) == pytest.approx((fused.object_damping,
                                                                                fused.object_friction))
    else:
        assert tree.free and tree.num_parts == 0 and len(scene.palm[0]) == fused.num_palm_boxes
    sims = _sims(task)
    q, _ = sims[0].initial_state()
    q[:, :sims[0].nu] = torch.as_tensor(bench_task(task).open_q[:sims[0].nu])
    poses = [sim.observe(q) for sim in sims]
    torch.testing.assert_close(poses[1][0][:, -1], poses[0][0][:, -1])  # the object
    torch.testing.assert_close(poses[1][0][:, :sims[0].nu], poses[0][0][:, :sims[0].nu])  # the hand's links
    torch.testing.assert_close(poses[1][1], poses[0][1])  # the fingertips


@pytest.mark.parametrize("task", TASKS)
def test_tree_steps_as_the_fused_kernel_out_of_contact(task):
    """Away from contact the two kernel sets are one physics, to float32 rounding: the hand's joints under random
    torques, the object (a knob spinning with its Coulomb friction off, whose laws differ; a cube thrown spinning
    above the palm)."""
    sims = _sims(task)
    nu, n = sims[0].nu, sims[0].num_worlds
    open_q = torch.as_tensor(bench_task(task).open_q, dtype=torch.float32)
    q, qd = open_q.expand(n, -1).clone(), torch.zeros(n, sims[0].nv)
    if sims[0].object_is_free:
        q[:, nu + 2] += 0.3
        qd[:, nu:] = torch.tensor([0.1, 0.0, 0.5, 3.0, -2.0, 5.0])
    else:
        qd[:, nu] = 2.0
    states = [(q, qd), (q.clone(), qd.clone())]
    actions = -0.5 * torch.rand(6, n, nu, generator=torch.Generator().manual_seed(0))  # opening: no contact
    for action in actions:
        for i, sim in enumerate(sims):
            params = sim.default_params()
            for name in ("joint_friction", "knob_hinge/friction"):
                if name in params.keys():
                    params[name] = torch.zeros_like(params[name])
            out = sim.step(*states[i], _torque(sim, action), params)
            assert float(out.contact_force.abs().max()) == 0.0
            states[i] = (out.joint_q, out.joint_qd)
        (qa, qda), (qb, qdb) = states
        torch.testing.assert_close(qb[:, :nu], qa[:, :nu])
        torch.testing.assert_close(qdb[:, :nu], qda[:, :nu])
        torch.testing.assert_close(qb[:, nu:], qa[:, nu:], rtol=1e-5, atol=1e-6)
        torch.testing.assert_close(qdb[:, nu:], qda[:, nu:], rtol=1e-4, atol=1e-5)
    assert float((states[0][0][:, nu:] - open_q[nu:]).abs().max()) > 1e-3  # the object moved


def _contact_gradient_check(task):
    """d(state, fingertips, wrench after one step in contact)/d(motor torques) of the tree scene, float64, against
    central differences."""
    _, scene = _scenes(task)
    sim = make_simulator(scene, num_worlds=1, contact=task_contact(task), dtype=torch.float64)
    poses = bench_task(task)
    q = torch.as_tensor(poses.open_q, dtype=torch.float64)[None].clone()
    qd, params = torch.zeros(1, sim.nv, dtype=torch.float64), sim.default_params()
    close = torch.as_tensor(poses.close_action, dtype=torch.float64)[None]
    with torch.no_grad():  # into contact
        for _ in range(12):
            out = sim.step(q, qd, _torque(sim, close), params)
            q, qd = out.joint_q, out.joint_qd
            if float(out.contact_force[0]) > 0:
                break
    assert float(out.contact_force[0]) > 0
    weights = torch.randn(sim.nv, generator=torch.Generator().manual_seed(0), dtype=torch.float64)

    def loss(action):
        o = sim.step(q, qd, _torque(sim, action), params)
        return (o.joint_qd[0] * weights).sum() + o.fingertips.sum() + o.wrench.sum() * 1e-2

    action = close.clone().requires_grad_(True)
    loss(action).backward()
    eps, fd = 1e-6, np.zeros(sim.nu)
    with torch.no_grad():
        for i in range(sim.nu):
            plus, minus = close.clone(), close.clone()
            plus[0, i] += eps
            minus[0, i] -= eps
            fd[i] = (loss(plus) - loss(minus)).item() / (2 * eps)
    assert np.abs(fd).max() > 1e-3
    np.testing.assert_allclose(action.grad[0].numpy(), fd, rtol=1e-4, atol=1e-6 * np.abs(fd).max())


def test_claw_tree_gradient_in_contact_matches_finite_differences():
    _contact_gradient_check("screw_claw")


@pytest.mark.slow  # the Allegro's float64 build of the split kernels
@pytest.mark.parametrize("task", [t for t in TASKS if t != "screw_claw"])
def test_allegro_tree_gradient_in_contact_matches_finite_differences(task):
    _contact_gradient_check(task)


@pytest.mark.parametrize("articulated", [False, True])
def test_a_sliding_single_body_is_refused_naming_its_joint(tmp_path, articulated):
    """A single object body on a slide joint is neither scene's: read either way, one error naming the joint, its
    body and the joints it may be."""
    text = CLAW_XML.read_text().replace('<joint name="knob_hinge" type="hinge"', '<joint name="knob_hinge" type="slide"')
    path = tmp_path / "slide.xml"
    path.write_text(text)
    with pytest.raises(AssetError, match="joint 'knob_hinge' of body 'object' must be a hinge or a free joint"):
        load_scene(path, articulated=articulated)
