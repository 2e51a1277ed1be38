"""task.mirror: worlds with a negative goal see the task in a mirror (dexmots_rl.envs.mirror)."""

import pytest
import torch
from torchrl.envs.utils import step_mdp

from dexmots_rl.envs import list_tasks, make_env, task_config
from dexmots_rl.envs.mirror import MirrorGoal, SignedPermutation


def _mirrored_pair(action: str, goal: str):
    """An env of two worlds: world 1 is world 0's reflection (its fingers swapped and angles negated, its goal
    negated), with the same knob parameters."""
    env = make_env("screw_claw", num_envs=2, seed=3, dtype=torch.float64, differentiable=False, action=action,
                   goal=goal, mirror=True)
    td = env.reset()
    order = [2, 3, 0, 1, 4]
    for key in (("sim", "joint_q"), ("sim", "joint_qd")):
        x = td.get(key).clone()
        x[0] += 0.05 * torch.randn(5, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
        x[1] = -x[0, order]
        td.set(key, x)
    goal = td.get(("task", "goal")).clone()
    goal[1] = -goal[0]
    td.set(("task", "goal"), goal)
    for key in td.get(("sim", "params")).keys():
        value = td.get(("sim", "params", key)).clone()
        value[1] = value[0]
        td.set(("sim", "params", key), value)
    return env, td


@pytest.mark.parametrize("action,goal", [("vi", "pose_wrench"), ("torque", "pose"), ("position", "pose_traj")])
def test_a_world_and_its_reflection_see_the_same_task(action, goal):
    """Driven by the same (canonical) actions, a world turning +θ and its reflection turning -θ give the policy
    the same observation and earn the same reward at every step, while their knobs turn opposite ways."""
    env, td = _mirrored_pair(action, goal)
    g = torch.Generator().manual_seed(2)
    for step in range(6):
        a = 2 * torch.rand(1, env.action_spec.shape[-1], generator=g, dtype=torch.float64) - 1
        td.set("action", a.expand(2, -1).clone())
        td = env.step(td)
        nxt = td.get("next")
        obs = nxt.get("observation")
        torch.testing.assert_close(obs[1], obs[0], rtol=0, atol=1e-9)
        torch.testing.assert_close(nxt.get("reward")[1], nxt.get("reward")[0], rtol=0, atol=1e-9)
        knob = nxt.get(("object", "q"))
        torch.testing.assert_close(knob[1], -knob[0], rtol=0, atol=1e-12)
        td = step_mdp(td)
    assert float(knob[0].abs()) > 1e-4  # the knob moved, so the test compared something that can differ


def test_mirror_off_adds_no_transform():
    env = make_env("screw_claw", num_envs=2, seed=0, differentiable=False, mirror=False)
    assert not any(isinstance(t, MirrorGoal) for t in env.transform)
    assert any(isinstance(t, MirrorGoal) for t in make_env("screw_claw", num_envs=2, differentiable=False).transform)


@pytest.mark.parametrize("task", [t for t in list_tasks() if t != "screw_claw"])
def test_mirror_is_refused_by_tasks_without_the_symmetry(task):
    with pytest.raises(ValueError, match="task.mirror"):
        make_env(task, num_envs=1, mirror=True)


def test_signed_permutation_rejects_bad_maps():
    with pytest.raises(ValueError, match="permutation"):
        SignedPermutation((0, 0), (1.0, 1.0))
    with pytest.raises(ValueError, match="signs"):
        SignedPermutation((1, 0), (2.0, 1.0))
    with pytest.raises(ValueError, match="3 entries"):
        SignedPermutation.negate(3)(torch.zeros(2))


def test_a_saved_config_without_the_field_keeps_its_unmirrored_task():
    """A checkpoint's task config saved before task.mirror existed was trained without the mirror."""
    assert task_config("screw_claw").mirror is True
    env = make_env({"name": "screw_claw"}, num_envs=1, differentiable=False)
    assert not any(isinstance(t, MirrorGoal) for t in env.transform)


def test_pgdm_features_of_a_world_and_its_reflection_agree():
    """PGDM builds its own observation; on a mirrored task it reflects it as the task's observation is."""
    from hydra import compose, initialize_config_dir

    from dexmots_rl.algorithms import pgdm
    from dexmots_rl.apps.train import config_dir

    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        algo = compose("config", overrides=["algo=pgdm"]).algo
    env, td = _mirrored_pair("vi", "pose_wrench")
    features = pgdm.PGDMFeatures(env.base_env, algo)
    td.set("action", torch.full((2, 8), 0.3, dtype=torch.float64))
    nxt = env.step(td).get("next")
    obs = features.observation(nxt)
    torch.testing.assert_close(obs[1], obs[0], rtol=0, atol=1e-9)
    assert not torch.allclose(nxt.get(("hand", "q"))[1], nxt.get(("hand", "q"))[0])


def test_the_scripted_controller_acts_the_same_in_a_mirrored_and_an_unmirrored_env():
    """ScriptedPolicy acts in the real scene: through the mirrored env the worlds step as without it."""
    from dexmots_rl.envs import ScriptedPolicy

    outcomes = []
    for mirror in (True, False):
        env = make_env("screw_claw", num_envs=4, differentiable=False, seed=0, action="torque", mirror=mirror)
        td = env.rollout(5, ScriptedPolicy(env.base_env))
        assert (td["task", "goal"] < 0).any() and (td["task", "goal"] > 0).any()
        outcomes.append(td["next", "sim", "joint_q"])
    torch.testing.assert_close(outcomes[0], outcomes[1], rtol=0, atol=0)


def test_resuming_a_run_saved_before_the_field_keeps_its_unmirrored_task():
    """A resumed run trains its checkpoint's task; a task config saved before task.mirror existed had none."""
    from hydra import compose, initialize_config_dir

    from dexmots_rl.algorithms.rundir import resume_config
    from dexmots_rl.apps.train import config_dir

    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        cfg = compose("config", overrides=["task=screw_claw"])
    saved = {"task": {k: v for k, v in dict(cfg.task).items() if k != "mirror"}, "algo": dict(cfg.algo),
             "seed": cfg.seed}
    assert cfg.task.mirror is True
    assert resume_config(cfg, {"config": saved}, "old_run", overrides=[]).task.mirror is False


def test_a_raw_env_refuses_mirror_on_a_task_without_the_symmetry():
    with pytest.raises(ValueError, match="task.mirror"):
        make_env("allegro_rotate", num_envs=1, mirror=True, raw=True)
