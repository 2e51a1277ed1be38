"""Shared fixtures for the dexmots_rl test suite.

Warp compiles one kernel module per scene structure and float type (docs/results.md, compile times; then
cached on disk), so tests share scenes and precisions; docs/devnotes.md (the test suite's two sets) says which
builds the fast set may make. The fixtures here share the two the simulator tests use most:

* the claw scene, in float64 (gradient checks and dynamics sanity) and float32 (the envs' default dtype),
* the 3D oracle scene ``tests/assets/chain3d.xml`` in float64 (dynamics against MuJoCo).

``Simulator`` objects are cheap once their kernels are loaded (``build_kernels`` is cached per process), so
tests build the number of worlds they need from the scenes below, which are built once per test run.
"""

from __future__ import annotations

import os

import pytest
import torch

from dexmots_rl.envs import TASKS
from dexmots_rl.sim import Simulator, load_scene
from simutil import CHAIN3D, CLAW


def _worker_group(item, task_of_module: dict[str, str]) -> str:
    """The task whose scene a test builds (a registered task's name, or the module defining its env, among the
    test's parameters), else the test's file: a task's tests share its kernels, a file's its fixtures."""
    for value in getattr(getattr(item, "callspec", None), "params", {}).values():
        if isinstance(value, str) and (value in TASKS or value in task_of_module):
            return "task " + task_of_module.get(value, value)
    return item.nodeid.split("::")[0]


def pytest_collection_modifyitems(config, items):
    """Under pytest-xdist (``--dist loadgroup``), one worker runs each group: a task's tests in every file, so
    two workers never compile one scene's kernels at once, and the long task checks spread over the workers."""
    if not config.pluginmanager.hasplugin("xdist"):
        return
    modules = [entry.env_class.__module__ for entry in TASKS.values()]
    task_of_module = {entry.env_class.__module__: name for name, entry in TASKS.items()
                      if modules.count(entry.env_class.__module__) == 1}
    for item in items:
        item.add_marker(pytest.mark.xdist_group(_worker_group(item, task_of_module)))


def pytest_configure(config):
    """Under pytest-xdist (``make test`` runs one worker per core) each worker takes its share of the cores for
    the simulator's world blocks and torch, so the workers don't wait on each other's threads."""
    workers = getattr(config, "workerinput", {}).get("workercount")
    if workers:
        share = max(1, len(os.sched_getaffinity(0)) // workers)
        os.environ.setdefault("DEXMOTS_CPU_THREADS", str(share))
        torch.set_num_threads(share)
        _compile_each_module_once()


def _compile_each_module_once() -> None:
    """Workers that need one kernel module at the same moment (the claw and Allegro scenes most tests share) would
    each compile it: warp builds in a private directory and renames it into the cache. A file lock per module name
    in the cache lets the second wait for the first's build and load it. Warp's ``Module.load`` is wrapped (a
    private class: warp-lang is pinned to one minor version); a module already loaded in this process takes no lock."""
    import fcntl

    import warp as wp
    from warp._src.context import Module, runtime

    load = Module.load

    def load_once(self, device, block_dim=None, *args, **kwargs):
        wp.init()
        key = (runtime.get_device(device).context, self.options["block_dim"] if block_dim is None else block_dim)
        if key in self.execs:
            return load(self, device, block_dim, *args, **kwargs)
        with open(os.path.join(wp.config.kernel_cache_dir, f".{self.name}.lock"), "a") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
            return load(self, device, block_dim, *args, **kwargs)

    Module.load = load_once


@pytest.fixture(scope="session")
def claw_scene():
    return load_scene(CLAW)


@pytest.fixture(scope="session")
def chain_scene():
    return load_scene(CHAIN3D)


@pytest.fixture(scope="session")
def make_claw_sim(claw_scene):
    """Factory ``make_claw_sim(num_worlds, dtype=torch.float64, **kwargs)``, reusing simulators."""
    cache: dict = {}

    def make(num_worlds: int, dtype: torch.dtype = torch.float64, **kwargs) -> Simulator:
        key = (num_worlds, dtype, tuple(sorted(kwargs.items())))
        if key not in cache:
            cache[key] = Simulator(claw_scene, num_worlds=num_worlds, dtype=dtype, **kwargs)
        return cache[key]

    return make


@pytest.fixture(scope="session")
def chain_sim(chain_scene):
    """The oracle scene with one tiny float64 substep, so (qd_out - qd) / dt is the joint acceleration.

    7 worlds: one without torque plus one per hand dof with a unit torque (columns of M^-1)."""
    return Simulator(chain_scene, num_worlds=7, dtype=torch.float64, substeps=1, dt=1e-7)
