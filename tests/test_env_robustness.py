"""The env under bad input: the reward sees the clamped action, clear errors for a state-less step and a missing
GPU, absurd reference plans are rejected, the env pickles."""

from __future__ import annotations

import copy
import pickle

import pytest
import torch

from dexmots_rl.envs import make_env

N = 2


@pytest.fixture(scope="module")
def raw_env():
    return make_env("screw_claw", num_envs=N, differentiable=False, seed=0, raw=True)


def _step_with(env, action, start=None):
    td = (env.reset() if start is None else start).clone()
    td.set("action", action)
    return env.step(td)["next"]


def test_reward_penalises_the_clamped_action(raw_env):
    # #16.5: the physics clamps to [-1, 1] but the action penalty used the raw action (1e19 -> -1e19 reward)
    dim = raw_env.action_spec.shape[-1]
    start = raw_env.reset()
    huge = _step_with(raw_env, torch.full((N, dim), 1e19), start)
    unit = _step_with(raw_env, torch.ones(N, dim), start)
    assert torch.isfinite(huge["reward"]).all()
    torch.testing.assert_close(huge["reward"], unit["reward"])
    torch.testing.assert_close(huge["reward_terms", "action"], unit["reward_terms", "action"])


def test_reward_gradient_stays_finite_for_large_actions():
    env = make_env("screw_claw", num_envs=N, differentiable=True, seed=0, raw=True)
    dim = env.action_spec.shape[-1]
    action = torch.tensor([[5.0] * dim, [0.5] * dim], requires_grad=True)
    td = env.reset()
    td.set("action", action)
    env.step(td)["next", "reward"].sum().backward()
    assert torch.isfinite(action.grad).all()


@pytest.mark.parametrize("key", [("sim", "joint_q"), ("task", "goal"), ("sim", "params")])
def test_step_without_state_names_the_missing_key(raw_env, key):
    td = raw_env.reset()
    td.set("action", torch.zeros(raw_env.action_spec.shape))
    del td[key]
    with pytest.raises(KeyError, match=key[0]) as err:
        raw_env.step(td)
    assert key[1] in str(err.value)


def test_cuda_without_gpu_is_a_clear_value_error():
    if torch.cuda.is_available():
        pytest.skip("this machine has a GPU")
    with pytest.raises(ValueError, match="cuda"):
        make_env("screw_claw", num_envs=1, device="cuda:0")


def test_env_pickles_and_deepcopies_and_continues_the_same_stream():
    # #16.8: the simulator (ctypes) made DexEnv unpicklable; it is now rebuilt from the constructor args
    env = make_env("screw_claw", num_envs=2, seed=3)  # a TransformedEnv around the DexEnv
    env.reset()
    for clone in (pickle.loads(pickle.dumps(env)), copy.deepcopy(env)):
        assert clone.base_env.sim is not env.base_env.sim and clone.batch_size == env.batch_size
        torch.testing.assert_close(clone.reset()["observation"], copy.deepcopy(env).reset()["observation"])
        td = clone.rand_step(clone.reset())
        assert torch.isfinite(td["next", "reward"]).all()
    raw = pickle.loads(pickle.dumps(env.base_env))
    assert raw.num_envs == 2 and raw.differentiable and raw._seed == 3


def _observation_in_child(env):
    return env.reset()["observation"].shape


def test_env_survives_a_spawn_process_round_trip():
    import multiprocessing as mp

    env = make_env("screw_claw", num_envs=2, seed=0)
    with mp.get_context("spawn").Pool(1) as pool:
        assert pool.apply(_observation_in_child, (env,)) == env.reset()["observation"].shape


def test_a_partial_reset_keeps_the_kept_worlds_reward_terms(raw_env):
    td = _step_with(raw_env, torch.full((N, raw_env.action_spec.shape[-1]), 0.3))
    terms = td["reward_terms"].clone()
    assert any(bool((value != 0).all()) for value in terms.values())
    td.set("_reset", torch.tensor([[True], [False]]))
    out = raw_env._reset(td)
    for name, value in terms.items():
        assert bool((out["reward_terms", name][0] == 0).all()), name  # the reset world starts afresh
        assert torch.equal(out["reward_terms", name][1], value[1]), name  # the kept world keeps its terms
