"""Checkpoints: one ``.pt`` file holding a plain dict (loads with ``weights_only=True``), written atomically.

=================  ====================================================================
key                value
=================  ====================================================================
``format``         ``"dexmots-checkpoint"``
``version``        ``1``
``task`` / algo    the task and algorithm names (resume checks them)
``config``         the resolved run configuration (plain dict)
``iteration``      iterations completed
``modules``        ``{name: state_dict}`` (actor, critic, loss incl. target critic, normaliser, ahac)
``optimizers``     ``{name: state_dict}``
``env_state``      the env's TensorDict where training stopped (plain dict of tensors)
``rng``            torch and env-generator RNG states, for bit-identical resumes on CPU
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

__all__ = ["CheckpointError", "FORMAT_NAME", "FORMAT_VERSION", "save_checkpoint", "load_checkpoint", "latest_checkpoint"]

FORMAT_NAME = "dexmots-checkpoint"
FORMAT_VERSION = 1


class CheckpointError(ValueError):
    """A checkpoint file that is missing, truncated, not ours, or from another format version."""


def save_checkpoint(path: str | os.PathLike, state: dict[str, Any]) -> None:
    """Write ``state`` (plus format and version) to ``path`` atomically: temp file, fsync, ``os.replace``."""
    atomic_torch_save({"format": FORMAT_NAME, "version": FORMAT_VERSION, **state}, path)


def load_checkpoint(path: str | os.PathLike, task: str | None = None) -> dict[str, Any]:
    """Load and check a checkpoint; ``task`` (if given) must match the one it was trained on."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint {path} does not exist")
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # truncated zip, pickle garbage, ...
        raise CheckpointError(f"checkpoint {path} is truncated or not a checkpoint ({type(e).__name__}: {e})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT_NAME:
        raise CheckpointError(f"checkpoint {path}: not a {FORMAT_NAME} file")
    if data.get("version") != FORMAT_VERSION:
        raise CheckpointError(f"checkpoint {path}: format version {data.get('version')!r}, this library reads "
                              f"version {FORMAT_VERSION}")
    if task is not None and data.get("task") != task:
        raise CheckpointError(f"checkpoint {path} is from task {data.get('task')!r}, not {task!r}")
    return data


def latest_checkpoint(run_dir: str | os.PathLike) -> Path:
    """``<run_dir>/checkpoints/last.pt``, with a clear error when the run has none."""
    path = Path(run_dir) / "checkpoints" / "last.pt"
    if not path.is_file():
        raise CheckpointError(f"{run_dir} has no checkpoint (expected {path})")
    return path
