"""Atomic file writes: a temp file beside the target, fsync, ``os.replace``, then fsync of the directory.

A crash mid-write never leaves a half-written checkpoint, plan or recording where a good one was.

Example:
    >>> import os, tempfile
    >>> path = os.path.join(tempfile.mkdtemp(), "x.bin")
    >>> atomic_write(path, lambda f: f.write(b"hello"))
    >>> open(path, "rb").read()
    b'hello'
"""

from __future__ import annotations

import json
import logging
import math
import os
import tempfile
import time
from pathlib import Path
from typing import IO, Any, Callable

__all__ = ["atomic_write", "atomic_torch_save", "atomic_write_json", "json_safe", "dumps_json", "clean_stale_temps"]

log = logging.getLogger(__name__)


def atomic_write(path: str | os.PathLike, write: Callable[[IO[bytes]], object]) -> None:
    """Call ``write(f)`` on a binary temp file in ``path``'s directory and move it over ``path``. An
    ``OSError`` (a full disk, a read-only or missing directory) leaves ``path`` as it was, no temp file
    behind, and names ``path``, not the temp file the user never asked for."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as e:
        raise _naming(e, path) from None
    try:
        # mkstemp creates 0600; a plain open() would give 0666 & ~umask, which is what users expect of
        # checkpoints and plans they share
        os.fchmod(fd, 0o666 & ~_umask())
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as e:
        if os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(e, OSError):
            raise _naming(e, path) from None
        raise
    # persist the rename itself; not possible on every platform, so best effort
    try:
        dir_fd = os.open(path.parent, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(dir_fd)
    except OSError:
        log.debug("could not fsync directory %s", path.parent)
    finally:
        os.close(dir_fd)


def _naming(error: OSError, path: Path) -> OSError:
    """``error`` about ``path`` (the same type: ``PermissionError``, ...), not about the temp file."""
    if error.errno is None:  # no system error to restate (a message of its own)
        return error
    return OSError(error.errno, error.strerror, str(path))


class _WriteErrors:
    """A binary file whose ``write`` remembers the ``OSError`` it raised: torch's zip writer turns a failed
    write (a full disk) into a ``RuntimeError`` about stream positions when it closes the archive."""

    def __init__(self, f: IO[bytes]):
        self.f, self.error = f, None

    def write(self, data) -> int:
        try:
            return self.f.write(data)
        except OSError as e:
            self.error = e
            raise

    def flush(self) -> None:
        self.f.flush()


def atomic_torch_save(obj, path: str | os.PathLike) -> None:
    """``torch.save(obj)`` to ``path`` atomically; a failed write is its ``OSError`` (see :func:`atomic_write`)."""
    import torch

    def save(f: IO[bytes]) -> None:
        guarded = _WriteErrors(f)
        try:
            torch.save(obj, guarded)
        except RuntimeError:
            if guarded.error is None:
                raise
            raise guarded.error from None

    atomic_write(path, save)


def _umask() -> int:
    # /proc avoids os.umask's set-and-restore, which races with other threads creating files
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def json_safe(obj: Any) -> Any:
    """``obj`` with every non-finite float replaced by ``None`` (JSON has no NaN/Infinity; Python's
    ``json`` would write bare ``NaN``, which strict parsers reject)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    return obj


def dumps_json(obj: Any, **kwargs) -> str:
    """Strict JSON text of ``obj``: non-finite floats become ``null``."""
    return json.dumps(json_safe(obj), allow_nan=False, **kwargs)


def atomic_write_json(path: str | os.PathLike, obj: Any, indent: int | None = 2) -> None:
    """Write ``obj`` as strict JSON (see :func:`dumps_json`) to ``path`` atomically."""
    text = dumps_json(obj, indent=indent) + "\n"
    atomic_write(path, lambda f: f.write(text.encode()))


def clean_stale_temps(directory: str | os.PathLike, min_age_s: float = 0.0) -> list[Path]:
    """Remove the temp files (``.<name>.*.tmp``) a killed writer left in ``directory``; returns them.

    Only call it where no other writer can be mid-save (e.g. a run directory under its lock): a live
    writer's temp file looks the same. ``min_age_s`` spares files modified more recently than that."""
    directory = Path(directory)
    if not directory.is_dir():
        return []
    removed, now = [], time.time()
    for tmp in directory.glob(".*.tmp"):
        try:
            if tmp.is_file() and now - tmp.stat().st_mtime >= min_age_s:
                tmp.unlink()
                removed.append(tmp)
        except FileNotFoundError:
            continue
    if removed:
        log.info("removed %d stale temp file(s) in %s", len(removed), directory)
    return removed
