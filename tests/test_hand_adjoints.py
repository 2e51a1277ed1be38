"""Hand-written adjoints (``adj_polytope_sdf`` in _object_sdf_kernels.py, ``adj_contact_force`` in
_contact_kernels.py, ``adj_link_inertia`` in _chain_kernels.py) against central finite differences, in float64: the knob's signed
distance at face, edge and corner points, the contact law (against a hinged and a free object) and a link's
mass-matrix and bias-force contribution with respect to every differentiable input.

No ``from __future__ import annotations`` here: warp reads the probe kernels' annotations.
"""

from pathlib import Path

import numpy as np
import pytest
import torch
import warp as wp

from dexmots_rl.sim import Simulator, load_scene
from dexmots_rl.sim._constants import GEOM_SDF

EPS = 1e-6
FREE_BOX = Path(__file__).parent / "assets" / "free_box.xml"


def _saved(ns, device, n, field):
    """A Saved struct whose ``field`` has one row of n slots (what the probe's replay reads back)."""
    saved = ns.Saved()
    fields = {"sdf": ("sdf", "sdf_jac"), "contact": ("contact", "law"), "inertia": ("inertia",)}[field]
    for name, dtype in (("finger", ns.vec7), ("contact", ns.vecC), ("sdf", ns.vec4), ("sdf_jac", ns.mat43),
                        ("law", ns.mat43), ("inertia", ns.matJJ1)):
        setattr(saved, name, wp.zeros((1, n) if name in fields else (0, 1), dtype=dtype, device=device))
    return saved


def _ad_and_fd(sim, probe, inputs: dict, types: dict, weight, saved):
    """d(sum_i out_i)/d(input) by warp's tape through the probe kernel, and by central differences of
    each input component; both as {name: [n, components]}."""
    n = weight.shape[0]

    def run(values, tape=None):
        arrays = {k: wp.array(v, dtype=types[k], device=sim.device, requires_grad=tape is not None)
                  for k, v in values.items()}
        out = wp.zeros(n, dtype=wp.float64, device=sim.device, requires_grad=tape is not None)
        args = [sim.model, saved, *arrays.values(), weight]
        if tape is None:
            wp.launch(probe, dim=n, inputs=args, outputs=[out], device=sim.device)
            return out.numpy()
        with tape:
            wp.launch(probe, dim=n, inputs=args, outputs=[out], device=sim.device)
        tape.backward(grads={out: wp.ones(n, dtype=wp.float64, device=sim.device)})
        return {k: a.grad.numpy().reshape(n, -1) for k, a in arrays.items()}

    ad, fd = run(inputs, wp.Tape()), {}
    for name, value in inputs.items():
        flat = value.reshape(n, -1)
        fd[name] = np.zeros_like(flat)
        for c in range(flat.shape[1]):
            step = np.zeros_like(flat)
            step[:, c] = EPS
            plus, minus = dict(inputs), dict(inputs)
            plus[name], minus[name] = (flat + step).reshape(value.shape), (flat - step).reshape(value.shape)
            fd[name][:, c] = (run(plus) - run(minus)) / (2 * EPS)
    return ad, fd


def _sdf_kernel(ns):
    @wp.kernel(module="unique")
    def probe(m: ns.Model, saved: ns.Saved, p: wp.array(dtype=ns.vec3), weight: wp.array(dtype=ns.vec4),
              out: wp.array(dtype=wp.float64)):
        i = wp.tid()
        sd = ns.object_sdf(m, p[i], saved, 0, i)
        saved.sdf[0, i] = sd  # what the simulator's taped forward does: the adjoint's replay loads it
        out[i] = wp.dot(sd, weight[i])

    return probe


def _points_near_edges(planes: np.ndarray, count: int, smooth: float, rng) -> np.ndarray:
    """Random points within 3 cm of the surface: two in three have their two largest face distances
    within 2 smoothing lengths (edges and corners, where several faces share the weight)."""
    bound = np.abs(planes[:, 3]).max()
    out = []
    while len(out) < count:
        p = rng.uniform(-1.3 * bound, 1.3 * bound, size=3)
        g = np.sort(planes[:, :3] @ p - planes[:, 3])[::-1]
        if abs(g[0]) < 0.03 and (g[0] - g[1] < 2 * smooth or len(out) % 3 == 0):
            out.append(p)
    return np.asarray(out)


def test_polytope_sdf_adjoint_matches_finite_differences(claw_scene):
    assert claw_scene.object_shape != GEOM_SDF and len(claw_scene.object_planes) > 4
    sim = Simulator(claw_scene, num_worlds=1, dtype=torch.float64)
    ns, rng = sim.kernels, np.random.default_rng(0)
    pts = _points_near_edges(np.asarray(claw_scene.object_planes), 48, sim.contact.surface_smoothing, rng)
    n = len(pts)
    weight = wp.array(rng.uniform(-1, 1, size=(n, 4)), dtype=ns.vec4, device=sim.device)
    ad, fd = _ad_and_fd(sim, _sdf_kernel(ns), {"p": pts}, {"p": ns.vec3}, weight, _saved(ns, sim.device, n, "sdf"))
    assert np.abs(fd["p"]).max() > 1.0  # the weighted normal's derivative (~1/smoothing) is exercised
    np.testing.assert_allclose(ad["p"], fd["p"], rtol=1e-5, atol=1e-6 * np.abs(fd["p"]).max())


def _contact_kernel(ns, rad: float, dt: float):
    @wp.kernel(module="unique")
    def probe(m: ns.Model, saved: ns.Saved, p: wp.array(dtype=ns.vec3), sd: wp.array(dtype=ns.vec4),
              Ro: wp.array(dtype=ns.mat33), xo: wp.array(dtype=ns.vec3), vo: wp.array(dtype=ns.vec3),
              wo: wp.array(dtype=ns.vec3), A: wp.array(dtype=ns.matJ3), O: wp.array(dtype=ns.matJ3),
              qdf: wp.array(dtype=ns.vecJ), weight: wp.array(dtype=ns.vecC), out: wp.array(dtype=wp.float64)):
        i = wp.tid()
        res = ns.contact_force(m, p[i], wp.float64(rad), sd[i], Ro[i], xo[i], vo[i], wo[i], 0, A[i], O[i],
                               qdf[i], wp.float64(dt), saved, 0, i)
        saved.contact[0, i] = res
        out[i] = wp.dot(res, weight[i])

    return probe


@pytest.mark.parametrize("object_kind,dt", [("hinge", 0.0), ("hinge", 0.2),  # the free box: its own float64 build
                                           *(pytest.param("free", dt, marks=pytest.mark.slow) for dt in (0.0, 0.02))])
def test_contact_force_adjoint_matches_finite_differences(claw_scene, object_kind, dt):
    """Every differentiable input of the contact law (sphere centre, signed distance and normal, object
    pose and velocity, the finger's joint axes/origins and velocities), with sliding and near-sticking
    tangential velocities; explicit normal damping (dt 0, and always on the claw's hinged knob) and, on a free
    box, damping implicit against the object's mobility (dt 0.02 s: dt kd stiffness mobility up to about 1)."""
    scene = claw_scene if object_kind == "hinge" else load_scene(FREE_BOX)
    sim = Simulator(scene, num_worlds=1, dtype=torch.float64)
    ns, rng = sim.kernels, np.random.default_rng(1)
    n, J, rad = 16, sim.scene.joints_per_finger, 0.08

    def unit(k):
        v = rng.normal(size=(k, 3))
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    # penetration from -2 cm (soft pre-contact) to +1 cm; relative speeds around the friction's slip
    # velocity (0.2 m/s), slow enough that the damping factor stays positive
    inputs = {
        "p": rng.uniform(-0.1, 0.1, (n, 3)),
        "sd": np.concatenate([rad - rng.uniform(-0.02, 0.01, (n, 1)), unit(n)], axis=1),
        "Ro": np.stack([np.linalg.qr(rng.normal(size=(3, 3)))[0] for _ in range(n)]),
        "xo": rng.uniform(-0.05, 0.05, (n, 3)),
        "vo": rng.uniform(-0.1, 0.1, (n, 3)),
        "wo": rng.uniform(-1.0, 1.0, (n, 3)),
        "A": np.stack([unit(J) for _ in range(n)]),
        "O": rng.uniform(-0.1, 0.1, (n, J, 3)),
        "qdf": rng.uniform(-1.0, 1.0, (n, J)),
    }
    types = {"p": ns.vec3, "sd": ns.vec4, "Ro": ns.mat33, "xo": ns.vec3, "vo": ns.vec3, "wo": ns.vec3,
             "A": ns.matJ3, "O": ns.matJ3, "qdf": ns.vecJ}
    weight = wp.array(rng.uniform(-1, 1, (n, 7 + J)), dtype=ns.vecC, device=sim.device)
    ad, fd = _ad_and_fd(sim, _contact_kernel(ns, rad, dt), inputs, types, weight,
                        _saved(ns, sim.device, n, "contact"))
    for name in inputs:
        assert np.abs(fd[name]).max() > 0, name
        np.testing.assert_allclose(ad[name], fd[name], rtol=1e-5, atol=1e-6 * np.abs(fd[name]).max(), err_msg=name)


def _inertia_kernel(ns, link: int):
    @wp.kernel(module="unique")
    def probe(m: ns.Model, saved: ns.Saved, R: wp.array(dtype=ns.mat33), x: wp.array(dtype=ns.vec3),
              acc: wp.array(dtype=ns.vec3), al: wp.array(dtype=ns.vec3), om: wp.array(dtype=ns.vec3),
              A: wp.array(dtype=ns.matJ3), O: wp.array(dtype=ns.matJ3), weight: wp.array(dtype=ns.matJJ1),
              out: wp.array(dtype=wp.float64)):
        i = wp.tid()
        mb = ns.link_inertia(m, link, 0, R[i], x[i], acc[i], al[i], om[i], A[i], O[i], saved, 0)
        saved.inertia[0, link] = mb
        out[i] = wp.ddot(mb, weight[i])

    return probe


def test_link_inertia_adjoint_matches_finite_differences(claw_scene):
    """A link's [mass matrix | bias force] block with respect to its frame, the chain's velocity terms and
    the finger's joint axes and origins (one world per probe: the block is saved per link)."""
    sim = Simulator(claw_scene, num_worlds=1, dtype=torch.float64)
    ns, rng, J = sim.kernels, np.random.default_rng(2), sim.scene.joints_per_finger
    axes = rng.normal(size=(1, J, 3))
    inputs = {
        "R": np.linalg.qr(rng.normal(size=(3, 3)))[0][None],
        "x": rng.uniform(-0.1, 0.1, (1, 3)),
        "acc": rng.uniform(-10, 10, (1, 3)),
        "al": rng.uniform(-5, 5, (1, 3)),
        "om": rng.uniform(-3, 3, (1, 3)),
        "A": axes / np.linalg.norm(axes, axis=2, keepdims=True),
        "O": rng.uniform(-0.1, 0.1, (1, J, 3)),
    }
    types = {"R": ns.mat33, "x": ns.vec3, "acc": ns.vec3, "al": ns.vec3, "om": ns.vec3, "A": ns.matJ3, "O": ns.matJ3}
    weight = wp.array(rng.uniform(-1, 1, (1, J, J + 1)), dtype=ns.matJJ1, device=sim.device)
    for link in range(J):
        probe = _inertia_kernel(ns, link)
        ad, fd = _ad_and_fd(sim, probe, inputs, types, weight, _saved(ns, sim.device, J, "inertia"))
        for name in inputs:
            assert np.abs(fd[name]).max() > 0, (link, name)
            np.testing.assert_allclose(ad[name], fd[name], rtol=1e-5, atol=1e-7 * np.abs(fd[name]).max(),
                                       err_msg=f"link {link}: {name}")
