"""The pre-grasps of task ``operate``: every library object's shipped file holds grasps with no penetration, the
named fingertips on their parts and the object left at rest; the env starts from them; a URDF gets them from
the fallback regions through ``dexmots-pregrasp``; bad regions and bad command lines are one clear error."""

from __future__ import annotations

import dataclasses
import json

import mujoco
import pytest
import torch

from dexmots_rl.apps import pregrasp as pregrasp_app
from dexmots_rl.assets.hand_scene import hand_object_scene_xml
from dexmots_rl.assets.objects import GraspRegion, ObjectError, list_objects, load_object
from dexmots_rl.assets.objects.generators import GENERATORS
from dexmots_rl.envs import make_env
from dexmots_rl.envs.object_pregrasp import check_object_pregrasp, find_object_pregrasps, object_regions, \
    operate_pregrasp_path, release_drift
from dexmots_rl.envs.pregrasp import PregraspError, load_pregrasps
from dexmots_rl.envs.tasks.allegro.operate_object import OperateObjectEnv, build_scene
from dexmots_rl.sim import ArticulatedSimulator, load_scene

from partnet_fixtures import stapler

NAMES = [name for name, _ in list_objects()]


@pytest.mark.parametrize("name", NAMES)
def test_shipped_pregrasps_hold_the_object_without_moving_it(name):
    """Each shipped pose: MuJoCo finds every named fingertip within 5 mm of its part and no hand geom more than
    3 mm inside the object; released under the hand holding the pose for 20 steps (0.33 s), a free base moves
    less than 1 mm and the operated joint stays within 5 % of its range of rest."""
    scene, asset = build_scene(name)
    lower, upper = scene.dof_lower[:scene.num_hand_dofs], scene.dof_upper[:scene.num_hand_dofs]
    poses = load_pregrasps(operate_pregrasp_path(name), scene.num_hand_dofs, "operate", lower, upper,
                           object_name=name)
    assert len(poses) >= 2
    model = mujoco.MjModel.from_xml_path(str(scene.path))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    regions = object_regions(asset, model, data)
    assert asset.grasp_regions and regions == asset.grasp_regions  # every class describes its own
    for pose in poses:
        ok, details = check_object_pregrasp(model, data, scene, asset, pose, regions)
        assert ok, details
        assert all(d <= 0.005 for d in details["tip_distance"].values())
    sim = ArticulatedSimulator(scene, num_worlds=len(poses), contact=OperateObjectEnv.contact_params)
    joint = sim.tree.joint_names.index(asset.operated_joint)
    lo, hi = sim.tree.joint_range[joint]
    shift, moved = release_drift(sim, poses, 20, joint)
    assert (shift < 0.001).all(), shift
    assert (moved < 0.05 * (hi - lo)).all(), moved


@pytest.mark.parametrize("name", NAMES)
def test_operate_resets_into_the_pregrasps_and_holding_them_keeps_the_object_still(name):
    """Without joint noise every world starts at one of the shipped poses with the object at rest; the
    position action that holds that pose keeps a free base within 1 mm and the operated joint near rest."""
    env = make_env("operate", num_envs=3, object=name, seed=1, joint_noise=0.0, action="position", raw=True)
    poses = torch.as_tensor(json.loads(operate_pregrasp_path(name).read_text())["poses"], dtype=env.dtype)
    td = env.reset()
    hand = td["sim", "joint_q"][:, :env.sim.nu]
    assert (torch.cdist(hand, poses).min(dim=1).values < 1e-5).all()
    hold = env.actions.actions_for_targets(hand)
    base0 = td["object", "base_pose"].clone()
    q0 = td["object", "q"][:, env.joint_index].clone()
    for _ in range(10):
        td["action"] = hold
        td = env.step(td)["next"]
    assert ((td["object", "base_pose"][:, :3] - base0[:, :3]).norm(dim=-1) < 0.001).all()
    lo, hi = env.sim.tree.joint_range[env.joint_index]
    assert ((td["object", "q"][:, env.joint_index] - q0).abs() < 0.05 * (hi - lo)).all()


def test_a_urdf_gets_pregrasps_from_the_fallback_regions(tmp_path):
    """A URDF has no regions: ``dexmots-pregrasp --task operate --object <urdf>`` puts index and middle on the
    operated part's front face and the thumb on its back; the task starts from that file. Without a file the
    task searches them on first use (tests/test_urdf_operate.py)."""
    path = stapler(tmp_path)
    out = pregrasp_app.generate_operate(str(path), candidates=8, keep=2, out=tmp_path / "mine.json")
    data = json.loads(out.read_text())
    assert data["task"] == "operate" and data["object"] == load_object(path).name and len(data["poses"]) >= 1
    env = make_env("operate", num_envs=2, object=str(path), pregrasps=str(out), seed=0, joint_noise=0.0, raw=True)
    hand = env.reset()["sim", "joint_q"][:, :env.sim.nu].double()
    assert (torch.cdist(hand, torch.as_tensor(data["poses"], dtype=hand.dtype)).min(dim=1).values < 1e-5).all()
    other = operate_pregrasp_path("jar_a")
    with pytest.raises(PregraspError, match="field 'object' is 'jar_a'"):
        make_env("operate", num_envs=1, object="jar_b", pregrasps=str(other))


@pytest.mark.parametrize("change, message", [
    (dict(finger="pinky"), r"grasp_regions\[0\].finger: must be one of"),
    (dict(part="lid"), r"grasp_regions\[0\].part: 'lid' is not a part"),
    (dict(normal=(0.0, 0.0, 0.0)), r"grasp_regions\[0\]: the normal must be non-zero"),
    (dict(squeeze=0.05), r"grasp_regions\[0\].squeeze"),
])
def test_a_bad_grasp_region_names_its_field(change, message):
    asset = load_object("spray_bottle_a")
    bad = (dataclasses.replace(asset.grasp_regions[0], **change), *asset.grasp_regions[1:])
    with pytest.raises(ObjectError, match=message):
        dataclasses.replace(asset, grasp_regions=bad)
    region = GraspRegion("index", "bottle", (0.0, 0.0, 0.0), (1.0, 0.0, 0.0))
    with pytest.raises(ObjectError, match=r"grasp_regions\[1\].finger: .* each at most once"):
        dataclasses.replace(asset, grasp_regions=(region, region))


@pytest.mark.parametrize("argv, message", [
    (["--task", "operate"], "--task operate needs --object"),
    (["--task", "operate", "--object", "jar_a", "--all"], "--task operate needs --object"),
    (["--task", "allegro_rotate"], "--task 'allegro_rotate' has no pre-grasps to search; tasks with pre-grasps: "),
])
def test_dexmots_pregrasp_operate_arguments(argv, message):
    with pytest.raises(SystemExit, match=message):
        pregrasp_app.main(argv)


@pytest.mark.parametrize("object_class", sorted(GENERATORS))
def test_a_drawn_variant_of_every_class_gets_pregrasps(object_class, tmp_path):
    """The regions come from each generator's own sizes: a variant drawn around the class's defaults (sizes
    +-10 %, feel +-30 %) gets verified pre-grasps too."""
    asset = GENERATORS[object_class](rng=11, name=f"{object_class}_variant")
    path = tmp_path / "scene.xml"
    path.write_text(hand_object_scene_xml(asset, tmp_path))
    scene = load_scene(path)
    model = mujoco.MjModel.from_xml_path(str(path))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    poses = find_object_pregrasps(scene, asset, object_regions(asset, model, data), candidates=4, keep=1,
                                  contact=OperateObjectEnv.contact_params)
    assert poses.shape == (1, scene.num_hand_dofs)


def test_dexmots_pregrasp_on_a_tool_task_searches_its_object(tmp_path, capsys):
    """``--task jar`` (a task built on operate) searches jar_a's pre-grasps; the jar task starts from the file."""
    pregrasp_app.main(["--task", "jar", "--candidates", "4", "--keep", "1", "--out", str(tmp_path)])
    out = tmp_path / "jar_a.json"
    assert capsys.readouterr().out.strip() == str(out)
    assert json.loads(out.read_text())["object"] == "jar_a"
    env = make_env("jar", num_envs=1, seed=0, joint_noise=0.0, pregrasps=str(out), raw=True)
    hand = env.reset()["sim", "joint_q"][0, :env.sim.nu]
    expected = torch.as_tensor(json.loads(out.read_text())["poses"][0], dtype=hand.dtype)
    assert torch.allclose(hand, expected, atol=1e-5)
