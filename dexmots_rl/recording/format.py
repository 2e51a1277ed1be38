"""The DexMOTS recording format: an MCAP file (zstd chunks) that Foxglove opens as it is.

=====================  ==========================  ====================================================
topic                  schema (encoding)           content
=====================  ==========================  ====================================================
``/tf``                ``foxglove.FrameTransforms``  every frame: ``world`` -> ``world{w}`` (the world's
                       (protobuf)                    place in the grid), ``world{w}`` -> ``world{w}/{body}``
                                                     for every recorded body (the hand's links, then the
                                                     object's bodies, by MJCF name), and ``world{w}/goal``
                                                     (the object's base at its goal pose)
``/scene``             ``foxglove.SceneUpdate``      once: frame-locked entities ``world{w}/part{k}`` (a
                       (protobuf)                    triangle mesh in its body's frame, or in ``world{w}``
                                                     for the palm, static parts and the table; metadata
                                                     ``name``, ``role``, ``body``), ``world{w}/goal`` (the
                                                     object at rest, translucent)
``/scene/wrench``      ``foxglove.SceneUpdate``      every frame: arrows at the object, in ``world{w}``:
                                                     actual / target force and torque
``/dexmots/step``      ``dexmots.Step`` (JSON)       every frame: ``frame``, ``episode``, ``time`` and per
                                                     world lists: ``reward``, ``success``, ``step``,
                                                     ``object_q``, ``wrench``, ``target_wrench``, ``goal``,
                                                     ``hand_q``, ``joint_q``, ``joint_qd``,
                                                     ``reward_terms.{name}``, ``params.{name}`` (the
                                                     world's physical parameters) and, on a frame that
                                                     a step led to, ``control.{tau,q_target,kp,kd}``
                                                     (the hand's drive over that step)
=====================  ==========================  ====================================================

An MCAP metadata record ``dexmots`` holds ``format``, ``version``, ``task``, ``num_worlds``,
``num_frames``, ``dt``, ``dtype``, ``body_names`` (JSON), ``num_hand_links``, ``world_offsets`` (JSON),
``start_time_ns``, the arrow scales ``force_scale`` / ``torque_scale``, ``goal`` (``"false"`` when the
recorded task has no goal pose: the ghost then sits on the object and is hidden at first) and ``task_config``
(JSON: the recorded env's task config, from which ``make_env`` rebuilds the task; ``null`` for a bare simulator).
``joint_qd``, ``params``, ``control`` and ``task_config`` are newer than the other fields: a reader accepts
recordings without them. A frame's log time is ``start_time_ns + frame * dt``;
episodes follow each other on one timeline (``episode`` says which). Poses are position + ``wxyz`` quaternion
(Foxglove's ``xyzw`` on ``/tf``); float values go through float64 (protobuf doubles, JSON ``repr``), so
a float32 recording reads back bit-exact. In Foxglove: a 3D panel (fixed frame ``world``) and a Plot
panel on ``/dexmots/step.reward[0]`` etc.

Example:
    >>> RecordingFormatError("bad.mcap: not an MCAP file").args[0]
    'bad.mcap: not an MCAP file'
"""

from __future__ import annotations

import dataclasses

import torch
from tensordict import TensorDict

from .geometry import SceneGeometry

__all__ = ["CONTROL_FIELDS", "FORMAT_NAME", "FORMAT_VERSION", "TF_TOPIC", "SCENE_TOPIC", "WRENCH_TOPIC", "STEP_TOPIC", "ROOT_FRAME",
           "STEP_SCHEMA", "RecordingFormatError", "Recording", "world_frame", "body_frame"]

FORMAT_NAME = "dexmots-recording"
FORMAT_VERSION = 2
TF_TOPIC, SCENE_TOPIC, WRENCH_TOPIC, STEP_TOPIC = "/tf", "/scene", "/scene/wrench", "/dexmots/step"
ROOT_FRAME = "world"
CONTROL_FIELDS = ("tau", "q_target", "kp", "kd")  # the hand's drive (dexmots_rl.sim.Control), per world and joint
STEP_SCHEMA_NAME = "dexmots.Step"
_LIST = {"type": "array", "items": {"type": "number"}}
_LISTS = {"type": "array", "items": _LIST}
STEP_SCHEMA = {
    "title": STEP_SCHEMA_NAME,
    "type": "object",
    "properties": {
        "frame": {"type": "integer"},
        "episode": {"type": "integer"},
        "time": {"type": "number", "description": "seconds since the recording started"},
        "reward": _LIST, "success": {"type": "array", "items": {"type": "boolean"}},
        "step": {"type": "array", "items": {"type": "integer"}},
        "object_q": _LISTS, "wrench": _LISTS, "target_wrench": _LISTS, "goal": _LISTS, "hand_q": _LISTS,
        "joint_q": _LISTS, "joint_qd": _LISTS,
        "reward_terms": {"type": "object", "additionalProperties": _LIST},
        "params": {"type": "object", "additionalProperties": _LIST},
        "control": {"type": "object", "additionalProperties": _LISTS},
    },
}


class RecordingFormatError(ValueError):
    """A recording that is missing, truncated, corrupted, or not a DexMOTS recording."""


def world_frame(w: int) -> str:
    return f"{ROOT_FRAME}{w}"


def body_frame(w: int, name: str) -> str:
    """``world{w}/{name}``: the frame of recorded body ``name`` (its MJCF name) in world ``w``."""
    return f"{world_frame(w)}/{name}"


@dataclasses.dataclass
class Recording:
    """A recording read back by :func:`~dexmots_rl.recording.read_recording`.

    ``frames`` is a TensorDict of batch ``[F, N]`` (frames x worlds) with ``"body_pose"`` [F, N, B, 7],
    ``"goal_pose"`` [F, N, 7], ``"reward"``, ``"success"``, ``("task", "step")``, ``("object", "q")``,
    ``("object", "wrench")``, ``"target_wrench"``, ``("task", "goal")``, ``("hand", "q")``,
    ``("sim", "joint_q")`` and ``("reward_terms", name)``; where the file has them, ``("sim", "joint_qd")``,
    ``("sim", "params", name)`` and ``("control", name)`` for ``name`` in :data:`CONTROL_FIELDS` (NaN on a
    frame no step led to: an episode's first). ``episode`` [F] and ``time`` [F] (seconds)
    index the timeline; ``world_offsets`` [N, 3] is where each world is drawn.
    """

    meta: dict
    geometry: SceneGeometry
    frames: TensorDict
    episode: torch.Tensor
    time: torch.Tensor
    world_offsets: torch.Tensor

    @property
    def num_frames(self) -> int:
        return int(self.frames.batch_size[0])

    @property
    def num_worlds(self) -> int:
        return int(self.frames.batch_size[1])

    @property
    def reward_terms(self) -> list[str]:
        return sorted(self.frames["reward_terms"].keys()) if "reward_terms" in self.frames.keys() else []
