"""Bad input fails loudly with one exception naming the offending field; a blown-up world is contained."""

from __future__ import annotations

import pytest
import torch

from dexmots_rl.envs import make_env
from dexmots_rl.sim import AssetError, load_scene

N = 3


@pytest.fixture(scope="module")
def env():
    return make_env("screw_claw", num_envs=N, differentiable=False, seed=0, action="torque", goal="pose", initial="open")


@pytest.fixture(scope="module")
def raw_env():
    return make_env("screw_claw", num_envs=N, differentiable=False, seed=0, raw=True, action="torque", goal="pose", initial="open")


def test_unknown_task_lists_known_tasks():
    with pytest.raises(ValueError, match="screw_claw") as info:
        make_env("screw_clawz", num_envs=1)
    assert "screw_clawz" in str(info.value)


@pytest.mark.parametrize("num_envs", [0, -1])
def test_nonpositive_num_envs(num_envs):
    with pytest.raises(ValueError, match="num_envs"):
        make_env("screw_claw", num_envs=num_envs, action="torque", goal="pose", initial="open")


def test_unknown_action_type():
    with pytest.raises(ValueError, match="action") as info:
        make_env("screw_claw", num_envs=1, action="velocity", goal="pose", initial="open")
    assert "velocity" in str(info.value) and "torque" in str(info.value)


def _bad_actions():
    good = torch.zeros(N, 4)
    nan, inf = good.clone(), good.clone()
    nan[1, 2] = float("nan")
    inf[2, 0] = float("inf")
    return {
        "shape_dim": torch.zeros(N, 3),
        "shape_batch": torch.zeros(N, 1, 4),
        "int_dtype": torch.zeros(N, 4, dtype=torch.int64),
        "nan": nan,
        "inf": inf,
        "neg_inf": -inf,
    }


@pytest.mark.parametrize("kind", list(_bad_actions()))
@pytest.mark.parametrize("which", ["transformed", "raw"])
def test_bad_action_raises_value_error(env, raw_env, kind, which):
    e = env if which == "transformed" else raw_env
    td = e.reset()
    td.set("action", _bad_actions()[kind])
    with pytest.raises(ValueError, match="action"):
        e.step(td)


def test_valid_action_is_accepted(raw_env):
    """The counterpart of the bad-action tests: the same path with a good action works."""
    td = raw_env.reset()
    td.set("action", torch.zeros(N, 4))
    out = raw_env.step(td)["next"]
    assert out["reward"].shape == (N, 1)


def test_asset_that_does_not_parse(tmp_path):
    path = tmp_path / "broken.xml"
    path.write_text("<mujoco><worldbody><body name='hand'><geom type='sphere' size='0.1'</body></mujoco>")
    with pytest.raises(AssetError, match="broken.xml") as info:
        load_scene(path)
    assert str(path) in str(info.value)


def test_missing_asset(tmp_path):
    path = tmp_path / "nowhere" / "missing.xml"
    with pytest.raises(AssetError, match="missing.xml") as info:
        load_scene(path)
    assert str(path) in str(info.value)


def test_asset_without_conventions(tmp_path):
    """Valid MJCF that lacks the 'hand'/'object' bodies is rejected with the path and the missing names."""
    path = tmp_path / "nohand.xml"
    path.write_text("<mujoco><worldbody><body name='thing'><joint/><geom type='sphere' size='0.1'/>"
                    "</body></worldbody></mujoco>")
    with pytest.raises(AssetError, match="hand") as info:
        load_scene(path)
    assert str(path) in str(info.value)


# ----------------------------------------------------------------------------------------- blow-ups
@pytest.mark.parametrize("index,value", [(0, 1e9), (2, float("nan")), (4, float("inf"))],
                         ids=["huge_hand_speed", "nan_hand_speed", "inf_knob_speed"])
def test_blown_up_world_is_reset_and_counted(raw_env, index, value):
    td = raw_env.reset()
    td.set("action", torch.zeros(N, 4))
    clean = raw_env.step(td.clone())["next"]
    bad = td.clone()
    bad["sim", "joint_qd"][1, index] = value
    out = raw_env.step(bad)["next"]

    assert out["terminated"].squeeze(-1).tolist() == [False, True, False]
    assert out["done"].squeeze(-1).tolist() == [False, True, False]
    assert out["info", "sim_failures"].squeeze(-1).tolist() == [0, 1, 0]
    assert int(out["task", "step"][1]) == 0  # the blown world restarts its episode
    for key, value_ in out.items(include_nested=True, leaves_only=True):
        if value_.is_floating_point():
            assert torch.isfinite(value_).all(), key
    # the blown world got a fresh initial state (at rest, inside the joint limits)
    assert (out["sim", "joint_qd"][1] == 0).all()
    assert float(out["reward"][1]) == 0.0
    # the other worlds are exactly what a clean step gives them
    for key, value_ in clean.items(include_nested=True, leaves_only=True):
        assert torch.equal(out[key][[0, 2]], value_[[0, 2]]), key
    # failures keep counting across steps
    again = out.clone()
    again["sim", "joint_qd"][1, index] = value
    again.set("action", torch.zeros(N, 4))
    assert out["info", "sim_failures"].squeeze(-1).tolist() == [0, 1, 0]
    assert raw_env.step(again)["next", "info", "sim_failures"].squeeze(-1).tolist() == [0, 2, 0]


def test_numpy_integers_are_whole_numbers():
    import numpy as np

    env = make_env("screw_claw", num_envs=np.int64(2), seed=np.int64(3), raw=True)
    assert env.num_envs == 2 and type(env.num_envs) is int


@pytest.mark.parametrize("seed", ["abc", 1.7, [1]])
def test_a_seed_that_is_not_an_integer_is_named(seed):
    with pytest.raises(ValueError, match=r"^seed must be an integer, got "):
        make_env("screw_claw", num_envs=1, seed=seed, raw=True)


@pytest.mark.parametrize("dt", [0.5, 1e-9])
def test_a_plan_of_another_step_is_refused_naming_both(tmp_path, dt):
    from dexmots_rl.trajectories import PoseWrenchTrajectory

    steps = 4
    plan = PoseWrenchTrajectory(torch.zeros(steps, 3), torch.tensor([[1.0, 0, 0, 0]] * steps), torch.zeros(steps, 6),
                                dt=dt, joint_q=torch.zeros(steps, 1), joint_torque=torch.zeros(steps, 1))
    plan.save(tmp_path / "plan.pt")
    with pytest.raises(ValueError, match=rf"plan\.pt was planned with dt {dt:.6g} s, the env steps dt 0\.0166667 s"):
        make_env("screw_claw", num_envs=1, references=str(tmp_path / "plan.pt"), raw=True)


def test_random_bytes_for_a_checkpoint_are_one_line_naming_the_file(tmp_path):
    import os

    from dexmots_rl.algorithms.checkpoint import CheckpointError, load_checkpoint
    from dexmots_rl.apps.eval import main as eval_main

    path = tmp_path / "last.pt"
    path.write_bytes(os.urandom(4096))
    with pytest.raises(CheckpointError) as err:
        load_checkpoint(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value) and "weights_only" not in str(err.value)
    with pytest.raises(SystemExit) as cli:
        eval_main([str(path), "--episodes", "1"])
    assert str(cli.value.code).startswith(f"dexmots-eval: checkpoint {path} ") and "\n" not in str(cli.value.code)


@pytest.mark.parametrize("objects, named", [(" , ", "names no object"), ("stapler_a,drawer_a", "'drawer_a'"),
                                            (["scissors_a", "stapler_a"], "'stapler_a'")])
def test_task_objects_that_name_nothing_or_mix_topologies_are_one_error_naming_the_field(objects, named):
    with pytest.raises(ValueError) as err:  # task=operate takes objects of any class, but one topology at a time
        make_env("operate", num_envs=1, objects=objects, raw=True)
    msg = str(err.value)
    assert msg.startswith("task.objects") and named in msg and "scene.xml" not in msg and "\n" not in msg


def test_a_world_that_left_the_physics_is_reset_and_counted(monkeypatch):
    """A step that leaves a world's tool deep in the table (8.3 m, slowly) or its part far past a stop (7.9 rad) is
    a blow-up like a non-finite state: that world is reset, terminated, counted, rewarded 0; the others are not."""
    env = make_env("scissors", num_envs=3, differentiable=False, seed=0, raw=True)
    sim, tree = env.sim, env.sim.object_tree
    td = env.reset()
    td.set("action", torch.zeros(3, env.action_spec.shape[-1]))
    clean = env.step(td.clone())["next"]
    assert not clean["terminated"].any()
    step, nu = sim.step, sim.nu
    pivot = nu + 7 * tree.free + env.joint_index

    def leaving(*args, **kwargs):
        out = step(*args, **kwargs)
        q, pose = out.joint_q.clone(), out.body_pose.clone()
        q[1, nu + 2] -= 8.3  # world 1: the tool's base sunk through the table (its bodies with it)
        pose[1, nu:, 2] -= 8.3
        q[2, pivot] = float(tree.joint_range[env.joint_index, 1]) + 7.9  # world 2: the pivot past its stop
        return type(out)((q, out.joint_qd, out.wrench, out.contact_force, pose, *out[5:]))

    monkeypatch.setattr(sim, "step", leaving)
    out = env.step(td.clone())["next"]
    assert out["terminated"].squeeze(-1).tolist() == [False, True, True]
    assert out["info", "sim_failures"].squeeze(-1).tolist() == [0, 1, 1]
    assert out["reward"][1:].abs().max() == 0 and int(out["task", "step"][1:].abs().max()) == 0
    for key, value in clean.items(include_nested=True, leaves_only=True):
        assert torch.equal(out[key][0], value[0]), key
    # a step that stays within the physics is not flagged
    fresh = env.reset()
    assert not sim.outside_physics(fresh["sim", "joint_q"], fresh["sim", "body_pose"], fresh["sim", "params"]).any()
