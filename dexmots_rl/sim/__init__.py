"""Differentiable simulation core (the only package that imports warp); this module is its public surface.

``load_scene`` (MJCF via MuJoCo) -> ``make_simulator`` (kernels + model arrays on a device) -> ``step`` (state
tensors in, a :class:`StepOutput` out, through an autograd Function). A scene whose object is one hinged or free
body (the knob, the cube) is a :class:`SceneModel` stepped by :class:`Simulator`; a hand with an articulated object
on a table (a base with moving parts) is an :class:`ArticulatedScene` stepped by :class:`ArticulatedSimulator`;
both are a :class:`HandSimulator`, and ``make_simulator`` picks the one for a scene. The object alone on its table
is :class:`ObjectSimulator`; ``make_renderer`` draws a scene's worlds. Import from here: the submodules are the
implementation and may move.

Example:
    >>> from dexmots_rl.assets import asset_path
    >>> from dexmots_rl.sim import load_scene, make_simulator
    >>> sim = make_simulator(load_scene(asset_path("claw_screw.xml")), num_worlds=2)
    >>> q, qd = sim.initial_state()
    >>> sim.step(q, qd, sim.zero_control(), sim.default_params()).joint_q.shape
    torch.Size([2, 5])
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

# scenes
from ._model import AssetError, ContactParams, SceneModel, load_scene  # noqa: E402
from ._articulated_scene import ArticulatedScene  # noqa: E402
from ._object_model import HINGE, SLIDE, ObjectTree, joint_param_names  # noqa: E402
from ._object_variants import load_variants  # noqa: E402
from ._object_sim import TableContact, load_object_tree  # noqa: E402
# simulators and their step
from ._hand_sim import Control, HandSimulator, SimStep, StepOutput, TapeTrajectory, check_device  # noqa: E402
from ._simulator import Simulator  # noqa: E402
from ._articulated import ArticulatedSimulator, ArticulatedStepOutput  # noqa: E402
from ._object_sim import ObjectSimulator  # noqa: E402
from ._factory import make_simulator  # noqa: E402
from ._stepper import Trajectory, cpu_threads  # noqa: E402
# drawing: images, and the scene's meshes (recordings)
from ._render import Camera, Renderer  # noqa: E402
from ._mesh_render import LABEL_TABLE, MeshRenderer, make_renderer  # noqa: E402
from ._scene_meshes import (GOAL_RGBA, ROLE_RGBA, STATIC, MeshPart, SceneGeometry, box_mesh, quat_to_mat,  # noqa: E402
                           recorded_body_names, scene_geometry, transform)
# ahead-of-time compilation
from ._aot import compile_scene, warp_versions  # noqa: E402

__all__ = [
    # scenes
    "AssetError", "ContactParams", "SceneModel", "ArticulatedScene", "ObjectTree", "HINGE", "SLIDE", "TableContact",
    "joint_param_names",
    "load_scene", "load_variants", "load_object_tree",
    # simulators and their step
    "make_simulator", "HandSimulator", "Simulator", "ArticulatedSimulator", "ObjectSimulator", "Control", "StepOutput",
    "ArticulatedStepOutput", "SimStep", "TapeTrajectory", "Trajectory", "check_device", "cpu_threads",
    # drawing
    "make_renderer", "Camera", "Renderer", "MeshRenderer", "LABEL_TABLE", "SceneGeometry", "MeshPart",
    "scene_geometry", "recorded_body_names", "box_mesh", "quat_to_mat", "transform", "ROLE_RGBA", "GOAL_RGBA",
    "STATIC",
    # compilation
    "compile_scene", "warp_versions",
]
