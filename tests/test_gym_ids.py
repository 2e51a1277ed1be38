"""``import dexmots_rl`` registers the gymnasium ids of every shipped task, without importing gymnasium, warp
or the envs itself."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from dexmots_rl.envs import list_tasks
from dexmots_rl.gym_ids import SHIPPED_TASKS, gym_id

ROOT = Path(__file__).resolve().parents[1]


def _python(code: str) -> str:
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.strip()


def test_shipped_tasks_are_the_registry():
    assert sorted(SHIPPED_TASKS) == list_tasks()


@pytest.mark.parametrize("imports", ["import dexmots_rl; heavy = sorted(m for m in ('gymnasium', 'warp', "
                                     "'dexmots_rl.envs') if m in sys.modules); import gymnasium",
                                     "import gymnasium; heavy = []; import dexmots_rl"])
def test_import_dexmots_rl_registers_the_gym_ids(imports):
    out = _python(f"import sys; {imports}; "
                  f"print(heavy, sorted(i for i in gymnasium.registry if i.startswith('dexmots/')))")
    assert out == f"[] {sorted(gym_id(t) for t in SHIPPED_TASKS)}"


def test_registered_id_builds_the_env_after_import_dexmots_rl():
    assert _python("import dexmots_rl, gymnasium; env = gymnasium.make('dexmots/ScrewClaw-v0'); "
                   "print(env.reset(seed=0)[0].ndim)").splitlines()[-1] == "1"
