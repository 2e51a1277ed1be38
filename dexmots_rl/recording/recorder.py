"""``EpisodeRecorder``: episodes of any DexMOTS env to an MCAP recording (format: :mod:`.format`).

Frames are encoded as they are recorded and kept in memory; :meth:`EpisodeRecorder.close` writes the file
atomically (a temp file in the same folder, fsync, ``os.replace``), so a reader never sees half a file.
With ``live=True`` every :meth:`~EpisodeRecorder.end_episode` also writes the file (everything recorded
so far), which is what ``dexmots-view --live`` polls for. A recorder holds every encoded frame, so for a
long training run make one recorder per evaluation rather than one for the whole run.

Example:
    >>> import tempfile, os
    >>> from dexmots_rl.envs import make_env
    >>> env = make_env("screw_claw", num_envs=2, differentiable=False, seed=0)
    >>> path = os.path.join(tempfile.mkdtemp(), "run.mcap")
    >>> with EpisodeRecorder(path, env, start_time_ns=0) as rec:
    ...     rec.record_rollout(env.rollout(3, tensordict=env.reset(), auto_reset=False,
    ...                                  break_when_any_done=False))
    >>> from dexmots_rl.recording import read_recording
    >>> read_recording(path).frames["body_pose"].shape
    torch.Size([4, 2, 5, 7])
"""

from __future__ import annotations

import json
import logging
import math
import os
import time
from pathlib import Path

import numpy as np
import torch
from tensordict import TensorDictBase

from ..atomic import atomic_write
from .geometry import BASE_RGBA, GOAL_RGBA, HAND_RGBA, OBJECT_RGBA, scene_geometry
from .format import (FORMAT_NAME, FORMAT_VERSION, ROOT_FRAME, SCENE_TOPIC, STEP_SCHEMA, STEP_TOPIC, TF_TOPIC,
                        WRENCH_TOPIC, body_frame, world_frame)

__all__ = ["EpisodeRecorder", "grid_offsets", "FORCE_SCALE", "TORQUE_SCALE"]

log = logging.getLogger(__name__)

GOAL_STEP = 10**6  # the reference at this step is the end of the plan (the goal ghost)
FORCE_SCALE, TORQUE_SCALE = 1e-3, 0.2  # arrow length per N (m/N) and per N m (m/(N m))
FORCE_RGBA, TARGET_FORCE_RGBA = (0.90, 0.20, 0.20, 1.0), (0.20, 0.80, 0.20, 0.8)
TORQUE_RGBA, TARGET_TORQUE_RGBA = (0.95, 0.60, 0.10, 1.0), (0.20, 0.60, 0.95, 0.8)


def grid_offsets(num_worlds: int, spacing: float) -> np.ndarray:
    """[N, 3] positions of worlds on a square grid in the xy-plane (world 0 at the origin)."""
    cols = max(1, math.ceil(math.sqrt(num_worlds)))
    w = np.arange(num_worlds)
    return np.stack([(w // cols) * spacing, (w % cols) * spacing, np.zeros(num_worlds)], -1).astype(np.float64)


def _task_name(base) -> str:
    config = getattr(base, "config", None)
    return getattr(config, "name", None) or type(base).__name__


def _pb():
    from foxglove_schemas_protobuf import (ArrowPrimitive_pb2, Color_pb2, CylinderPrimitive_pb2, FrameTransform_pb2,
                                           FrameTransforms_pb2, KeyValuePair_pb2, Point3_pb2, Pose_pb2,
                                           Quaternion_pb2, SceneEntity_pb2, SceneUpdate_pb2, SpherePrimitive_pb2,
                                           TriangleListPrimitive_pb2, Vector3_pb2)

    return {m: getattr(mod, m) for mod, m in [
        (ArrowPrimitive_pb2, "ArrowPrimitive"), (Color_pb2, "Color"), (CylinderPrimitive_pb2, "CylinderPrimitive"),
        (FrameTransform_pb2, "FrameTransform"), (FrameTransforms_pb2, "FrameTransforms"),
        (KeyValuePair_pb2, "KeyValuePair"), (Point3_pb2, "Point3"), (Pose_pb2, "Pose"),
        (Quaternion_pb2, "Quaternion"), (SceneEntity_pb2, "SceneEntity"), (SceneUpdate_pb2, "SceneUpdate"),
        (SpherePrimitive_pb2, "SpherePrimitive"), (TriangleListPrimitive_pb2, "TriangleListPrimitive"),
        (Vector3_pb2, "Vector3")]}


def _quat_from_to(src: np.ndarray, d: np.ndarray) -> tuple[float, float, float, float]:
    """``(x, y, z, w)`` of the shortest rotation taking unit ``src`` to unit ``d``."""
    c = float(np.dot(src, d))
    if c < -1 + 1e-9:  # opposite: half turn about any axis orthogonal to src
        axis = np.cross(src, [0.0, 0.0, 1.0] if abs(src[2]) < 0.9 else [1.0, 0.0, 0.0])
        axis /= np.linalg.norm(axis)
        return float(axis[0]), float(axis[1]), float(axis[2]), 0.0
    v = np.cross(src, d)
    q = np.array([v[0], v[1], v[2], 1.0 + c])
    q /= np.linalg.norm(q)
    return tuple(float(x) for x in q)


class EpisodeRecorder:
    """Record frames of ``env`` (a ``DexEnv`` or a ``TransformedEnv`` over one) to ``path``; see the module docstring.

    ``record(td)`` takes one frame: the TensorDict ``env.reset()`` returns, or the ``"next"`` entry of a
    step. The wrench arrows start on the object's bounding sphere (in their own direction, so they stick
    out of the object); ``force_scale`` (m/N) and ``torque_scale`` (m/(N m)) set their lengths, clipped
    to a third of the spacing between worlds.
    """

    def __init__(self, path: str | os.PathLike, env, *, live: bool = False, start_time_ns: int | None = None,
                 force_scale: float = FORCE_SCALE, torque_scale: float = TORQUE_SCALE,
                 world_spacing: float | None = None, task: str | None = None):
        self.path = Path(path)
        self.base = getattr(env, "base_env", env)
        self.sim = self.base.sim
        self.num_worlds = int(self.base.batch_size[0])
        self.num_bodies = int(self.sim.num_bodies)
        self.geometry = scene_geometry(self.sim.scene)
        self.live, self.dt = live, float(self.sim.dt)
        self.start_time_ns = time.time_ns() if start_time_ns is None else int(start_time_ns)
        self.force_scale, self.torque_scale = force_scale, torque_scale
        self.world_spacing = world_spacing
        self.task = task or _task_name(self.base)
        self.episode, self.num_frames = 0, 0
        self._frames_in_episode = 0
        self._messages: list[tuple[str, int, bytes]] = []
        self._offsets: np.ndarray | None = None
        self._warned: set[str] = set()
        self._closed = False
        self._pb = _pb()
        verts = self.geometry.object_vertices
        self._bound = float(np.linalg.norm(verts, axis=1).max()) if len(verts) else 0.0

    # --------------------------------------------------------------------------------------- public
    def record(self, td: TensorDictBase) -> None:
        """Encode one frame (all worlds) from an env TensorDict."""
        if self._closed:
            raise RuntimeError(f"recorder for {self.path} is closed")
        td = td.detach() if hasattr(td, "detach") else td
        n = self.num_worlds
        joint_q = td.get(("sim", "joint_q"))
        if joint_q.shape[0] != n:
            raise ValueError(f"expected a TensorDict of {n} worlds, got batch {tuple(td.batch_size)}")
        with torch.no_grad():
            body_pose = self.sim.observe(joint_q)[0].cpu().to(torch.float64).numpy()
            goal_pose, target = self._reference(td, body_pose)
        if self._offsets is None:
            self._offsets = grid_offsets(n, self.world_spacing or self._spacing(body_pose[0]))
        t_ns = self.start_time_ns + round(self.num_frames * self.dt * 1e9)
        if self.num_frames == 0:
            self._messages.append((SCENE_TOPIC, t_ns, self._scene_update(t_ns).SerializeToString()))
        self._messages.append((TF_TOPIC, t_ns, self._transforms(t_ns, body_pose, goal_pose).SerializeToString()))
        wrench = td.get(("object", "wrench")).detach().cpu()
        self._messages.append((WRENCH_TOPIC, t_ns, self._arrows(t_ns, body_pose, wrench.double().numpy(),
                                                                target.double().numpy()).SerializeToString()))
        step = self._step_message(td, target)
        self._messages.append((STEP_TOPIC, t_ns, json.dumps(step, separators=(",", ":")).encode()))
        self.num_frames += 1
        self._frames_in_episode += 1

    def record_rollout(self, rollout: TensorDictBase) -> None:
        """Record a torchrl rollout [N, T] as one episode: its first state, then every ``"next"`` state."""
        self.record(rollout[:, 0].exclude("next"))
        for k in range(rollout.shape[1]):
            self.record(rollout[:, k].get("next"))
        self.end_episode()

    def end_episode(self) -> None:
        """Close the current episode (the next frame starts a new one); writes the file when ``live``."""
        if self._frames_in_episode:
            self.episode += 1
            self._frames_in_episode = 0
        if self.live:
            self.flush()

    def flush(self) -> Path:
        """Write everything recorded so far to ``path`` atomically."""
        if not self._messages:
            raise RuntimeError(f"nothing recorded for {self.path}")
        atomic_write(self.path, self._write)
        log.info("wrote %s (%d frames, %d worlds)", self.path, self.num_frames, self.num_worlds)
        return self.path

    def close(self) -> Path | None:
        """Write the file (if anything was recorded) and stop recording."""
        if self._closed:
            return self.path
        self._closed = True
        return self.flush() if self._messages else None

    def __enter__(self) -> EpisodeRecorder:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:  # do not replace a good file with the frames of a failed run
            self._closed = True

    # ------------------------------------------------------------------------------------- internals
    def _warn_once(self, what: str, exc: Exception) -> None:
        if what not in self._warned:
            self._warned.add(what)
            log.warning("recording without %s: %s: %s", what, type(exc).__name__, exc)

    def _reference(self, td, body_pose: np.ndarray) -> tuple[np.ndarray, torch.Tensor]:
        """Goal pose [N, 7] (the end of the reference plan) and the target wrench [N, 6] now."""
        n = self.num_worlds
        goal = body_pose[:, -1].copy()
        target = torch.zeros(n, 6, dtype=torch.float64)
        try:  # references clamp steps to their plan: a step past any episode is the plan's end, the goal
            last = torch.full((n, 1), GOAL_STEP, dtype=torch.int64, device=self.base.device)
            goal = self.base.reference(td, last)["pose"][:, 0].detach().cpu().double().numpy()
        except Exception as exc:  # a task without references: the ghost sits on the object
            self._warn_once("a goal pose", exc)
        try:
            target = self.base.reference(td, td.get(("task", "step")))["wrench"][:, 0].detach().cpu()
        except Exception as exc:
            self._warn_once("a target wrench", exc)
        return goal, target

    def _spacing(self, poses: np.ndarray) -> float:
        g = self.geometry
        radii = [float(np.linalg.norm(l.spheres[:, :3], axis=1).max() + l.spheres[:, 3].max()) if len(l.spheres)
                 else 0.0 for l in g.links]
        radii.append(float(np.linalg.norm(g.object_vertices, axis=1).max()) if len(g.object_vertices) else 0.0)
        centre = 0.5 * (poses[:, :3].min(0) + poses[:, :3].max(0))
        reach = max(float(np.linalg.norm(p[:3] - centre)) + r for p, r in zip(poses, radii))
        return round(2.4 * reach, 3)

    def _color(self, rgba):
        r, g, b, a = rgba
        return self._pb["Color"](r=r, g=g, b=b, a=a)

    def _pose(self, pos, quat_xyzw=(0.0, 0.0, 0.0, 1.0)):
        pb = self._pb
        x, y, z, w = quat_xyzw
        return pb["Pose"](position=pb["Vector3"](x=float(pos[0]), y=float(pos[1]), z=float(pos[2])),
                          orientation=pb["Quaternion"](x=x, y=y, z=z, w=w))

    def _timestamp(self, t_ns: int):
        from google.protobuf.timestamp_pb2 import Timestamp

        return Timestamp(seconds=t_ns // 1_000_000_000, nanos=t_ns % 1_000_000_000)

    def _scene_update(self, t_ns: int):
        pb, g, ts = self._pb, self.geometry, self._timestamp(t_ns)
        verts = [pb["Point3"](x=float(v[0]), y=float(v[1]), z=float(v[2])) for v in g.object_vertices]
        indices = [int(i) for i in g.object_faces.reshape(-1)]
        update = pb["SceneUpdate"]()
        for w in range(self.num_worlds):
            for i, link in enumerate(g.links):
                frame = body_frame(w, i, self.num_bodies)
                e = update.entities.add(timestamp=ts, frame_id=frame, id=f"world{w}/link{i}", frame_locked=True)
                e.metadata.append(pb["KeyValuePair"](key="body", value=g.body_names[i]))
                e.metadata.append(pb["KeyValuePair"](key="geometry", value=json.dumps(
                    {"spheres": link.spheres.tolist(), "segments": link.segments.tolist()})))
                for s in link.spheres:
                    d = 2 * float(s[3])
                    e.spheres.add(pose=self._pose(s[:3]), size=pb["Vector3"](x=d, y=d, z=d),
                                  color=self._color(HAND_RGBA))
                for seg in link.segments:
                    p0, p1, d = seg[:3], seg[3:6], 2 * float(seg[6])
                    length = float(np.linalg.norm(p1 - p0))
                    e.cylinders.add(pose=self._pose(0.5 * (p0 + p1), _quat_from_to(np.array([0, 0, 1.0]),
                                                                                   (p1 - p0) / length)),
                                    size=pb["Vector3"](x=d, y=d, z=length), bottom_scale=1.0, top_scale=1.0,
                                    color=self._color(HAND_RGBA))
            for kind, frame, rgba in (("object", body_frame(w, self.num_bodies - 1, self.num_bodies), OBJECT_RGBA),
                                      ("goal", f"{world_frame(w)}/goal", GOAL_RGBA)):
                e = update.entities.add(timestamp=ts, frame_id=frame, id=f"world{w}/{kind}", frame_locked=True)
                e.metadata.append(pb["KeyValuePair"](key="body", value=kind))
                e.triangles.add(pose=self._pose((0, 0, 0)), points=verts, indices=indices, color=self._color(rgba))
            if len(g.base_boxes):  # an operable object's static base: cubes in the world's frame
                e = update.entities.add(timestamp=ts, frame_id=world_frame(w), id=f"world{w}/base", frame_locked=True)
                e.metadata.append(pb["KeyValuePair"](key="base_boxes", value=json.dumps(g.base_boxes.tolist())))
                for box in g.base_boxes:
                    qw, qx, qy, qz = (float(x) for x in box[3:7])
                    e.cubes.add(pose=self._pose(box[:3], (qx, qy, qz, qw)),
                                size=pb["Vector3"](x=2 * float(box[7]), y=2 * float(box[8]), z=2 * float(box[9])),
                                color=self._color(BASE_RGBA))
        return update

    def _transforms(self, t_ns: int, body_pose: np.ndarray, goal_pose: np.ndarray):
        pb, ts = self._pb, self._timestamp(t_ns)
        msg = pb["FrameTransforms"]()

        def add(parent, child, pose):
            msg.transforms.add(timestamp=ts, parent_frame_id=parent, child_frame_id=child,
                               translation=pb["Vector3"](x=float(pose[0]), y=float(pose[1]), z=float(pose[2])),
                               rotation=pb["Quaternion"](x=float(pose[4]), y=float(pose[5]), z=float(pose[6]),
                                                         w=float(pose[3])))

        for w in range(self.num_worlds):
            wf = world_frame(w)
            add(ROOT_FRAME, wf, [*self._offsets[w], 1.0, 0.0, 0.0, 0.0])
            for b in range(self.num_bodies):
                add(wf, body_frame(w, b, self.num_bodies), body_pose[w, b])
            add(wf, f"{wf}/goal", goal_pose[w])
        return msg

    def _arrows(self, t_ns: int, body_pose: np.ndarray, wrench: np.ndarray, target: np.ndarray):
        pb, ts = self._pb, self._timestamp(t_ns)
        update = pb["SceneUpdate"]()
        longest = 0.33 * float(np.linalg.norm(self._offsets[1] - self._offsets[0])) if self.num_worlds > 1 else 1.0
        x_axis = np.array([1.0, 0.0, 0.0])
        for w in range(self.num_worlds):
            e = update.entities.add(timestamp=ts, frame_id=world_frame(w), id=f"world{w}/wrench", frame_locked=True)
            centre = body_pose[w, -1, :3]
            for vec, scale, rgba in ((wrench[w, :3], self.force_scale, FORCE_RGBA),
                                     (target[w, :3], self.force_scale, TARGET_FORCE_RGBA),
                                     (wrench[w, 3:], self.torque_scale, TORQUE_RGBA),
                                     (target[w, 3:], self.torque_scale, TARGET_TORQUE_RGBA)):
                norm = float(np.linalg.norm(vec))
                length = min(norm * scale, longest)
                if not np.isfinite(norm) or length < 1e-4:
                    continue
                head = min(0.3 * length, 0.06)
                origin = centre + self._bound * vec / norm  # on the object's bounding sphere
                e.arrows.add(pose=self._pose(origin, _quat_from_to(x_axis, vec / norm)), shaft_length=length - head,
                             shaft_diameter=0.015, head_length=head, head_diameter=0.04, color=self._color(rgba))
        return update

    def _step_message(self, td, target: torch.Tensor) -> dict:
        n = self.num_worlds

        def rows(key, default_width=None, dtype=None):
            value = td.get(key, None)
            if value is None:
                value = torch.zeros(n, default_width or 0, dtype=dtype or torch.float64)
            return value.detach().cpu().reshape(n, -1).tolist()

        reward = td.get("reward", None)
        success = td.get("success", None)
        step = {
            "frame": self.num_frames,
            "episode": self.episode,
            "time": self.num_frames * self.dt,
            "reward": [0.0] * n if reward is None else reward.detach().cpu().reshape(n).tolist(),
            "success": [False] * n if success is None else success.detach().cpu().reshape(n).tolist(),
            "step": rows(("task", "step"), 1, torch.int64),
            "object_q": rows(("object", "q")),
            "wrench": rows(("object", "wrench"), 6),
            "target_wrench": target.reshape(n, 6).tolist(),
            "goal": rows(("task", "goal")),
            "hand_q": rows(("hand", "q")),
            "joint_q": rows(("sim", "joint_q")),
        }
        step["step"] = [s[0] for s in step["step"]]
        terms = td.get("reward_terms", None)
        if terms is not None:
            step["reward_terms"] = {name: terms.get(name).detach().cpu().reshape(n).tolist()
                                    for name in sorted(terms.keys())}
        return step

    def _write(self, stream) -> None:
        from mcap.writer import CompressionType, Writer
        from mcap_protobuf.schema import register_schema

        writer = Writer(stream, compression=CompressionType.ZSTD, enable_crcs=True, enable_data_crcs=True)
        writer.start(profile="", library=f"dexmots_rl {FORMAT_NAME}/{FORMAT_VERSION}")
        tf_schema = register_schema(writer, self._pb["FrameTransforms"])
        scene_schema = register_schema(writer, self._pb["SceneUpdate"])
        step_schema = writer.register_schema(name=STEP_SCHEMA["title"], encoding="jsonschema",
                                             data=json.dumps(STEP_SCHEMA).encode())
        channels = {
            TF_TOPIC: writer.register_channel(TF_TOPIC, "protobuf", tf_schema),
            SCENE_TOPIC: writer.register_channel(SCENE_TOPIC, "protobuf", scene_schema),
            WRENCH_TOPIC: writer.register_channel(WRENCH_TOPIC, "protobuf", scene_schema),
            STEP_TOPIC: writer.register_channel(STEP_TOPIC, "json", step_schema),
        }
        dtype = str(self.base.dtype).replace("torch.", "")
        writer.add_metadata("dexmots", {
            "format": FORMAT_NAME, "version": str(FORMAT_VERSION), "task": str(self.task),
            "num_worlds": str(self.num_worlds), "num_frames": str(self.num_frames), "dt": repr(self.dt),
            "dtype": dtype, "body_names": json.dumps(self.geometry.body_names),
            "world_offsets": json.dumps(self._offsets.tolist()), "start_time_ns": str(self.start_time_ns),
            "force_scale": repr(self.force_scale), "torque_scale": repr(self.torque_scale),
        })
        sequence: dict[str, int] = {}
        for topic, t_ns, data in self._messages:
            seq = sequence[topic] = sequence.get(topic, -1) + 1
            writer.add_message(channels[topic], log_time=t_ns, data=data, publish_time=t_ns, sequence=seq)
        writer.finish()
