"""The operable objects (spray bottle, scissors, stapler): generated assets, the part's range stop, the
pre-grasps, and the tasks' own checks. The registry-wide checks (specs, seeding, FD gradients through
contact from the pre-grasp, defaults) are in test_tasks.py.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch

from dexmots_rl.assets import asset_path
from dexmots_rl.assets.operable import OBJECTS, scene_file, scene_xml
from dexmots_rl.envs import make_env, task_entry
from dexmots_rl.envs.tasks.allegro.operate import HAND_CONTACT
from dexmots_rl.envs.pregrasp import PregraspError, check_pregrasp, find_pregrasps, load_pregrasps, pregrasp_path
from dexmots_rl.sim import Control, Simulator, load_scene

OPERABLE = sorted(OBJECTS)


@pytest.mark.parametrize("name", OPERABLE)
def test_shipped_scene_is_the_generator_output(name):
    text = scene_xml(OBJECTS[name])
    assert text == scene_xml(OBJECTS[name])  # deterministic
    assert asset_path(scene_file(name)).read_text() == text, "rerun: python -m dexmots_rl.assets.operable"
    scene = load_scene(asset_path(scene_file(name)))
    assert scene.num_base_boxes == len(OBJECTS[name].base) and scene.object_limited
    assert scene.object_range == OBJECTS[name].joint_range


def test_bad_object_fails_naming_the_field():
    with pytest.raises(ValueError, match="joint_range"):
        dataclasses.replace(OBJECTS["stapler"], joint_range=(0.5, 0.1))
    with pytest.raises(ValueError, match="unknown operable object 'kettle'"):
        scene_file("kettle")


@pytest.mark.parametrize("name", OPERABLE)
def test_every_pregrasp_touches_the_object_without_penetrating(name):
    env_class = task_entry(name).env_class
    poses = load_pregrasps(pregrasp_path(name), 16)
    assert len(poses) >= 2
    for q in poses:
        ok, details = check_pregrasp(env_class.asset_path(), q, env_class.contact_regions)
        assert ok, details
        assert max(details["tip_distance"].values()) <= 0.005 and details["deepest_penetration"] >= -0.003


def test_pregrasp_search_is_deterministic_and_matches_the_shipped_file():
    env_class = task_entry("stapler").env_class
    shipped = json.loads(pregrasp_path("stapler").read_text())
    found = find_pregrasps(env_class.asset_path(), env_class.contact_regions, env_class.pregrasp_hint,
                           candidates=16, keep=len(shipped["poses"]), seed=shipped["seed"],
                           contact=env_class.contact_params)
    np.testing.assert_allclose(found, np.asarray(shipped["poses"]), atol=2e-6)


def test_episodes_start_from_the_pregrasps():
    env = make_env("stapler", num_envs=64, seed=0, joint_noise=0.0)
    starts = env.reset()["sim", "joint_q"][:, :16].double()
    poses = torch.as_tensor(load_pregrasps(pregrasp_path("stapler"), 16))
    nearest = torch.cdist(starts, poses).min(-1)
    assert nearest.values.max() < 1e-5  # every start is one of the pre-grasps (float32 rounding)
    assert len(set(nearest.indices.tolist())) == len(poses)  # and all of them are drawn


def test_bad_pregrasp_file_fails_naming_the_field(tmp_path):
    path = tmp_path / "p.json"
    path.write_text(json.dumps({"format": "dexmots-pregrasps-v1", "poses": [[0.0] * 3]}))
    with pytest.raises(PregraspError, match=r"poses\[0\] must be a list of 16"):
        load_pregrasps(path, 16)
    path.write_text("{")
    with pytest.raises(PregraspError, match="not a pre-grasp file"):
        load_pregrasps(path, 16)
    with pytest.raises(PregraspError, match="no pre-grasp file"):
        load_pregrasps(tmp_path / "missing.json", 16)


@pytest.mark.parametrize("field, value", [("goal_fraction", (0.5, 1.2)), ("stiffness_range", (-1.0, 0.1)),
                                          ("initial", "grasp")])
def test_bad_task_parameters_fail_naming_the_field(field, value):
    with pytest.raises(ValueError, match=f"task.{field}"):
        make_env("spray_bottle", num_envs=1, **{field: value})


def test_goal_is_ninety_percent_of_the_range():
    for name in OPERABLE:
        lo, hi = OBJECTS[name].joint_range
        goal = make_env(name, num_envs=2, seed=0).reset()["task", "goal"]
        assert torch.allclose(goal, torch.full_like(goal, lo + 0.9 * (hi - lo)))


def _stapler_sim(n=2):
    scene = load_scene(asset_path("allegro_stapler.xml"))
    sim = Simulator(scene, num_worlds=n, dtype=torch.float64, contact=HAND_CONTACT)  # the task's contact law
    q, qd = sim.initial_state()
    q[:, :16] = torch.as_tensor((0.0,) * 12 + (0.263, 0.0, 0.0, 0.0))  # straight fingers, far above the arm
    zeros = torch.zeros(n, 16, dtype=torch.float64)
    control = Control(zeros, q[:, :16].clone(), torch.full_like(zeros, 1.0), torch.full_like(zeros, 0.05))
    return sim, q, qd, control


def test_sprung_part_released_returns_to_rest():
    sim, q, qd, control = _stapler_sim()
    q[:, 16] = torch.tensor([0.25, 0.45], dtype=torch.float64)
    params = sim.default_params()
    for _ in range(120):
        out = sim.step(q, qd, control, params)
        q, qd = out.joint_q, out.joint_qd
    assert torch.all(q[:, 16].abs() < 0.01), q[:, 16]


def test_range_stop_holds_the_part_and_its_gradient_matches_finite_differences():
    sim, q, qd, control = _stapler_sim()
    params = sim.default_params()
    push = torch.zeros(2, 6, dtype=torch.float64)
    push[:, 4] = torch.tensor([0.5, 1.0])  # about world +y = the hinge axis: 2-4x the spring's torque at the stop
    q[:, 16] = 0.49
    for _ in range(30):
        out = sim.step(q, qd, Control(control.tau, control.q_target, control.kp, control.kd, push), params)
        q, qd = out.joint_q, out.joint_qd
    upper = sim.scene.object_range[1]
    assert torch.all(q[:, 16] > upper - 0.005) and torch.all(q[:, 16] < upper + 0.015), q[:, 16]

    def final_angle(q_obj0):
        qq, vv = q.detach().clone(), qd.detach().clone()
        qq = torch.cat([qq[:, :16], q_obj0[:, None]], -1)
        vv = torch.zeros_like(vv)
        for _ in range(3):
            out = sim.step(qq, vv, Control(control.tau, control.q_target, control.kp, control.kd, push), params)
            qq, vv = out.joint_q, out.joint_qd
        return qq[:, 16].sum()

    x = torch.tensor([0.505, 0.51], dtype=torch.float64, requires_grad=True)  # inside the stop's ramp
    (grad,) = torch.autograd.grad(final_angle(x), x)
    eps = 1e-6
    fd = torch.stack([(final_angle(x.detach() + eps * e) - final_angle(x.detach() - eps * e)) / (2 * eps)
                      for e in torch.eye(2, dtype=torch.float64)])
    assert torch.allclose(grad, fd, rtol=1e-5, atol=1e-8), (grad, fd)


@pytest.mark.parametrize("name", OPERABLE)
def test_explicit_joint_friction_is_stable_over_the_randomised_range(name):
    """The part's Coulomb friction f tanh(v / 0.05) is explicit: per substep it must not flip the velocity
    (dt f / (0.05 I) < 1), or a light part chatters about rest (the spray trigger did, without armature)."""
    env = make_env(name, num_envs=1, seed=0)
    sim = env.base_env.sim
    f_max = env.base_env.config.friction_range[1]
    assert sim.dt / sim.substeps * f_max / (0.05 * float(sim.model.obj_axial_inertia)) < 1.0
