"""The Allegro hand's constants (:mod:`dexmots_rl.envs.tasks.allegro.hand`) against its MJCF scenes, and every
Allegro task simulating with the hand's one contact law."""

from __future__ import annotations

import mujoco
import pytest

from dexmots_rl.assets import asset_path
from dexmots_rl.envs import list_tasks
from dexmots_rl.envs.registry import task_contact, task_entry
from dexmots_rl.envs.tasks.allegro import hand

ALLEGRO_TASKS = [t for t in list_tasks() if task_entry(t).env_class.__module__.startswith(hand.__package__)]


@pytest.mark.parametrize("scene", ["allegro_knob.xml", "allegro_cube.xml"])
def test_constants_match_the_mjcf(scene):
    model = mujoco.MjModel.from_xml_path(str(asset_path(scene)))
    hinges = [j for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE]
    names = tuple(mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in hinges[:len(hand.JOINT_NAMES)])
    assert names == hand.JOINT_NAMES
    # each finger's chain starts at the body its MJCF names after it, in the constants' order
    bodies = [model.jnt_bodyid[hinges[f * hand.JOINTS_PER_FINGER]] for f in range(len(hand.FINGERS))]
    assert tuple(mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) for b in bodies) == hand.FINGERS
    lower, upper = model.jnt_range[hinges[:len(hand.JOINT_NAMES)]].T
    assert lower[12] == pytest.approx(hand.THUMB_ROTATION_MIN)
    assert all(lo <= q <= hi for q, lo, hi in zip(hand.OPEN, lower, upper)), "the open pose is outside a joint's range"


@pytest.mark.parametrize("task", ALLEGRO_TASKS)
def test_allegro_tasks_use_the_hand_contact_law(task):
    assert task_contact(task) is hand.CONTACT
