"""Progress bars are drawn on a terminal only: a log file gets no carriage-return updates."""

from __future__ import annotations

import io
import re
from pathlib import Path

import dexmots_rl
from dexmots_rl.progress import progress_bar


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_bar_draws_on_a_terminal_and_writes_nothing_into_a_log():
    terminal, log = _Terminal(), io.StringIO()
    for stream in (terminal, log):
        for _ in progress_bar(range(500), file=stream, mininterval=0):
            pass
    assert terminal.getvalue().count("\r") > 10
    assert log.getvalue() == ""


def test_disable_still_disables_on_a_terminal():
    terminal = _Terminal()
    for _ in progress_bar(range(10), file=terminal, disable=True):
        pass
    assert terminal.getvalue() == ""


def test_every_bar_of_the_library_goes_through_progress_bar():
    package = Path(dexmots_rl.__file__).parent
    direct = [str(p.relative_to(package)) for p in package.rglob("*.py")
              if p.name != "progress.py" and re.search(r"^\s*(from tqdm|import tqdm)", p.read_text(), re.M)]
    assert not direct, f"modules that draw tqdm bars on any stream: {direct}"
