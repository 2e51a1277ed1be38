"""Draw each object class of the library (its first instance, at rest and operated) to a PNG.

    python scripts/render_objects.py [--out docs/figures/objects] [--names spray_bottle_a ...]

One figure per class, ``<out>/<class>.png``: two views of the meshes (matplotlib, Agg, flat shading from
one light), at rest and with every joint at 90 % of its range.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import trimesh  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402

from dexmots_rl.assets.objects import list_objects, load_object  # noqa: E402
from dexmots_rl.assets.objects.scene import bounding_box, posed_meshes  # noqa: E402

LIGHT = np.array([0.4, -0.5, 0.8]) / np.linalg.norm([0.4, -0.5, 0.8])


def draw(ax, asset, q, title: str) -> None:
    rest_low, rest_high = bounding_box(asset)
    flat = (rest_high[2] - rest_low[2]) < 0.3 * (rest_high - rest_low).max()  # lying tools: seen from higher up
    low, high = bounding_box(asset, q)
    elev, azim = (55 if flat else 22), -60
    eye = np.array([np.cos(np.radians(elev)) * np.cos(np.radians(azim)),
                    np.cos(np.radians(elev)) * np.sin(np.radians(azim)), np.sin(np.radians(elev))])
    triangles, colors = [], []
    for part, mesh in posed_meshes(asset, q):
        # small faces sort better in matplotlib's painter's algorithm; faces turned away are not drawn
        vertices, faces = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, (high - low).max() / 25)
        mesh = trimesh.Trimesh(vertices, faces, process=False)
        front = mesh.face_normals @ eye > 0
        rgba = np.array(part.geoms[0].rgba)
        shade = 0.45 + 0.55 * np.clip(mesh.face_normals[front] @ LIGHT, 0.0, 1.0)
        triangles.append(mesh.triangles[front])
        colors.append(np.clip(rgba[None, :3] * shade[:, None], 0, 1))
    # one collection for all parts: matplotlib orders faces by depth only within a collection
    colors = np.concatenate(colors)
    ax.add_collection3d(Poly3DCollection(np.concatenate(triangles), facecolors=colors, edgecolors=colors,
                                         linewidths=0.4, antialiased=False))
    # equal scale on all axes, each axis as long as the object's extent along it (at least a fifth of the
    # longest) so that flat tools fill the frame
    centre = (low + high) / 2
    half = np.maximum((high - low) / 2, (high - low).max() / 10) * 1.05
    for set_limits, c, h in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre, half):
        set_limits(c - h, c + h)
    ax.set_box_aspect(tuple(half), zoom=0.95)
    ax.view_init(elev=elev, azim=azim)
    ax.set_axis_off()
    ax.set_title(title, fontsize=9)


def render(name: str, out: Path) -> Path:
    asset = load_object(name)
    operated = {j.name: j.range[0] + 0.9 * (j.range[1] - j.range[0]) for j in asset.joints}
    fig = plt.figure(figsize=(6.4, 3.4), dpi=110)
    for i, (q, label) in enumerate([(None, "at rest"), (operated, "operated (90 % of range)")]):
        draw(fig.add_subplot(1, 2, i + 1, projection="3d"), asset, q, f"{name}: {label}")
    fig.subplots_adjust(left=0, right=1, bottom=0, top=0.93, wspace=0)
    path = out / f"{asset.object_class}.png"
    fig.savefig(path)
    plt.close(fig)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/figures/objects"))
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
        print(render(name, args.out))


if __name__ == "__main__":
    main()
