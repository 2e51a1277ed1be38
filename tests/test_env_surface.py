"""Code above the envs (trainers, the recorder, the console scripts) uses an env's public surface: the state comes
in its TensorDicts, the gradient counters of a backward through ``env.counting_gradients()``, the worlds' random
stream through ``env.get_rng_state()`` / ``env.set_rng_state()``, the scene and time step as ``env.scene`` /
``env.dt``; never the env's simulator (``.sim``) or generator (``.generator``)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
import torch

from dexmots_rl.envs import GRADIENT_COUNTS, make_env

PACKAGE = Path(__file__).resolve().parents[1] / "dexmots_rl"
FOLDERS = ("algorithms", "recording", "apps")
PRIVATE = ("sim", "generator")
#: console scripts that measure or identify the simulator itself, and so drive an env's simulator directly
SIMULATOR_TOOLS = {
    "apps/bench_grad.py": "checks the simulator's gradients against finite differences",
    "apps/bench_throughput.py": "times the simulator's step against MuJoCo's",
    "apps/bench_pipeline.py": "times the simulator's step apart from the env's rollout",
    "apps/bench_sysid.py": "identifies the simulator's parameters (as dexmots_rl.sysid does)",
}
OWN_OBJECT_FACTORIES = {"make_simulator", "Generator"}  # a module's own simulator or generator is its own to use


def _called_names(node: ast.AST) -> set[str]:
    names = set()
    for sub in ast.walk(node):
        if isinstance(sub, ast.Call):
            func = sub.func
            names.add(func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", ""))
    return names


def private_reaches(source: str, where: str) -> list[str]:
    """Each ``x.sim`` / ``x.generator`` (or ``getattr(x, "sim")``) in ``source``, but ``self.<name>`` where the
    module itself makes that object (``self.generator = torch.Generator(...)``)."""
    tree = ast.parse(source)
    own = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and _called_names(node.value) & OWN_OBJECT_FACTORIES:
            own |= {t.attr for t in node.targets if isinstance(t, ast.Attribute)
                    and isinstance(t.value, ast.Name) and t.value.id == "self"}
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and node.attr in PRIVATE:
            if not (isinstance(node.value, ast.Name) and node.value.id == "self" and node.attr in own):
                found.append((node.lineno, f".{node.attr}"))
        elif (isinstance(node, ast.Call) and getattr(node.func, "id", None) == "getattr" and len(node.args) > 1
              and isinstance(node.args[1], ast.Constant) and node.args[1].value in PRIVATE):
            found.append((node.lineno, f"getattr(..., {node.args[1].value!r})"))
    return [f"{where}:{line} {what}" for line, what in sorted(found)]


def test_trainers_recorder_and_scripts_use_the_envs_public_surface():
    found = []
    for folder in FOLDERS:
        for path in sorted((PACKAGE / folder).glob("*.py")):
            where = f"{folder}/{path.name}"
            if where not in SIMULATOR_TOOLS:
                found += private_reaches(path.read_text(), where)
    assert not found, ("use the env's public surface (TensorDict keys, counting_gradients, get_rng_state / "
                       "set_rng_state, scene, dt) instead of:\n" + "\n".join(found))


def test_the_check_sees_each_way_of_reaching_in():
    source = """
class Planner:
    def __init__(self, env):
        self.generator = torch.Generator().manual_seed(0)  # its own: allowed
        self.env = env

    def draw(self, env):
        a = env.base_env.generator.get_state()
        b = self.env.sim.observe(None)
        c = getattr(env, "sim", env)
        return torch.rand(1, generator=self.generator), a, b, c
"""
    assert [hit.split(" ")[1] for hit in private_reaches(source, "x.py")] == [
        ".generator", ".sim", "getattr(...,"]


@pytest.fixture(scope="module")
def env():
    return make_env("screw_claw", num_envs=2, seed=3)


def test_a_saved_rng_state_replays_the_worlds_draws(env):
    state = env.get_rng_state()
    first = env.reset()[("task", "goal")]
    env.set_rng_state(state)
    assert torch.equal(env.reset()[("task", "goal")], first)
    assert not torch.equal(env.reset()[("task", "goal")], first)  # the stream moved on


@pytest.mark.parametrize("bad", [None, torch.zeros(3, dtype=torch.uint8), torch.zeros(5056)])
def test_a_foreign_rng_state_is_refused_by_name(env, bad):
    before = env.get_rng_state()
    with pytest.raises(ValueError, match="rng state: expected the uint8 tensor"):
        env.set_rng_state(bad)
    assert torch.equal(env.get_rng_state(), before)


def test_counting_gradients_reports_what_the_backward_adds(env):
    """The counters grow in the backward pass only; the block reports that growth per world."""
    td = env.reset()
    with env.counting_gradients() as unused:
        pass
    assert all(int(unused[key].abs().sum()) == 0 for key in GRADIENT_COUNTS)
    action = torch.ones(2, env.action_spec.shape[-1], requires_grad=True)
    out = env.step(td.set("action", action))["next"]
    with env.counting_gradients() as counted:
        out["reward"].sum().backward()
    assert action.grad is not None
    before = {key: out[key] for key in GRADIENT_COUNTS}  # what the step published, before the backward
    after = env.gradient_counts()
    for key in GRADIENT_COUNTS:
        assert counted[key].shape == (2, 1) and counted[key].dtype == torch.int64
        assert torch.equal(counted[key], after[key] - before[key])
