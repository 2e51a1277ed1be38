"""An object on its own: its parts' meshes posed at given joint positions, and a minimal MuJoCo scene.

:func:`posed_meshes` places every part's visual mesh in the world for given joint positions (what a figure
or a viewer draws); :func:`object_scene_xml` writes a table plane, a light and the object as one MJCF model
(gravity on, the object's base at the origin), which MuJoCo compiles to check or simulate the object alone.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from .description import IDENTITY, ObjectAsset, Part

__all__ = ["part_transforms", "posed_meshes", "object_scene_xml", "bounding_box"]


def _pose_matrix(pos, quat) -> np.ndarray:
    matrix = trimesh.transformations.quaternion_matrix(np.asarray(quat, dtype=float))
    matrix[:3, 3] = pos
    return matrix


def _joint_matrix(part: Part, q: float) -> np.ndarray:
    joint = part.joint
    axis = np.asarray(joint.axis, dtype=float) / np.linalg.norm(joint.axis)
    if joint.kind == "slide":
        return trimesh.transformations.translation_matrix(axis * q)
    return trimesh.transformations.rotation_matrix(q, axis, point=np.asarray(joint.anchor, dtype=float))


def part_transforms(asset: ObjectAsset, q: dict[str, float] | None = None, pos=(0.0, 0.0, 0.0),
                    quat=IDENTITY) -> dict[str, np.ndarray]:
    """4x4 world transforms of every part's frame; ``q`` maps joint names to positions (missing: 0), the
    base placed at ``pos``/``quat``."""
    q = q or {}
    unknown = set(q) - {j.name for j in asset.joints}
    if unknown:
        raise KeyError(f"object {asset.name!r} has no joints {sorted(unknown)}; its joints: "
                       f"{[j.name for j in asset.joints]}")
    world = {asset.parts[0].name: _pose_matrix(pos, quat)}
    for part in asset.parts[1:]:
        world[part.name] = (world[part.parent] @ _pose_matrix(part.pos, part.quat)
                            @ _joint_matrix(part, float(q.get(part.joint.name, 0.0))))
    return world


def posed_meshes(asset: ObjectAsset, q: dict[str, float] | None = None) -> list[tuple[Part, trimesh.Trimesh]]:
    """Each part with a visual mesh, its mesh moved into the world frame (base at the origin)."""
    world = part_transforms(asset, q)
    return [(part, asset.meshes[part.visual].copy().apply_transform(world[part.name]))
            for part in asset.parts if part.visual is not None]


def bounding_box(asset: ObjectAsset, q: dict[str, float] | None = None) -> np.ndarray:
    """(2, 3) world bounds of the visual meshes at joint positions ``q`` (rest by default)."""
    bounds = np.array([mesh.bounds for _, mesh in posed_meshes(asset, q)])
    return np.stack([bounds[:, 0].min(axis=0), bounds[:, 1].max(axis=0)])


def object_scene_xml(asset: ObjectAsset, mesh_dir: str | Path, pos=(0.0, 0.0, 0.0), quat=IDENTITY,
                     timestep: float = 0.002) -> str:
    """A complete MJCF model: a table plane at z = 0 (contype 1, conaffinity 2: it touches the object's
    collision geoms, which touch each other only through their joints), a light, and the object with its
    base at ``pos``/``quat``. Mesh files are written into ``mesh_dir``."""
    assets, body = asset.mjcf(mesh_dir, pos=pos, quat=quat)
    return (
        f'<mujoco model="{asset.name}_scene">\n'
        '  <compiler angle="radian"/>\n'
        f'  <option timestep="{timestep:g}" gravity="0 0 -9.81"/>\n'
        f"  <asset>\n{assets}  </asset>\n"
        "  <worldbody>\n"
        '    <light name="sun" pos="0 0 1" dir="0 0 -1" directional="true"/>\n'
        '    <geom name="table" type="plane" size="0.5 0.5 0.01" contype="1" conaffinity="2" '
        'friction="0.8 0.005 0.0001" rgba="0.8 0.75 0.65 1"/>\n'
        f"{body}"
        "  </worldbody>\n"
        "</mujoco>\n")
