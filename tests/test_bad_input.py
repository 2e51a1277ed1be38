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
