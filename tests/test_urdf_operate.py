"""A URDF object in task ``operate``: its names kept apart from the hand's, the loader's options from the task
config, pre-grasps found on first use, and real files' quirks (tests/partnet_fixtures.py writes the folders)."""

from __future__ import annotations

import pytest

import partnet_fixtures as fx
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
