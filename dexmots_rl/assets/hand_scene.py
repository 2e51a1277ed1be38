"""A scene of the Allegro hand above a table with an articulated object on it (MJCF text).

The hand is ``allegro_knob.xml``'s (the same links, joints, motors and mount: palm down, fingers along world
+x, fingertips curling down and back toward the thumb), with gravity on and its palm box colliding. The object (an
:class:`~dexmots_rl.assets.objects.ObjectAsset`) stands on a table plane so that its grasp point (where a hand
holds the tool) is at the world origin, where the knob of ``allegro_rotate`` stands: in the fingers' reach,
the object turned about the vertical by its ``grasp_yaw`` (a spray bottle's trigger toward the thumb).
"""

from __future__ import annotations

import math
from pathlib import Path

from . import asset_path

__all__ = ["hand_object_scene_xml", "GRASP_POINT"]

GRASP_POINT = (0.0, 0.0, 0.0)  # m, world: where the object's grasp point is placed


def hand_object_scene_xml(asset, mesh_dir: str | Path, grasp_point=GRASP_POINT) -> str:
    """MJCF of the Allegro hand with ``asset`` on a table; mesh files are written into ``mesh_dir``."""
    hand = asset_path("allegro_knob.xml").read_text()
    hand_body = hand[hand.index('    <body name="hand"'):hand.index('    <body name="object"')]
    # the palm touches the object here (in the knob scene it is drawn only)
    palm = hand_body.index('name="palm"')
    end = hand_body.index("/>", palm)
    hand_body = hand_body[:palm] + hand_body[palm:end].replace('contype="0" conaffinity="0"',
                                                               'contype="1" conaffinity="2"') + hand_body[end:]
    head = hand[hand.index("  <compiler"):hand.index("  <asset>")].replace('gravity="0 0 0"', 'gravity="0 0 -9.81"')
    actuators = hand[hand.index("  <actuator>"):]
    # the base turned by grasp_yaw about the vertical, placed so that its grasp point lands on grasp_point
    c, s = math.cos(asset.grasp_yaw), math.sin(asset.grasp_yaw)
    ax, ay, az = asset.grasp
    gx, gy, gz = grasp_point[0] - (c * ax - s * ay), grasp_point[1] - (s * ax + c * ay), grasp_point[2] - az
    turn = (math.cos(asset.grasp_yaw / 2), 0.0, 0.0, math.sin(asset.grasp_yaw / 2))
    assets, body = asset.mjcf(mesh_dir, pos=(gx, gy, gz), quat=turn)
    return (f'<mujoco model="allegro_{asset.name}">\n{head}  <asset>\n{assets}  </asset>\n  <worldbody>\n'
            f'    <geom name="table" type="plane" pos="0 0 {gz!r}" size="0.5 0.5 0.01" contype="1" conaffinity="2" '
            f'rgba="0.8 0.75 0.65 1"/>\n{hand_body}{body}  </worldbody>\n{actuators}')
