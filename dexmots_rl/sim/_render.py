"""RGB images of every world from one warp ray-casting kernel (forward only, no gradients): the knob and cube scenes.

A scene with an articulated object (task ``operate``) is drawn from its meshes by :mod:`._mesh_render`
(:func:`~._mesh_render.make_renderer` picks the renderer of a scene).

One launch renders all worlds: one thread per pixel per world casts a ray from a fixed pinhole camera
(per-pixel rays and the floor/sky behind the scene are computed once per camera; a tiny launch per call
places each world's capsules) and intersects it with

* the hand: every finger link's contact points (:attr:`SceneModel.point_pos`, sphere-swept point sets)
  as capsules (collinear runs of equal-radius points merge back into their capsule; a point alone is a
  sphere), culled by bounding spheres computed once per world;
* the object: convex planes (slab clipping), sphere, cylinder (analytic), or the signed-distance grid
  (sphere tracing with trilinear lookups), in the object frame; a light band on the object's +x side
  (``|y| < 0.2 bound``) makes its rotation visible in the image (the octagonal knob looks the same
  every 45 degrees otherwise);
* a checkered floor at ``floor_z`` and a sky gradient behind it.

Shading is Lambert with one directional light plus ambient. Hand links get one hue per finger (darker
towards the base), the object is blue with a white band, the floor grey. Link and object poses are
:meth:`Simulator.observe`'s ``[N, B, 7]`` (pos + wxyz quat): ``Renderer.render_state(sim, joint_q)``
does both. Output: ``uint8 [N, H, W, 3]`` (torch owns the memory; warp writes it in place through
``wp.from_torch``); optional labels ``uint8 [N, H, W]`` (:data:`LABEL_SKY`, ``_FLOOR``, ``_HAND``,
``_OBJECT``). On CPU the pixels are split into one block per core (a warp CPU launch runs on one core).
The warp code is in :mod:`._render_kernels`.

Example:
    >>> import torch
    >>> from dexmots_rl.assets import asset_path
    >>> from dexmots_rl.sim import Simulator, load_scene
    >>> from dexmots_rl.sim._render import Renderer
    >>> sim = Simulator(load_scene(asset_path("claw_screw.xml")), num_worlds=2)
    >>> q, _ = sim.initial_state()
    >>> img = Renderer(sim.scene, height=32, width=32).render_state(sim, q)
    >>> img.shape, img.dtype
    (torch.Size([2, 32, 32, 3]), torch.uint8)
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch
import warp as wp

from ._model import HINGE, OBJECT_HINGE, SceneModel
from ._pixel_funcs import LABEL_SKY, Backdrop, View
from ._render_kernels import (LABEL_FLOOR, LABEL_HAND, LABEL_OBJECT, RenderScene, background_kernel, place_segments,
                              render_kernel)
from ._hand_sim import check_device
from ._stepper import cpu_threads, launch_stream, run_blocks

__all__ = ["Camera", "RayCaster", "Renderer", "default_camera", "framing_camera", "camera_view", "reach_spheres",
           "hand_reach_spheres", "LABEL_SKY", "LABEL_FLOOR", "LABEL_HAND", "LABEL_OBJECT"]

MIN_PIXELS_PER_THREAD = 16384  # below this a second CPU thread costs more than it saves
FINGER_HUES = ((0.85, 0.25, 0.2), (0.2, 0.7, 0.3), (0.95, 0.6, 0.1), (0.6, 0.3, 0.8), (0.9, 0.8, 0.2))


@dataclasses.dataclass(frozen=True)
class Camera:
    """A pinhole camera at ``position`` looking at ``target``; ``fov`` is the vertical field of view (deg)."""

    position: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    fov: float = 50.0


def _axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotation matrices [S, 3, 3] about a unit ``axis`` by ``angle`` [S] (Rodrigues)."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.eye(3) + s * k + (1 - c) * (k @ k)


def reach_spheres(scene: SceneModel, samples: int = 512, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Centres [M, 3] and radii [M] of spheres covering the hand over ``samples`` random joint
    configurations within the joint limits (:func:`hand_reach_spheres`) and the object's bounding sphere at its
    initial pose: what :func:`default_camera` frames."""
    centres, radii = hand_reach_spheres(scene, samples, seed)
    obj = scene.object_base_pos if scene.object_kind == OBJECT_HINGE else scene.object_q0[:3]
    return (np.concatenate([centres, np.asarray(obj, np.float64)[None]]),
            np.concatenate([radii, [scene.object_bound]]))


def hand_reach_spheres(scene, samples: int = 512, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Centres [M, 3] and radii [M] of the hand's contact spheres over ``samples`` random joint configurations
    within the joint limits (unlimited hinges over a full turn, unlimited slides at 0); ``scene`` has the hand
    fields of :class:`SceneModel`."""
    rng = np.random.default_rng(seed)
    hinge = scene.joint_type == HINGE  # unlimited: hinges over a full turn, slides at 0
    lo = np.where(scene.dof_limited, scene.dof_lower, np.where(hinge, -math.pi, 0.0))
    hi = np.where(scene.dof_limited, scene.dof_upper, np.where(hinge, math.pi, 0.0))
    q = rng.uniform(lo, hi, (samples, scene.num_hand_dofs))
    j, p_per = scene.joints_per_finger, scene.points_per_link
    centres, radii = [], []
    for f in range(scene.num_fingers):
        rot = np.broadcast_to(scene.finger_base_rot[f], (samples, 3, 3))
        x = np.broadcast_to(scene.finger_base_pos[f], (samples, 3))
        for k in range(j):
            i = f * j + k
            x = x + rot @ scene.link_offset_pos[i]
            rot = rot @ scene.link_offset_rot[i]
            if scene.joint_type[i] == HINGE:
                rot = rot @ _axis_angle(scene.joint_axis[i], q[:, i])
            else:
                x = x + (rot @ scene.joint_axis[i]) * q[:, i : i + 1]
            pts = scene.point_pos[i * p_per : (i + 1) * p_per]
            centres.append((x[:, None] + np.einsum("sab,pb->spa", rot, pts)).reshape(-1, 3))
            radii.append(np.tile(scene.point_radius[i * p_per : (i + 1) * p_per], samples))
    return np.concatenate(centres), np.concatenate(radii)


def default_camera(scene: SceneModel, elevation: float = 60.0, fov: float = 45.0, aspect: float = 1.0) -> Camera:
    """Oblique view from behind the hand (above it, opposite the object) that frames the hand's whole
    reach within its joint limits and the object (:func:`reach_spheres`), for images of ``aspect``
    (width / height)."""
    centres, radii = reach_spheres(scene)
    obj = centres[-1]
    ahead = obj - scene.finger_base_pos.mean(0)
    ahead[2] = 0.0
    ahead = ahead / np.linalg.norm(ahead) if np.linalg.norm(ahead) > 1e-9 else np.array([1.0, 0.0, 0.0])
    el = math.radians(elevation)
    fwd = ahead * math.cos(el) - np.array([0.0, 0.0, math.sin(el)])  # from the camera towards the target
    return framing_camera(centres, radii, fwd, fov, aspect)


def framing_camera(centres: np.ndarray, radii: np.ndarray, forward, fov: float = 45.0,
                   aspect: float = 1.0) -> Camera:
    """The camera looking along ``forward`` (not vertical) at the centre of the spheres' bounding box, from
    the nearest distance at which every sphere (``centres`` [M, 3], ``radii`` [M], m) is inside the frame
    (5 % margin), for images of ``aspect`` (width / height)."""
    centres, radii = np.asarray(centres, np.float64), np.asarray(radii, np.float64)
    lo, hi = (centres - radii[:, None]).min(0), (centres + radii[:, None]).max(0)
    target = 0.5 * (lo + hi)
    fwd = np.asarray(forward, np.float64) / np.linalg.norm(forward)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    rel = centres - target
    tan_h = 0.95 * math.tan(math.radians(fov) / 2)  # 5 % margin
    # distance d at which every sphere projects inside the frame: |p.r| + r <= tan * aspect * (d + p.f)
    need = np.maximum((np.abs(rel @ right) + radii) / (tan_h * aspect), (np.abs(rel @ up) + radii) / tan_h)
    dist = float((need - rel @ fwd + radii).max())
    pos = target - fwd * dist
    return Camera(tuple(float(x) for x in pos), tuple(float(x) for x in target), fov=fov)


def camera_view(cam: Camera, height: int, width: int, light) -> View:
    """The kernels' view of camera ``cam`` for ``height`` x ``width`` images; ``light``: towards the light."""
    pos, target = np.asarray(cam.position, np.float64), np.asarray(cam.target, np.float64)
    fwd = target - pos
    if np.linalg.norm(fwd) < 1e-9:
        raise ValueError("camera position and target coincide")
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, np.asarray(cam.up, np.float64))
    if np.linalg.norm(right) < 1e-9:
        raise ValueError("camera up vector is parallel to the viewing direction")
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    v = View()
    v.pos, v.forward, v.right, v.up = (wp.vec3(*x.astype(np.float32)) for x in (pos, fwd, right, up))
    v.tan_half = math.tan(math.radians(cam.fov) / 2)
    v.light = wp.vec3(*(np.asarray(light, np.float32) / np.linalg.norm(light)))
    v.height, v.width = height, width
    return v


def _link_capsules(pts: list[tuple[np.ndarray, float]]) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Capsules (a, b, radius) through one link's sample spheres in order: consecutive points of equal
    radius are joined, and a point on the line of the capsule before it extends that capsule (so a
    capsule geom's samples merge back into one capsule); a point alone is a sphere (a == b)."""
    out: list[tuple[np.ndarray, np.ndarray, float]] = []
    for p, r in pts:
        if out and abs(out[-1][2] - r) < 1e-9:
            a, b, _ = out[-1]
            ab, bp = b - a, p - b
            if np.allclose(a, b) or (np.linalg.norm(np.cross(ab, bp)) < 1e-9 * max(np.linalg.norm(ab), 1e-9)
                                     and np.dot(ab, bp) >= 0):
                out[-1] = (a, p, r)
            else:
                out.append((b, p, r))
            continue
        out.append((p, p, r))
    return out


def _segments(scene: SceneModel) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Capsules (a, b, radius, body, colour) of every hand link (:func:`_link_capsules`)."""
    seg_a, seg_b, seg_r, seg_body, seg_col = [], [], [], [], []
    p_per = scene.points_per_link
    j = scene.joints_per_finger
    for link in range(scene.num_hand_dofs):
        f, k = divmod(link, j)
        col = np.array(FINGER_HUES[f % len(FINGER_HUES)]) * (0.6 + 0.4 * (k + 1) / j)
        pts = [(scene.point_pos[link * p_per + i], float(scene.point_radius[link * p_per + i])) for i in range(p_per)]
        for a, b, r in _link_capsules([(p, r) for p, r in pts if r > 0]):
            seg_a.append(a), seg_b.append(b), seg_r.append(r), seg_body.append(link), seg_col.append(col)
    if not seg_a:
        return np.zeros((1, 3)), np.zeros((1, 3)), np.zeros(1), np.zeros(1, np.int32), np.zeros((1, 3))
    return (np.array(seg_a), np.array(seg_b), np.array(seg_r), np.array(seg_body, np.int32), np.array(seg_col))


class RayCaster:
    """What both renderers share (this module's :class:`Renderer`, :class:`~._mesh_render.MeshRenderer`): the image
    size and device, the camera's view, the background computed once, and :meth:`render`, which places the bodies
    of every world (:meth:`_place`) and launches the pixel kernel over blocks of pixels, one CPU thread each."""

    min_pixels_per_thread: int  # below this a second CPU thread costs more than it saves
    pixel_kernel: object  # one pixel of one world: (scene, view, placed..., background..., p0) -> image, labels
    num_bodies: int  # B of the body_pose [N, B, 7] it draws

    def _open(self, scene, height: int, width: int, device) -> None:
        if int(height) <= 0 or int(width) <= 0:
            raise ValueError(f"image size must be positive, got {height}x{width}")
        self.scene, self.height, self.width = scene, int(height), int(width)
        self.torch_device = check_device(device)
        self.device = wp.device_from_torch(self.torch_device)

    def _start(self, camera: Camera, light, background) -> None:
        """Fix the camera and compute each pixel's ray and the background behind the scene (``background``: its
        kernel) once; needs ``self._scene`` built."""
        self.camera = camera
        self._view = camera_view(camera, self.height, self.width, light)
        self._no_labels = wp.zeros((1, 1), dtype=wp.uint8, device=self.device)
        npix = self.height * self.width
        self._backdrop = bd = Backdrop()
        bd.rays, bd.depth = wp.empty(npix, dtype=wp.vec3, device=self.device), wp.empty(npix, device=self.device)
        bd.color, bd.label = wp.empty(npix, dtype=wp.vec3, device=self.device), wp.empty(npix, wp.uint8, self.device)
        wp.launch(background, dim=npix, inputs=[self._scene, self._view, bd], device=self.device)

    def _place(self, pose, n: int, stream) -> list:
        """Launch what places the drawn bodies of ``n`` worlds from ``pose``; the pixel kernel's inputs between the
        view and the background."""
        raise NotImplementedError

    def render(self, body_pose: torch.Tensor, labels: bool = False):
        """Images ``uint8 [N, H, W, 3]`` of body poses ``[N, B, 7]`` (any float dtype, no gradient);
        with ``labels=True`` returns ``(images, labels uint8 [N, H, W])``."""
        nb = self.num_bodies
        if body_pose.dim() != 3 or body_pose.shape[1:] != (nb, 7):
            raise ValueError(f"body_pose must have shape [N, {nb}, 7], got {tuple(body_pose.shape)}")
        n, h, w = body_pose.shape[0], self.height, self.width
        pose = wp.from_torch(body_pose.detach().to(self.torch_device, torch.float32).contiguous())
        image = torch.empty(n, h, w, 3, dtype=torch.uint8, device=self.torch_device)
        lab = torch.empty(n, h, w, dtype=torch.uint8, device=self.torch_device) if labels else None
        w_image = wp.from_torch(image.view(n, h * w, 3), dtype=wp.uint8)
        w_lab = wp.from_torch(lab.view(n, h * w), dtype=wp.uint8) if labels else self._no_labels
        stream = launch_stream(self.device)  # CUDA: torch's stream, ordered with the tensors around the launches
        placed = self._place(pose, n, stream)

        def launch(lo, hi):
            wp.launch(self.pixel_kernel, dim=hi - lo, inputs=[self._scene, self._view, *placed, self._backdrop, lo],
                      outputs=[w_image, w_lab, int(labels)], device=self.device, stream=stream)

        total = n * h * w
        if total:
            threads = cpu_threads() if self.device.is_cpu else 1
            blocks = max(1, min(threads, total // self.min_pixels_per_thread))
            bounds = [round(i * total / blocks) for i in range(blocks + 1)]
            run_blocks(launch, list(zip(bounds[:-1], bounds[1:])))
        return (image, lab) if labels else image

    def render_state(self, sim, joint_q: torch.Tensor, labels: bool = False):
        """Render states ``joint_q [N, nq]`` of ``sim`` (the simulator of this renderer's scene)."""
        pose, _ = sim.observe(joint_q.detach())
        return self.render(pose, labels=labels)


class Renderer(RayCaster):
    """Renders ``uint8 [N, H, W, 3]`` images of body poses ``[N, B, 7]`` (see the module docstring).

    ``camera`` defaults to :func:`default_camera`; ``light`` is the direction towards the light.
    """

    min_pixels_per_thread = MIN_PIXELS_PER_THREAD
    pixel_kernel = render_kernel

    def __init__(self, scene: SceneModel, height: int = 64, width: int = 64, camera: Camera | None = None,
                 device: str | torch.device = "cpu", floor_z: float = 0.0, tile: float = 0.2,
                 light: tuple[float, float, float] = (-0.4, -0.3, 1.0)):
        self._open(scene, height, width, device)
        a, b, r, body, col = _segments(scene)

        def arr(x, dtype):
            return wp.array(np.asarray(x, dtype=np.float32), dtype=dtype, device=self.device)

        sc = RenderScene()
        sc.seg_a, sc.seg_b, sc.seg_r = arr(a, wp.vec3), arr(b, wp.vec3), arr(r, float)
        sc.seg_body = wp.array(body, dtype=int, device=self.device)
        sc.seg_color = arr(col, wp.vec3)
        sc.num_segments = int(r.size if r.any() else 0)
        sc.object_body = scene.num_hand_dofs
        sc.shape = int(scene.object_shape)
        planes = scene.object_planes if len(scene.object_planes) else np.zeros((1, 4))
        sc.planes, sc.num_planes = arr(planes, wp.vec4), int(len(scene.object_planes))
        sc.size = wp.vec3(*np.asarray(scene.object_shape_size, dtype=np.float32), 0.0)
        sc.bound = float(scene.object_bound) * 1.001
        sdf = np.asarray(scene.object_sdf, dtype=np.float32)
        if sdf.ndim != 3 or min(sdf.shape) < 2:
            sdf = np.zeros((2, 2, 2), np.float32)
        sc.sdf = wp.array(sdf, dtype=float, device=self.device)
        sc.sdf_origin = wp.vec3(*np.asarray(scene.object_sdf_origin, np.float32))
        sc.sdf_cell = float(scene.object_sdf_cell)
        sc.floor_z, sc.tile = float(floor_z), float(tile)
        self._scene = sc
        self._start(camera or default_camera(scene, aspect=self.width / self.height), light, background_kernel)
        self._num_segments, self._segs = len(r), None
        self.num_bodies = scene.num_hand_dofs + 1

    def _place(self, pose, n: int, stream) -> list:
        if self._segs is None or self._segs[0].shape[0] != n:
            shape = (n, self._num_segments)
            self._segs = (wp.empty(shape, dtype=wp.vec3, device=self.device),
                          wp.empty(shape, dtype=wp.vec3, device=self.device),
                          wp.empty(shape, dtype=wp.vec4, device=self.device))
        wp.launch(place_segments, dim=(n, self._num_segments), inputs=[self._scene, pose], outputs=list(self._segs),
                  device=self.device, stream=stream)
        return [pose, *self._segs]
