"""Identified object parameters: the JSON file ``dexmots-sysid`` writes and ``task.object_params`` reads.

A task built with ``task.object_params=<file>`` simulates every world with the file's values of the named
physical parameters (``("sim", "params", name)``) instead of its randomised or nominal ones; the parameters
the file does not name keep the task's draw. The file::

    {"format": "dexmots-object-params", "version": 1, "task": "screw_claw",
     "params": {"joint_damping": 0.52, "joint_friction": 0.61},
     "std": {"joint_damping": 0.004, "joint_friction": 0.01}, ...}

``std`` (one standard deviation from the identification's covariance) and any other key are informative.

Example:
    >>> import os, tempfile
    >>> path = os.path.join(tempfile.mkdtemp(), "knob.json")
    >>> write_object_params(path, "screw_claw", {"joint_damping": 0.5})
    >>> read_object_params(path, ("joint_damping", "joint_friction"))
    {'joint_damping': 0.5}
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

from ..atomic import atomic_write_json

__all__ = ["OBJECT_PARAMS_FORMAT", "read_object_params", "write_object_params"]

OBJECT_PARAMS_FORMAT = "dexmots-object-params"
_VERSION = 1


def write_object_params(path: str | os.PathLike, task: str, params: dict[str, float], **extra) -> None:
    """Write ``params`` ({name: value}) for ``task`` to ``path`` atomically; ``extra`` keys are stored as they are
    (JSON values: e.g. ``std``, the data the values came from)."""
    atomic_write_json(path, {"format": OBJECT_PARAMS_FORMAT, "version": _VERSION, "task": task,
                             "params": {k: float(v) for k, v in params.items()}, **extra})


def read_object_params(path: str | os.PathLike, known: tuple[str, ...]) -> dict[str, float]:
    """The ``{name: value}`` of an object-parameter file, checked: one ``ValueError`` naming the file and the bad
    element (not a file of this format, a value that is not a finite number, a name not in ``known``, the
    scene's parameter names)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"task.object_params: no such file {path}")
    try:
        data = json.loads(path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"task.object_params: {path} is not JSON ({exc})") from None
    if not isinstance(data, dict) or data.get("format") != OBJECT_PARAMS_FORMAT:
        raise ValueError(f"task.object_params: {path} is not a {OBJECT_PARAMS_FORMAT} file (write it with "
                         "dexmots-sysid)")
    params = data.get("params")
    if not isinstance(params, dict) or not params:
        raise ValueError(f"task.object_params: {path} has no 'params' mapping")
    for name, value in params.items():
        if name not in known:
            raise ValueError(f"task.object_params: {path} names parameter {name!r}, which this scene does not have; "
                             f"its parameters are {', '.join(known) or 'none'}")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ValueError(f"task.object_params: {path}: params.{name} must be a finite number, got {value!r}")
    return {name: float(value) for name, value in params.items()}
