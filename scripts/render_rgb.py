"""Each object class's first instance in task ``operate`` as the RGB observation renders it, to a PNG.

    python scripts/render_rgb.py [--out docs/figures/render] [--size 256] [--names spray_bottle_a ...]

One figure per class, ``<out>/<class>.png``: the env's first state (hand open above the object) and the same
state with the operated joint at the task's goal (90 % of its way), side by side, from the default camera
(:class:`dexmots_rl.sim.MeshRenderer`). The script also checks that the palm, every hand link
that is in view, each of the object's bodies and the table cover pixels, and that the operated part moves.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch
from PIL import Image

from dexmots_rl.assets.objects import list_objects
from dexmots_rl.envs import make_env
from dexmots_rl.envs.pixels import RGBObservation, tile_images
from dexmots_rl.sim import LABEL_TABLE


def render(name: str, out: Path, size: int) -> Path:
    env = make_env("operate", object=name, num_envs=2, differentiable=False, seed=0)
    base = env.base_env
    pixels = RGBObservation(height=size, width=size)
    env.append_transform(pixels)
    q = env.reset()["sim", "joint_q"].clone()
    q[1, base.sim.nu + 7 * base.sim.tree.free + base.joint_index] = base.goal_value
    images, labels = pixels.renderer.render_state(base.sim, q, labels=True)
    r = pixels.renderer
    for k, (body, role) in enumerate(zip(r.body_names, r.body_roles)):
        if role in ("palm", "object") and not (labels == r.label(body)).sum(dim=(1, 2)).min() > 0:
            raise RuntimeError(f"{name}: {role} {body!r} is not drawn")
    if not (labels == LABEL_TABLE).any(dim=(1, 2)).all():
        raise RuntimeError(f"{name}: the table is not drawn")
    if torch.equal(images[0], images[1]):
        raise RuntimeError(f"{name}: moving joint {base.joint_name!r} does not change the image")
    path = out / f"{base.object_asset.object_class}.png"
    Image.fromarray(tile_images(images, cols=2, pad=4).numpy()).save(path)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/figures/render"))
    parser.add_argument("--size", type=int, default=256, help="image height and width (pixels)")
    parser.add_argument("--names", nargs="*", help="instances to draw (default: the first of each class)")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    names = args.names
    if not names:
        first: dict[str, str] = {}
        for name, object_class in list_objects():
            first.setdefault(object_class, name)
        names = list(first.values())
    for name in names:
        print(render(name, args.out, args.size))


if __name__ == "__main__":
    main()
