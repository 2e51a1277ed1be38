"""Checkpoints: one ``.pt`` file holding a plain dict (loads with ``weights_only=True``), written atomically.

=================  ====================================================================
key                value
=================  ====================================================================
``format``         ``"dexmots-checkpoint"``
``version``        ``2`` (version 1: the same without a checksum, still read)
``sha256``         :func:`~dexmots_rl.integrity.payload_digest` of everything else, checked on load
``task`` / algo    the task and algorithm names (resume checks them)
``config``         the resolved run configuration (plain dict)
``iteration``      iterations completed
``modules``        ``{name: state_dict}`` (actor, critic, loss incl. target critic, normaliser, ahac)
``optimizers``     ``{name: state_dict}``
``env_state``      the env's TensorDict where training stopped (plain dict of tensors): the worlds mid-episode
``rng``            torch and env-generator RNG states (:func:`rng_states`), for bit-identical resumes on CPU
``replay_buffer``  SAC's transitions and write cursor (:func:`~.common.replay_buffer_state`)
``counters``       env steps, skipped updates, ...
=================  ====================================================================

Example:
    >>> import tempfile, os
    >>> path = os.path.join(tempfile.mkdtemp(), "ckpt.pt")
    >>> save_checkpoint(path, {"task": "screw_claw", "algo": "shac", "iteration": 3})
    >>> load_checkpoint(path)["iteration"]
    3
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import torch

from ..atomic import atomic_torch_save
from ..integrity import checksum_problem, load_failure, with_checksum

__all__ = ["CheckpointError", "FORMAT_NAME", "FORMAT_VERSION", "save_checkpoint", "load_checkpoint", "latest_checkpoint",
           "restore_rng_states", "rng_states"]

FORMAT_NAME = "dexmots-checkpoint"
FORMAT_VERSION = 2
_READABLE_VERSIONS = (1, 2)  # 1: before checksums


class CheckpointError(ValueError):
    """A checkpoint file that is missing, truncated, corrupt, not ours, or from another format version."""


def save_checkpoint(path: str | os.PathLike, state: dict[str, Any]) -> None:
    """Write ``state`` (plus format and version) to ``path`` atomically: temp file, fsync, ``os.replace``."""
    atomic_torch_save(with_checksum({"format": FORMAT_NAME, "version": FORMAT_VERSION, **state}), path)


def load_checkpoint(path: str | os.PathLike, task: str | None = None) -> dict[str, Any]:
    """Load and check a checkpoint; ``task`` (if given) must match the one it was trained on."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint {path} does not exist")
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # truncated zip, pickle garbage, ...
        raise CheckpointError(f"checkpoint {path} is truncated or not a checkpoint ({load_failure(e)})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT_NAME:
        raise CheckpointError(f"checkpoint {path}: not a {FORMAT_NAME} file")
    version = data.get("version")
    if isinstance(version, bool) or version not in _READABLE_VERSIONS:
        raise CheckpointError(f"checkpoint {path}: format version {version!r}, this library reads "
                              f"versions {', '.join(map(str, _READABLE_VERSIONS))}")
    if version >= 2:
        problem = checksum_problem(data)
        if problem is not None:
            raise CheckpointError(f"checkpoint {path} {problem}; it cannot be trusted (use another checkpoint)")
    if task is not None and data.get("task") != task:
        raise CheckpointError(f"checkpoint {path} is from task {data.get('task')!r}, not {task!r}")
    return data


def latest_checkpoint(run_dir: str | os.PathLike) -> Path:
    """``<run_dir>/checkpoints/last.pt``, with a clear error when the run has none."""
    path = Path(run_dir) / "checkpoints" / "last.pt"
    if not path.is_file():
        raise CheckpointError(f"{run_dir} has no checkpoint (expected {path})")
    return path


def rng_states(env) -> dict[str, torch.Tensor]:
    """The random streams a training run draws from: torch's (sampled actions, minibatch order, ...) and the
    task env's generator (the worlds' resets: goals, frictions, starts); ``env`` the task env or a
    ``TransformedEnv`` on it."""
    return {"torch": torch.get_rng_state(), "env": env.get_rng_state()}


def restore_rng_states(env, states: dict[str, torch.Tensor]) -> None:
    """Set the streams :func:`rng_states` saved (a checkpoint's ``rng``)."""
    torch.set_rng_state(states["torch"])
    if "env" in states:
        env.set_rng_state(states["env"])
