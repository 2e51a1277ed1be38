"""Hand and object descriptions (MJCF files compiled by MuJoCo)."""

from __future__ import annotations

from pathlib import Path

__all__ = ["ASSET_DIR", "asset_path"]

ASSET_DIR = Path(__file__).resolve().parent


def asset_path(name: str) -> Path:
    """Absolute path of a bundled asset file, e.g. ``asset_path("claw_screw.xml")``."""
    return ASSET_DIR / name
