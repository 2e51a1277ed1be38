"""RGB images of every world of a hand-and-articulated-object scene, ray cast against each body's mesh.

:class:`MeshRenderer` draws what :func:`~dexmots_rl.sim._scene_meshes.scene_geometry` reads from the scene's MJCF
(what the viewer draws too): every hand link and the palm with their geoms, every object part with its
watertight visual mesh (the object library's ``group="1"`` meshes; a part without one with its collision
primitives), and the table. Each drawn body is one :class:`warp.Mesh` in its own frame, built once; the table is
a checkered rectangle at its top surface (the sky behind it). Colours are the MJCF's: the object's parts each
have their own, so the trigger of a spray bottle stands out from its body.

One launch renders all worlds: a tiny launch per call places each drawn body from ``body_pose [N, B, 7]``
(pos + wxyz quat per recorded body, :meth:`ArticulatedSimulator.observe`'s order: hand links, then the object's
bodies; static bodies such as the palm are drawn in the world frame), then one thread per pixel per world tests
every body's bounding sphere and traces the ray through the meshes it meets (their BVHs). Shading is Lambert
with one directional light plus ambient, flat per triangle. Output: ``uint8 [N, H, W, 3]``; optional labels
``uint8 [N, H, W]``: :data:`LABEL_SKY`, :data:`LABEL_TABLE`, then ``FIRST_BODY_LABEL + k`` for drawn body
``k`` (its name and role are ``body_names[k]``, ``body_roles[k]``; :meth:`MeshRenderer.label`).

:func:`make_renderer` picks this renderer for an articulated scene and :class:`~._render.Renderer` (analytic
shapes) for the knob and cube scenes.

Example:
    >>> from dexmots_rl.envs.tasks.allegro.operate_object import build_scene
    >>> from dexmots_rl.sim import ArticulatedSimulator
    >>> scene, asset = build_scene("spray_bottle_a")
    >>> sim = ArticulatedSimulator(scene, num_worlds=2)
    >>> r = MeshRenderer(scene, height=32, width=32)
    >>> q, _ = sim.initial_state()
    >>> img, labels = r.render_state(sim, q, labels=True)
    >>> img.shape, img.dtype, r.body_names[-2:]
    (torch.Size([2, 32, 32, 3]), torch.uint8, ['object', 'object/trigger'])
    >>> bool((labels == r.label("object/trigger")).any())
    True
"""

from __future__ import annotations

import logging

import numpy as np
import torch
import warp as wp

from ._articulated_scene import ArticulatedScene
from ._render import Camera, RayCaster, Renderer, framing_camera, hand_reach_spheres
from ._render_mesh_kernels import (FIRST_BODY_LABEL, LABEL_SKY, LABEL_TABLE, MeshScene, mesh_background_kernel,
                                  mesh_render_kernel, place_bodies)
from ._scene_meshes import STATIC, SceneGeometry, scene_geometry

__all__ = ["MeshRenderer", "make_renderer", "framing_spheres", "VIEW_DIRECTION", "LABEL_SKY", "LABEL_TABLE",
           "FIRST_BODY_LABEL"]

log = logging.getLogger(__name__)

VIEW_DIRECTION = (0.35, -1.0, 0.6)  # from the scene towards the default camera: front right of the hand, above
MIN_PIXELS_PER_THREAD = 4096  # below this a second CPU thread costs more than it saves (mesh pixels are dear)


def make_renderer(scene, *, height: int = 64, width: int = 64, camera: Camera | None = None,
                  device: str | torch.device = "cpu", asset=None):
    """The renderer of ``scene``: a :class:`MeshRenderer` for an articulated-object scene (``asset``: its object,
    used when the scene's MJCF file is gone), else a :class:`~._render.Renderer`."""
    if isinstance(scene, ArticulatedScene):
        return MeshRenderer(scene, height, width, camera=camera, device=device, asset=asset)
    return Renderer(scene, height, width, camera=camera, device=device)


def _rest_poses(scene) -> np.ndarray:
    """World poses [B, 4, 4] of the object's bodies with every part joint at 0 (the base at its initial pose)."""
    tree = scene.tree
    out = np.zeros((tree.num_bodies, 4, 4))
    for b in range(tree.num_bodies):
        local = np.eye(4)
        local[:3, :3], local[:3, 3] = tree.offset_rot[b], tree.offset_pos[b]
        out[b] = local if tree.parent[b] < 0 else out[tree.parent[b]] @ local
    return out


def framing_spheres(scene, geometry: SceneGeometry, samples: int = 256) -> tuple[np.ndarray, np.ndarray]:
    """Centres [M, 3] and radii [M] (m) of what the default camera frames: the hand's reach within its joint
    limits, the palm, and the object's drawn vertices at rest."""
    centres, radii = hand_reach_spheres(scene, samples)
    pts = [p.vertices for p in geometry.parts if p.body == STATIC and p.role == "palm"]
    rest, links = _rest_poses(scene), geometry.num_hand_links
    for p in geometry.parts:
        if p.role == "object" and p.body >= links:
            pose = rest[p.body - links]
            pts.append(p.vertices @ pose[:3, :3].T + pose[:3, 3])
    pts = np.concatenate(pts) if pts else np.zeros((0, 3))
    return np.concatenate([centres, pts]), np.concatenate([np.maximum(radii, 0.0), np.zeros(len(pts))])


class MeshRenderer(RayCaster):
    """Renders ``uint8 [N, H, W, 3]`` images of an articulated scene's body poses ``[N, B, 7]`` (see the module
    docstring). ``camera`` defaults to one along :data:`VIEW_DIRECTION` framing :func:`framing_spheres`;
    ``light`` is the direction towards the light; ``geometry`` defaults to ``scene_geometry(scene, asset)``."""

    min_pixels_per_thread = MIN_PIXELS_PER_THREAD
    pixel_kernel = mesh_render_kernel

    def __init__(self, scene, height: int = 64, width: int = 64, camera: Camera | None = None,
                 device: str | torch.device = "cpu", light: tuple[float, float, float] = (-0.4, -0.3, 1.0),
                 asset=None, geometry: SceneGeometry | None = None, tile: float = 0.05, fov: float = 45.0):
        self._open(scene, height, width, device)
        self.geometry = geometry = geometry or scene_geometry(scene, asset)
        if camera is None:
            centres, radii = framing_spheres(scene, geometry)
            camera = framing_camera(centres, radii, -np.asarray(VIEW_DIRECTION), fov, self.width / self.height)
        self.num_bodies = len(geometry.body_names)
        self._build(geometry, tile)
        self._start(camera, light, mesh_background_kernel)
        self._placed = None

    def _build(self, geometry: SceneGeometry, tile: float) -> None:
        """One warp mesh per drawn body (a recorded body's parts merged; each static part alone), the table."""
        groups: dict[tuple, list] = {}
        table = []
        for part in geometry.parts:
            if part.role == "table":
                table.append(part)
                continue
            key = (part.body,) if part.body != STATIC else (STATIC, part.name, part.role)
            groups.setdefault(key, []).append(part)
        self.body_names, self.body_roles, self._meshes = [], [], []
        body, centre, radius, face_start, colors = [], [], [], [], []
        faces_so_far = 0
        for key, parts in groups.items():
            verts, faces, offset = [], [], 0
            for p in parts:
                verts.append(p.vertices)
                faces.append(p.faces + offset)
                colors.append(np.tile(np.asarray(p.rgba[:3], np.float32), (len(p.faces), 1)))
                offset += len(p.vertices)
            v, f = np.concatenate(verts), np.concatenate(faces)
            self._meshes.append(wp.Mesh(points=wp.array(v.astype(np.float32), dtype=wp.vec3, device=self.device),
                                        indices=wp.array(f.reshape(-1).astype(np.int32), dtype=int,
                                                         device=self.device)))
            lo, hi = v.min(0), v.max(0)
            c = 0.5 * (lo + hi)
            body.append(key[0])
            centre.append(c)
            radius.append(float(np.linalg.norm(v - c, axis=1).max()) * 1.001 + 1e-5)
            face_start.append(faces_so_far)
            faces_so_far += len(f)
            self.body_names.append(geometry.body_names[key[0]] if key[0] != STATIC else parts[0].name)
            self.body_roles.append(parts[0].role)
        if len(self._meshes) > 255 - FIRST_BODY_LABEL:
            raise ValueError(f"{len(self._meshes)} drawn bodies: labels are uint8 (at most "
                             f"{255 - FIRST_BODY_LABEL})")

        def arr(x, dtype):
            return wp.array(np.asarray(x), dtype=dtype, device=self.device)

        sc = MeshScene()
        sc.mesh = arr(np.array([m.id for m in self._meshes], dtype=np.uint64), wp.uint64)
        sc.body = arr(np.array(body, np.int32), int)
        sc.centre, sc.radius = arr(np.array(centre, np.float32), wp.vec3), arr(np.array(radius, np.float32), float)
        sc.face_start = arr(np.array(face_start, np.int32), int)
        sc.face_color = arr(np.concatenate(colors), wp.vec3)
        sc.num_drawn = len(self._meshes)
        sc.has_table = int(bool(table))
        sc.tile = float(tile)
        if table:  # the table's top surface: where the object stands
            v = np.concatenate([p.vertices for p in table])
            sc.table_z = float(v[:, 2].max())
            sc.table_lo, sc.table_hi = wp.vec2(*v[:, :2].min(0).astype(np.float32)), wp.vec2(
                *v[:, :2].max(0).astype(np.float32))
            sc.table_color = wp.vec3(*np.asarray(table[0].rgba[:3], np.float32))
        self._scene = sc

    def label(self, name: str) -> int:
        """The label value of drawn body ``name`` (a recorded body's name, or a static part's)."""
        if name not in self.body_names:
            raise KeyError(f"no drawn body {name!r}; drawn: {', '.join(self.body_names)}")
        return FIRST_BODY_LABEL + self.body_names.index(name)

    def _place(self, pose, n: int, stream) -> list:
        if self._placed is None or self._placed[0].shape[0] != n:
            shape = (n, self._scene.num_drawn)
            self._placed = (wp.empty(shape, dtype=wp.transform, device=self.device),
                            wp.empty(shape, dtype=wp.vec4, device=self.device))
        wp.launch(place_bodies, dim=(n, self._scene.num_drawn), inputs=[self._scene, pose], outputs=list(self._placed),
                  device=self.device, stream=stream)
        return list(self._placed)
