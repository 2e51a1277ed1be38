"""The PartNet-Mobility-style URDF loader, on folders the tests write (see tests/partnet_fixtures.py).

The kinematics are checked against MuJoCo's own compilation of the original URDF: at several joint positions,
every joint's anchor and axis in the world, and every part's drawn extent along 26 directions, must be the
original's scaled by the loader's factor and moved by its offset.
"""

from __future__ import annotations

import logging
import math
import re
from pathlib import Path

import mujoco
import numpy as np
import pytest

import partnet_fixtures as fx
from dexmots_rl.assets.objects import SCENE_PREFIX, ObjectError
from dexmots_rl.assets.objects.urdf import (CONTINUOUS_RANGE, DEFAULT_DENSITY, DEFAULT_SIZE, HINGE_DEFAULTS,
                                            MIN_HALF_EXTENT, UrdfError, load_urdf)

ANCHOR_TOL = 1e-6  # m, after scaling to ~0.2 m
EXTENT_TOL = 1e-5  # m: the drawn hulls keep every piece's extreme points (float32 in MuJoCo's mesh store)
FLAT_EXTENT_TOL = EXTENT_TOL + MIN_HALF_EXTENT * math.sqrt(3)  # flat pieces are drawn thickened on both sides
# URDF spheres and cylinders become polyhedra inscribed in them (about 0.1 % of their radius inside)
ROUND_EXTENT_TOL = EXTENT_TOL + 5e-5


def compile_original(urdf: Path) -> mujoco.MjModel:
    text = urdf.read_text()
    keep = (f'<mujoco><compiler discardvisual="false" fusestatic="false" strippath="false" '
            f'meshdir="{urdf.parent}"/></mujoco>')
    text = re.sub(r"(<robot[^>]*>)", lambda m: m.group(1) + keep, text, count=1)
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(lambda message: None)  # e.g. "equal lower and upper limits" (welded by us)
    try:
        spec = mujoco.MjSpec.from_string(text)
    finally:
        mujoco.set_mju_user_warning(previous)
    for geom in list(spec.geoms):  # only the kinematics and the drawn pieces are compared; MuJoCo cannot
        if geom.contype or geom.conaffinity:  # take a flat piece as a collision mesh
            spec.delete(geom)
    for mesh in spec.meshes:  # open and flat pieces have no volume: weigh their surface instead
        mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL
    spec.compiler.boundmass, spec.compiler.boundinertia = 1e-3, 1e-6  # drawn geoms weigh nothing
    return spec.compile()


@pytest.fixture(autouse=True)
def no_mujoco_log_file(tmp_path, monkeypatch):
    """MuJoCo appends its warnings to MUJOCO_LOG.TXT in the working directory: the loader must not let it."""
    monkeypatch.chdir(tmp_path)
    yield
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


def compile_ours(asset, mesh_dir: Path) -> mujoco.MjModel:
    assets, body = asset.mjcf(mesh_dir)
    return mujoco.MjModel.from_xml_string(
        f'<mujoco><asset>\n{assets}</asset><worldbody>\n'
        f'    <geom name="table" type="plane" size="1 1 0.01"/>\n{body}</worldbody></mujoco>')


def visual_points(model, data, owner) -> dict[str, np.ndarray]:
    """World points of the drawn (group 1) geoms, per part (``owner(body id)``): mesh vertices, and for
    primitives their exact support points along :data:`DIRECTIONS` (box corners)."""
    out: dict[str, list] = {}
    for g in range(model.ngeom):
        if model.geom_group[g] != 1:
            continue
        rotation, size = data.geom_xmat[g].reshape(3, 3), model.geom_size[g]
        kind = model.geom_type[g]
        if kind == mujoco.mjtGeom.mjGEOM_MESH:
            start, count = model.mesh_vertadr[model.geom_dataid[g]], model.mesh_vertnum[model.geom_dataid[g]]
            local = model.mesh_vert[start:start + count]
        elif kind == mujoco.mjtGeom.mjGEOM_BOX:
            local = (np.array(list(np.ndindex(2, 2, 2))) * 2 - 1) * size
        elif kind == mujoco.mjtGeom.mjGEOM_SPHERE:
            local = size[0] * (DIRECTIONS @ rotation)
        else:  # cylinder along local z: rim point towards the direction, end cap on the direction's side
            d = DIRECTIONS @ rotation
            radial = d[:, :2] / np.maximum(np.linalg.norm(d[:, :2], axis=1, keepdims=True), 1e-12)
            local = np.column_stack([size[0] * radial, size[1] * np.sign(d[:, 2])])
        out.setdefault(owner(model.geom_bodyid[g]), []).append(data.geom_xpos[g] + local @ rotation.T)
    return {part: np.concatenate(v) for part, v in out.items()}


def bounding_box(points: np.ndarray) -> np.ndarray:
    return np.array([points.min(axis=0), points.max(axis=0)])


# the 26 directions to the faces, edges and corners of a cube: a part's extent along each (its support)
DIRECTIONS = np.array([d for d in np.ndindex(3, 3, 3) if d != (1, 1, 1)], dtype=float) - 1.0
DIRECTIONS /= np.linalg.norm(DIRECTIONS, axis=1, keepdims=True)


def check_against_original(urdf: Path, asset, tmp_path: Path, positions=(0.0, 0.35, 1.0), welded=None,
                           extent_tol=EXTENT_TOL) -> None:
    """``welded``: the original's positions of the joints the loader welded."""
    original, ours = compile_original(urdf), compile_ours(asset, tmp_path / "meshes")
    d_orig, d_ours = mujoco.MjData(original), mujoco.MjData(ours)
    for name, q in (welded or {}).items():
        d_orig.qpos[original.joint(name).qposadr[0]] = q
    factor = asset.params["scale"]
    origin = np.array([asset.params[f"urdf_origin_{a}"] for a in "xyz"])
    part_names = [p.name for p in asset.parts]

    def original_owner(body: int) -> str:
        while original.body(body).name not in part_names[1:] and original.body_parentid[body] != 0:
            body = original.body_parentid[body]
        name = original.body(body).name
        return name if name in part_names[1:] else part_names[0]

    def our_owner(body: int) -> str:
        name = ours.body(body).name
        return part_names[0] if name == "object" else name.split("/", 1)[1]

    for fraction in positions:
        for joint in asset.joints:
            low, high = joint.range
            q = low + fraction * (high - low)
            original_q = q / factor if joint.kind == "slide" else q
            d_orig.qpos[original.joint(joint.name).qposadr[0]] = original_q
            d_ours.qpos[ours.joint(SCENE_PREFIX + joint.name).qposadr[0]] = q
        if asset.base == "free":
            d_ours.qpos[3] = 1.0
        mujoco.mj_kinematics(original, d_orig)
        mujoco.mj_kinematics(ours, d_ours)
        for joint in asset.joints:
            a, b = original.joint(joint.name).id, ours.joint(SCENE_PREFIX + joint.name).id
            np.testing.assert_allclose(d_ours.xanchor[b], origin + factor * d_orig.xanchor[a], atol=ANCHOR_TOL)
            np.testing.assert_allclose(d_ours.xaxis[b], d_orig.xaxis[a], atol=1e-9)
        expected, got = visual_points(original, d_orig, original_owner), visual_points(ours, d_ours, our_owner)
        assert sorted(got) == sorted(expected) and set(got) <= set(part_names)
        for part, points in got.items():
            support = (points @ DIRECTIONS.T).max(axis=0)
            expected_support = ((origin + factor * expected[part]) @ DIRECTIONS.T).max(axis=0)
            np.testing.assert_allclose(support, expected_support, atol=extent_tol, err_msg=part)
            assert_inside_boxes(ours, d_ours, origin + factor * expected[part], part, asset.parts[0].name,
                                max(extent_tol - EXTENT_TOL, 1e-6))


def assert_inside_boxes(model, data, points: np.ndarray, part: str, base: str, tol: float) -> None:
    """Every point of the part's pieces lies in one of its collision boxes (flat pieces are thickened)."""
    body = model.body("object" if part == base else f"object/{part}").id
    inside = np.zeros(len(points), dtype=bool)
    for g in np.flatnonzero((model.geom_bodyid == body) & (model.geom_type == mujoco.mjtGeom.mjGEOM_BOX)):
        local = (points - data.geom_xpos[g]) @ data.geom_xmat[g].reshape(3, 3)
        inside |= np.all(np.abs(local) <= model.geom_size[g] + tol, axis=1)
    assert inside.all(), f"{part}: {np.count_nonzero(~inside)} of {len(points)} mesh points outside its boxes"


def check_asset(asset, max_geoms: int = 4) -> None:
    asset.validate()
    for part in asset.parts:
        assert 1 <= len(part.geoms) <= max_geoms
        assert all(g.kind in ("box", "sphere") and g.mass > 0 for g in part.geoms)
        assert part.visual is None or asset.meshes[part.visual].is_watertight


def test_stapler_lid_on_a_hinge(tmp_path):
    urdf = fx.stapler(tmp_path / "100001")
    asset = load_urdf(urdf)
    check_asset(asset)
    assert asset.name == "100001" and asset.object_class == "stapler" and asset.base == "free"
    assert [p.name for p in asset.parts] == ["base", "link_0"]
    lid = asset.joint("joint_0")
    assert lid.kind == "hinge" and lid.range == (0.0, 0.45) and asset.operated_joint == "joint_0"
    assert (lid.damping, lid.stiffness) == (HINGE_DEFAULTS["damping"], 0)
    assert lid.friction > HINGE_DEFAULTS["friction"]  # raised to hold the unsprung lid up (test_urdf_rest.py)
    assert "lid" in asset.description
    check_against_original(urdf, asset, tmp_path, extent_tol=FLAT_EXTENT_TOL)  # the stapler has a flat piece
    # the object stands on the table (z = 0), centred, at the default size
    model = compile_ours(asset, tmp_path / "m2")
    data = mujoco.MjData(model)
    data.qpos[3] = 1.0
    mujoco.mj_kinematics(model, data)
    box = bounding_box(visual_points(model, data, lambda body: "all")["all"])
    assert box[0, 2] == pytest.approx(0.0, abs=1e-6)
    np.testing.assert_allclose((box[0, :2] + box[1, :2]) / 2, 0.0, atol=1e-6)
    assert np.max(box[1] - box[0]) == pytest.approx(DEFAULT_SIZE, rel=1e-5)
    masses = model.body_subtreemass[model.body("object").id]
    assert masses == pytest.approx(sum(g.mass for p in asset.parts for g in p.geoms))


def test_free_base_rests_on_the_table(tmp_path):
    asset = load_urdf(fx.stapler(tmp_path / "100003"), size=0.15)
    model = compile_ours(asset, tmp_path / "m")
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    start = data.xpos[model.body("object").id].copy()
    while data.time < 1.0:
        mujoco.mj_step(model, data)
    moved = data.xpos[model.body("object").id] - start
    assert np.all(np.isfinite(data.qpos)) and np.linalg.norm(moved) < 2e-3, moved
    assert data.qpos[7] == pytest.approx(0.0, abs=0.05)  # the arm rests on the base, not fallen through


@pytest.mark.parametrize("size", [0.12, 0.2])
def test_unit_normalised_object_scaled_to_the_target_size(tmp_path, size):
    urdf = fx.stapler(tmp_path / "100002")
    asset = load_urdf(urdf, size=size, base="fixed")
    model = compile_ours(asset, tmp_path / "m")
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    box = bounding_box(visual_points(model, data, lambda body: "all")["all"])
    assert np.max(box[1] - box[0]) == pytest.approx(size, rel=1e-5)
    assert asset.params["size"] == pytest.approx(size)
    by_factor = load_urdf(urdf, scale=0.1)
    assert by_factor.params["scale"] == 0.1
    assert by_factor.params["size"] == pytest.approx(0.1 * size / asset.params["scale"])


def test_prismatic_drawer(tmp_path):
    urdf = fx.drawer(tmp_path / "200001")
    asset = load_urdf(urdf, size=0.2, base="fixed", max_geoms_per_part=2)
    check_asset(asset, max_geoms=2)
    slide = asset.joint("joint_0")
    assert slide.kind == "slide"
    assert slide.range == pytest.approx((0.0, 0.5 * asset.params["scale"]))
    assert (slide.damping, slide.friction) == (2.5, 0.1)  # <dynamics> read
    check_against_original(urdf, asset, tmp_path)


def test_two_revolute_parts_like_scissors(tmp_path):
    urdf = fx.scissors(tmp_path / "300001")
    asset = load_urdf(urdf, base="fixed")
    check_asset(asset)
    assert [(p.name, p.parent) for p in asset.parts] == [("base", None), ("link_1", "base"), ("link_0", "link_1")]
    assert asset.parts[0].geoms[0].kind == "sphere"  # the empty base link is the pivot pin
    check_against_original(urdf, asset, tmp_path, positions=(0.0, 0.2, 0.9))


def test_fixed_chain_merges_into_its_parent(tmp_path):
    urdf = fx.lever_on_fixed_chain(tmp_path / "400001")
    asset = load_urdf(urdf)
    check_asset(asset)
    assert [(p.name, p.parent) for p in asset.parts] == [("base", None), ("link_0", "base")]
    check_against_original(urdf, asset, tmp_path)  # the merged cap and knob are drawn where the URDF puts them


def test_continuous_joint_gets_one_turn(tmp_path):
    urdf = fx.knob(tmp_path / "500001")
    asset = load_urdf(urdf, base="fixed")
    check_asset(asset)
    assert asset.joint("joint_0").range == CONTINUOUS_RANGE
    check_against_original(urdf, asset, tmp_path, positions=(0.1, 0.6, 0.9), extent_tol=ROUND_EXTENT_TOL)


def test_hull_collision(tmp_path):
    urdf = fx.knob(tmp_path / "500002")
    asset = load_urdf(urdf, collision="hull")
    for part in asset.parts:
        (geom,) = part.geoms
        hull = asset.meshes[geom.mesh]
        assert geom.kind == "mesh" and hull.is_watertight and hull.is_convex
        assert geom.mass == pytest.approx(DEFAULT_DENSITY * hull.volume)
    model = compile_ours(asset, tmp_path / "m")
    assert model.body_subtreemass[model.body("object").id] == pytest.approx(sum(
        g.mass for p in asset.parts for g in p.geoms), rel=1e-6)


def test_more_than_four_moving_parts_keeps_four(tmp_path, caplog):
    urdf = fx.keyboard(tmp_path / "600001", keys=7)
    with caplog.at_level(logging.WARNING):
        asset = load_urdf(urdf, base="fixed")
    assert [j.name for j in asset.joints] == ["joint_1", "joint_2", "joint_3", "joint_4"]
    assert "6 moving joints" in caplog.text and "['joint_5', 'joint_6'] welded" in caplog.text
    assert "joint 'joint_7' has lower == upper (0.05): welded" in caplog.text
    check_against_original(urdf, asset, tmp_path, positions=(0.0, 1.0), welded={"joint_7": 0.05})
    chosen = load_urdf(urdf, base="fixed", operated_joint="joint_6")
    assert chosen.operated_joint == "joint_6" and "joint_6" in [j.name for j in chosen.joints]


def _mutate(text: str, old: str, new: str) -> str:
    assert old in text
    return text.replace(old, new, 1)


BAD_FILES = {
    "limit lower > upper": (lambda t: _mutate(t, 'lower="0" upper="0.45"', 'lower="2.0" upper="1.0"'),
                            "joint 'joint_0': <limit> lower 2 > upper 1"),
    "unknown joint type": (lambda t: _mutate(t, 'type="revolute"', 'type="planar"'),
                           "joint 'joint_0': joint type 'planar' is not supported"),
    "link cycle": (lambda t: _mutate(t, '<parent link="base"/>', '<parent link="link_0"/>'),
                   "form a cycle"),
    "not XML": (lambda t: t[: len(t) // 2], "not well-formed XML"),
    "missing limit": (lambda t: _mutate(t, '<limit lower="0" upper="0.45"/>', ""),
                      "joint 'joint_0': a revolute joint needs <limit"),
    "unknown link": (lambda t: _mutate(t, '<child link="link_0"/>', '<child link="link_9"/>'),
                     "joint 'joint_0': <child link='link_9'> names no <link>"),
    "bad origin": (lambda t: _mutate(t, 'rpy="0 0 0"', 'rpy="0 zero 0"'), "joint 'joint_0' <origin rpy>"),
    "missing mesh": (lambda t: _mutate(t, "original-3.obj", "original-99.obj"),
                     "link 'link_0' <visual> <mesh filename='textured_objs/original-99.obj'>: no such file"),
    # magnitudes no object has: each would go non-finite in float32 or make a part spin
    "huge origin": (lambda t: _mutate(t, 'xyz="-0.45 0.2 0"', 'xyz="1e30 0.2 0"'),
                    "joint 'joint_0' <origin xyz>: '1e30 0.2 0' is out of range (each at most 1000"),
    "huge hinge limits": (lambda t: _mutate(t, 'lower="0" upper="0.45"', 'lower="-1e6" upper="1e6"'),
                          "joint 'joint_0' <limit lower>: '-1e6' is out of range (each at most 12.5"),
    "huge damping": (lambda t: _mutate(t, '<limit lower="0" upper="0.45"/>',
                                       '<limit lower="0" upper="0.45"/><dynamics damping="1e30"/>'),
                     "joint 'joint_0' <dynamics damping>: '1e30' is out of range (each at most 10 in"),
    "huge mesh scale": (lambda t: _mutate(t, 'original-3.obj"', 'original-3.obj" scale="1e6 1 1"'),
                        "link 'link_0' <visual> <mesh scale>: '1e6 1 1' is out of range"),
    "all fixed": (lambda t: _mutate(t, 'type="revolute"', 'type="fixed"'),
                  "no moving joint (every joint is fixed, or a revolute/prismatic one with lower == upper): "
                  "there is nothing to operate; joints: ['joint_1', 'joint_0']"),
    "only welded": (lambda t: _mutate(t, 'lower="0" upper="0.45"', 'lower="0.2" upper="0.2"'), "no moving joint"),
}


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_bad_file_names_the_file_and_the_element(tmp_path, case):
    urdf = fx.stapler(tmp_path / "700001")
    mutate, message = BAD_FILES[case]
    urdf.write_text(mutate(urdf.read_text()))
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    with pytest.raises(UrdfError) as error:
        load_urdf(urdf)
    assert str(urdf) in str(error.value) and message in str(error.value), str(error.value)
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before  # nothing written


@pytest.mark.parametrize("vertices, message", [
    ([[0, 0, 0], [0.1, 0, 0], [0.2, 0, 0]], "degenerate (its triangles have no area)"),
    ([[0, 0, 0], [0.1, 0, 0], [0, float("nan"), 0]], "has no triangles"),  # trimesh drops the bad face
    ([[0, 0, 0], [0.1, 0, 0], [0, 1e30, 0]], "vertices must be finite and within 1000"),
])
def test_bad_mesh_names_the_file_and_the_element(tmp_path, vertices, message):
    urdf = fx.stapler(tmp_path / "700002")
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in vertices]
    (urdf.parent / "textured_objs" / "original-3.obj").write_text("\n".join(lines + ["f 1 2 3", ""]))
    with pytest.raises(UrdfError) as error:
        load_urdf(urdf)
    assert f"{urdf}: link 'link_0' <visual> mesh 'textured_objs/original-3.obj': {message}" in str(error.value), \
        str(error.value)


def test_sizes_and_slides_out_of_range(tmp_path):
    urdf = fx.stapler(tmp_path / "700003")
    with pytest.raises(UrdfError, match=r"scale 1000000.0 makes the object 1e\+06 m long; its longest side "
                                        r"must be within \(0.01, 1.0\) m"):
        load_urdf(urdf, scale=1e6)
    with pytest.raises(ObjectError, match=r"^load_urdf: size must be within \(0.01, 1.0\) m .*got 1000"):
        load_urdf(urdf, size=1000)
    with pytest.raises(ObjectError, match=r"^load_urdf: density must be within"):
        load_urdf(urdf, density=1e30)
    drawer = fx.drawer(tmp_path / "700004")
    drawer.write_text(_mutate(drawer.read_text(), 'lower="0" upper="0.5"', 'lower="0" upper="50"'))
    with pytest.raises(UrdfError, match=r"joint 'joint_0' <limit>: \(0, 50\) slides farther than 2 times"):
        load_urdf(drawer)


def test_bad_arguments(tmp_path):
    urdf = fx.stapler(tmp_path / "800001")
    with pytest.raises(ObjectError, match="scale or size"):
        load_urdf(urdf, scale=0.1, size=0.2)
    with pytest.raises(ObjectError, match="collision must be"):
        load_urdf(urdf, collision="sdf")
    with pytest.raises(ObjectError, match="density"):
        load_urdf(urdf, density=-1.0)
    with pytest.raises(UrdfError, match="operated_joint 'joint_9'"):
        load_urdf(urdf, operated_joint="joint_9")
    with pytest.raises(UrdfError, match="cannot be read"):
        load_urdf(tmp_path / "missing" / "mobility.urdf")
    assert math.isfinite(load_urdf(urdf, density=100.0).parts[0].geoms[0].mass)
