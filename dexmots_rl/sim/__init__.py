"""Differentiable simulation core (the only package that imports warp).

``load_scene`` (MJCF via MuJoCo) -> a simulator (kernels + model arrays on a device) -> ``step`` (state tensors
in, state tensors out, through an autograd Function). A scene whose object is one hinged or free body (the knob,
the cube) is a :class:`SceneModel` stepped by :class:`Simulator`; a hand with an articulated object on a table
(a base with moving parts) is an :class:`ArticulatedScene` stepped by :class:`ArticulatedSimulator`, with the same
interface; the object alone on its table is :class:`ObjectSimulator`.
"""

from __future__ import annotations

import os

import warp as wp

wp.config.quiet = True
# module-load messages go to stdout at INFO level; keep stdout clean for JSON-printing commands
wp.config.log_level = wp.LOG_WARNING
# unrolled loops keep warp's adjoints exact; our kernels nest short loops over fingers/links/points
wp.config.max_unroll = max(wp.config.max_unroll, 64)
wp.init()
if os.environ.get("DEXMOTS_VERIFY_AUTOGRAD"):
    wp.config.verify_autograd_array_access = True

from .model import AssetError, ContactParams, SceneModel, load_scene  # noqa: E402
from .simulator import Control, SimStep, Simulator, StepOutput  # noqa: E402
from .articulated import ArticulatedScene, ArticulatedSimulator, ArticulatedStepOutput  # noqa: E402
from .object_sim import ObjectSimulator, TableContact, load_object_tree  # noqa: E402

__all__ = ["AssetError", "ContactParams", "SceneModel", "load_scene", "Control", "SimStep", "Simulator", "StepOutput",
           "ArticulatedScene", "ArticulatedSimulator", "ArticulatedStepOutput", "ObjectSimulator", "TableContact",
           "load_object_tree"]
