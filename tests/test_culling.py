"""The box specialisation of a convex object skips work only: a step with it equals a step without.

A box-shaped object's largest face distance is computed as ``max(|p - c| - h)`` (``box_object``) instead
of the loop over its six face planes; it feeds the culling tests (``link_near``, ``sphere_near``) and the
smooth distance. Each case steps a task's bench scene in contact in float64 twice, once with the
specialisation turned off, and compares every output; the plane reader is checked on its own too.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from dexmots_rl.apps.bench_setup import bench_task
from dexmots_rl.envs import task_contact, task_scene
from dexmots_rl.sim import Control, Simulator
from dexmots_rl.sim import _simulator as simulator_module


def test_box_of_planes_reads_centre_and_half_extents():
    planes = np.array([[1, 0, 0, 0.3], [-1, 0, 0, 0.1], [0, 1, 0, 0.2], [0, -1, 0, 0.2], [0, 0, 1, 0.5],
                       [0, 0, -1, -0.1]], dtype=float)
    centre, half = simulator_module._box_of_planes(planes)
    np.testing.assert_allclose(centre, [0.1, 0.0, 0.3])
    np.testing.assert_allclose(half, [0.2, 0.2, 0.2])
    tilted = planes.copy()
    tilted[0, :3] = [0.8, 0.6, 0.0]
    assert simulator_module._box_of_planes(tilted) is None  # not axis-aligned
    assert simulator_module._box_of_planes(planes[:5]) is None  # not six faces
    assert simulator_module._box_of_planes(np.vstack([planes[:1], planes[:5]])) is None  # an axis without its -face


def _steps(task: str, monkeypatch, box: bool, steps: int = 3):
    if not box:
        monkeypatch.setattr(simulator_module, "_box_of_planes", lambda planes: None)
    scene, poses = task_scene(task), bench_task(task)
    sim = Simulator(scene, 2, dtype=torch.float64, contact=task_contact(task))
    gear = torch.as_tensor(scene.actuator_gear, dtype=torch.float64)
    tau = (torch.tensor(poses.close_action, dtype=torch.float64) * gear).expand(2, sim.nu).contiguous()
    zero = torch.zeros_like(tau)
    q = torch.tensor(poses.touch_q, dtype=torch.float64).expand(2, sim.nq).contiguous()
    qd = torch.zeros(2, sim.nv, dtype=torch.float64)
    outs, params = [], sim.default_params()
    for _ in range(steps):
        out = sim.step(q, qd, Control(tau, zero, zero, zero), params)
        q, qd = out.joint_q, out.joint_qd
        outs.append(out)
    return outs


@pytest.mark.parametrize("task", [pytest.param("repose_cube", marks=pytest.mark.slow)])  # the cube in float64
def test_box_specialisation_changes_no_force(task, monkeypatch):
    fast = _steps(task, monkeypatch, box=True)
    assert sum(float(o.contact_force.sum()) for o in fast) > 0.0  # the scene is in contact
    generic = _steps(task, monkeypatch, box=False)
    for a, b in zip(fast, generic):
        for x, y in zip(a, b):
            torch.testing.assert_close(x, y, rtol=1e-10, atol=1e-12)
