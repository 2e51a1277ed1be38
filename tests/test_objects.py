"""The procedural object library: every shipped object is valid, compiles in MuJoCo, stands on the table,
is sized for the Allegro hand and can be operated by one finger; the generators are seeded and checked."""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import sys
import types

import mujoco
import numpy as np
import pytest

from dexmots_rl.assets.objects import (SCENE_PREFIX, ObjectError, list_objects, load_object, object_scene_xml)
from dexmots_rl.assets.objects.generators import GENERATORS, PARAMS
from dexmots_rl.assets.objects.scene import bounding_box, part_transforms

NAMES = [name for name, _ in list_objects()]
CLASSES = sorted(GENERATORS)
FINGER_TORQUE, FINGER_FORCE = 0.5, 5.0  # what one Allegro finger gives (N m at a joint, N at a fingertip)


@functools.lru_cache(maxsize=None)
def asset(name: str):
    return load_object(name)


def compile_scene(a, tmp_path, **kwargs):
    return mujoco.MjModel.from_xml_string(object_scene_xml(a, tmp_path / "meshes", **kwargs))


# ---------------------------------------------------------------------------------------------- library
def test_library_ships_enough_objects_and_classes():
    pairs = list_objects()
    assert len(pairs) >= 14 and len({c for _, c in pairs}) >= 6
    assert len(NAMES) == len(set(NAMES))
    for name, object_class in pairs:
        assert asset(name).object_class == object_class and asset(name).name == name


def test_load_object_rejects_unknown_names_listing_the_choices():
    with pytest.raises(ObjectError, match="unknown object 'teapot'.*spray_bottle_a"):
        load_object("teapot")


def test_load_object_hands_urdf_paths_to_the_urdf_loader(monkeypatch):
    calls = []
    fake = types.ModuleType("dexmots_rl.assets.objects.urdf")
    fake.load_urdf = lambda path, **options: calls.append((str(path), options)) or "loaded"
    monkeypatch.setitem(sys.modules, "dexmots_rl.assets.objects.urdf", fake)
    assert load_object("data/7310/mobility.urdf", size=0.15) == "loaded"
    assert calls == [("data/7310/mobility.urdf", {"size": 0.15})]


def test_a_second_build_replaces_the_mesh_files_rather_than_rewriting_them(tmp_path):
    """Runs that build the same scene side by side (a sweep's seeds) share its folder: a rebuild must move
    complete files in (a new inode, the old one intact for a reader that holds it), never truncate a mesh
    that another process's MuJoCo compiler is reading."""
    a = asset("jar_a")
    a.mjcf(tmp_path)
    path = tmp_path / "jar_a_lid.obj"
    before = path.read_bytes()
    with open(path, "rb") as reader:
        a.mjcf(tmp_path)
        assert reader.read() == before
        assert path.stat().st_ino != os.fstat(reader.fileno()).st_ino
    assert path.read_bytes() == before and not list(tmp_path.glob(".*.tmp"))


def test_load_object_is_deterministic():
    first, again = load_object("valve_b"), load_object("valve_b")
    assert first.params == again.params
    for key, mesh in first.meshes.items():
        np.testing.assert_array_equal(mesh.vertices, again.meshes[key].vertices)


# -------------------------------------------------------------------------------------------- instances
@pytest.mark.parametrize("name", NAMES)
def test_instance_is_valid_watertight_and_hand_sized(name):
    a = asset(name)
    a.validate()
    assert a.operated_joint is not None and len(a.parts) >= 2
    for key, mesh in a.meshes.items():
        assert mesh.is_watertight and mesh.volume > 0, f"{name}: mesh {key}"
    for part in a.parts:
        assert part.visual is not None and len(part.geoms) <= 5
        assert all(g.mass > 0 for g in part.geoms)
    low, high = bounding_box(a)
    extent = (high - low).max()
    assert 0.03 <= extent <= 0.30, f"{name}: {extent:.3f} m"
    # the base frame's z = 0 is the table: the object stands on it, not in it nor above it
    assert abs(low[2]) < 1e-3, f"{name}: lowest point {low[2]:.4f} m"
    # the grasp point is on the tool (within 2 cm of its bounds), where pre-grasps put the hand
    assert np.all(np.asarray(a.grasp) > low - 0.02) and np.all(np.asarray(a.grasp) < high + 0.02)


@pytest.mark.parametrize("name", NAMES)
def test_free_base_rests_on_the_table(name, tmp_path):
    a = asset(name)
    model = compile_scene(a, tmp_path)
    data = mujoco.MjData(model)
    if a.base == "fixed":
        assert model.nq == len(a.joints)  # no free joint
        return
    mujoco.mj_step(model, data, nstep=int(1.0 / model.opt.timestep))
    base = model.body("object").id
    assert np.linalg.norm(data.xpos[base]) < 0.01, f"{name}: the base moved {data.xpos[base]}"
    up = data.xmat[base].reshape(3, 3)[:, 2]
    assert math.acos(min(1.0, up[2])) < 0.02, f"{name}: tilted by {math.acos(min(1.0, up[2])):.3f} rad"
    assert np.isfinite(data.qpos).all()


def _settle(model, data, seconds: float, force: float = 0.0, dof: int = 0) -> None:
    data.qfrc_applied[:] = 0.0
    data.qfrc_applied[dof] = force
    mujoco.mj_step(model, data, nstep=int(seconds / model.opt.timestep))


def check_operable(a, tmp_path) -> None:
    """The base held 5 cm above the table, with gravity: at rest each joint holds its rest; 0.5 N m (5 N on
    a slide) drives it across its range; released, a sprung joint returns toward its rest and an unsprung
    one stays."""
    fixed = dataclasses.replace(a, base="fixed")
    model = compile_scene(fixed, tmp_path, pos=(0.0, 0.0, 0.05))
    for joint in fixed.joints:
        data = mujoco.MjData(model)
        j = model.joint(SCENE_PREFIX + joint.name)
        qpos, dof = j.qposadr[0], j.dofadr[0]
        lo, hi = joint.range
        span, where = hi - lo, f"{a.name}.{joint.name}"
        push = FINGER_FORCE if joint.kind == "slide" else FINGER_TORQUE
        _settle(model, data, 0.5)
        assert data.qpos[qpos] < lo + 0.1 * span, f"{where}: sags to {data.qpos[qpos]:.3f}"
        _settle(model, data, 1.0, push, dof)
        assert data.qpos[qpos] > lo + 0.9 * span, f"{where}: reaches {data.qpos[qpos]:.3f} of {hi}"
        _settle(model, data, 1.5)
        if joint.stiffness > 0:
            assert data.qpos[qpos] < lo + 0.2 * span, f"{where}: returns to {data.qpos[qpos]:.3f}"
        else:
            assert data.qpos[qpos] > lo + 0.7 * span, f"{where}: slips to {data.qpos[qpos]:.3f}"


@pytest.mark.parametrize("name", NAMES)
def test_one_finger_operates_each_joint_and_the_spring_returns_it(name, tmp_path):
    check_operable(asset(name), tmp_path)


@pytest.mark.parametrize("object_class", CLASSES)
def test_sampled_variants_stay_operable(object_class, tmp_path):
    """Variants drawn around the defaults (sizes +-10 %, spring, damping, friction +-30 %) still stand on the
    table and work with one finger: the ranges around the defaults are safe to randomise over."""
    for seed in range(4):
        variant = GENERATORS[object_class](rng=seed, name=f"{object_class}_{seed}")
        check_operable(variant, tmp_path)


@pytest.mark.parametrize("object_class", CLASSES)
def test_part_frames_agree_with_mujoco(object_class, tmp_path):
    name = next(n for n, c in list_objects() if c == object_class)
    a = asset(name)
    model = compile_scene(a, tmp_path, pos=(0.1, -0.05, 0.0))
    data = mujoco.MjData(model)
    q = {}
    for joint in a.joints:
        q[joint.name] = joint.range[0] + 0.7 * (joint.range[1] - joint.range[0])
        data.qpos[model.joint(SCENE_PREFIX + joint.name).qposadr[0]] = q[joint.name]
    if a.base == "free":
        data.qpos[:7] = (0.1, -0.05, 0.0, 1.0, 0.0, 0.0, 0.0)
    mujoco.mj_kinematics(model, data)
    for part, transform in part_transforms(a, q, pos=(0.1, -0.05, 0.0)).items():
        body = model.body("object" if part == a.parts[0].name else f"object/{part}").id
        np.testing.assert_allclose(transform[:3, 3], data.xpos[body], atol=1e-9)
        np.testing.assert_allclose(transform[:3, :3], data.xmat[body].reshape(3, 3), atol=1e-9)


def test_part_transforms_reject_unknown_joints():
    with pytest.raises(KeyError, match="no joints \\['spout'\\].*trigger"):
        part_transforms(asset("spray_bottle_a"), {"spout": 0.1})


# ------------------------------------------------------------------------------------------- generators
@pytest.mark.parametrize("object_class", CLASSES)
def test_generator_same_seed_same_object_and_draws_within_ranges(object_class):
    generate, params = GENERATORS[object_class], PARAMS[object_class]
    first, again, other = generate(rng=3), generate(rng=3), generate(rng=4)
    assert first.params == again.params and first.params != other.params
    for key, mesh in first.meshes.items():
        np.testing.assert_array_equal(mesh.vertices, again.meshes[key].vertices)
    rng = np.random.default_rng(0)
    for _ in range(10):
        drawn = params().sample(rng, scale=0.3)
        drawn.validate()
        for field, (low, high, _, _) in params.ranges().items():
            assert low <= getattr(drawn, field) <= high
    assert generate(params().sample(rng)).object_class == object_class


@pytest.mark.parametrize("object_class", CLASSES)
def test_generator_rejects_a_bad_parameter_naming_it(object_class):
    generate, params = GENERATORS[object_class], PARAMS[object_class]
    field = next(f for f in dataclasses.fields(params) if f.metadata["kind"] != "count")
    high = field.metadata["range"][1]
    bad = dataclasses.replace(params(), **{field.name: high * 2 + 1})
    with pytest.raises(ObjectError, match=rf"{params.__name__}\.{field.name}.*outside its range"):
        generate(bad)
    with pytest.raises(ObjectError, match=rf"{field.name}.*finite"):
        generate(dataclasses.replace(params(), **{field.name: float("nan")}))


@pytest.mark.parametrize("object_class", CLASSES)
def test_generator_rejects_bad_seeds_and_parameters_naming_the_field(object_class):
    """A bad seed, another class's parameters or an unknown parameter name: one ObjectError naming the field."""
    generate, params = GENERATORS[object_class], PARAMS[object_class]
    other = next(cls for name, cls in sorted(PARAMS.items()) if name != object_class)
    for seed in (-1, 1.5, "3", True):
        with pytest.raises(ObjectError, match=rf"^{object_class}: rng: must be a seed"):
            generate(rng=seed)
    with pytest.raises(ObjectError, match=rf"^{object_class}: params must be a {params.__name__}.*{other.__name__}"):
        generate(params=other())
    with pytest.raises(ObjectError, match=rf"^{object_class}: params must be a {params.__name__}.*dict"):
        generate(params={})
    with pytest.raises(ObjectError, match=rf"^{params.__name__}: no parameter 'bogus'; its parameters: \["):
        params(bogus=1)
    with pytest.raises(ObjectError, match=rf"^{params.__name__}: {len(dataclasses.fields(params)) + 1} values"):
        params(*range(len(dataclasses.fields(params)) + 1))
    with pytest.raises(ObjectError, match=rf"^{params.__name__}.sample: rng: must be a seed"):
        params().sample(-1)
    assert generate(rng=np.int64(2)).params == generate(rng=2).params


def test_count_parameters_must_be_integers():
    with pytest.raises(ObjectError, match="ValveParams.spokes.*integer"):
        GENERATORS["valve"](PARAMS["valve"](spokes=3.5))
    assert len(GENERATORS["valve"](PARAMS["valve"](spokes=5)).parts[1].geoms) == 5
