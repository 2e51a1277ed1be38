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

import dataclasses
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
from .format import (CONTROL_FIELDS, FORMAT_NAME, FORMAT_VERSION, ROOT_FRAME, SCENE_TOPIC, STEP_SCHEMA, STEP_TOPIC,
                     TF_TOPIC, WRENCH_TOPIC, body_frame, world_frame)
from .geometry import quat_to_mat, scene_geometry
from .scene_messages import arrow_style, arrows_update, protobuf_types, scene_update

__all__ = ["EpisodeRecorder", "record_simulation", "grid_offsets", "FORCE_SCALE", "TORQUE_SCALE"]

log = logging.getLogger(__name__)

GOAL_STEP = 10**6  # the reference at this step is the end of the plan (the goal ghost)
FORCE_SCALE, TORQUE_SCALE = 1e-3, 0.2  # arrow length per N (m/N) and per N m (m/(N m))


def grid_offsets(num_worlds: int, spacing: float) -> np.ndarray:
    """[N, 3] positions of worlds on a square grid in the xy-plane (world 0 at the origin)."""
    cols = max(1, math.ceil(math.sqrt(num_worlds)))
    w = np.arange(num_worlds)
    return np.stack([(w // cols) * spacing, (w % cols) * spacing, np.zeros(num_worlds)], -1).astype(np.float64)


def _task_name(base) -> str:
    config = getattr(base, "config", None)
    return getattr(config, "name", None) or type(base).__name__


class EpisodeRecorder:
    """Record frames of ``env`` (a ``DexEnv``, a ``TransformedEnv`` over one, or a simulator: a
    :class:`~dexmots_rl.sim.Simulator` or :class:`~dexmots_rl.sim.ArticulatedSimulator`) to ``path``;
    see the module docstring.

    ``record(td)`` takes one frame: the TensorDict ``env.reset()`` returns, or the ``"next"`` entry of a
    step, which carries every body's pose as ``("sim", "body_pose")`` (for a simulator: ``("sim", "joint_q")``,
    ``("sim", "body_pose")`` and optionally ``("object", "wrench")``, what :func:`record_simulation` writes). The wrench
    arrows start where they leave the object's bounding box and are sized by the scene
    (:func:`~dexmots_rl.recording.scene_messages.arrow_style`); ``force_scale`` (m/N) and ``torque_scale``
    (m/(N m)) set their lengths.
    """

    def __init__(self, path: str | os.PathLike, env, *, live: bool = False, start_time_ns: int | None = None,
                 force_scale: float = FORCE_SCALE, torque_scale: float = TORQUE_SCALE,
                 world_spacing: float | None = None, task: str | None = None):
        self.path = Path(path)
        # an env and a simulator both tell their scene, time step and dtype
        self.env, self.base = env, getattr(env, "base_env", env)
        self.num_worlds = int(self.base.batch_size[0]) if hasattr(self.base, "batch_size") else int(
            self.base.num_worlds)
        # an env over a library object built its scene in a temporary folder: its asset rebuilds the MJCF
        self.geometry = scene_geometry(self.base.scene, asset=getattr(self.base, "object_asset", None))
        self.live, self.dt = live, float(self.base.dt)
        self.start_time_ns = time.time_ns() if start_time_ns is None else int(start_time_ns)
        self.force_scale, self.torque_scale = force_scale, torque_scale
        self.world_spacing = world_spacing
        self.task = task or _task_name(self.base)
        self._style = None
        self._has_goal = True  # until a frame has no goal pose
        self.episode, self.num_frames = 0, 0
        self._frames_in_episode = 0
        self._messages: list[tuple[str, int, bytes]] = []
        self._offsets: np.ndarray | None = None
        self._warned: set[str] = set()
        self._closed = False
        self._pb = protobuf_types()

    # --------------------------------------------------------------------------------------- public
    def record(self, td: TensorDictBase, action: torch.Tensor | None = None) -> None:
        """Encode one frame (all worlds) from an env TensorDict; ``action``: the base env's action of the step
        that led to it (its hand drive is recorded, what system identification replays)."""
        if self._closed:
            raise RuntimeError(f"recorder for {self.path} is closed")
        td = td.detach() if hasattr(td, "detach") else td
        n = self.num_worlds
        joint_q = td.get(("sim", "joint_q"))
        if joint_q.shape[0] != n:
            raise ValueError(f"expected a TensorDict of {n} worlds, got batch {tuple(td.batch_size)}")
        body_pose = td.get(("sim", "body_pose"), None)
        if body_pose is None:
            raise KeyError("the frame has no ('sim', 'body_pose') (every body's pose [N, B, 7]): record the "
                           "TensorDicts an env returns, or a simulator's frames as record_simulation writes them")
        if tuple(body_pose.shape[1:]) != (len(self.geometry.body_names), 7):
            raise ValueError(f"('sim', 'body_pose') has shape {tuple(body_pose.shape)}; the scene "
                             f"{self.base.scene.path} has {len(self.geometry.body_names)} bodies, so [N, "
                             f"{len(self.geometry.body_names)}, 7]")
        with torch.no_grad():
            body_pose = body_pose.cpu().to(torch.float64).numpy()
            goal_pose, target = self._reference(td, body_pose)
        if self._offsets is None:
            self._offsets = grid_offsets(n, self.world_spacing or self._spacing(body_pose[0]))
            self._style = arrow_style(self.geometry, body_pose[0])
        t_ns = self.start_time_ns + round(self.num_frames * self.dt * 1e9)
        if self.num_frames == 0:
            self._messages.append((SCENE_TOPIC, t_ns, self._scene_update(t_ns).SerializeToString()))
        self._messages.append((TF_TOPIC, t_ns, self._transforms(t_ns, body_pose, goal_pose).SerializeToString()))
        wrench = td.get(("object", "wrench"), None)
        wrench = torch.zeros(n, 6) if wrench is None else wrench.detach().cpu()
        self._messages.append((WRENCH_TOPIC, t_ns, self._arrows(t_ns, body_pose, wrench.double().numpy(),
                                                                target.double().numpy()).SerializeToString()))
        step = self._step_message(td, target)
        if action is not None:
            control = self.base.actions(action.detach().to(self.base.dtype))
            step["control"] = {name: getattr(control, name).detach().cpu().reshape(n, -1).tolist()
                               for name in CONTROL_FIELDS}
        self._messages.append((STEP_TOPIC, t_ns, json.dumps(step, separators=(",", ":")).encode()))
        self.num_frames += 1
        self._frames_in_episode += 1

    def record_rollout(self, rollout: TensorDictBase) -> None:
        """Record a torchrl rollout [N, T] as one episode: its first state, then every ``"next"`` state."""
        self.record(rollout[:, 0].exclude("next"))
        for k in range(rollout.shape[1]):
            self.record(rollout[:, k].get("next"), self._base_action(rollout[:, k]))
        self.end_episode()

    def _base_action(self, td: TensorDictBase) -> torch.Tensor | None:
        """The action the base env applied in the step of ``td`` (the rollout's action through the env's inverse
        transforms, e.g. a mirrored world's reflected back), or None when there is no env action to record."""
        if "action" not in td.keys() or not hasattr(self.base, "actions"):
            return None
        td = td.select("action", ("task", "goal"), strict=False).clone()
        transform = getattr(self.env, "transform", None)
        return (transform.inv(td) if transform is not None else td).get("action")

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
        goal = body_pose[:, self.geometry.num_hand_links].copy()
        target = torch.zeros(n, 6, dtype=torch.float64)
        if not hasattr(self.base, "reference"):  # a bare simulator: no task, no goal
            self._has_goal = False
            return goal, target
        try:  # references clamp steps to their plan: a step past any episode is the plan's end, the goal
            last = torch.full((n, 1), GOAL_STEP, dtype=torch.int64, device=self.base.device)
            ref = self.base.reference(td, last)["pose"][:, 0].detach().cpu().double().numpy()
            valid = np.abs(np.linalg.norm(ref[:, 3:7], axis=-1) - 1.0) < 1e-3  # a fixed base may say zeros
            goal = np.where(valid[:, None], ref, goal)
        except Exception as exc:  # a task without references: the ghost sits on the object
            self._has_goal = False
            self._warn_once("a goal pose", exc)
        try:
            ref = self.base.reference(td, td.get(("task", "step")))
            target = ref["wrench"][:, 0].detach().cpu()
            if "joint_torque" in ref.keys() and hasattr(self.base, "joint_name"):  # an operated joint's plan
                target = target + self._joint_target(ref["joint_torque"][:, 0].detach().cpu(), body_pose)
        except Exception as exc:
            self._warn_once("a target wrench", exc)
        return goal, target

    def _joint_target(self, force: torch.Tensor, body_pose: np.ndarray) -> torch.Tensor:
        """[N, 6]: the planned generalised force ``force`` [N, 1] on the task's operated joint as a world
        vector along the joint's axis: a torque about a hinge's, a force along a slide's."""
        from ..sim import SLIDE

        tree = self.base.scene.tree
        j = tree.joint_names.index(self.base.joint_name)
        part_quat = body_pose[:, self.geometry.num_hand_links + j + 1, 3:]  # the part the joint moves
        axis = np.stack([quat_to_mat(q) @ tree.joint_axis[j] for q in part_quat])
        out = torch.zeros(len(axis), 6, dtype=torch.float64)
        lane = slice(0, 3) if int(tree.joint_kind[j]) == SLIDE else slice(3, 6)
        out[:, lane] = force.double().reshape(-1, 1) * torch.as_tensor(axis)
        return out

    def _spacing(self, poses: np.ndarray) -> float:
        pts = self.geometry.world_points(poses)
        return round(1.2 * float(np.ptp(pts, 0)[:2].max()), 3) if len(pts) else 1.0

    def _timestamp(self, t_ns: int):
        from google.protobuf.timestamp_pb2 import Timestamp

        return Timestamp(seconds=t_ns // 1_000_000_000, nanos=t_ns % 1_000_000_000)

    def _scene_update(self, t_ns: int):
        return scene_update(self._pb, self.geometry, self.num_worlds, self._timestamp(t_ns))

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
            for b, name in enumerate(self.geometry.body_names):
                add(wf, body_frame(w, name), body_pose[w, b])
            add(wf, f"{wf}/goal", goal_pose[w])
        return msg

    def _arrows(self, t_ns: int, body_pose: np.ndarray, wrench: np.ndarray, target: np.ndarray):
        f, t = self.force_scale, self.torque_scale
        vectors = np.stack([wrench[:, :3] * f, target[:, :3] * f, wrench[:, 3:] * t, target[:, 3:] * t], 1)
        base = body_pose[:, self.geometry.num_hand_links]
        return arrows_update(self._pb, self._style, self._timestamp(t_ns), base, vectors)

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
            "joint_qd": rows(("sim", "joint_qd")),
        }
        params = td.get(("sim", "params"), None)
        if params is not None:
            step["params"] = {name: params.get(name).detach().cpu().reshape(n).tolist()
                              for name in sorted(params.keys())}
        step["step"] = [s[0] for s in step["step"]]
        terms = td.get("reward_terms", None)
        if terms is not None:
            step["reward_terms"] = {name: terms.get(name).detach().cpu().reshape(n).tolist()
                                    for name in sorted(terms.keys())}
        return step

    def _task_config(self) -> dict | None:
        """The recorded env's task config as a plain dict (``make_env`` rebuilds the task from it), or None."""
        config = getattr(self.base, "config", None)
        return dataclasses.asdict(config) if dataclasses.is_dataclass(config) else None

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
            "num_hand_links": str(self.geometry.num_hand_links),
            "world_offsets": json.dumps(self._offsets.tolist()), "start_time_ns": str(self.start_time_ns),
            "force_scale": repr(self.force_scale), "torque_scale": repr(self.torque_scale),
            "goal": "true" if self._has_goal else "false",
            "task_config": json.dumps(self._task_config()),
        })
        sequence: dict[str, int] = {}
        for topic, t_ns, data in self._messages:
            seq = sequence[topic] = sequence.get(topic, -1) + 1
            writer.add_message(channels[topic], log_time=t_ns, data=data, publish_time=t_ns, sequence=seq)
        writer.finish()


def record_simulation(sim, steps: int, path: str | os.PathLike, control=None, state=None, params=None,
                      **recorder_kwargs) -> Path:
    """Step a simulator ``steps`` times and record its initial state and every step to ``path`` (one episode).

    ``state``: ``(joint_q, joint_qd)`` to start from (default ``sim.initial_state()``); ``control``: a
    :class:`~dexmots_rl.sim.Control`, or a callable ``control(step, joint_q, joint_qd)`` returning one
    (default: zero); ``params``: the named parameters (default ``sim.default_params()``). Keyword arguments
    go to :class:`EpisodeRecorder`.
    """
    from tensordict import TensorDict

    joint_q, joint_qd = state if state is not None else sim.initial_state()
    params = sim.default_params() if params is None else params
    n = joint_q.shape[0]

    def frame(q, body_pose, wrench):
        return TensorDict({("sim", "joint_q"): q, ("sim", "body_pose"): body_pose, ("object", "wrench"): wrench},
                          batch_size=[n])

    with EpisodeRecorder(path, sim, **recorder_kwargs) as rec, torch.no_grad():
        rec.record(frame(joint_q, sim.observe(joint_q, joint_qd, params)[0], torch.zeros(n, 6, dtype=joint_q.dtype)))
        for k in range(steps):
            u = control(k, joint_q, joint_qd) if callable(control) else control or sim.zero_control()
            out = sim.step(joint_q, joint_qd, u, params)
            joint_q, joint_qd = out.joint_q, out.joint_qd
            rec.record(frame(joint_q, out.body_pose, out.wrench))
        rec.end_episode()
    return Path(path)
