"""RGB observations: the warp ray caster (sim/_render.py) and the RGBObservation transform (envs/pixels.py)."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest
import torch
from torchrl.envs.utils import check_env_specs

from dexmots_rl.assets import asset_path
from dexmots_rl.envs import make_env
from dexmots_rl.envs.pixels import RGBObservation, tile_images
from dexmots_rl.sim import load_scene
from dexmots_rl.sim._render import LABEL_FLOOR, LABEL_HAND, LABEL_OBJECT, Renderer, _link_capsules, reach_spheres
from simutil import CLAW_OPEN_Q, batch_state

H = W = 48


@pytest.fixture(scope="module")
def sim(make_claw_sim):
    return make_claw_sim(3, dtype=torch.float32)


@pytest.fixture(scope="module")
def renderer(claw_scene):
    return Renderer(claw_scene, H, W)


def _render(renderer, sim, q):
    return renderer.render_state(sim, q, labels=True)


def test_images_are_uint8_and_show_hand_object_and_floor(renderer, sim):
    q, _ = batch_state(sim, CLAW_OPEN_Q)
    img, lab = _render(renderer, sim, q)
    assert img.shape == (3, H, W, 3) and img.dtype == torch.uint8
    assert lab.shape == (3, H, W) and lab.dtype == torch.uint8
    for label in (LABEL_HAND, LABEL_OBJECT, LABEL_FLOOR):
        assert (lab == label).sum(dim=(1, 2)).min() > 10, f"label {label} barely visible"
    # hand and object pixels are coloured differently from the floor (not background)
    floor = img[lab == LABEL_FLOOR].float()
    for label in (LABEL_HAND, LABEL_OBJECT):
        px = img[lab == label].float()
        assert (px.mean(0) - floor.mean(0)).abs().max() > 40
    assert torch.equal(img[0], img[1])  # same state, same image


def test_knob_angle_changes_only_object_pixels(renderer, sim):
    q, _ = batch_state(sim, CLAW_OPEN_Q)
    q[1, 4] = 0.3  # knob turned (the octagon repeats every 45 deg; the marker band breaks the symmetry)
    q[2, 4] = 0.3 + math.pi / 4
    img, lab = _render(renderer, sim, q)
    changed = (img[0] != img[1]).any(-1)
    assert changed.sum() > 5
    assert ((lab[0] == LABEL_OBJECT) | (lab[1] == LABEL_OBJECT))[changed].all()
    assert not torch.equal(img[1], img[2])  # a 45 deg turn of the octagon is still visible


def test_hand_joints_change_the_image(renderer, sim):
    q, _ = batch_state(sim, CLAW_OPEN_Q)
    q[1, :4] = torch.tensor([0.5, -0.6, -0.5, 0.6])  # closed on the knob
    img, lab = _render(renderer, sim, q)
    changed = (img[0] != img[1]).any(-1)
    assert changed.sum() > 20
    assert (lab[0][changed] == LABEL_HAND).any() and (lab[1][changed] == LABEL_HAND).any()


def test_default_camera_keeps_the_whole_reach_in_view(claw_scene, renderer, sim):
    gen = torch.Generator().manual_seed(0)
    lo, hi = torch.as_tensor(claw_scene.dof_lower), torch.as_tensor(claw_scene.dof_upper)
    q = torch.zeros(3, sim.nq)
    q[:, :4] = (lo + (hi - lo) * torch.rand(3, 4, generator=gen)).float()
    q[0, :4] = torch.tensor([math.pi / 2, 0.0, -math.pi / 2, 0.0])  # fully spread
    _, lab = _render(renderer, sim, q)
    border = torch.cat([lab[:, 0], lab[:, -1], lab[:, :, 0], lab[:, :, -1]], -1)
    assert not (border == LABEL_HAND).any() and not (border == LABEL_OBJECT).any()
    centres, radii = reach_spheres(claw_scene, samples=8)
    assert centres.shape[0] == radii.shape[0] > 8


def _pose(scene, object_quat=(1.0, 0.0, 0.0, 0.0)):
    """Body poses [1, B, 7] without a simulator: links at the origin, the object at its base."""
    pose = torch.zeros(1, scene.num_hand_dofs + 1, 7)
    pose[..., 3] = 1.0
    pose[0, -1, :3] = torch.as_tensor(scene.object_base_pos)
    pose[0, -1, 3:] = torch.tensor(object_quat)
    return pose


@pytest.mark.parametrize("geom", ['type="sphere" size="0.2"', 'type="cylinder" size="0.2 0.15"', "sdf"])
def test_other_object_shapes_render(tmp_path: Path, geom):
    if geom == "sdf":
        scene = load_scene(Path(__file__).parent / "assets" / "u_block.xml")
    else:
        claw = asset_path("claw_screw.xml").read_text()
        xml = re.sub(r'<geom name="knob"[^>]*/>', f'<geom name="knob" {geom}/>', claw)
        (tmp_path / "scene.xml").write_text(xml)
        scene = load_scene(tmp_path / "scene.xml")
    r = Renderer(scene, 32, 32, floor_z=-1.0)
    half = math.sin(0.25)
    img, lab = r.render(torch.cat([_pose(scene), _pose(scene, (math.cos(0.25), 0.0, 0.0, half))]), labels=True)
    assert (lab == LABEL_OBJECT).sum(dim=(1, 2)).min() > 5
    assert not torch.equal(img[0], img[1])  # rotation about z is visible (marker band / shape)


def test_capsule_samples_merge_back_into_capsules():
    x, y = torch.eye(3)[0].numpy(), torch.eye(3)[1].numpy()
    line = [(x * s, 0.1) for s in (-1.0, -1 / 3, 1 / 3, 1.0)]  # a capsule geom's 4 samples
    caps = _link_capsules(line + [(x + y, 0.1), (x + y, 0.02)])  # then a bend, then a tip sphere
    assert len(caps) == 3
    (a0, b0, r0), (a1, b1, _), (a2, b2, r2) = caps
    assert (a0 == -x).all() and (b0 == x).all() and r0 == 0.1
    assert (a1 == x).all() and (b1 == x + y).all()
    assert (a2 == b2).all() and r2 == 0.02


def test_bad_inputs(claw_scene, renderer):
    with pytest.raises(ValueError, match="image size"):
        Renderer(claw_scene, 0, 8)
    with pytest.raises(ValueError, match="body_pose"):
        renderer.render(torch.zeros(2, 3, 7))
    with pytest.raises(ValueError, match="pixels"):
        tile_images(torch.zeros(8, 8, 3))


def test_tile_images_places_worlds_row_by_row():
    px = torch.arange(5, dtype=torch.uint8).view(5, 1, 1, 1).expand(5, 2, 3, 3)
    mosaic = tile_images(px, cols=2, pad=1, pad_value=255)
    assert mosaic.shape == (3 * 3 - 1, 2 * 4 - 1, 3)
    assert mosaic[0, 0, 0] == 0 and mosaic[0, 4, 0] == 1 and mosaic[3, 0, 0] == 2 and mosaic[6, 0, 0] == 4
    assert mosaic[6, 4, 0] == 255 and mosaic[2, 0, 0] == 255  # missing cell and gap


def test_rgb_observation_transform_specs_and_rollout():
    env = make_env("screw_claw", num_envs=2, differentiable=False, seed=0, action="torque", goal="pose", initial="open")
    env.append_transform(RGBObservation(height=H, width=W))
    spec = env.observation_spec["pixels"]
    assert spec.shape == (2, H, W, 3) and spec.dtype == torch.uint8
    check_env_specs(env)
    td = env.rollout(4)
    assert td["next", "pixels"].shape == (2, 4, H, W, 3)
    assert not torch.equal(td["next", "pixels"][:, 0], td["next", "pixels"][:, -1])  # fingers moved
    assert "pixels" in env.reset().keys()


def test_make_env_obs_rgb_and_standalone_forward(sim):
    env = make_env("screw_claw", num_envs=2, differentiable=False, seed=0, obs="rgb", action="torque", goal="pose", initial="open")
    td = env.reset()
    assert td["pixels"].shape == (2, 64, 64, 3)
    # outside an env (e.g. relabelling stored states): pass the simulator; leading dims are kept
    t = RGBObservation(height=16, width=16, sim=sim)
    out = t(td.select(("sim", "joint_q")).unsqueeze(0))
    assert out["pixels"].shape == (1, 2, 16, 16, 3)
