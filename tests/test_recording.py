"""MCAP recordings: exact round trip, Foxglove schemas, clear errors for damaged files, dexmots-record."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
import torch
from mcap.reader import make_reader
from tensordict.nn import TensorDictModule

from dexmots_rl.envs import make_env
from dexmots_rl.apps import record
from dexmots_rl.envs.tasks.screw_claw import scripted_claw_action
from dexmots_rl.viz import EpisodeRecorder, RecordingFormatError, read_recording
from dexmots_rl.recording.geometry import scene_geometry

STEPS, WORLDS, EPISODES = 5, 2, 2


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    env = make_env("screw_claw", num_envs=WORLDS, differentiable=False, seed=0, max_episode_steps=STEPS, action="torque", goal="pose", initial="open")
    policy = TensorDictModule(scripted_claw_action, in_keys=["desired_goal"], out_keys=["action"])
    path = tmp_path_factory.mktemp("rec") / "run.mcap"
    rollouts = []
    with EpisodeRecorder(path, env, start_time_ns=0) as rec:
        for _ in range(EPISODES):
            rollouts.append(env.rollout(STEPS, policy, tensordict=env.reset(), auto_reset=False,
                                        break_when_any_done=False))
            rec.record_rollout(rollouts[-1])
    return env, path, rollouts


def _states(rollout):
    """The recorded frames of one rollout, [T + 1, N]: its first state, then every next state."""
    first = rollout[:, :1].exclude("next", "action")
    nxt = rollout.get("next")
    keys = [k for k in first.keys(True, True) if k in nxt.keys(True, True)]
    return torch.cat([first.select(*keys), nxt.select(*keys)], 1).transpose(0, 1)


def test_round_trip_is_exact(recorded):
    env, path, rollouts = recorded
    rec = read_recording(path)
    assert rec.num_frames == EPISODES * (STEPS + 1) and rec.num_worlds == WORLDS
    assert rec.episode.tolist() == [e for e in range(EPISODES) for _ in range(STEPS + 1)]
    assert torch.allclose(rec.time, torch.arange(rec.num_frames, dtype=torch.float64) * env.base_env.sim.dt)
    assert rec.meta["task"] == "screw_claw" and rec.meta["dtype"] == "float32"
    assert rec.reward_terms == sorted(env.base_env.reward_terms)
    for e, rollout in enumerate(rollouts):
        got = rec.frames[e * (STEPS + 1) : (e + 1) * (STEPS + 1)]
        want = _states(rollout)
        for key in [("object", "q"), ("object", "wrench"), ("hand", "q"), ("sim", "joint_q"), ("task", "goal"),
                    ("task", "step"), "success"]:
            assert torch.equal(got[key], want[key]), key
        assert torch.equal(got["reward"][1:], rollout["next", "reward"].transpose(0, 1))
        assert (got["reward"][0] == 0).all()
        for name in env.base_env.reward_terms:
            assert torch.equal(got["reward_terms", name][1:], rollout["next", "reward_terms", name].transpose(0, 1))
        poses, _ = env.base_env.sim.observe(want["sim", "joint_q"].reshape(-1, want["sim", "joint_q"].shape[-1]))
        assert torch.equal(got["body_pose"], poses.reshape(got["body_pose"].shape))
        assert torch.equal(got["body_pose"][..., -1, :], want["object", "pose"])
    # the goal ghost: the knob turned by the goal angle about z
    goal = rec.frames["task", "goal"][0, :, 0].double()
    quat = rec.frames["goal_pose"][0, :, 3:].double()
    assert torch.allclose(quat[:, 0], torch.cos(goal / 2), atol=1e-6)
    assert torch.allclose(quat[:, 3], torch.sin(goal / 2), atol=1e-6)
    # the target wrench is the reference torque about the hinge while the reference ramps
    assert (rec.frames["target_wrench"][1:STEPS, :, 5].abs() > 0).all()


def test_geometry_round_trip(recorded):
    env, path, _ = recorded
    want, got = scene_geometry(env.base_env.sim.scene), read_recording(path).geometry
    assert got.body_names == want.body_names and got.num_hand_links == want.num_hand_links == 4
    assert len(got.parts) == len(want.parts)
    for a, b in zip(got.parts, want.parts):
        assert (a.name, a.role, a.body) == (b.name, b.role, b.body)
        assert (a.vertices == b.vertices).all() and (a.faces == b.faces).all()
        assert a.rgba == pytest.approx(b.rgba)
    assert (got.ghost_vertices == want.ghost_vertices).all() and (got.ghost_faces == want.ghost_faces).all()


def test_mcap_carries_foxglove_schemas_and_zstd_chunks(recorded):
    from mcap_protobuf.decoder import DecoderFactory

    _, path, _ = recorded
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        topics = {c.topic: (summary.schemas[c.schema_id].name, c.message_encoding) for c in summary.channels.values()}
        assert topics == {"/tf": ("foxglove.FrameTransforms", "protobuf"),
                          "/scene": ("foxglove.SceneUpdate", "protobuf"),
                          "/scene/wrench": ("foxglove.SceneUpdate", "protobuf"),
                          "/dexmots/step": ("dexmots.Step", "json")}
        assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
        # decoded by the generic protobuf decoder, as Foxglove does
        _, _, _, tf = next(reader.iter_decoded_messages(topics=["/tf"]))
        frames = {t.child_frame_id for t in tf.transforms}
        assert {"world0", "world0/right_proximal", "world0/left_distal", "world0/object", "world1/goal"} <= frames
        _, _, _, scene = next(reader.iter_decoded_messages(topics=["/scene"]))
        ids = {e.id: e for e in scene.entities}
        assert ids["world1/part2"].frame_locked and ids["world1/part2"].frame_id == "world1/left_proximal"
        assert all(len(e.triangles) == 1 for e in scene.entities)
        assert ids["world0/goal"].triangles[0].color.a < 1
        arrows = [m for _, _, _, m in reader.iter_decoded_messages(topics=["/scene/wrench"])]
        assert len(arrows) == EPISODES * (STEPS + 1) and any(e.arrows for m in arrows for e in m.entities)
        _, _, msg = next(reader.iter_messages(topics=["/dexmots/step"]))
        assert set(json.loads(msg.data)) >= {"reward", "success", "object_q", "wrench", "target_wrench", "reward_terms"}


@pytest.mark.parametrize("damage", ["half", "tail", "flip", "garbage", "empty"])
def test_damaged_files_fail_with_one_clear_error(recorded, tmp_path, damage):
    data = recorded[1].read_bytes()
    mid = len(data) // 2
    bad = {"half": data[:mid], "tail": data[:-20], "flip": data[:mid] + bytes([data[mid] ^ 0xFF]) + data[mid + 1 :],
           "garbage": b"definitely not mcap" * 10, "empty": b""}[damage]
    path = tmp_path / "bad.mcap"
    path.write_bytes(bad)
    with pytest.raises(RecordingFormatError, match="bad.mcap: .*(truncated|corrupted|not a valid MCAP)"):
        read_recording(path)


def test_every_single_byte_flip_or_cut_is_caught(recorded, tmp_path):
    data = recorded[1].read_bytes()
    path = tmp_path / "bad.mcap"
    for k in range(0, len(data), max(1, len(data) // 40)):
        for bad in (data[:k] + bytes([data[k] ^ 0x5A]) + data[k + 1 :], data[:k]):
            path.write_bytes(bad)
            with pytest.raises(RecordingFormatError):
                read_recording(path)


def test_other_mcap_files_and_missing_files_are_refused(tmp_path):
    from mcap.writer import Writer

    other = tmp_path / "other.mcap"
    with open(other, "wb") as f:
        w = Writer(f)
        w.start()
        w.finish()
    with pytest.raises(RecordingFormatError, match="not a dexmots-recording"):
        read_recording(other)
    with pytest.raises(RecordingFormatError, match="no such recording"):
        read_recording(tmp_path / "missing.mcap")


def test_writes_are_atomic_and_live_mode_writes_each_episode(recorded, tmp_path):
    env, path, rollouts = recorded
    out = tmp_path / "run.mcap"
    out.write_bytes(path.read_bytes())
    with pytest.raises(RuntimeError, match="boom"):
        with EpisodeRecorder(out, env) as rec:
            rec.record_rollout(rollouts[0])
            raise RuntimeError("boom")
    assert out.read_bytes() == path.read_bytes()  # the failed run replaced nothing
    live = EpisodeRecorder(tmp_path / "live.mcap", env, live=True)
    live.record_rollout(rollouts[0])
    assert read_recording(tmp_path / "live.mcap").num_frames == STEPS + 1
    live.record_rollout(rollouts[1])
    live.close()
    assert read_recording(tmp_path / "live.mcap").episode.tolist()[-1] == 1
    assert sorted(os.listdir(tmp_path)) == ["live.mcap", "run.mcap"]  # no temp files left behind


def test_dexmots_record_cli(tmp_path, capsys):
    out = tmp_path / "cli.mcap"
    record.main(["task=screw_claw", "episodes=2", "num_envs=2", "steps=3", f"out={out}", "policy=random"])
    summary = json.loads(capsys.readouterr().out)
    assert summary["frames"] == 8 and summary["policy"] == "random"
    rec = read_recording(out)
    assert rec.num_frames == 8 and rec.num_worlds == 2 and rec.episode.max() == 1
    for argv, match in [(["bogus=1"], "bogus: no such key in the config .* its keys: checkpoint, device, episodes,"), (["steps=zero"], "steps must be an integer"),
                        (["+bogus=1"], "bogus: no such key in the config .* its keys: checkpoint, device, episodes,"),
                        (["task=stapler", "task.object=drawer_a"], "task.object: 'drawer_a' is a drawer"),
                        (["task.ramp_steps=0"], "task.ramp_steps"),
                        (["policy=magic"], "policy must be one of"),
                        ([f"checkpoint={tmp_path / 'none.pt'}", "steps=2"], "does not exist")]:
        with pytest.raises(SystemExit, match=match):
            record.main(argv)


# each scene in float64 is a build of its own: the claw's is the dynamics tests', the others run in the slow set
SLOW_SCENES = ("allegro_knob.xml", "allegro_cube.xml", str(Path(__file__).parent / "assets" / "claw_scissors.xml"))


@pytest.mark.parametrize("xml", ["claw_screw.xml", *(pytest.param(x, marks=pytest.mark.slow) for x in SLOW_SCENES)])
def test_every_body_of_the_shipped_scenes_is_drawn_where_mujoco_puts_it(xml):
    import mujoco
    import numpy as np

    from dexmots_rl.assets import asset_path
    from dexmots_rl.recording.geometry import STATIC, transform
    from dexmots_rl.sim import Simulator, load_scene

    scene = load_scene(asset_path(xml))
    geo = scene_geometry(scene)
    assert {p.body for p in geo.parts if p.role == "hand"} == set(range(geo.num_hand_links))
    assert [p.body for p in geo.parts if p.role == "object"] == [geo.num_hand_links]
    assert any(p.role == "palm" for p in geo.parts) == xml.startswith("allegro")  # the claw's root has no geom
    # at a random pose, each single-primitive link's mesh is centred on MuJoCo's geom
    sim = Simulator(scene, 1, dtype=torch.float64)
    q = sim.initial_state()[0] + 0.3 * torch.rand(1, sim.nq, generator=torch.Generator().manual_seed(0))
    pose = sim.observe(q)[0][0].numpy()
    m = mujoco.MjModel.from_xml_path(str(asset_path(xml)))
    d = mujoco.MjData(m)
    d.qpos[:] = q[0].numpy()
    mujoco.mj_kinematics(m, d)
    checked = 0
    for p in geo.parts:
        body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, p.name)
        geoms = [g for g in range(m.ngeom) if m.geom_bodyid[g] == body]
        if len(geoms) != 1 or m.geom_type[geoms[0]] == mujoco.mjtGeom.mjGEOM_MESH:
            continue
        world = p.vertices if p.body == STATIC else transform(p.vertices, pose[p.body])
        assert np.allclose(0.5 * (world.min(0) + world.max(0)), d.geom_xpos[geoms[0]], atol=1e-6), p.name
        checked += 1
    assert checked >= 4  # the claw's four links; the Allegro's 12 one-capsule links, its palm and box objects


def test_an_env_is_recorded_from_its_tensordicts_alone(tmp_path, monkeypatch):
    """Every body's pose rides in the env's TensorDict (``("sim", "body_pose")``): the recorder does not ask the
    simulator (only a bare simulator, which has no TensorDict, is observed)."""
    env = make_env("screw_claw", num_envs=2, differentiable=False, seed=0)
    rollout = env.rollout(3, tensordict=env.reset(), auto_reset=False, break_when_any_done=False)

    def observe(*args, **kwargs):
        raise AssertionError("the recorder observed the simulator")

    monkeypatch.setattr(env.sim, "observe", observe)
    with EpisodeRecorder(tmp_path / "env.mcap", env) as rec:
        rec.record_rollout(rollout)
    recording = read_recording(tmp_path / "env.mcap")
    assert recording.num_frames == 4 and recording.num_worlds == 2


@pytest.mark.parametrize("drop, error, words", [
    (("sim", "body_pose"), KeyError, "no ('sim', 'body_pose')"),
    (None, ValueError, "('sim', 'body_pose') has shape (2, 4, 7)"),
])
def test_a_frame_without_every_bodys_pose_is_refused_and_nothing_written(tmp_path, drop, error, words):
    env = make_env("screw_claw", num_envs=2, differentiable=False, seed=0)
    frame = env.reset()
    if drop is None:  # a pose per body, one body short
        frame.set(("sim", "body_pose"), frame.get(("sim", "body_pose"))[:, 1:])
    else:
        del frame[drop]
    rec = EpisodeRecorder(tmp_path / "env.mcap", env)
    with pytest.raises(error) as caught:
        rec.record(frame)
    assert words in str(caught.value)
    assert rec.num_frames == 0 and not (tmp_path / "env.mcap").exists()
