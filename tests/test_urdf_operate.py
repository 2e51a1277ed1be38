"""A URDF object in task ``operate``: its names kept apart from the hand's, the loader's options from the task
config, pre-grasps found on first use, and real files' quirks (tests/partnet_fixtures.py writes the folders)."""

from __future__ import annotations

import json

import pytest
import torch

import partnet_fixtures as fx
from dexmots_rl.envs import make_env
from dexmots_rl.envs.tasks.allegro.operate_object import build_scene


@pytest.fixture(autouse=True)
def own_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("DEXMOTS_CACHE", str(tmp_path / "cache"))


def test_object_names_like_the_hands_do_not_clash(tmp_path):
    """A joint named j3 and a link named palm, as the hand's: the scene compiles, and every name a user sees
    (the tree's joints, the per-joint parameters, the operated joint) is the URDF's."""
    urdf = fx.stapler(tmp_path / "100001")
    text = urdf.read_text().replace('joint name="joint_0"', 'joint name="j3"').replace('"link_0"', '"palm"')
    urdf.write_text(text)
    scene, asset = build_scene(str(urdf))
    assert scene.tree.joint_names == ["j3"] and asset.operated_joint == "j3"
    assert "j3/damping" in scene.tree.param_names
    assert [p.name for p in asset.parts] == ["base", "palm"]


def test_loader_options_from_the_command_line(tmp_path):
    """``task.urdf.size`` / ``task.urdf.base`` / ``task.joint`` reach the loader from the command line: a 14 cm
    fixed-base object, the chosen joint operated; on a library object the options are one clear error."""
    from hydra import compose, initialize_config_dir

    from dexmots_rl.apps.train import CONFIG_DIR

    urdf = fx.keyboard(tmp_path / "600001", keys=7)  # joint_7 welded, joint_5 and _6 beyond four
    overrides = ["task=operate", f"task.object={urdf}", "task.urdf.size=0.14", "task.urdf.base=fixed",
                 "task.joint=joint_6", "task.initial=open"]
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose("config", overrides=overrides)
    env = make_env(cfg.task, num_envs=1, seed=0, raw=True, differentiable=False)
    asset = env.object_asset
    assert asset.params["size"] == pytest.approx(0.14) and asset.base == "fixed" and not env.sim.tree.free
    assert env.joint_name == "joint_6" and "joint_6" in env.sim.tree.joint_names  # kept among the four moved
    with pytest.raises(ValueError, match=r"task.urdf.base must be one of free, fixed, got 'welded'"):
        make_env("operate", num_envs=1, object=str(urdf), urdf={"base": "welded"})
    with pytest.raises(ValueError, match=r"task.urdf.size: the loader's options apply to a .urdf object, and "
                                         r"'jar_a' is a library object"):
        make_env("operate", num_envs=1, object="jar_a", urdf={"size": 0.14})


def test_a_urdf_gets_pregrasps_on_first_use_and_reads_them_back(tmp_path, monkeypatch):
    """No pre-grasp file: the first env searches them (the fallback regions) and keeps them in the object's scene
    folder; the second reads them back without searching; the env starts from them."""
    from dexmots_rl.envs.tasks.allegro import urdf_object
    from dexmots_rl.envs.tasks.allegro.operate_object import scene_dir

    urdf = fx.stapler(tmp_path / "100002")
    env = make_env("operate", num_envs=2, object=str(urdf), seed=0, joint_noise=0.0, raw=True)
    cached = scene_dir(str(urdf)) / urdf_object.PREGRASP_FILE
    poses = torch.as_tensor(json.loads(cached.read_text())["poses"], dtype=env.dtype)
    hand = env.reset()["sim", "joint_q"][:, :env.sim.nu]
    assert (torch.cdist(hand, poses).min(dim=1).values < 1e-5).all()

    def no_search(*args, **kwargs):
        raise AssertionError("searched again")

    monkeypatch.setattr("dexmots_rl.envs.object_pregrasp.find_object_pregrasps", no_search)
    make_env("operate", num_envs=1, object=str(urdf), seed=0, raw=True)
