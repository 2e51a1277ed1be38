"""The scene geometry a recording carries: every body of the scene as triangle meshes.

The meshes are read by :func:`dexmots_rl.sim.scene_geometry` (shared with the RGB renderer); this module names
them for the recording's readers and writers.
"""

from __future__ import annotations

from ..sim import (GOAL_RGBA, ROLE_RGBA, STATIC, MeshPart, SceneGeometry, box_mesh, quat_to_mat, recorded_body_names,
                   scene_geometry, transform)

__all__ = ["MeshPart", "SceneGeometry", "scene_geometry", "recorded_body_names", "box_mesh", "ROLE_RGBA",
           "GOAL_RGBA", "STATIC", "quat_to_mat", "transform"]
