"""dexmots-view: serves the page, refuses a taken port, follows a live file; headless-browser check."""

from __future__ import annotations

import importlib.util
import socket
import time
import urllib.request
from pathlib import Path

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
        assert viewer._handles["object"].batched_positions.shape == (1, 3)
        viewer._gui["world"].value = "all"
        assert viewer._handles["object"].batched_positions.shape == (2, 3)
        assert viewer._handles["arrows"].points.shape == (8, 2, 3)
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


def test_headless_browser_draws_hand_and_object(recording, tmp_path):
    check = _browser_check()
    if check.find_chromium() is None:
        pytest.skip("no Chromium on this machine (apt-get install chromium to run the browser check)")
    result = check.run_check(recording, out=tmp_path / "shot.png", size=(800, 500), timeout=90)
    assert result["ok"], result
    # the hand, the object and the timeline are all drawn (#16.9)
    assert result["hand_pixels"] >= 200 and result["object_pixels"] >= 200 and result["timeline"], result
    assert (tmp_path / "shot.png").stat().st_size > 10_000
