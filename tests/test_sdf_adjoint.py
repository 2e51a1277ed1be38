"""The hand-written adjoint of the convex-polytope signed distance (kernels.adj_polytope_sdf) against
central finite differences, in float64, at points near faces, edges and corners of the claw's knob.

No ``from __future__ import annotations`` here: warp reads the probe kernel's annotations.
"""

import numpy as np
import pytest
import torch
import warp as wp

from dexmots_rl.sim import Simulator
from dexmots_rl.sim.model import SHAPE_SDF

EPS = 1e-6


def _probe_kernel(ns, dtype):
    vec3, vec4 = ns.vec3, ns.vec4

    @wp.kernel(module="unique")
    def probe(m: ns.Model, saved: ns.Saved, p: wp.array(dtype=vec3), weight: wp.array(dtype=vec4),
              out: wp.array(dtype=dtype)):
        i = wp.tid()
        sd = ns.object_sdf(m, p[i], saved, 0, i)
        saved.sdf[0, i] = sd  # what the simulator's taped forward does: the adjoint's replay loads it
        out[i] = wp.dot(sd, weight[i])

    return probe


def _points_near_edges(planes: np.ndarray, count: int, smooth: float, rng) -> np.ndarray:
    """Random points within 3 cm of the surface whose two largest face distances are within 2 smoothing
    lengths of each other (edges and corners, where several faces share the weight), plus face points."""
    bound = np.abs(planes[:, 3]).max()
    out = []
    while len(out) < count:
        p = rng.uniform(-1.3 * bound, 1.3 * bound, size=3)
        g = np.sort(planes[:, :3] @ p - planes[:, 3])[::-1]
        if abs(g[0]) < 0.03 and (g[0] - g[1] < 2 * smooth or len(out) % 3 == 0):
            out.append(p)
    return np.asarray(out)


def test_polytope_sdf_adjoint_matches_finite_differences(claw_scene):
    assert claw_scene.object_shape != SHAPE_SDF and len(claw_scene.object_planes) > 4
    sim = Simulator(claw_scene, num_worlds=1, dtype=torch.float64)
    ns, dtype = sim.kernels, wp.float64
    probe = _probe_kernel(ns, dtype)
    rng = np.random.default_rng(0)
    pts = _points_near_edges(np.asarray(claw_scene.object_planes), 48, sim.contact.surface_smoothing, rng)
    n = len(pts)
    weight = wp.array(rng.uniform(-1, 1, size=(n, 4)), dtype=ns.vec4, device=sim.device)
    saved = ns.Saved()
    saved.sdf = wp.zeros((1, n), dtype=ns.vec4, device=sim.device)
    saved.finger = wp.zeros((0, 1), dtype=ns.vec7, device=sim.device)
    saved.contact = wp.zeros((0, 1), dtype=ns.vecC, device=sim.device)
    saved.hit = wp.zeros((0, 1), dtype=wp.int32, device=sim.device)

    def run(points, tape=None):
        p = wp.array(points, dtype=ns.vec3, device=sim.device, requires_grad=tape is not None)
        out = wp.zeros(n, dtype=dtype, device=sim.device, requires_grad=tape is not None)
        if tape is None:
            wp.launch(probe, dim=n, inputs=[sim.model, saved, p, weight], outputs=[out], device=sim.device)
            return out.numpy()
        with tape:
            wp.launch(probe, dim=n, inputs=[sim.model, saved, p, weight], outputs=[out], device=sim.device)
        tape.backward(grads={out: wp.ones(n, dtype=dtype, device=sim.device)})
        return p.grad.numpy()

    ad = run(pts, wp.Tape())
    fd = np.stack([(run(pts + EPS * e) - run(pts - EPS * e)) / (2 * EPS) for e in np.eye(3)], axis=1)
    assert np.abs(fd).max() > 1.0  # the weighted normal's derivative (~1/smoothing) is exercised
    np.testing.assert_allclose(ad, fd, rtol=1e-5, atol=1e-6 * np.abs(fd).max())
