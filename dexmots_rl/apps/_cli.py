"""Shared console-script plumbing: an environment failure (full disk, read-only or missing directory,
permissions) is one line on stderr naming the program, not a traceback."""

from __future__ import annotations

import errno
import os
from contextlib import contextmanager

__all__ = ["errors_as_one_line", "os_errors_as_one_line"]


@contextmanager
def os_errors_as_one_line(prog: str):
    """Turn an ``OSError`` raised inside the block into ``SystemExit("<prog>: ...")``."""
    try:
        yield
    except OSError as e:
        where = f" ({e.filename})" if e.filename else ""
        if e.errno in (errno.ENOSPC, getattr(errno, "EDQUOT", -1)) and e.strerror == os.strerror(e.errno):
            raise SystemExit(f"{prog}: no space left on device{where}; free some space and rerun") from None
        # a message of our own (not the system's) already says what to do
        raise SystemExit(f"{prog}: {e.strerror or e}{where}") from None


@contextmanager
def errors_as_one_line(prog: str, *errors: type[BaseException]):
    """:func:`os_errors_as_one_line`, and ``errors`` (bad input: ``ValueError`` by default) as
    ``SystemExit("<prog>: <message>")``."""
    try:
        with os_errors_as_one_line(prog):
            yield
    except errors or (ValueError,) as e:
        raise SystemExit(f"{prog}: {e}") from None
