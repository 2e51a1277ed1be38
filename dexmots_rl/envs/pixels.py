"""RGB observations: a torchrl transform rendering every world with the scene's ray caster.

The renderer is :func:`dexmots_rl.sim.make_renderer`'s: the meshes of every hand link, the palm,
each object part and the table for a scene with an articulated object (task ``operate``,
:class:`~dexmots_rl.sim.MeshRenderer`), analytic shapes for the knob and cube scenes
(:class:`~dexmots_rl.sim.Renderer`).

:class:`RGBObservation` reads the state ``("sim", "joint_q")`` after every reset and step, renders the
worlds from a fixed camera (one warp launch, a thread per pixel per world) and writes ``"pixels"``,
``uint8 [N, H, W, 3]`` (channels last, like torchrl's pixel envs; ``ToTensorImage`` makes float
``[N, 3, H, W]`` for a CNN). Pixels carry no gradient (rendering is forward only); the state keys the
differentiable objectives use are untouched. Partial resets simply re-render every world.

Wiring: ``make_env(task, ..., obs="rgb")`` appends this transform; by hand::

    env = make_env("screw_claw", num_envs=16, differentiable=False)
    env.append_transform(RGBObservation(height=64, width=64))

Example:
    >>> from dexmots_rl.envs import make_env
    >>> from dexmots_rl.envs.pixels import RGBObservation, tile_images
    >>> env = make_env("screw_claw", num_envs=2, differentiable=False, seed=0)
    >>> env.append_transform(RGBObservation(height=32, width=32))  # doctest: +ELLIPSIS
    TransformedEnv(...)
    >>> td = env.reset()
    >>> td["pixels"].shape, td["pixels"].dtype
    (torch.Size([2, 32, 32, 3]), torch.uint8)
    >>> tile_images(td["pixels"], cols=2).shape
    torch.Size([32, 64, 3])
"""

from __future__ import annotations

import logging
import math

import torch
from tensordict import TensorDictBase
from torchrl.data import Bounded, Composite

from .transforms import StateTransform

__all__ = ["RGBObservation", "tile_images"]

log = logging.getLogger(__name__)


class RGBObservation(StateTransform):
    """Render ``("sim", "joint_q")`` into ``out_key`` (default ``"pixels"``), ``uint8 [N, H, W, 3]``.

    Args:
        height, width: image size in pixels.
        camera: a :class:`dexmots_rl.sim.Camera`; default: framed on the hand's reach and the
            object (the :func:`dexmots_rl.sim.make_renderer` renderer's default).
        sim: the :class:`~dexmots_rl.sim.Simulator` to render; default: the parent env's ``.sim``
            (needed only when the transform is used outside an env).
        out_key: where the images go.
    """

    def __init__(self, height: int = 64, width: int = 64, camera=None, sim=None, out_key="pixels"):
        if int(height) <= 0 or int(width) <= 0:
            raise ValueError(f"image size must be positive, got {height}x{width}")
        super().__init__(in_keys=[("sim", "joint_q")], out_keys=[out_key])
        self.height, self.width, self.camera = int(height), int(width), camera
        self._sim, self._renderer = sim, None

    @property
    def sim(self):
        if self._sim is not None:
            return self._sim
        parent = self.parent
        base = getattr(parent, "base_env", None) if parent is not None else None
        sim = getattr(base, "sim", None)
        if sim is None:
            raise RuntimeError("RGBObservation needs a DexEnv parent (an env with a .sim) or sim=...")
        return sim

    @property
    def renderer(self):
        if self._renderer is None:
            from ..sim import make_renderer

            sim = self.sim
            base = getattr(self.parent, "base_env", None) if self.parent is not None else None
            self._renderer = make_renderer(sim.scene, height=self.height, width=self.width, camera=self.camera,
                                           device=sim.torch_device, asset=getattr(base, "object_asset", None))
            log.info("RGBObservation: %dx%d images, camera %s", self.height, self.width, self._renderer.camera)
        return self._renderer

    def render(self, joint_q: torch.Tensor) -> torch.Tensor:
        """Images of states ``joint_q [..., nq]``: ``uint8 [..., H, W, 3]``."""
        batch = joint_q.shape[:-1]
        flat = joint_q.detach().reshape(-1, joint_q.shape[-1])
        images = self.renderer.render_state(self.sim, flat)
        return images.reshape(*batch, self.height, self.width, 3)

    def _call(self, td: TensorDictBase) -> TensorDictBase:
        joint_q = td.get(self.in_keys[0], None)
        if joint_q is None:
            return td
        pixels = self.render(joint_q)
        td.set(self.out_keys[0], pixels if td.device is None else pixels.to(td.device))
        return td

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        batch = observation_spec.shape
        observation_spec[self.out_keys[0]] = Bounded(
            low=0, high=255, shape=(*batch, self.height, self.width, 3), dtype=torch.uint8,
            device=observation_spec.device)
        return observation_spec


def tile_images(pixels: torch.Tensor, cols: int | None = None, pad: int = 0, pad_value: int = 255) -> torch.Tensor:
    """Tile worlds' images ``[N, H, W, C]`` into one mosaic ``[rows*(H+pad)-pad, cols*(W+pad)-pad, C]``,
    row by row (``cols`` defaults to ``ceil(sqrt(N))``; missing cells and gaps are ``pad_value``).

    Example:
        >>> import torch
        >>> tile_images(torch.zeros(5, 8, 8, 3, dtype=torch.uint8), cols=3, pad=1).shape
        torch.Size([17, 26, 3])
    """
    if pixels.dim() != 4:
        raise ValueError(f"pixels must be [N, H, W, C], got shape {tuple(pixels.shape)}")
    n, h, w, c = pixels.shape
    cols = int(cols or max(1, math.ceil(math.sqrt(n))))
    if cols <= 0 or pad < 0:
        raise ValueError(f"cols must be positive and pad >= 0, got cols={cols}, pad={pad}")
    rows = max(1, math.ceil(n / cols))
    canvas = torch.full((rows * (h + pad), cols * (w + pad), c), pad_value, dtype=pixels.dtype, device=pixels.device)
    for i in range(n):
        r, k = divmod(i, cols)
        canvas[r * (h + pad) : r * (h + pad) + h, k * (w + pad) : k * (w + pad) + w] = pixels[i]
    return canvas[: rows * (h + pad) - pad, : cols * (w + pad) - pad]
