"""Object variants: one scene of K objects of one topology, each world simulating its own (sim/_object_variants.py)."""

import tempfile
from pathlib import Path

import numpy as np
import pytest
import torch

from dexmots_rl.assets.hand_scene import hand_object_scene_xml
from dexmots_rl.assets.objects import ObjectError, list_objects, load_object, object_split
from dexmots_rl.sim import ArticulatedSimulator, AssetError, load_scene, load_variants

PAIR = ["spray_bottle_a", "spray_bottle_b"]  # one class: the same topology, other sizes, ranges and springs


def _paths(names, folder):
    paths = []
    for i, name in enumerate(names):
        sub = Path(folder) / f"{i}_{name}"
        sub.mkdir()
        (sub / "scene.xml").write_text(hand_object_scene_xml(load_object(name), sub))
        paths.append(sub / "scene.xml")
    return paths


def _closing(sim, flex):
    """Position control toward a pose curling the index and middle fingers (``flex`` [N] rad per world)."""
    ctrl = sim.zero_control()
    n, nu = sim.num_worlds, sim.nu
    target = torch.zeros(n, nu, dtype=sim.dtype)
    target[:, [1, 2, 5, 6]] = torch.as_tensor(flex, dtype=sim.dtype).reshape(n, 1)
    ctrl.q_target = target
    ctrl.kp, ctrl.kd = torch.full((n, nu), 3.0, dtype=sim.dtype), torch.full((n, nu), 0.1, dtype=sim.dtype)
    return ctrl


def _start(sim, variants):
    """Each world's initial state on its variant, and parameters naming the variant."""
    q, qd = sim.initial_state()
    q[:, sim.nu:] = torch.as_tensor(sim.scene.variant_q0[variants], dtype=sim.dtype)
    params = sim.default_params()
    for name, value in params.items():  # each world's own object's parameters (joints, masses)
        for w, v in enumerate(variants):
            own = sim.scene.variant_trees[v].default_param_values()
            if name in own:
                value[w] = own[name]
    if sim.scene.num_variants > 1:
        params["variant"] = torch.as_tensor(variants, dtype=sim.dtype).reshape(-1, 1)
    return q, qd, params


def test_different_topologies_fail_naming_the_file_and_field(tmp_path):
    bottle, drawer = _paths(["spray_bottle_a", "drawer_a"], tmp_path)
    with pytest.raises(AssetError, match=r"(?s)drawer_a.*free"):
        load_variants([bottle, drawer])


def test_the_hand_must_be_the_same(tmp_path):
    first, second = _paths(PAIR, tmp_path)
    text = second.read_text()
    changed = text.replace('damping="0.1"', 'damping="0.2"', 1)  # the hand joints' damping (their default class)
    assert changed != text
    second.write_text(changed)
    with pytest.raises(AssetError, match=r"(?s)spray_bottle_b.*hand's dof_damping"):
        load_variants([first, second])


def test_worlds_step_their_own_variant_exactly():
    """Worlds on variant k of a two-variant scene step bitwise as a one-object scene of that object."""
    with tempfile.TemporaryDirectory() as tmp:
        paths = _paths(PAIR, tmp)
        scene = load_variants(paths)
        singles = [load_scene(p) for p in paths]
    assert scene.num_variants == 2 and scene.param_names[-1] == "variant"
    assert not np.array_equal(scene.variant_trees[0].sample_pos, scene.variant_trees[1].sample_pos)
    variants = [1, 0, 1, 0]
    sim = ArticulatedSimulator(scene, 4)
    q, qd, params = _start(sim, variants)
    ctrl = _closing(sim, [1.2, 1.1, 1.0, 1.3])
    pose0, _ = sim.observe(q, qd, params)
    states = []
    with torch.no_grad():
        for _ in range(12):
            out = sim.step(q, qd, ctrl, params)
            q, qd = out.joint_q, out.joint_qd
            states.append((q, qd, out.wrench, out.body_pose))
    assert float(out.contact_force.max()) > 0.05
    for k, single in enumerate(singles):
        worlds = [w for w, v in enumerate(variants) if v == k]
        one = ArticulatedSimulator(single, len(worlds))
        q1, qd1, params1 = _start(one, [0] * len(worlds))
        for name in params1.keys():
            params1[name] = params[name][worlds]
        ctrl1 = _closing(one, [[1.2, 1.1, 1.0, 1.3][w] for w in worlds])
        torch.testing.assert_close(one.observe(q1, qd1)[0], pose0[worlds], rtol=0, atol=0)
        with torch.no_grad():
            for q_v, qd_v, wrench_v, pose_v in states:
                out1 = one.step(q1, qd1, ctrl1, params1)
                q1, qd1 = out1.joint_q, out1.joint_qd
                for mine, theirs in ((q1, q_v), (qd1, qd_v), (out1.wrench, wrench_v), (out1.body_pose, pose_v)):
                    assert torch.equal(mine, theirs[worlds])


@pytest.mark.slow  # the tool scene's float64 build
def test_gradient_with_two_variants_matches_finite_differences():
    """d(state after one step)/d(position targets) in float64, two worlds on two variants of one batch, through
    finger contact and the table, against central differences."""
    with tempfile.TemporaryDirectory() as tmp:
        scene = load_variants(_paths(PAIR, tmp))
    sim = ArticulatedSimulator(scene, 2, dtype=torch.float64)
    q, qd, params = _start(sim, [0, 1])
    ctrl = _closing(sim, [1.2, 1.2])
    with torch.no_grad():  # into contact
        for _ in range(8):
            out = sim.step(q, qd, ctrl, params)
            q, qd = out.joint_q, out.joint_qd
    assert (out.contact_force > 0.05).all()
    weights = torch.randn(2, sim.nv, generator=torch.Generator().manual_seed(0), dtype=torch.float64)

    def loss(target):
        c = _closing(sim, [1.2, 1.2])
        c.q_target = target
        o = sim.step(q, qd, c, params)
        return (o.joint_qd * weights).sum() + o.fingertips.sum() + o.wrench.sum() * 1e-2

    target = ctrl.q_target.clone().requires_grad_(True)
    loss(target).backward()
    grad = target.grad.numpy()
    eps = 1e-6
    fd = np.zeros_like(grad)
    with torch.no_grad():
        for w in range(2):
            for i in range(sim.nu):
                plus, minus = ctrl.q_target.clone(), ctrl.q_target.clone()
                plus[w, i] += eps
                minus[w, i] -= eps
                fd[w, i] = (loss(plus) - loss(minus)).item() / (2 * eps)
    assert np.abs(fd[0]).max() > 1e-3 and np.abs(fd[1]).max() > 1e-3
    np.testing.assert_allclose(grad, fd, rtol=1e-4, atol=1e-6 * np.abs(fd).max())
    # a variant index outside [0, K) is refused, naming the parameter
    params["variant"][1] = 2.0
    with pytest.raises(ValueError, match="variant"):
        sim.step(q, qd, ctrl, params)


def test_sample_variants_draws_sizes_only():
    from dexmots_rl.assets.objects import sample_variants
    from dexmots_rl.assets.objects.generators import PARAMS
    from dexmots_rl.assets.objects.generators.common import make_rng

    base = PARAMS["spray_bottle"]()
    drawn = base.sample_sizes(make_rng(3), 0.1)
    kinds = {f.name: f.metadata["kind"] for f in __import__("dataclasses").fields(base)}
    for name, kind in kinds.items():
        ratio = getattr(drawn, name) / getattr(base, name) if getattr(base, name) else 1.0
        assert (0.9 <= ratio <= 1.1) if kind == "size" else ratio == 1.0, name
    assert any(getattr(drawn, n) != getattr(base, n) for n, k in kinds.items() if k == "size")
    variants = sample_variants("spray_bottle_a", 3, rng=3)
    again = sample_variants("spray_bottle_a", 3, rng=3)
    assert [v.name for v in variants] == ["spray_bottle_a", "spray_bottle_a_size1", "spray_bottle_a_size2"]
    assert variants[1].grasp == again[1].grasp and variants[1].grasp != variants[0].grasp


def test_operate_draws_a_variant_per_world_at_every_reset():
    """``operate`` with size variants: each world starts on its variant's rest pose with its goal, keeps the
    variant through the episode, and a partial reset redraws only the reset worlds' variants."""
    from dexmots_rl.envs import make_env

    env = make_env("operate", num_envs=6, object="spray_bottle_a", variants=3, seed=0, differentiable=False,
                   raw=True)
    assert env.sim.scene.num_variants == 3
    td = env.reset()
    variant = td["sim", "params", "variant"].reshape(-1).long()
    assert len(set(variant.tolist())) > 1
    table = env._variant_values
    nu = env.sim.nu
    torch.testing.assert_close(td["sim", "joint_q"][:, nu:], table["q0"][variant])
    torch.testing.assert_close(td["task", "goal"], table["goal_value"][variant])
    for _ in range(3):
        td["action"] = torch.zeros(6, env.action_spec.shape[-1])
        td = env.step(td)["next"]
        assert torch.isfinite(td["sim", "joint_q"]).all()
        assert torch.equal(td["sim", "params", "variant"].reshape(-1).long(), variant)
    shift, tilt = env.base_motion(td)
    assert (shift < 0.005).all() and (tilt < 0.05).all()  # each base at rest where its variant stands
    for _ in range(4):  # partial resets: the kept worlds keep their variant, the reset one draws again
        td["_reset"] = torch.tensor([True, False, False, False, False, False]).reshape(6, 1)
        fresh = env.reset(td)
        assert torch.equal(fresh["sim", "params", "variant"][1:], td["sim", "params", "variant"][1:])
        td = fresh
    assert not env.task_success(td, td["task", "goal"]).any()


def test_operate_over_several_instances():
    from dexmots_rl.envs import make_env

    with pytest.raises(ValueError, match="task.variants"):
        make_env("operate", num_envs=2, objects=PAIR, variants=2)
    env = make_env("operate", num_envs=4, objects=",".join(reversed(PAIR)), seed=1, raw=True)
    assert env.sim.scene.num_variants == 2 and env.object_asset.name == PAIR[1]
    start = env.reset()
    variant = start["sim", "params", "variant"].reshape(-1).long()
    hand = start["hand", "q"]
    for w in range(4):  # each world starts from one of its own instance's pre-grasps (plus the joint noise)
        poses = env._variant_pregrasps[int(variant[w])]
        assert (hand[w] - poses).abs().amax(-1).min() <= env.config.joint_noise + 1e-6
    td = env.rollout(3, break_when_any_done=False)
    assert torch.isfinite(td["next", "reward"]).all()
    variant = td["next", "sim", "params", "variant"][:, -1].reshape(-1).long()
    goals = env._variant_values["goal_value"]
    assert goals[0] != goals[1]  # spray_bottle_b pulls its trigger less far
    torch.testing.assert_close(td["next", "task", "goal"][:, -1], goals[variant])


@pytest.mark.parametrize("object_class", sorted({cls for _, cls in list_objects()}))
def test_training_and_heldout_instances_never_overlap(object_class):
    split = object_split(object_class)
    instances = [name for name, cls in list_objects() if cls == object_class]
    assert split["train"] and split["heldout"]
    assert not set(split["train"]) & set(split["heldout"])
    assert sorted(split["train"] + split["heldout"]) == sorted(instances)
    assert object_split(instances[0]) == split  # an instance names its class
    # each part is one scene of variants: the class's instances share their topology
    with tempfile.TemporaryDirectory() as folder:
        paths = _paths(instances, folder)
        assert load_variants(paths).num_variants == len(instances)


def test_operate_on_a_split():
    from dexmots_rl.envs import make_env
    from dexmots_rl.envs.tasks.allegro.operate_object import object_names

    assert object_names("heldout", "valve_a") == object_split("valve")["heldout"]
    assert object_names("train", "valve_b") == ["valve_a", "valve_c"]
    with pytest.raises(ValueError, match="task.objects=train"):
        object_names("train", "/data/tool/mobility.urdf")
    with pytest.raises(ObjectError, match="unknown class"):
        object_split("kettle")
    env = make_env("valve", num_envs=2, objects="heldout", seed=0, raw=True)
    assert env.object_asset.name == "valve_b" and env.sim.scene.num_variants == 1
    assert torch.isfinite(env.rollout(2)["next", "reward"]).all()


def test_success_by_variant_names_each_object():
    from dexmots_rl.algorithms.evaluation import _success_by

    variant = torch.tensor([0.0, 1.0, 1.0, 0.0, 1.0])
    won = torch.tensor([True, False, True, True, False])
    rows = _success_by(variant, won, labels=["valve_a", "valve_b"])
    assert [(r["label"], r["episodes"], r["success_rate"]) for r in rows] == [("valve_a", 2, 1.0),
                                                                             ("valve_b", 3, pytest.approx(1 / 3))]
