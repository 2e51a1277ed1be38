"""RGB images of task operate: the mesh ray caster (sim/_mesh_render.py) on one object of every library class."""

from __future__ import annotations

import pytest
import torch

from dexmots_rl.assets.objects import list_objects
from dexmots_rl.envs import make_env
from dexmots_rl.envs.tasks.allegro.operate_object import build_scene
from dexmots_rl.sim import LABEL_TABLE, ArticulatedSimulator, MeshRenderer, Renderer, make_renderer
from dexmots_rl.sim._mesh_render import FIRST_BODY_LABEL

H = W = 48
FIRST_OF_CLASS = list({cls: name for name, cls in reversed(list_objects())}.values())


@pytest.fixture(scope="module", params=FIRST_OF_CLASS)
def scene(request):
    scene, asset = build_scene(request.param)
    sim = ArticulatedSimulator(scene, 3)
    return request.param, sim, asset, MeshRenderer(scene, H, W)


def _state(sim, asset, operated: float = 0.9):
    """Three worlds at rest; world 1 with the operated joint ``operated`` of the way across its range."""
    q, _ = sim.initial_state()
    tree = sim.tree
    j = tree.joint_names.index(asset.operated_joint or tree.joint_names[0])
    lo, hi = (float(v) for v in tree.joint_range[j])
    col = sim.nu + 7 * tree.free + j
    rest = float(q[0, col])
    far = hi if hi - rest >= rest - lo else lo
    q[1, col] = rest + operated * (far - rest)
    return q, j


def test_palm_links_every_part_and_the_table_are_drawn(scene):
    name, sim, asset, r = scene
    q, _ = _state(sim, asset)
    img, lab = r.render_state(sim, q, labels=True)
    assert img.shape == (3, H, W, 3) and img.dtype == torch.uint8 and lab.shape == (3, H, W)
    assert torch.equal(img[0], img[2])  # same state, same image
    counts = {body: int((lab[0] == r.label(body)).sum()) for body in r.body_names}
    for body in sim.tree.body_names:
        assert counts[body] > 3, f"{name}: object body {body!r} covers {counts[body]} pixels"
    palm = [b for b, role in zip(r.body_names, r.body_roles) if role == "palm"]
    assert palm and all(counts[b] > 20 for b in palm), f"{name}: palm {counts}"
    links = [b for b, role in zip(r.body_names, r.body_roles) if role == "hand"]
    assert len(links) == sim.nu and sum(counts[b] > 0 for b in links) >= 10  # the thumb hides under the palm
    assert (lab[0] == LABEL_TABLE).sum() > 0.1 * H * W
    # each object body's pixels wear its own colour: distinct from the table's and from each other part's
    table = img[0][lab[0] == LABEL_TABLE].float().mean(0)
    means = [img[0][lab[0] == r.label(b)].float().mean(0) for b in sim.tree.body_names]
    for body, mean in zip(sim.tree.body_names, means):
        assert (mean - table).abs().max() > 25, f"{name}: {body!r} looks like the table"
    colours = {tuple(p.rgba[:3]) for p in r.geometry.parts if p.role == "object"}
    assert len(colours) == sim.tree.num_bodies, f"{name}: parts share a colour"


def test_moving_the_operated_joint_changes_only_its_parts_pixels(scene):
    name, sim, asset, r = scene
    q, j = _state(sim, asset)
    img, lab = r.render_state(sim, q, labels=True)
    changed = (img[0] != img[1]).any(-1)
    assert changed.sum() > 3, f"{name}: operating joint {j} changes {int(changed.sum())} pixels"
    moved = [r.label(b) for b, on in zip(sim.tree.body_names, sim.tree.ancestor[:, j]) if on]
    seen = torch.zeros_like(changed)
    for label in moved:
        seen |= (lab[0] == label) | (lab[1] == label)
    assert seen[changed].all(), f"{name}: pixels changed where the moving part is in neither image"


def test_default_camera_keeps_the_hand_reach_and_object_in_view(scene):
    name, sim, asset, r = scene
    gen = torch.Generator().manual_seed(0)
    lo, hi = (torch.as_tensor(v, dtype=torch.float32) for v in (sim.scene.dof_lower, sim.scene.dof_upper))
    q, _ = sim.initial_state()
    q[:, :sim.nu] = lo + (hi - lo) * torch.rand(3, sim.nu, generator=gen)
    _, lab = r.render_state(sim, q, labels=True)
    border = torch.cat([lab[:, 0], lab[:, -1], lab[:, :, 0], lab[:, :, -1]], -1)
    assert not (border >= FIRST_BODY_LABEL).any(), f"{name}: a body touches the image border"


def test_bad_inputs_and_renderer_choice(scene, claw_scene):
    _, sim, _, r = scene
    with pytest.raises(ValueError, match="body_pose"):
        r.render(torch.zeros(2, 3, 7))
    with pytest.raises(KeyError, match="no drawn body"):
        r.label("nose")
    with pytest.raises(ValueError, match="image size"):
        MeshRenderer(sim.scene, 0, 8, geometry=r.geometry)
    with pytest.raises(ValueError, match="cuda:7"):
        MeshRenderer(sim.scene, 8, 8, device="cuda:7", geometry=r.geometry)
    assert isinstance(make_renderer(sim.scene, height=8, width=8), MeshRenderer)
    assert type(make_renderer(claw_scene, height=8, width=8)) is Renderer


def test_make_env_operate_obs_rgb():
    env = make_env("operate", object=FIRST_OF_CLASS[0], num_envs=2, differentiable=False, seed=0, obs="rgb")
    assert env.observation_spec["pixels"].shape == (2, 64, 64, 3)
    td = env.rollout(3, break_when_any_done=False)
    assert td["next", "pixels"].shape == (2, 3, 64, 64, 3) and td["next", "pixels"].dtype == torch.uint8
    assert not torch.equal(td["pixels"][:, 0], td["next", "pixels"][:, -1])  # the random actions moved the fingers


@pytest.mark.slow  # CUDA code generation of the mesh renderer
def test_mesh_renderer_compiles_to_ptx_without_a_gpu():
    from dexmots_rl.sim._aot import compile_mesh_renderer

    row = compile_mesh_renderer("cuda", arch=90)
    assert row["ok"], row.get("error")
    assert row["artifact"].endswith(".sm90.ptx") and "mesh_render_kernel" in row["kernel"]


def test_a_partnet_urdf_object_is_drawn(tmp_path):
    """A PartNet-Mobility-style folder: its links' OBJ pieces (open ones too) are drawn, each part in view."""
    from partnet_fixtures import stapler

    env = make_env("operate", num_envs=1, object=str(stapler(tmp_path)), differentiable=False, seed=0, obs="rgb",
                   initial="open")
    td = env.reset()
    r, sim = env.transform[-1].renderer, env.base_env.sim
    _, lab = r.render_state(sim, td["sim", "joint_q"], labels=True)
    for body in sim.tree.body_names:
        assert (lab == r.label(body)).sum() > 3, f"{body!r} is not drawn"
    assert td["pixels"].shape == (1, 64, 64, 3)
