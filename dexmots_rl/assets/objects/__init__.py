"""Articulated objects: the description (:mod:`.description`), procedural generators and a URDF loader."""

from __future__ import annotations

from .description import GEOM_KINDS, MAX_MOVING_PARTS, Geom, Joint, ObjectAsset, ObjectError, Part

__all__ = ["GEOM_KINDS", "MAX_MOVING_PARTS", "Geom", "Joint", "ObjectAsset", "ObjectError", "Part"]
