"""dexmots-view: serves the page, refuses a taken port, follows a live file; headless-browser check."""

from __future__ import annotations

import importlib.util
import socket
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from tensordict.nn import TensorDictModule

from dexmots_rl.envs import make_env
from dexmots_rl.envs.tasks.screw_claw import scripted_claw_action
from dexmots_rl.viz import EpisodeRecorder, read_recording
from dexmots_rl.viz.viewer import PortInUseError, ReplayViewer, check_port_free, main

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "browser_check.py"
STEPS = 8


@pytest.fixture(scope="module")
def episodes():
    env = make_env("screw_claw", num_envs=2, differentiable=False, seed=0, max_episode_steps=STEPS, action="torque", goal="pose", initial="open")
    policy = TensorDictModule(scripted_claw_action, in_keys=["desired_goal"], out_keys=["action"])
    return env, [env.rollout(STEPS, policy, tensordict=env.reset(), auto_reset=False, break_when_any_done=False)
                 for _ in range(2)]


@pytest.fixture(scope="module")
def recording(episodes, tmp_path_factory):
    env, rollouts = episodes
    path = tmp_path_factory.mktemp("view") / "run.mcap"
    with EpisodeRecorder(path, env) as rec:
        rec.record_rollout(rollouts[0])
    return path


def _listening_socket():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen()
    return s


def test_viewer_serves_the_page_and_steps_through_frames(recording):
    viewer = ReplayViewer(recording, port=0)
    try:
        assert viewer.port > 0
        with urllib.request.urlopen(viewer.url, timeout=10) as r:
            assert r.status == 200 and b"<html" in r.read(2000).lower()
        viewer.set_frame(5)
        assert viewer.frame == 5
        viewer.set_frame(10**6)  # clamped
        assert viewer.frame == STEPS
        viewer._gui["world"].value = "1"  # one world: the plot shows its reward and reward terms
        assert len(viewer._plot.series) == 2 + len(viewer.rec.reward_terms)
        obj = next(f"part{k}" for k, p in enumerate(viewer.rec.geometry.parts) if p.role == "object")
        assert viewer._handles[obj].batched_positions.shape == (1, 3)
        viewer._gui["world"].value = "all"
        assert viewer._handles[obj].batched_positions.shape == (2, 3)
        # the arrows drawn: those of non-zero length (a zero one would still draw its head)
        points = viewer._handles["arrows"].points
        assert points.ndim == 3 and 1 <= len(points) <= 8
        assert (((points[:, 1] - points[:, 0]) ** 2).sum(-1) > 1e-8).all()
        viewer._toggle_play()
        time.sleep(0.3)
        assert viewer._gui["play"].label == "Pause"
    finally:
        viewer.stop()


def test_taken_port_is_a_clear_error(recording, capsys):
    with _listening_socket() as s:
        port = s.getsockname()[1]
        with pytest.raises(PortInUseError, match=f"port {port} on 127.0.0.1 is already in use"):
            check_port_free("127.0.0.1", port)
        with pytest.raises(PortInUseError):
            ReplayViewer(recording, port=port)
        with pytest.raises(SystemExit, match="already in use"):
            main([str(recording), "--port", str(port)])


@pytest.mark.parametrize("port", ["99999", "-1"])
def test_out_of_range_port_fails_at_once(tmp_path, capsys, port):
    # #16.6: viser used to start, then fail deep in asyncio with an OverflowError traceback; the check
    # comes before the recording is even opened
    with pytest.raises(SystemExit) as err:
        main([str(tmp_path / "any.mcap"), "--port", port])
    assert err.value.code == 2
    assert "--port must be in 0..65535" in capsys.readouterr().err


def test_bad_recording_is_a_clear_error(tmp_path):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 30)
    with pytest.raises(SystemExit, match="bad.mcap: "):
        main([str(bad), "--port", "0"])


def test_live_viewer_follows_a_growing_recording(episodes, tmp_path):
    env, rollouts = episodes
    path = tmp_path / "live.mcap"
    viewer = ReplayViewer(path, port=0, live=True, poll_s=0.05)  # the file does not exist yet
    try:
        rec = EpisodeRecorder(path, env, live=True)
        for episode, rollout in enumerate(rollouts):
            rec.record_rollout(rollout)
            deadline = time.monotonic() + 10
            # the viewer's thread swaps in the grown recording, then moves its frame: wait for both
            while (viewer.rec is None or viewer.rec.num_frames < (episode + 1) * (STEPS + 1)
                   or (episode > 0 and viewer.frame != viewer.rec.num_frames - 1)) and time.monotonic() < deadline:
                time.sleep(0.05)
            assert viewer.rec.num_frames == (episode + 1) * (STEPS + 1)
            assert viewer.frame == viewer.rec.num_frames - 1 or episode == 0  # parked on the end: follows
        rec.close()
        assert read_recording(path).num_frames == 2 * (STEPS + 1)
    finally:
        viewer.stop()


def _browser_check():
    spec = importlib.util.spec_from_file_location("browser_check", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow  # a headless browser
def test_headless_browser_draws_hand_and_object(recording, tmp_path):
    check = _browser_check()
    if check.find_chromium() is None:
        pytest.skip("no Chromium on this machine (apt-get install chromium to run the browser check)")
    result = check.run_check(recording, out=tmp_path / "shot.png", size=(800, 500), timeout=90)
    assert result["ok"], result
    # the claw's links, its knob and the timeline are all drawn
    assert set(result["pixels"]) == {"hand", "object:object"} and result["timeline"], result
    assert min(result["pixels"].values()) >= 200, result
    assert (tmp_path / "shot.png").stat().st_size > 10_000


@pytest.fixture(scope="module")
def articulated_recording(tmp_path_factory):
    """Two worlds of the Allegro hand and the scissors (a free base and a moving half) on the table."""
    from dexmots_rl.assets.hand_scene import hand_object_scene_xml
    from dexmots_rl.assets.objects import load_object
    from dexmots_rl.recording import record_simulation
    from dexmots_rl.sim import ArticulatedSimulator, load_scene

    folder = tmp_path_factory.mktemp("scissors")
    (folder / "scene.xml").write_text(hand_object_scene_xml(load_object("scissors_a"), folder))
    sim = ArticulatedSimulator(load_scene(folder / "scene.xml"), num_worlds=2)
    q, qd = sim.initial_state()
    q[1, -1] = 0.4  # world 1: the scissors opened
    return sim, record_simulation(sim, 4, folder / "scissors.mcap", state=(q, qd))


def test_articulated_recording_carries_every_body(articulated_recording):
    sim, path = articulated_recording
    rec = read_recording(path)
    g = rec.geometry
    assert g.body_names[g.num_hand_links:] == ["object", "object/half_b"] and rec.frames["body_pose"].shape[2] == 18
    roles = {(p.role, p.name) for p in g.parts}
    assert {("palm", "hand"), ("table", "world"), ("object", "object"), ("object", "object/half_b")} <= roles
    assert {p.body for p in g.parts if p.role == "hand"} == set(range(16))  # every link
    # the object's bodies are drawn with their visual meshes (MuJoCo's compiled vertices), not their boxes
    half_b = next(p for p in g.parts if p.name == "object/half_b")
    assert len(half_b.faces) > 500
    # the opened half follows its recorded pose: its mesh turns with the joint
    pose = rec.frames["body_pose"][-1].double().numpy()
    tips = [g.world_points(pose[w], roles=("object",)) for w in range(2)]
    assert abs(np.ptp(tips[0][:, 1]) - np.ptp(tips[1][:, 1])) > 0.01
    viewer = ReplayViewer(path, port=0)
    try:  # the first view frames the hand and the scissors: every vertex is in front of the camera, in view
        cam = viewer.server.initial_camera
        eye, look = np.asarray(cam.position), np.asarray(cam.look_at)
        pts = np.concatenate([g.world_points(pose[w]) + rec.world_offsets[w].numpy() for w in range(2)])
        fwd = (look - eye) / np.linalg.norm(look - eye)
        right = np.cross(fwd, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        up = np.cross(right, fwd)
        rel = pts - eye
        depth = rel @ fwd
        half = np.tan(cam.fov / 2)  # vertical; the browser check's 800 x 500 view is 1.6 times as wide
        assert (depth > 0).all() and (np.abs(rel @ up) / depth).max() < half
        assert (np.abs(rel @ right) / depth).max() < 1.6 * half
        # and it fills the view: the scene spans most of its height or width
        assert max(np.ptp((rel @ up) / depth) / (2 * half), np.ptp((rel @ right) / depth) / (3.2 * half)) > 0.5
        # a bare simulator has no goal: the ghost (which would tint the object) starts hidden
        assert rec.meta["goal"] == "false" and not viewer._handles["goal"].visible
        # the arrows' heads are sized by the scene (the scissors' half diagonal), not 5 cm
        assert 0.005 < viewer._style.head_length < 0.04
    finally:
        viewer.stop()


@pytest.mark.slow  # a headless browser
def test_headless_browser_draws_palm_object_parts_and_table(articulated_recording, tmp_path):
    check = _browser_check()
    if check.find_chromium() is None:
        pytest.skip("no Chromium on this machine (apt-get install chromium to run the browser check)")
    _, path = articulated_recording
    result = check.run_check(path, out=tmp_path / "shot.png", size=(800, 500), timeout=90)
    assert result["ok"], result
    # hiding each group changes the picture where it is drawn: the hand's links, the palm, the table and
    # each of the scissors' halves
    assert set(result["pixels"]) == {"hand", "palm", "table", "object:object", "object:object/half_b"}, result
    assert min(result["pixels"].values()) >= 200, result


def test_a_scene_whose_mjcf_is_gone_is_drawn_from_its_object(tmp_path):
    import shutil

    from dexmots_rl.assets.hand_scene import hand_object_scene_xml
    from dexmots_rl.assets.objects import load_object
    from dexmots_rl.recording.geometry import scene_geometry
    from dexmots_rl.sim import load_scene

    asset = load_object("valve_a")
    folder = tmp_path / "gone"
    folder.mkdir()
    (folder / "scene.xml").write_text(hand_object_scene_xml(asset, folder))
    scene = load_scene(folder / "scene.xml")
    want = scene_geometry(scene)
    shutil.rmtree(folder)
    with pytest.raises(ValueError, match="scene.xml: the scene's MJCF file is gone"):
        scene_geometry(scene)
    got = scene_geometry(scene, asset=asset)
    assert [(p.name, p.role, p.body) for p in got.parts] == [(p.name, p.role, p.body) for p in want.parts]
    assert all(np.array_equal(a.vertices, b.vertices) for a, b in zip(got.parts, want.parts))


def test_the_printed_address_is_the_host_it_serves_on(recording):
    viewer = ReplayViewer(recording, host="0.0.0.0", port=0)
    try:
        assert viewer.url == f"http://0.0.0.0:{viewer.port}/"
    finally:
        viewer.stop()


def test_tool_task_arrows_are_scaled_to_its_forces_and_show_the_target(tmp_path):
    """On a tool task (newtons, not the claw's tens of newtons) the arrows are scaled to the recording's
    forces: none is drawn shorter than its head (a loose cone), and the planned force on the operated joint
    is drawn (a torque about the lever's axis)."""
    from dexmots_rl.recording.geometry import quat_to_mat
    from dexmots_rl.recording.scene_messages import TYPICAL_ARROW_SHARE, TYPICAL_FLOOR
    from dexmots_rl.viz.viewer import ARROW_COLORS

    import torch

    env = make_env("door_handle", num_envs=2, differentiable=False, seed=0, max_episode_steps=6)
    torch.manual_seed(0)  # the random actions (torch's generator): the same contact, whatever ran before
    path = tmp_path / "door.mcap"
    with EpisodeRecorder(path, env) as rec:
        rec.record_rollout(env.rollout(6, None, tensordict=env.reset(), auto_reset=False, break_when_any_done=False))
    recording = read_recording(path)
    target = recording.frames["target_wrench"].double().numpy()
    tree, j = env.base_env.sim.tree, env.base_env.sim.tree.joint_names.index(env.base_env.joint_name)
    lever = recording.frames["body_pose"].double().numpy()[:, :, recording.geometry.num_hand_links + j + 1]
    axis = np.stack([[quat_to_mat(q) @ tree.joint_axis[j] for q in frame] for frame in lever[..., 3:]])
    assert np.abs(target).max() > 0 and np.allclose(target[..., :3], 0)
    assert np.allclose(np.cross(target[..., 3:], axis), 0, atol=1e-9)  # about the lever's axis
    viewer = ReplayViewer(path, port=0)
    try:
        style, (force_scale, torque_scale) = viewer._style, viewer._scales
        forces = np.linalg.norm(recording.frames["object", "wrench"].double().numpy()[..., :3], axis=-1)
        assert forces.max() > 0  # the fingers touch the lever
        assert force_scale * max(np.percentile(forces[forces > 0], 75), TYPICAL_FLOOR[0]) == pytest.approx(
            TYPICAL_ARROW_SHARE * style.max_length)  # a hinge's target is a torque: the forces are the measured
        target_blue = ARROW_COLORS[3].astype(int)
        drawn_targets = 0
        for f in range(recording.num_frames):
            points, colors = viewer._arrow_points(f, [0, 1], recording.world_offsets.double().numpy())
            assert (np.linalg.norm(points[:, 1] - points[:, 0], axis=-1) > style.head_length).all()
            drawn_targets += int((np.abs(colors - target_blue).sum(-1) <= 3).sum())
        assert drawn_targets > 0
    finally:
        viewer.stop()
