"""Recorded trajectories for system identification: an MCAP recording or a documented ``.npz``.

:class:`Trajectories` holds ``F`` frames of ``N`` worlds: the full simulator state per frame (the hand's joints,
then the object's coordinates: a free base's position and ``wxyz`` quaternion first, then its parts' joints), the
hand's drive over the step that led to each frame, the task that simulates the scene, and the physical
parameters the recording was made with where it says them.

The ``.npz`` layout (arrays; ``F`` frames, ``N`` worlds, ``nu`` hand joints)::

    hand_q, hand_qd          [F, N, nu]     hand joint positions (rad, m) and velocities
    object_q, object_qd      [F, N, nq_o], [F, N, nv_o]   the object's coordinates and velocities
    tau, q_target, kp, kd    [F, N, nu]     the drive ``tau + kp (q_target - q) - kd qd`` applied over the
                                            step from frame f - 1 to frame f (row 0 unused; NaN: no step)
    dt                       scalar         seconds between frames (the task's env step)
    task                     str            the task: its registry name or its config as JSON
    episode                  [F] (optional) episode index per frame; a step never crosses episodes
    params/<name>            [F, N, 1] (optional) the parameters the data was made with (truth, if known)

Example:
    >>> import numpy as np
    >>> t = Trajectories(joint_q=np.zeros((3, 2, 5)), joint_qd=np.zeros((3, 2, 5)),
    ...                  control={k: np.zeros((3, 2, 4)) for k in CONTROL_FIELDS}, episode=np.zeros(3, int),
    ...                  dt=1 / 60, task={"name": "screw_claw"}, params={})
    >>> t.num_frames, t.num_worlds, len(t.segment_starts(2))
    (3, 2, 2)
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import numpy as np

from ..atomic import atomic_write
from ..recording import RecordingFormatError, read_recording
from ..recording.format import CONTROL_FIELDS

__all__ = ["CONTROL_FIELDS", "Trajectories", "load_trajectories", "save_npz"]


@dataclasses.dataclass
class Trajectories:
    """F frames x N worlds of recorded motion (see the module docstring); arrays are float64 numpy."""

    joint_q: np.ndarray  # [F, N, nq]: hand joints, then the object's coordinates
    joint_qd: np.ndarray  # [F, N, nv]
    control: dict  # name in CONTROL_FIELDS -> [F, N, nu]: the drive over the step into frame f (NaN: none)
    episode: np.ndarray  # [F] int
    dt: float
    task: dict  # the task config (at least its "name"): make_env rebuilds the scene from it
    params: dict  # name -> [F, N, 1]: the values the data was made with, where known
    source: str = ""

    @property
    def num_frames(self) -> int:
        return int(self.joint_q.shape[0])

    @property
    def num_worlds(self) -> int:
        return int(self.joint_q.shape[1])

    def segment_starts(self, steps: int) -> list[tuple[int, int]]:
        """``(frame, world)`` of every run of ``steps`` steps that stays in one episode and has a drive on each
        step: the shooting segments, non-overlapping within a world."""
        usable = np.isfinite(np.stack([c for c in self.control.values()])).all(axis=(0, 3))  # [F, N]
        same = self.episode[1:] == self.episode[:-1]  # step f -> f + 1 stays in the episode
        starts = []
        for w in range(self.num_worlds):
            f = 0
            while f + steps < self.num_frames:
                ok = same[f:f + steps].all() and usable[f + 1:f + steps + 1, w].all()
                if ok:
                    starts.append((f, w))
                    f += steps
                else:
                    f += 1
        return starts


def _task_of(value, where: str) -> dict:
    text = str(value)
    if text.lstrip().startswith("{"):
        try:
            task = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{where}: 'task' is not valid JSON ({exc})") from None
    else:
        task = {"name": text}
    if not isinstance(task, dict) or not task.get("name"):
        raise ValueError(f"{where}: 'task' must name the task (its registry name or its config as JSON)")
    return task


def _from_mcap(path: Path) -> Trajectories:
    rec = read_recording(path)
    frames = rec.frames
    missing = [key for key in (("sim", "joint_qd"), ("control", "tau")) if key not in frames.keys(True)]
    if missing:
        raise ValueError(f"{path}: the recording lacks {'/'.join(missing[0])} (the hand's drive and the velocities "
                         "are recorded by this library's dexmots-record and dexmots-eval --record); record it again")
    task = json.loads(rec.meta.get("task_config", "null") or "null")
    if not task:
        raise ValueError(f"{path}: the recording does not say its task config (a bare simulator's recording)")

    def arr(key):
        return frames.get(key).double().numpy()

    params = {}
    if "params" in frames["sim"].keys():
        params = {name: arr(("sim", "params", name)) for name in frames["sim", "params"].keys()}
    return Trajectories(joint_q=arr(("sim", "joint_q")), joint_qd=arr(("sim", "joint_qd")),
                        control={k: arr(("control", k)) for k in CONTROL_FIELDS}, episode=rec.episode.numpy(),
                        dt=float(rec.meta["dt"]), task=task, params=params, source=str(path))


def _from_npz(path: Path) -> Trajectories:
    try:
        data = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: not a readable .npz file ({exc})") from None
    with data:
        required = ("hand_q", "hand_qd", "object_q", "object_qd", *CONTROL_FIELDS, "dt", "task")
        missing = [k for k in required if k not in data.files]
        if missing:
            raise ValueError(f"{path}: missing array {missing[0]!r} (a trajectory file holds {', '.join(required)})")
        arrays = {k: np.asarray(data[k], dtype=np.float64) for k in required[:-2]}
        frames, worlds = arrays["hand_q"].shape[:2] if arrays["hand_q"].ndim == 3 else (None, None)
        for key, value in arrays.items():
            if value.ndim != 3 or value.shape[:2] != (frames, worlds):
                raise ValueError(f"{path}: {key!r} has shape {value.shape}; expected [frames, worlds, width] with "
                                 f"the hand_q's frames and worlds {(frames, worlds)}")
        dt = float(data["dt"])
        if not np.isfinite(dt) or dt <= 0:
            raise ValueError(f"{path}: 'dt' must be a positive number of seconds, got {dt}")
        episode = np.asarray(data["episode"], dtype=np.int64) if "episode" in data.files else np.zeros(frames, int)
        if episode.shape != (frames,):
            raise ValueError(f"{path}: 'episode' has shape {episode.shape}; expected ({frames},)")
        params = {k.split("/", 1)[1]: np.asarray(data[k], dtype=np.float64).reshape(frames, worlds, 1)
                  for k in data.files if k.startswith("params/")}
        task = _task_of(data["task"], str(path))
    return Trajectories(joint_q=np.concatenate([arrays["hand_q"], arrays["object_q"]], -1),
                        joint_qd=np.concatenate([arrays["hand_qd"], arrays["object_qd"]], -1),
                        control={k: arrays[k] for k in CONTROL_FIELDS}, episode=episode, dt=dt, task=task,
                        params=params, source=str(path))


def load_trajectories(path: str | os.PathLike) -> Trajectories:
    """Read an MCAP recording (``.mcap``) or a trajectory file (``.npz``, layout in the module docstring); one
    ``ValueError`` naming the file and what is wrong with it."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: no such file")
    if path.suffix == ".mcap":
        try:
            return _from_mcap(path)
        except RecordingFormatError as exc:
            raise ValueError(str(exc)) from None
    if path.suffix == ".npz":
        return _from_npz(path)
    raise ValueError(f"{path}: unknown trajectory file type {path.suffix!r} (an MCAP recording .mcap or a .npz)")


def save_npz(traj: Trajectories, path: str | os.PathLike, num_hand_dofs: int) -> None:
    """Write ``traj`` in the ``.npz`` layout (``num_hand_dofs``: where the hand's coordinates end)."""
    nu = num_hand_dofs
    arrays = {"hand_q": traj.joint_q[..., :nu], "object_q": traj.joint_q[..., nu:], "hand_qd": traj.joint_qd[..., :nu],
              "object_qd": traj.joint_qd[..., nu:], **traj.control, "dt": np.float64(traj.dt),
              "task": np.str_(json.dumps(traj.task)), "episode": traj.episode,
              **{f"params/{k}": v for k, v in traj.params.items()}}
    atomic_write(path, lambda stream: np.savez(stream, **arrays))
