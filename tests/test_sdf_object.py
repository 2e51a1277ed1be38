"""Non-convex objects: a U-shaped mesh is simulated through its signed-distance grid."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from dexmots_rl.sim import Simulator, load_scene
from dexmots_rl.sim._constants import GEOM_SDF

ASSET = Path(__file__).parent / "assets" / "u_block.xml"


@pytest.fixture(scope="module")
def sim():
    return Simulator(load_scene(ASSET), num_worlds=3, dtype=torch.float64, substeps=4)


def _state(sim, finger_x, hinge=0.0):
    q, qd = sim.initial_state()
    q[:, 0] = torch.as_tensor(finger_x, dtype=torch.float64)
    q[:, 1] = hinge
    return q, qd


def test_non_convex_mesh_uses_an_sdf_grid(sim):
    scene = sim.scene
    assert scene.object_shape == GEOM_SDF
    assert scene.object_sdf.ndim == 3 and min(scene.object_sdf.shape) > 8
    assert scene.object_sdf.min() < 0 < scene.object_sdf.max()


def test_notch_is_free_space_while_the_arm_is_solid(sim):
    # finger sphere (r = 0.02) at the U's origin sits in the notch, 0.05 from every wall: its convex hull
    # would report 7 cm of penetration; inside the left arm it really penetrates
    q, qd = _state(sim, [0.30, 0.20, 0.70])
    out = sim.step(q, qd, sim.zero_control(), sim.default_params())
    notch, arm, outside = out.contact_force.tolist()
    assert notch < 1.0
    assert arm > 100.0
    assert outside < 1e-3
    assert out.wrench[1, 0] > 0  # the arm is pushed away from the finger (+x)


def test_sdf_contact_gradients_match_finite_differences(sim):
    q, qd = _state(sim, [0.225, 0.23, 0.235], hinge=0.1)
    qd[:, 0] = 0.3
    params = sim.default_params()
    weights = [torch.randn(t.shape, dtype=torch.float64, generator=torch.Generator().manual_seed(i))
               for i, t in enumerate(sim.step(q, qd, sim.zero_control(), params)[:4])]

    def loss(q_in):
        out = sim.step(q_in, qd, sim.zero_control(), params)
        return sum((w * t).sum() for w, t in zip(weights, out[:4]))

    q_var = q.clone().requires_grad_()
    (grad,) = torch.autograd.grad(loss(q_var), q_var)
    assert sim.step(q, qd, sim.zero_control(), params).contact_force.min() > 1.0
    eps = 1e-6
    for w in range(3):
        for i in range(2):
            e = torch.zeros_like(q)
            e[w, i] = eps
            fd = (loss(q + e) - loss(q - e)).item() / (2 * eps)
            assert grad[w, i].item() == pytest.approx(fd, rel=1e-4, abs=1e-6)
