"""Articulated objects: the description (:mod:`.description`), procedural generators and a URDF loader.

``list_objects()`` names the shipped objects with their class; ``load_object(name_or_path)`` returns one as
an :class:`ObjectAsset` (a library name, or a ``.urdf`` file); ``sample_variants(name, k, rng)`` draws k size
variants of an instance (one topology); ``object_split(cls)`` splits a class's instances into
training and held-out ones; ``object_scene_xml`` writes an object on a table as a MuJoCo model.
"""

from __future__ import annotations

from .description import (FINGERS, GEOM_KINDS, MAX_MOVING_PARTS, SCENE_PREFIX, Geom, GraspRegion, Joint, ObjectAsset,
                          ObjectError, Part)
from .library import INSTANCES, SPLITS, list_objects, load_object, object_split, sample_variants
from .scene import object_scene_xml, posed_meshes

__all__ = ["FINGERS", "GEOM_KINDS", "MAX_MOVING_PARTS", "Geom", "GraspRegion", "Joint", "ObjectAsset", "ObjectError",
           "Part", "SCENE_PREFIX", "INSTANCES", "SPLITS", "list_objects", "load_object", "object_split", "sample_variants",
           "object_scene_xml", "posed_meshes"]
