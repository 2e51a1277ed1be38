"""The gymnasium facade: make_vec over batched worlds, SAME_STEP autoreset, spaces, env checker."""

from __future__ import annotations

import doctest
import re

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import dexmots_rl.envs.gym as dex_gym
from dexmots_rl.envs import list_tasks


def test_every_task_is_registered():
    assert {dex_gym.gym_id(t) for t in list_tasks()} <= set(gym.registry)
    assert "dexmots/ScrewClaw-v0" in gym.registry


def test_make_vec_batched_spaces_and_step():
    envs = gym.make_vec("dexmots/ScrewClaw-v0", num_envs=3)
    assert isinstance(envs.unwrapped, gym.vector.VectorEnv) and envs.num_envs == 3
    single_obs, single_act = envs.single_observation_space, envs.single_action_space
    from dexmots_rl.envs import make_env

    dim = make_env("screw_claw", num_envs=1).observation_spec["observation"].shape[-1]
    assert single_obs.dtype == np.float32 and single_obs.shape == (dim,)
    assert envs.observation_space.shape == (3, *single_obs.shape)
    assert envs.action_space.shape == (3, *single_act.shape)
    obs, info = envs.reset(seed=1)
    assert obs.shape == (3, dim) and obs.dtype == np.float32 and info["success"].shape == (3,)
    again, _ = envs.reset(seed=1)
    np.testing.assert_array_equal(obs, again)
    obs, reward, term, trunc, info = envs.step(envs.action_space.sample())
    assert envs.observation_space.contains(obs)
    assert reward.shape == term.shape == trunc.shape == (3,) and info["success"].dtype == bool
    envs.close()


def test_same_step_autoreset_restarts_finished_worlds():
    envs = dex_gym.DexVectorEnv("screw_claw", num_envs=2, seed=0, max_episode_steps=3)
    assert envs.metadata["autoreset_mode"] == gym.vector.AutoresetMode.SAME_STEP
    obs, _ = envs.reset(seed=0)
    zero = np.zeros(envs.action_space.shape, np.float32)
    for t in range(3):
        obs, reward, term, trunc, info = envs.step(zero)
    assert trunc.all() and info["_final_obs"].all()
    assert not np.allclose(info["final_obs"], obs)  # the returned obs is the new episode's first
    assert (envs._td["task", "step"] == 0).all()  # the worlds restarted in the same step
    obs, reward, term, trunc, info = envs.step(zero)
    assert not trunc.any() and "final_obs" not in info


def test_single_world_env_passes_gymnasiums_checker():
    env = gym.make("dexmots/ScrewClaw-v0")
    check_env(env.unwrapped, skip_render_check=True)
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs) and isinstance(info["success"], bool)


def test_module_doctest():
    assert doctest.testmod(dex_gym).failed == 0


def test_wrongly_shaped_actions_are_refused_naming_the_expected_shape():
    envs = dex_gym.DexVectorEnv("screw_claw", num_envs=4, seed=0)
    envs.reset(seed=0)
    good = np.zeros(envs.action_space.shape, np.float32)  # (4, action dim)
    for bad in (good.T, good.reshape(-1), good[None]):  # the same element count, another shape
        with pytest.raises(ValueError, match=re.escape(str(envs.action_space.shape))):
            envs.step(bad)
    envs.step(good)
    single = dex_gym.DexGymEnv("screw_claw", seed=0)
    single.reset(seed=0)
    with pytest.raises(ValueError, match=re.escape(str(single.action_space.shape))):
        single.step(np.zeros((1, *single.action_space.shape), np.float32))
    single.step(np.zeros(single.action_space.shape, np.float32))
