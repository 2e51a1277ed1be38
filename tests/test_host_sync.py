"""The GPU step path never reads a tensor back to the host: run on CPU in the configuration a CUDA device
gets (``sync_free`` env, graph-captured launches), with every host read of a tensor made to fail inside the
env's step, reset, reward and observation transforms and inside the simulator's reverse pass."""

from __future__ import annotations

import contextlib
import functools

import pytest
import torch

from dexmots_rl.envs import make_env
from dexmots_rl.sim import Trajectory

_DEPTH = [0]  # > 0 while guarded code runs


class HostRead(AssertionError):
    pass


def _forbidden(name, original):
    @functools.wraps(original)
    def read(*args, **kwargs):
        if _DEPTH[0]:
            raise HostRead(f"{name} inside the step path (a host read / GPU synchronisation)")
        return original(*args, **kwargs)
    return read


def _getitem(original):
    @functools.wraps(original)
    def getitem(self, index):
        if _DEPTH[0]:
            parts = index if isinstance(index, tuple) else (index,)
            if any(isinstance(p, torch.Tensor) and p.dtype == torch.bool for p in parts):
                raise HostRead("boolean-mask indexing inside the step path (its size is read on the host)")
        return original(self, index)
    return getitem


@contextlib.contextmanager
def _guarded():
    _DEPTH[0] += 1
    try:
        yield
    finally:
        _DEPTH[0] -= 1


def _guard(fn):
    @functools.wraps(fn)
    def guarded(*args, **kwargs):
        with _guarded():
            return fn(*args, **kwargs)
    return guarded


@pytest.fixture
def no_host_reads(monkeypatch):
    """Make host reads of tensors fail inside code wrapped with :func:`_guard`."""
    for name in ("item", "tolist", "cpu", "numpy", "nonzero", "__bool__", "__float__", "__int__", "__index__"):
        monkeypatch.setattr(torch.Tensor, name, _forbidden(f"Tensor.{name}", getattr(torch.Tensor, name)))
    monkeypatch.setattr(torch.Tensor, "__getitem__", _getitem(torch.Tensor.__getitem__))
    for name in ("nonzero", "masked_select", "unique"):
        monkeypatch.setattr(torch, name, _forbidden(f"torch.{name}", getattr(torch, name)))
    monkeypatch.setattr(Trajectory, "backward", _guard(Trajectory.backward))
    return monkeypatch


def _gpu_configured_env(task: str, monkeypatch):
    env = make_env(task, num_envs=3, seed=0, max_episode_steps=3, adjoint_clip=10.0)
    base = env.base_env
    base.sync_free = True  # what a CUDA device sets
    base.sim.graphs = True  # one launch per kernel, captured as graphs, as on CUDA
    monkeypatch.setattr(base, "_step", _guard(base._step))
    monkeypatch.setattr(base, "_reset", _guard(base._reset))
    for name in ("_step", "_reset", "_call"):
        monkeypatch.setattr(env.transform, name, _guard(getattr(env.transform, name)))
    return env


@pytest.mark.parametrize("task", ["screw_claw", "allegro_rotate", "repose_cube"])
def test_step_reset_and_reverse_pass_read_nothing_back(task, no_host_reads):
    env = _gpu_configured_env(task, no_host_reads)
    td = env.reset()
    # a differentiable rollout through auto-resets (episodes of 3 steps) and its backward pass
    td["action"] = torch.zeros(env.batch_size + env.action_spec.shape[-1:]).requires_grad_(True)
    actions = [td["action"]]
    total = 0.0
    for _ in range(5):
        out, td = env.step_and_maybe_reset(td)
        total = total + out["next", "reward"].sum()
        td = td.clone(False)
        td["action"] = (0.3 * torch.ones_like(td["action"].detach())).requires_grad_(True)
        actions.append(td["action"])
    total.backward()
    assert actions[0].grad is not None and torch.isfinite(actions[0].grad).all()
    with pytest.raises(HostRead):  # the guard does fire
        with _guarded():
            bool(td["done"].any())


def test_a_blown_up_world_is_reset_without_a_host_read(no_host_reads):
    env = _gpu_configured_env("screw_claw", no_host_reads)
    td = env.reset()
    td["sim", "joint_qd"][1] = 1e6  # world 1 is past MAX_JOINT_SPEED
    td["action"] = torch.zeros(env.batch_size + env.action_spec.shape[-1:])
    nxt = env.step(td)["next"]
    assert nxt["terminated"].squeeze(-1).tolist() == [False, True, False]
    assert nxt["info", "sim_failures"].squeeze(-1).tolist() == [0, 1, 0]
    assert torch.isfinite(nxt["sim", "joint_qd"]).all() and nxt["sim", "joint_qd"][1].abs().max() < 1e3


def test_the_graph_path_matches_the_block_path():
    """Graph-captured launches (CUDA's path) give bit-identical states and gradients to the CPU blocks."""
    from dexmots_rl.envs import task_contact, task_scene
    from dexmots_rl.sim import Control, Simulator

    scene = task_scene("screw_claw")

    def run(graphs: bool):
        sim = Simulator(scene, 4, contact=task_contact("screw_claw"))
        sim.graphs = graphs
        q, qd = sim.initial_state()
        q = (q + 0.1).requires_grad_(True)
        tau = torch.full((4, sim.nu), 30.0, requires_grad=True)
        zero = torch.zeros(4, sim.nu)
        a, b = q, qd
        for _ in range(3):
            out = sim.step(a, b, Control(tau, zero, zero, zero), sim.default_params())
            a, b = out.joint_q, out.joint_qd
        (a.sum() + b.square().sum() + out.fingertips.sum()).backward()
        return a.detach(), b.detach(), q.grad, tau.grad

    for blocks, graphs in zip(run(False), run(True)):
        assert torch.equal(blocks, graphs)
