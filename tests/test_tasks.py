"""One test module over every registered task: a new task gets these by registering.

Specs (both differentiable settings), seeding, partial resets, an FD gradient check through contact
(float64, from the task's bench pose), reference window shapes, reward terms, success dtype, and the
make_env defaults against the config dexmots-train composes.
"""

from __future__ import annotations

import dataclasses

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf
from torchrl.envs.utils import check_env_specs

from dexmots_rl.apps.train import CONFIG_DIR
from dexmots_rl.envs import list_tasks, make_env, task_config

TASK_NAMES = list_tasks()
N = 3


@pytest.fixture(params=TASK_NAMES)
def task(request):
    return request.param


@pytest.mark.parametrize("differentiable", [False, True])
def test_specs(task, differentiable):
    env = make_env(task, num_envs=N, differentiable=differentiable, seed=0)
    check_env_specs(env, seed=0)


def test_seeding_is_reproducible(task):
    a = make_env(task, num_envs=N, differentiable=False, seed=11)
    b = make_env(task, num_envs=N, differentiable=False, seed=11)
    c = make_env(task, num_envs=N, differentiable=False, seed=12)
    ta, tb, tc = a.reset(), b.reset(), c.reset()
    assert torch.equal(ta["task", "goal"], tb["task", "goal"])
    assert torch.equal(ta["sim", "joint_q"], tb["sim", "joint_q"])
    assert not torch.equal(ta["sim", "joint_q"], tc["sim", "joint_q"])


def test_partial_reset_keeps_other_worlds(task):
    env = make_env(task, num_envs=N, differentiable=False, seed=3)
    td = env.rollout(3, auto_reset=True, break_when_any_done=False)[:, -1]["next"].clone()
    mask = torch.tensor([True] + [False] * (N - 1)).reshape(N, 1)
    out = env.reset(td.clone().set("_reset", mask))
    for key in (("sim", "joint_q"), ("task", "goal"), ("task", "step")):
        assert torch.equal(out[key][1:], td[key][1:]), key
    assert int(out["task", "step"][0]) == 0


def test_declared_reward_terms_and_success(task):
    env = make_env(task, num_envs=N, differentiable=False, seed=1)
    nxt = env.rollout(2, break_when_any_done=False)["next"]
    base = env.base_env
    assert set(nxt["reward_terms"].keys()) == set(base.reward_terms)
    assert nxt["success"].dtype == torch.bool
    assert torch.isfinite(nxt["reward"]).all()


def test_evaluation_breakdowns_give_one_value_per_episode(task):
    from dexmots_rl.algorithms.evaluation import _episode_values

    env = make_env(task, num_envs=N, differentiable=False, seed=2)
    rollout = env.rollout(2, break_when_any_done=False)
    for name, key in env.base_env.breakdowns.items():
        values = _episode_values(env.base_env, rollout, key)
        assert values.shape == (N,) and bool(torch.isfinite(values).all()), name


def test_reference_window_shapes(task):
    env = make_env(task, num_envs=N, differentiable=False, seed=2, raw=True)
    td = env.reset()
    steps = torch.arange(5).expand(N, 5)
    ref = env.reference(td, steps)
    k = env.goal_window_widths()[0] if env.sim.scene.articulated else 0
    assert ref.batch_size == torch.Size([N, 5])
    assert ref["pose"].shape[-1] == 7 and ref["wrench"].shape[-1] == 6
    if k:
        assert ref["joint_q"].shape[-1] == k and ref["joint_torque"].shape[-1] == k


def test_make_env_is_the_trained_task(task):
    """make_env(task)'s config is the one dexmots-train composes for task=<name>: one source of defaults."""
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose("config", overrides=[f"task={task}"])
    composed = OmegaConf.to_container(cfg.task, resolve=True)
    default = dataclasses.asdict(task_config(task))
    assert OmegaConf.to_container(OmegaConf.create(default)) == composed
    env = make_env(task, num_envs=1, differentiable=False, seed=0, raw=True)
    assert env.config == task_config(task)
    assert env.action_type == composed["action"]


def test_unknown_option_names_the_field_and_lists_the_options(task):
    with pytest.raises(ValueError, match="no option 'not_a_field'.*options are: .*goal"):
        make_env(task, num_envs=1, not_a_field=1)


def test_bad_value_names_the_field(task):
    with pytest.raises(ValueError, match="task.max_episode_steps"):
        make_env(task, num_envs=1, max_episode_steps=0)


# each scene kind in float64 is a build of its own: the claw's (the dynamics tests build it too) runs in the fast
# set, the Allegro knob's, the cube's and the tools' in the slow one
FD_FAST = ("screw_claw",)
FD_TASKS = [name if name in FD_FAST else pytest.param(name, marks=pytest.mark.slow) for name in TASK_NAMES]


@pytest.mark.parametrize("fd_task", FD_TASKS)
def test_fd_gradient_through_contact(fd_task):
    """d(object velocity after 2 steps)/d(action) from the bench's contact pose: AD vs central FD (float64)."""
    from dexmots_rl.sim import Control

    env = make_env(fd_task, num_envs=1, differentiable=True, seed=0, raw=True, dtype=torch.float64, action="torque")
    poses = env.bench_poses()  # declared by the task, or built for its scene (the tool tasks: a pre-grasp)
    if poses is None:
        pytest.skip(f"{fd_task} declares no bench poses")
    sim = env.sim
    q0 = torch.tensor([poses.touch_q], dtype=torch.float64)
    params = sim.default_params()
    gear = torch.as_tensor(sim.scene.actuator_gear, dtype=torch.float64)
    zero = torch.zeros(1, sim.nu, dtype=torch.float64)

    def loss(action):
        q, qd, total = q0, torch.zeros(1, sim.nv, dtype=torch.float64), 0.0
        for _ in range(2):
            out = sim.step(q, qd, Control(action * gear, zero, zero, zero), params)
            q, qd = out.joint_q, out.joint_qd
            total = total + out.contact_force.sum()
        return (qd[:, sim.nu:] ** 2).sum() + 1e-3 * total

    action = torch.tensor([poses.squeeze_action], dtype=torch.float64, requires_grad=True)
    value = loss(action)
    assert float(env.sim.step(q0, torch.zeros(1, sim.nv, dtype=torch.float64),
                              Control(action.detach() * gear, zero, zero, zero), params).contact_force) > 0
    (grad,) = torch.autograd.grad(value, action)
    eps = 1e-6
    fd = torch.zeros_like(grad)
    for i in range(action.shape[-1]):
        step = torch.zeros_like(action)
        step[0, i] = eps
        with torch.no_grad():
            fd[0, i] = (loss(action + step) - loss(action - step)) / (2 * eps)
    scale = fd.abs().max().clamp_min(1e-9)
    assert ((grad - fd).abs().max() / scale) < 1e-4, (grad, fd)


RECIPES = sorted((CONFIG_DIR / "recipe").glob("*.yaml"))


@pytest.mark.parametrize("path", RECIPES, ids=[p.stem for p in RECIPES])
def test_recipe_names_a_task_and_a_method_and_sets_only_algo(path):
    """A recipe (configs/recipe/<task>_<algo>.yaml) is picked up by dexmots-train task=<task> algo=<algo>; it may
    set the method's settings but never the task's, so make_env(task) stays the task that is trained."""
    algos = {p.stem for p in (CONFIG_DIR / "algo").glob("*.yaml")}
    matches = [(t, path.stem[len(t) + 1:]) for t in TASK_NAMES if path.stem.startswith(t + "_")]
    assert len(matches) == 1 and matches[0][1] in algos, f"{path.name}: not <registered task>_<algo>"
    task, algo = matches[0]
    recipe = OmegaConf.load(path)
    assert set(recipe) == {"algo"}
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose("config", overrides=[f"task={task}", f"algo={algo}"])
        plain = compose("config", overrides=[f"task={task}", f"algo={algo}", "algo.iterations=7"])
    for key, value in recipe.algo.items():
        assert cfg.algo[key] == value
    assert plain.algo.iterations == 7  # the command line wins over the recipe
    default = OmegaConf.to_container(OmegaConf.create(dataclasses.asdict(task_config(task))))
    assert OmegaConf.to_container(cfg.task, resolve=True) == default


def test_a_task_lacking_a_hook_is_refused_at_registration_naming_it():
    from dexmots_rl.envs.base import DexEnv
    from dexmots_rl.envs.registry import TASKS, register_task

    class NoSuccessTest(DexEnv):
        asset = "claw_screw.xml"

        def sample_initial(self, n):
            return {}

        def reference(self, td, steps):
            return td

        def achieved_goal(self, obs):
            return obs

        def task_reward(self, obs, task, action):
            return action, {}

    before = dict(TASKS)
    with pytest.raises(ValueError, match=r"NoSuccessTest does not implement the task hook\(s\) task_success"):
        register_task("no_success_test", NoSuccessTest, type(task_config("screw_claw")))
    assert TASKS == before
