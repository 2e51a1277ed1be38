"""One module per task (a folder per hand family): its typed config, env class, randomisation,
reference, bench poses and scripted controller. Importing this package registers every task."""

from __future__ import annotations

from . import allegro, screw_claw  # noqa: F401  (each registers its tasks)

__all__ = ["allegro", "screw_claw"]
