"""Where a result comes from: the library's commit, the machine and the date, recorded with every run's
``metrics.json`` and every benchmark so a figure can be traced back (results carry command, machine, date and
commit).

Example:
    >>> sorted(provenance())
    ['commit', 'cores', 'cpu', 'date', 'python', 'version']
"""

from __future__ import annotations

import datetime
import os
import platform
import subprocess
from pathlib import Path

__all__ = ["commit", "cpu_model", "provenance"]


def commit() -> str | None:
    """The short git commit of the checkout this package is imported from, ``+dirty`` when the package's files
    differ from it (``None`` for an installed wheel)."""
    here = Path(__file__).resolve().parent
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=here, capture_output=True, text=True,
                              timeout=10)
        if head.returncode != 0 or not head.stdout.strip():
            return None
        dirty = subprocess.run(["git", "diff", "--quiet", "HEAD", "--", "."], cwd=here, timeout=10).returncode
    except (OSError, subprocess.SubprocessError):
        return None
    return head.stdout.strip() + ("+dirty" if dirty else "")


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo`` on Linux; else what :mod:`platform` knows)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def provenance() -> dict:
    """``{"commit", "version", "cpu", "cores", "python", "date"}`` of this process (date in UTC, ISO 8601)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        package_version = version("dexmots_rl")
    except PackageNotFoundError:
        package_version = None
    return {"commit": commit(), "version": package_version, "cpu": cpu_model(), "cores": os.cpu_count(),
            "python": platform.python_version(),
            "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}
