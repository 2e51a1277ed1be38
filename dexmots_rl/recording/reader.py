"""``read_recording``: a DexMOTS MCAP recording (format: :mod:`.format`) back to tensors.

The whole file is read record by record with CRCs checked, so a truncated or corrupted file, a file
that is not MCAP, or an MCAP file that is not a DexMOTS recording raises one
:class:`~dexmots_rl.recording.format.RecordingFormatError` naming the file and the problem.

Example:
    >>> import os, tempfile
    >>> path = os.path.join(tempfile.mkdtemp(), "broken.mcap")
    >>> _ = open(path, "wb").write(b"not an mcap file")
    >>> try:
    ...     read_recording(path)
    ... except RecordingFormatError as e:
    ...     print(str(e).split(": ", 1)[1][:21])
    not a valid MCAP file
"""

from __future__ import annotations

import io
import json
import logging
import math
import os
from pathlib import Path

import numpy as np
import torch
from tensordict import TensorDict

from .format import (CONTROL_FIELDS, FORMAT_NAME, FORMAT_VERSION, SCENE_TOPIC, STEP_TOPIC, TF_TOPIC, Recording,
                     RecordingFormatError, body_frame, world_frame)
from .geometry import MeshPart, SceneGeometry

__all__ = ["read_recording", "RecordingFormatError"]

log = logging.getLogger(__name__)

_FLOAT_FIELDS = {"object_q": ("object", "q"), "wrench": ("object", "wrench"), "target_wrench": "target_wrench",
                 "goal": ("task", "goal"), "hand_q": ("hand", "q"), "joint_q": ("sim", "joint_q")}


def _records(path: Path, data: bytes):
    import zlib

    from mcap.exceptions import EndOfFile, McapError
    from mcap.records import DataEnd, Footer, Message, Metadata
    from mcap.stream_reader import StreamReader

    out = {"meta": None, "channels": {}, "messages": [], "complete": False}
    try:
        for record in StreamReader(io.BytesIO(data), validate_crcs=True).records:
            if isinstance(record, Message):
                out["messages"].append(record)
            elif isinstance(record, Metadata) and record.name == "dexmots":
                out["meta"] = dict(record.metadata)
            elif type(record).__name__ == "Channel":
                out["channels"][record.id] = record.topic
            elif isinstance(record, DataEnd):
                out["complete"] = True
            elif isinstance(record, Footer) and record.summary_start and record.summary_crc:
                if zlib.crc32(data[record.summary_start : len(data) - 12]) != record.summary_crc:
                    raise RecordingFormatError(f"{path}: corrupted (summary section CRC mismatch)")
    except EndOfFile:
        raise RecordingFormatError(f"{path}: truncated (the MCAP file ends inside a record)") from None
    except McapError as exc:
        raise RecordingFormatError(f"{path}: not a valid MCAP file ({type(exc).__name__}: {exc})") from None
    except RecordingFormatError:
        raise
    except Exception as exc:  # zstd/struct/unicode errors from a damaged chunk
        raise RecordingFormatError(f"{path}: corrupted or truncated MCAP data ({type(exc).__name__}: {exc})") from None
    if not out["complete"]:
        raise RecordingFormatError(f"{path}: truncated (the MCAP file has no data end record)")
    return out


def _triangles(entity) -> tuple[np.ndarray, np.ndarray, tuple]:
    tri = entity.triangles[0]
    verts = np.array([[p.x, p.y, p.z] for p in tri.points], dtype=np.float64).reshape(-1, 3)
    c = tri.color
    return verts, np.asarray(tri.indices, dtype=np.int64).reshape(-1, 3), (c.r, c.g, c.b, c.a)


def _geometry(path: Path, scene, body_names: list[str], num_hand_links: int) -> SceneGeometry:
    """The drawn scene from world 0's entities of the first ``/scene`` message."""
    parts, ghost = [], None
    for e in scene.entities:
        if not e.id.startswith("world0/"):
            continue
        meta = {kv.key: kv.value for kv in e.metadata}
        if not e.triangles:
            raise RecordingFormatError(f"{path}: /scene entity {e.id} has no triangles")
        verts, faces, rgba = _triangles(e)
        if e.id == "world0/goal":
            ghost = (verts, faces)
            continue
        body = int(meta["body"])
        if not -1 <= body < len(body_names):
            raise RecordingFormatError(f"{path}: /scene entity {e.id} names body {body} of {len(body_names)}")
        parts.append(MeshPart(meta["name"], meta["role"], body, verts, faces, rgba))
    if ghost is None or not parts:
        raise RecordingFormatError(f"{path}: /scene has no meshes for world 0")
    return SceneGeometry(body_names, num_hand_links, parts, *ghost)


def _read_optional(frames: TensorDict, decoded: list[dict], n: int, dtype) -> None:
    """The step fields newer recordings add: ``joint_qd`` and ``params`` (when every frame has them) and the
    hand's drive ``control`` (NaN on the frames without it: each episode's first)."""
    if all("joint_qd" in d for d in decoded):
        frames["sim", "joint_qd"] = torch.tensor([d["joint_qd"] for d in decoded], dtype=dtype).reshape(len(decoded),
                                                                                                         n, -1)
    names = sorted(decoded[0].get("params", {}))
    if names and all(sorted(d.get("params", {})) == names for d in decoded):
        for name in names:
            frames["sim", "params", name] = torch.tensor([d["params"][name] for d in decoded],
                                                         dtype=dtype).unsqueeze(-1)
    with_control = [d["control"] for d in decoded if "control" in d]
    if with_control:
        width = len(with_control[0][CONTROL_FIELDS[0]][0])
        for name in CONTROL_FIELDS:
            missing = [[math.nan] * width] * n
            frames["control", name] = torch.tensor([d["control"][name] if "control" in d else missing
                                                    for d in decoded], dtype=dtype)


def read_recording(path: str | os.PathLike) -> Recording:
    """Load a recording written by :class:`~dexmots_rl.recording.EpisodeRecorder` (values exact); see the module docstring."""
    from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    path = Path(path)
    if not path.is_file():
        raise RecordingFormatError(f"{path}: no such recording")
    rec = _records(path, path.read_bytes())
    meta = rec["meta"]
    if meta is None or meta.get("format") != FORMAT_NAME:
        raise RecordingFormatError(f"{path}: an MCAP file, but not a {FORMAT_NAME} (no 'dexmots' metadata)")
    if meta.get("version") != str(FORMAT_VERSION):
        raise RecordingFormatError(f"{path}: format version {meta.get('version')!r}; this library reads "
                                   f"version {FORMAT_VERSION}")
    try:
        n, body_names = int(meta["num_worlds"]), json.loads(meta["body_names"])
        num_hand_links = int(meta["num_hand_links"])
        dtype = getattr(torch, meta["dtype"])
        num_bodies = len(body_names)
        by_topic: dict[str, list] = {}
        for m in rec["messages"]:
            by_topic.setdefault(rec["channels"][m.channel_id], []).append(m)
        if not by_topic.get(SCENE_TOPIC) or not by_topic.get(TF_TOPIC) or not by_topic.get(STEP_TOPIC):
            raise RecordingFormatError(f"{path}: missing one of the topics {TF_TOPIC}, {SCENE_TOPIC}, {STEP_TOPIC}")
        tfs, steps = by_topic[TF_TOPIC], by_topic[STEP_TOPIC]
        if len(tfs) != len(steps) or [m.log_time for m in tfs] != [m.log_time for m in steps]:
            raise RecordingFormatError(f"{path}: {len(tfs)} {TF_TOPIC} and {len(steps)} {STEP_TOPIC} messages "
                                       "do not pair up frame by frame")
        geometry = _geometry(path, SceneUpdate.FromString(by_topic[SCENE_TOPIC][0].data), body_names, num_hand_links)
        body = np.zeros((len(tfs), n, num_bodies, 7))
        goal = np.zeros((len(tfs), n, 7))
        offsets = np.zeros((n, 3))
        names = {body_frame(w, name): (w, b) for w in range(n) for b, name in enumerate(body_names)}
        goals = {f"{world_frame(w)}/goal": w for w in range(n)}
        worlds = {world_frame(w): w for w in range(n)}
        for f, m in enumerate(tfs):
            for t in FrameTransforms.FromString(m.data).transforms:
                pose = (t.translation.x, t.translation.y, t.translation.z,
                        t.rotation.w, t.rotation.x, t.rotation.y, t.rotation.z)
                if t.child_frame_id in names:
                    w, b = names[t.child_frame_id]
                    body[f, w, b] = pose
                elif t.child_frame_id in goals:
                    goal[f, goals[t.child_frame_id]] = pose
                elif f == 0 and t.child_frame_id in worlds:
                    offsets[worlds[t.child_frame_id]] = pose[:3]
        decoded = [json.loads(m.data) for m in steps]
        fields = {k: torch.tensor([d[k] for d in decoded], dtype=dtype) for k in _FLOAT_FIELDS}
        frames = TensorDict({
            "body_pose": torch.as_tensor(body, dtype=dtype),
            "goal_pose": torch.as_tensor(goal, dtype=dtype),
            "reward": torch.tensor([d["reward"] for d in decoded], dtype=dtype).unsqueeze(-1),
            "success": torch.tensor([d["success"] for d in decoded], dtype=torch.bool).unsqueeze(-1),
            ("task", "step"): torch.tensor([d["step"] for d in decoded], dtype=torch.int64).unsqueeze(-1),
            **{_FLOAT_FIELDS[k]: v.reshape(len(decoded), n, -1) for k, v in fields.items()},
        }, batch_size=[len(decoded), n])
        _read_optional(frames, decoded, n, dtype)
        terms = sorted(decoded[0].get("reward_terms", {}))
        for name in terms:
            frames["reward_terms", name] = torch.tensor([d["reward_terms"][name] for d in decoded],
                                                        dtype=dtype).unsqueeze(-1)
        episode = torch.tensor([d["episode"] for d in decoded], dtype=torch.int64)
        times = torch.tensor([d["time"] for d in decoded], dtype=torch.float64)
    except RecordingFormatError:
        raise
    except Exception as exc:  # missing keys, ragged lists, undecodable protobuf / JSON
        raise RecordingFormatError(f"{path}: malformed recording content ({type(exc).__name__}: {exc})") from None
    return Recording(meta=meta, geometry=geometry, frames=frames, episode=episode, time=times,
                     world_offsets=torch.as_tensor(offsets))
