"""Progress bars for people at a terminal: :func:`progress_bar` is a tqdm bar that is shown only when its
stream is a terminal. Redirected to a log file (a batch job, ``dexmots-table``'s launchers, ``> log``) it
writes nothing, instead of one carriage-return update per iteration; the metrics files and the log lines
report the progress there.

Example:
    >>> import io
    >>> log = io.StringIO()
    >>> for _ in progress_bar(range(1000), file=log):
    ...     pass
    >>> log.getvalue()
    ''
"""

from __future__ import annotations

import sys

__all__ = ["on_terminal", "progress_bar"]


def on_terminal(stream) -> bool:
    """Whether ``stream`` is an interactive terminal."""
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        return False


def progress_bar(*args, disable: bool = False, file=None, **kwargs):
    """``tqdm(*args, **kwargs)`` on ``file`` (default stderr), disabled unless that is a terminal."""
    from tqdm.auto import tqdm

    file = sys.stderr if file is None else file
    return tqdm(*args, disable=disable or not on_terminal(file), file=file, **kwargs)
