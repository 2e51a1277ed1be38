"""Mesh geoms of an articulated object collide with the fingers through their signed-distance grid
(sim/_mesh_sdf.py, ``grid_distance`` in sim/_kernel_funcs.py, ``finger_contact`` in sim/_hand_kernels.py)."""

import functools
import tempfile
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
import warp as wp

from dexmots_rl.assets.hand_scene import hand_object_scene_xml
from dexmots_rl.assets.objects import load_object
from dexmots_rl.sim import load_scene
from dexmots_rl.sim._articulated import ArticulatedSimulator
from dexmots_rl.sim._constants import GEOM_SDF, SDF_PAD
from dexmots_rl.sim._hand_kernels import build_hand_kernels
from dexmots_rl.sim._kernel_funcs import build_funcs
from dexmots_rl.sim._mesh_sdf import sdf_grid

vec3d, vec4d = wp.types.vector(3, wp.float64), wp.types.vector(4, wp.float64)
mat33d = wp.types.matrix((3, 3), wp.float64)


@functools.lru_cache(maxsize=None)
def _grid_kernel():
    grid_distance = build_funcs(wp.float64).grid_distance

    @wp.kernel(module="unique")
    def evaluate(values: wp.array(dtype=wp.float64), grid: wp.vec4i, half: vec3d, points: wp.array(dtype=vec3d),
                 out: wp.array(dtype=vec4d)):
        i = wp.tid()
        out[i] = grid_distance(values, grid, half, points[i])

    return evaluate


@functools.lru_cache(maxsize=None)
def _body_kernel(geoms: int):
    geom_distance = build_hand_kernels(wp.float64, 4, 4, 5, 2, geoms).geom_distance

    @wp.kernel(module="unique")
    def nearest(kind: wp.array(dtype=wp.int32), pos: wp.array(dtype=vec3d), rot: wp.array(dtype=mat33d),
                size: wp.array(dtype=vec3d), grid: wp.array(dtype=wp.vec4i), values: wp.array(dtype=wp.float64),
                points: wp.array(dtype=vec3d), out: wp.array(dtype=wp.float64)):
        i = wp.tid()
        best = wp.float64(1.0e6)
        for g in range(geoms):
            if kind[g] >= 0:
                q = wp.transpose(rot[g]) * (points[i] - pos[g])
                best = wp.min(best, geom_distance(kind[g], size[g], grid[g], values, q)[0])
        out[i] = best

    return nearest


def _grid_distance(values, lo, cell, points):
    half = 0.5 * cell * (np.array(values.shape) - 1)
    out = wp.zeros(len(points), dtype=vec4d, device="cpu")
    wp.launch(_grid_kernel(), dim=len(points), device="cpu",
              inputs=[wp.array(values.reshape(-1), dtype=wp.float64), wp.vec4i(0, *values.shape), vec3d(*half),
                      wp.array(points - (lo + half), dtype=vec3d), out])
    return out.numpy()


def test_grid_distance_matches_the_exact_signed_distance():
    """A torus (a hole, like a finger ring): the interpolated distance is trimesh's exact signed distance within
    the grid's resolution inside the grid, an upper bound outside it, and its normal points off the surface."""
    torus = trimesh.creation.torus(0.02, 0.006, major_sections=48, minor_sections=24)
    values, lo, cell = sdf_grid(torus.vertices, torus.faces, pad=0.01)
    grid_points = lo + cell * np.stack([np.random.default_rng(1).integers(0, n, 200) for n in values.shape], 1)
    np.testing.assert_allclose(values[tuple(((grid_points - lo) / cell).round().astype(int).T)],
                               -trimesh.proximity.signed_distance(torus, grid_points), atol=1e-6)
    rng = np.random.default_rng(0)
    hi = lo + cell * (np.array(values.shape) - 1)
    inside = rng.uniform(lo, hi, (400, 3))
    outside = rng.uniform(lo - 0.03, hi + 0.03, (400, 3))
    outside = outside[((outside < lo) | (outside > hi)).any(1)]
    got_in, got_out = _grid_distance(values, lo, cell, inside), _grid_distance(values, lo, cell, outside)
    exact_in = -trimesh.proximity.signed_distance(torus, inside)
    exact_out = -trimesh.proximity.signed_distance(torus, outside)
    assert np.abs(got_in[:, 0] - exact_in).max() < 0.5 * cell
    assert (got_out[:, 0] >= exact_out - 0.5 * cell).all() and (got_out[:, 0] > 0).all()
    # the centre of the hole: 14 mm from the tube
    assert _grid_distance(values, lo, cell, np.zeros((1, 3)))[0, 0] == pytest.approx(0.014, abs=0.5 * cell)
    clear = exact_in > 2 * cell  # away from the surface and the hole's axis (the distance's ridge)
    clear &= np.linalg.norm(inside[:, :2], axis=1) > 0.005
    closest, _, _ = trimesh.proximity.closest_point(torus, inside[clear])
    away = (inside[clear] - closest) / np.linalg.norm(inside[clear] - closest, axis=1, keepdims=True)
    assert np.einsum("ij,ij->i", got_in[clear, 1:], away).min() > 0.95


def _scissors():
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scene.xml"
        asset = load_object("scissors_a")
        path.write_text(hand_object_scene_xml(asset, tmp))
        return load_scene(path), asset.params


def test_a_sphere_fits_in_the_scissors_ring():
    """The finger ring's hole is free space: its centre is a ring radius from the ring's SDF, wider than every
    sphere of the Allegro's fingers (the 12 mm fingertip too), so a tip fits in it; the ring's oriented bounding
    box holds the centre."""
    scene, p = _scissors()
    g = scene.geoms
    ring = int(np.flatnonzero(g.kind[0] == GEOM_SDF)[0])
    assert (g.kind == GEOM_SDF).sum() == 2 and (g.kind[0] != GEOM_SDF).sum() >= 2
    centre = np.array([-p["handle_length"], p["handle_spread"], 0.75 * p["thickness"]])  # base half's ring
    band = centre + [p["ring_radius"] + 0.5 * p["ring_band"], 0.0, 0.0]
    above = band + [0.0, 0.0, 0.75 * p["thickness"] + 0.004]
    points = np.stack([centre, band, above])
    out = wp.zeros(3, dtype=wp.float64, device="cpu")
    wp.launch(_body_kernel(g.kind.shape[1]), dim=3, device="cpu",
              inputs=[wp.array(g.kind[0], dtype=wp.int32), wp.array(g.pos[0], dtype=vec3d),
                      wp.array(g.rot[0], dtype=mat33d), wp.array(g.size[0], dtype=vec3d),
                      wp.array(g.grid[0], dtype=wp.vec4i), wp.array(g.sdf_values, dtype=wp.float64),
                      wp.array(points, dtype=vec3d), out])
    hole, in_band, over = out.numpy()
    assert hole == pytest.approx(p["ring_radius"], abs=1.0e-3)
    assert hole > max(scene.point_radius) + 1.0e-3
    assert in_band < -0.5 * p["ring_band"] + 1.0e-3  # inside the band
    assert over == pytest.approx(0.004, abs=5.0e-4)
    assert np.all(g.size[0, ring] > SDF_PAD)
    ring_mesh = load_object("scissors_a").meshes["ring_a"]
    assert ring_mesh.bounding_box_oriented.contains([centre])[0]  # the box it collided as holds the hole


@pytest.mark.slow  # the tool scene's float64 build
def test_gradient_through_a_mesh_contact_matches_finite_differences():
    """A fingertip pressing down on the scissors' ring (a mesh geom): d(state after one step)/d(state), in
    float64, against central differences, over the finger's joints and the base's position."""
    scene, p = _scissors()
    sim = ArticulatedSimulator(scene, 1, dtype=torch.float64, substeps=4)
    q, qd = sim.initial_state()
    pose, _ = sim.observe(q)
    # the index fingertip's sphere (finger 0, last link, its last sample) in the world
    link = scene.joints_per_finger - 1
    sphere = (link + 1) * scene.points_per_link - 1
    x, wxyz = pose[0, link, :3].numpy(), pose[0, link, 3:].numpy()
    rot = trimesh.transformations.quaternion_matrix(wxyz)[:3, :3]
    centre, radius = x + rot @ scene.point_pos[sphere], float(scene.point_radius[sphere])
    # the outer side of the base half's ring, away from its shank and blade; the sphere 1.37 mm into its top
    # face, off the grid's planes (the interpolant's gradient, the normal, turns where a cell face is crossed)
    top = np.array([-p["handle_length"] - p["ring_radius"] - 0.5 * p["ring_band"], p["handle_spread"],
                    1.5 * p["thickness"]])
    nu = sim.nu
    q[0, nu:nu + 3] = torch.as_tensor(centre - [0.00029, 0.00017, radius - 0.00137] - top)
    params, ctrl = sim.default_params(), sim.zero_control()
    assert float(sim.step(q, qd, ctrl, params).contact_force[0]) > 0.5
    weights = torch.randn(sim.nv, generator=torch.Generator().manual_seed(0), dtype=torch.float64)

    def loss(q_in):
        o = sim.step(q_in, qd, ctrl, params)
        return (o.joint_qd[0] * weights).sum() + o.wrench.sum() * 1e-2

    q_var = q.clone().requires_grad_(True)
    (grad,) = torch.autograd.grad(loss(q_var), q_var)
    coords = [0, 1, 2, 3, nu, nu + 1, nu + 2]
    eps, fd = 1e-6, []
    with torch.no_grad():
        for i in coords:
            e = torch.zeros_like(q)
            e[0, i] = eps
            fd.append((loss(q + e) - loss(q - e)).item() / (2 * eps))
    fd = np.array(fd)
    assert np.abs(fd).max() > 1e-2
    np.testing.assert_allclose(grad[0, coords].numpy(), fd, rtol=1e-4, atol=1e-6 * np.abs(fd).max())
