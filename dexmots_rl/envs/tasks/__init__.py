"""One module per task (a folder per hand family): its typed config, env class, randomisation,
reference, bench poses and scripted controller. Importing this package registers every task."""

from __future__ import annotations

from . import screw_claw  # noqa: F401  (registers screw_claw)

__all__ = ["screw_claw"]
