"""The drawn scene as Foxglove messages (``/scene``, ``/scene/wrench``), and the wrench arrows' sizes.

Arrows are sized by the scene: :func:`arrow_style` takes a length ``s`` (the object's half diagonal, at least a
tenth of the hand's span) and gives shafts ``0.05 s`` thick, heads ``0.3 s`` long; an arrow starts where its
direction leaves the object's bounding box (so it sticks out of the object, on any side) and is at most
``2.5 s`` long. The viewer draws the same arrows from the same numbers, at lengths scaled to the forces of the
recording (:func:`arrow_scales`: the upper quartile of its forces, measured and target, is an arrow ``s`` long,
three heads, unless below a fingertip's push; likewise its torques), and leaves out an arrow shorter than its head (it would show as a loose cone).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .format import world_frame
from .geometry import GOAL_RGBA, STATIC, SceneGeometry, quat_to_mat

__all__ = ["ArrowStyle", "arrow_scales", "arrow_style", "arrow_segments", "protobuf_types", "scene_update", "arrows_update",
           "quat_from_to", "FORCE_RGBA", "TARGET_FORCE_RGBA", "TORQUE_RGBA", "TARGET_TORQUE_RGBA"]

FORCE_RGBA, TARGET_FORCE_RGBA = (0.90, 0.20, 0.20, 1.0), (0.20, 0.80, 0.20, 0.8)
TORQUE_RGBA, TARGET_TORQUE_RGBA = (0.95, 0.60, 0.10, 1.0), (0.20, 0.60, 0.95, 0.8)
ARROW_RGBAS = (FORCE_RGBA, TARGET_FORCE_RGBA, TORQUE_RGBA, TARGET_TORQUE_RGBA)


@dataclasses.dataclass
class ArrowStyle:
    """Wrench arrows of one scene (lengths in m): the object's bounding box in its base frame (``centre``,
    ``half``), shaft radius, head radius and length, and the longest arrow drawn."""

    centre: np.ndarray
    half: np.ndarray
    shaft_radius: float
    head_radius: float
    head_length: float
    max_length: float


def arrow_style(geometry: SceneGeometry, body_pose: np.ndarray) -> ArrowStyle:
    """Arrow sizes for ``geometry`` with its bodies at ``body_pose`` [B, 7] (one world); see the module docstring."""
    if len(geometry.ghost_vertices):
        lo, hi = geometry.ghost_vertices.min(0), geometry.ghost_vertices.max(0)
    else:
        lo = hi = np.zeros(3)
    hand = geometry.world_points(body_pose, roles=("hand", "palm"))
    span = float(np.linalg.norm(np.ptp(hand, 0))) if len(hand) else 0.0
    s = max(float(0.5 * np.linalg.norm(hi - lo)), 0.1 * span, 1e-3)
    return ArrowStyle(0.5 * (lo + hi), np.maximum(0.5 * (hi - lo), 1e-6), 0.05 * s, 0.12 * s, 0.3 * s, 2.5 * s)


TYPICAL_ARROW_SHARE = 0.4  # of the longest arrow: the length of a recording's upper-quartile force (or torque)
# a fingertip's push (1 N, 0.05 N m about a part 5 cm away): smaller forces are not enlarged to the typical
# length, so a scene at rest (a joint's reaction of 0.1 N) shows no arrow rather than a long one
TYPICAL_FLOOR = (1.0, 0.05)


def arrow_scales(style: ArrowStyle, wrenches: np.ndarray, default: tuple[float, float]) -> tuple[float, float]:
    """``(force_scale m/N, torque_scale m/(N m))`` for ``wrenches`` [..., 6] (every wrench a recording draws):
    its upper-quartile force (torque; at least :data:`TYPICAL_FLOOR`) is ``TYPICAL_ARROW_SHARE`` of
    ``style.max_length``; ``default`` for a recording whose forces (torques) are all zero."""
    scales = []
    for part, fallback, floor in ((wrenches[..., :3], default[0], TYPICAL_FLOOR[0]),
                                  (wrenches[..., 3:], default[1], TYPICAL_FLOOR[1])):
        norms = np.linalg.norm(part.reshape(-1, 3), axis=-1)
        norms = norms[np.isfinite(norms) & (norms > 1e-9)]
        typical = max(float(np.percentile(norms, 75)), floor) if len(norms) else 0.0
        scales.append(TYPICAL_ARROW_SHARE * style.max_length / typical if typical > 0 else fallback)
    return scales[0], scales[1]


def arrow_segments(style: ArrowStyle, base_pose: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """Start and end points [..., 2, 3] of arrows for ``vectors`` [..., 3] (already scaled to metres) at an
    object whose base is at ``base_pose`` [..., 7]; vectors are clipped to ``style.max_length``."""
    norm = np.linalg.norm(vectors, axis=-1, keepdims=True)
    finite = np.isfinite(norm)
    vec = np.where(finite, vectors, 0.0) * np.minimum(1.0, style.max_length / np.maximum(np.where(finite, norm, 0),
                                                                                         1e-12))
    rot = np.stack([quat_to_mat(q) for q in base_pose.reshape(-1, 7)[:, 3:]]).reshape(*base_pose.shape[:-1], 3, 3)
    centre = base_pose[..., :3] + np.einsum("...ij,j->...i", rot, style.centre)
    local = np.einsum("...ji,...j->...i", rot, vec)  # the direction in the base frame
    # where the ray from the centre leaves the bounding box
    exit_t = np.min(style.half / np.maximum(np.abs(local), 1e-12), axis=-1, keepdims=True)
    start = centre + exit_t * vec
    return np.stack([start, start + vec], -2)


def protobuf_types() -> dict:
    """The Foxglove protobuf message classes the recorder writes, by name."""
    from foxglove_schemas_protobuf import (ArrowPrimitive_pb2, Color_pb2, FrameTransform_pb2, FrameTransforms_pb2,
                                           KeyValuePair_pb2, Point3_pb2, Pose_pb2, Quaternion_pb2, SceneEntity_pb2,
                                           SceneUpdate_pb2, TriangleListPrimitive_pb2, Vector3_pb2)

    return {m: getattr(mod, m) for mod, m in [
        (ArrowPrimitive_pb2, "ArrowPrimitive"), (Color_pb2, "Color"), (FrameTransform_pb2, "FrameTransform"),
        (FrameTransforms_pb2, "FrameTransforms"), (KeyValuePair_pb2, "KeyValuePair"), (Point3_pb2, "Point3"),
        (Pose_pb2, "Pose"), (Quaternion_pb2, "Quaternion"), (SceneEntity_pb2, "SceneEntity"),
        (SceneUpdate_pb2, "SceneUpdate"), (TriangleListPrimitive_pb2, "TriangleListPrimitive"),
        (Vector3_pb2, "Vector3")]}


def quat_from_to(src: np.ndarray, d: np.ndarray) -> tuple[float, float, float, float]:
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


def _color(pb, rgba):
    r, g, b, a = rgba
    return pb["Color"](r=r, g=g, b=b, a=a)


def _pose(pb, pos, quat_xyzw=(0.0, 0.0, 0.0, 1.0)):
    x, y, z, w = quat_xyzw
    return pb["Pose"](position=pb["Vector3"](x=float(pos[0]), y=float(pos[1]), z=float(pos[2])),
                      orientation=pb["Quaternion"](x=x, y=y, z=z, w=w))


def _points(pb, vertices):
    return [pb["Point3"](x=float(v[0]), y=float(v[1]), z=float(v[2])) for v in vertices]


def scene_update(pb, geometry: SceneGeometry, num_worlds: int, timestamp):
    """``/scene``: every mesh part of every world, frame-locked to its body (or world) frame, and the ghost."""
    from .format import body_frame

    update = pb["SceneUpdate"]()
    parts = [(p, _points(pb, p.vertices), [int(i) for i in p.faces.reshape(-1)]) for p in geometry.parts]
    ghost = (_points(pb, geometry.ghost_vertices), [int(i) for i in geometry.ghost_faces.reshape(-1)])
    for w in range(num_worlds):
        for k, (p, points, indices) in enumerate(parts):
            frame = world_frame(w) if p.body == STATIC else body_frame(w, geometry.body_names[p.body])
            e = update.entities.add(timestamp=timestamp, frame_id=frame, id=f"world{w}/part{k}", frame_locked=True)
            for key, value in (("name", p.name), ("role", p.role), ("body", str(p.body))):
                e.metadata.append(pb["KeyValuePair"](key=key, value=value))
            e.triangles.add(pose=_pose(pb, (0, 0, 0)), points=points, indices=indices, color=_color(pb, p.rgba))
        e = update.entities.add(timestamp=timestamp, frame_id=f"{world_frame(w)}/goal", id=f"world{w}/goal",
                                frame_locked=True)
        e.metadata.append(pb["KeyValuePair"](key="role", value="goal"))
        e.triangles.add(pose=_pose(pb, (0, 0, 0)), points=ghost[0], indices=ghost[1], color=_color(pb, GOAL_RGBA))
    return update


def arrows_update(pb, style: ArrowStyle, timestamp, base_pose: np.ndarray, vectors: np.ndarray):
    """``/scene/wrench``: per world ``w`` the four arrows ``vectors`` [N, 4, 3] (m) at the object's base
    ``base_pose`` [N, 7] (actual force, target force, actual torque, target torque)."""
    update = pb["SceneUpdate"]()
    segments = arrow_segments(style, base_pose[:, None], vectors)  # [N, 4, 2, 3]
    x_axis = np.array([1.0, 0.0, 0.0])
    for w in range(len(base_pose)):
        e = update.entities.add(timestamp=timestamp, frame_id=world_frame(w), id=f"world{w}/wrench", frame_locked=True)
        for (start, end), rgba in zip(segments[w], ARROW_RGBAS):
            length = float(np.linalg.norm(end - start))
            if length < 1e-4:
                continue
            head = min(style.head_length, 0.5 * length)
            e.arrows.add(pose=_pose(pb, start, quat_from_to(x_axis, (end - start) / length)),
                         shaft_length=length - head, shaft_diameter=2 * style.shaft_radius, head_length=head,
                         head_diameter=2 * style.head_radius, color=_color(pb, rgba))
    return update

