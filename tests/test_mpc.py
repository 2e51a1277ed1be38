"""MPC baseline (``dexmots-train algo=mpc``): the sampled plan never loses to the nominal, refinement never
loses to the sampled plan, warm starts and episode boundaries, the planner on a pure-torch toy, the run
directory and the config checks."""

from __future__ import annotations

import json
import re

import pytest
import torch
from hydra import compose, initialize_config_dir

from dexmots_rl.algorithms.mpc import STATE, PredictiveSampler
from dexmots_rl.apps.train import CONFIG_DIR, run as train
from dexmots_rl.envs import make_env
from toy_envs import PointMassEnv

TOY_STATE = ["pos", "vel", "goal", "step_count"]


def _claw_state(worlds=2, seed=0):
    td = make_env("screw_claw", num_envs=worlds, differentiable=False, seed=seed).reset()
    return td, td.select(*STATE)


def _toy_planner(worlds=4, candidates=16, refine_steps=0, **kwargs):
    return PredictiveSampler(PointMassEnv(worlds * candidates, max_episode_steps=30),
                             PointMassEnv(worlds, max_episode_steps=30) if refine_steps else None,
                             num_worlds=worlds, candidates=candidates, refine_steps=refine_steps,
                             state_keys=TOY_STATE, step_key="step_count", initial_plan="zero", **kwargs)


def test_the_chosen_plan_is_never_worse_than_the_nominal_on_screw_claw():
    planner = PredictiveSampler.for_task("screw_claw", 2, candidates=6, horizon=4, knots=2, noise=0.5,
                                         refine_steps=0)
    check = make_env("screw_claw", num_envs=2, differentiable=False, raw=True)  # one world per plan
    td, state = _claw_state()
    nominal = planner.warm_start(state)
    candidates, returns = planner.sample(state, nominal)
    assert torch.equal(candidates[:, 0], nominal)
    # each of the K clones is its world: the batched returns are the plans' own returns from that state
    torch.testing.assert_close(returns[:, 0], planner.plan_return(check, state, nominal))
    torch.testing.assert_close(returns[:, 3], planner.plan_return(check, state, candidates[:, 3]))
    assert (returns[:, 1:] < returns[:, :1]).any()  # with this much noise some candidates are worse

    action = planner(td)["action"]  # samples afresh from the same nominal (the first plan of the episode)
    chosen = planner.plan_return(check, state, planner.plan)
    assert (chosen >= planner.plan_return(check, state, nominal) - 1e-5).all()
    real = planner.actions(planner.plan)[:, 0]  # the plan's action in the real scene
    # the claw's env is mirrored: worlds with a negative goal get the reflection, which the env reflects back
    mirrored = td["task", "goal"][:, 0] < 0
    assert mirrored.any() and (~mirrored).any()  # this state has one world of each kind
    torch.testing.assert_close(action[~mirrored], real[~mirrored])
    torch.testing.assert_close(action[mirrored], planner.mirror(real[mirrored]))
    assert planner.budget()["sim_steps"] == 2 * (2 * 6 * 4)  # sample() was called twice


def test_the_planner_acts_the_same_in_a_mirrored_and_an_unmirrored_env():
    """The planner plans in the real scene; through a mirrored env (task.mirror) the world steps as without."""
    from torchrl.envs.utils import step_mdp

    outcomes = []
    for mirror in (True, False):
        env = make_env("screw_claw", num_envs=2, differentiable=False, seed=0, mirror=mirror)
        planner = PredictiveSampler.for_task(env.base_env.config, 2, candidates=3, horizon=4, knots=2, seed=1,
                                             refine_steps=0)
        td = env.reset()
        for _ in range(2):
            td = step_mdp(env.step(planner(td)))
        outcomes.append(td["sim", "joint_q"])
    torch.testing.assert_close(outcomes[0], outcomes[1], rtol=0, atol=0)


def test_refinement_never_increases_the_cost_on_screw_claw():
    # a large step size: many gradient steps overshoot, and those must be rejected
    planner = PredictiveSampler.for_task("screw_claw", 2, candidates=2, horizon=4, knots=2, refine_steps=3,
                                         refine_lr=0.5)
    check = make_env("screw_claw", num_envs=2, differentiable=False, raw=True)
    _, state = _claw_state(seed=1)
    candidates, returns = planner.sample(state, planner.warm_start(state))
    knots, refined = planner.refine(state, candidates[:, 0], returns[:, 0])
    assert (refined >= returns[:, 0]).all()
    assert ((knots >= planner.low) & (knots <= planner.high)).all()
    # the reported return is the returned plan's own (not that of a rejected step)
    torch.testing.assert_close(planner.plan_return(check, state, knots), refined, rtol=1e-5, atol=1e-4)
    assert planner.budget()["grad_steps"] == 2 * 3 * 4


def test_gradient_refinement_improves_plans_on_a_toy():
    planner = _toy_planner(candidates=1, refine_steps=5, horizon=10, knots=3, refine_lr=0.2)
    state = PointMassEnv(4).reset().select(*TOY_STATE)
    zero = planner.initial(state)
    start = planner.plan_return(planner.refine_env, state, zero).detach()
    knots, refined = planner.refine(state, zero, start)
    assert (refined > start + 1e-3).all()  # the gradient of the return points uphill in every world
    assert (knots != zero).any()


def test_the_planner_drives_the_toy_point_masses_to_their_goals():
    env = PointMassEnv(4, max_episode_steps=30)
    planner = _toy_planner(candidates=16, refine_steps=1, horizon=10, knots=3, noise=0.5, refine_lr=0.1)
    env.set_seed(3)
    planned = env.rollout(30, planner, auto_reset=False, break_when_any_done=False, tensordict=env.reset())
    env.set_seed(3)  # the same 4 worlds, doing nothing
    idle = env.rollout(30, lambda td: td.set("action", torch.zeros(4, 2)), auto_reset=False,
                       break_when_any_done=False, tensordict=env.reset())
    torch.testing.assert_close(planned[:, 0]["pos"], idle[:, 0]["pos"])
    final_distance = (planned["next", "pos"] - planned["next", "goal"])[:, -1].norm(dim=-1)
    start_distance = (planned["pos"] - planned["goal"])[:, 0].norm(dim=-1)
    assert planned["next", "reward"].sum() > 0.5 * idle["next", "reward"].sum()  # rewards are negative
    assert (final_distance < 0.25 * start_distance).all()


def test_rewards_after_the_episode_end_do_not_count():
    planner = _toy_planner(worlds=2, candidates=1, horizon=5, knots=2)
    env = PointMassEnv(2, max_episode_steps=30)
    state = env.reset().select(*TOY_STATE)
    state["step_count"] = torch.tensor([[27], [10]])  # world 0 has 3 steps left, world 1 all 5
    knots = torch.full((2, 2, 2), 0.3)
    td, rewards = state.copy(), []
    for _ in range(5):
        td = env.step(td.set("action", knots[:, 0])).get("next")
        rewards.append(td["reward"].squeeze(-1))
    rewards = torch.stack(rewards, -1)
    expected = torch.stack([rewards[0, :3].sum(), rewards[1].sum()])
    torch.testing.assert_close(planner.plan_return(planner.sample_env, state, knots), expected)


@pytest.mark.parametrize("interpolation", ["zero", "linear"])
def test_the_warm_start_is_the_plan_one_step_later_and_restarts_with_an_episode(interpolation):
    planner = _toy_planner(worlds=2, candidates=1, horizon=4, knots=4, interpolation=interpolation)
    state = PointMassEnv(2).reset().select(*TOY_STATE)
    state["step_count"] = torch.tensor([[7], [0]])  # world 1 starts a new episode
    planner.plan = torch.arange(16.0).reshape(2, 4, 2) / 16
    shifted = planner.warm_start(state)
    # one knot per step: every knot moves one step earlier and the last one repeats
    torch.testing.assert_close(shifted[0], planner.plan[0, [1, 2, 3, 3]])
    torch.testing.assert_close(shifted[1], torch.zeros(4, 2))  # the initial plan ("zero")


def _cfg(run_dir, *overrides):
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return compose("config", overrides=[
            "algo=mpc", "task.max_episode_steps=4", "eval.episodes=2", "progress=false", "algo.candidates=2",
            "algo.horizon=3", "algo.knots=2", "algo.refine_steps=1", f"run_dir={run_dir}", *overrides])


def test_dexmots_train_algo_mpc_writes_the_evaluation(tmp_path):
    run = tmp_path / "run"
    result = train(_cfg(run))
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["algo"] == "mpc" and metrics["episodes"] == 2 and metrics["success_rate"] == result["success_rate"]
    for key in ("success_rate", "mean_final_error", "mean_time_to_success_s", "sim_failures", "success_by_friction",
                "success_by_damping", "wall_clock_s"):
        assert key in metrics, key
    assert metrics["env_steps"] == 2 * 4
    per_step = (2 + 2) * 3  # 2 candidates + 2 refinement passes, each 3 steps ahead
    assert metrics["sim_steps_per_control_step"] == per_step and metrics["grad_steps_per_control_step"] == 3
    assert metrics["sim_steps"] == 2 * 4 * per_step and metrics["grad_steps"] == 2 * 4 * 3
    # the planning's cost per evaluation episode beside its success (dexmots-table reports it)
    assert metrics["sim_steps_per_episode"] == 4 * per_step and metrics["grad_steps_per_episode"] == 4 * 3
    assert 0 < metrics["planning_cpu_s_per_episode"] == pytest.approx(metrics["planning_cpu_s"] / 2, abs=0.01)
    assert 0 < metrics["planning_wall_s_per_episode"] == pytest.approx(metrics["wall_clock_s"] / 2, abs=0.01)
    rows = (run / "metrics.jsonl").read_text().splitlines()
    assert len(rows) == 1 and json.loads(rows[0])["sim_steps"] == metrics["sim_steps"]
    assert (run / "config.yaml").is_file() and not (run / "checkpoints").exists()


@pytest.mark.parametrize("override, message", [
    ("algo.candidates=0", "algo.candidates must be an integer >= 1, got 0"),
    ("algo.horizon=1", "algo.knots must be <= algo.horizon (1), got 2"),
    ("algo.interpolation=cubic", "algo.interpolation must be one of zero, linear"),
    ("algo.noise=-0.1", "algo.noise must be a number >= 0"),
    ("algo.refine_lr=0", "algo.refine_lr must be a number > 0"),
    ("algo.refine_steps=-1", "algo.refine_steps must be an integer >= 0"),
])
def test_bad_mpc_fields_fail_with_one_clear_error(tmp_path, override, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        train(_cfg(tmp_path / "run", override))
    assert not (tmp_path / "run").exists()  # refused before anything was written
