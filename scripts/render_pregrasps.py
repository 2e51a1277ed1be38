"""Pictures of the shipped pre-grasps: the Allegro hand holding each class's first object, as MuJoCo draws it.

    MUJOCO_GL=egl python scripts/render_pregrasps.py                  # docs/figures/pregrasps/<class>.png
    MUJOCO_GL=egl python scripts/render_pregrasps.py --objects jar_b valve_c --out /tmp/figs

For each object: task ``operate``'s scene (:func:`~dexmots_rl.envs.tasks.allegro.operate_object.build_scene`)
with the hand at the object's first shipped pre-grasp and the object at rest, drawn by MuJoCo's offscreen
renderer from the front-left and from the thumb's side (two views side by side; colours are the MJCF's, the
collision geoms hidden behind the visual meshes). The PNG is written with a 256-colour palette.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
VIEWS = ((150.0, -25.0), (60.0, -35.0))  # (azimuth, elevation) in degrees: front-left, and the thumb's side


def figure(name: str, out: Path, size: tuple[int, int]) -> dict:
    """Draw ``name`` at its first shipped pre-grasp into ``out``; returns what was drawn."""
    import mujoco
    import numpy as np
    from PIL import Image

    from dexmots_rl.envs.object_pregrasp import operate_pregrasp_path
    from dexmots_rl.envs.tasks.allegro.operate_object import build_scene

    scene, _ = build_scene(name)
    pose = json.loads(operate_pregrasp_path(name).read_text())["poses"][0]
    model = mujoco.MjModel.from_xml_path(str(scene.path))
    data = mujoco.MjData(model)
    data.qpos[:len(pose)] = pose
    mujoco.mj_forward(model, data)
    # the object's visual meshes are drawn, its collision primitives (which they cover) are not
    for g in range(model.ngeom):
        if (mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or "").startswith("object") \
                and model.geom_group[g] == 0:
            model.geom_rgba[g, 3] = 0.0
    model.vis.headlight.ambient[:] = 0.45
    model.vis.headlight.diffuse[:] = 0.6
    renderer = mujoco.Renderer(model, size[1], size[0])
    option = mujoco.MjvOption()
    option.sitegroup[:] = 0
    camera = mujoco.MjvCamera()
    camera.lookat[:] = (-0.01, 0.0, 0.02)
    camera.distance = 0.38
    images = []
    for azimuth, elevation in VIEWS:
        camera.azimuth, camera.elevation = azimuth, elevation
        renderer.update_scene(data, camera, option)
        images.append(renderer.render())
    renderer.close()
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.concatenate(images, axis=1)).quantize(colors=256).save(out, optimize=True)
    return {"object": name, "figure": str(out), "bytes": out.stat().st_size}


def main(argv: list[str] | None = None) -> int:
    from dexmots_rl.assets.objects import list_objects

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=str(ROOT / "docs" / "figures" / "pregrasps"), help="folder of the PNGs")
    p.add_argument("--objects", nargs="*", default=None, help="default: each class's first object")
    p.add_argument("--size", type=int, nargs=2, default=(480, 400), metavar=("W", "H"), help="of one view")
    args = p.parse_args(argv)
    first: dict[str, str] = {}
    for name, cls in list_objects():
        first.setdefault(cls, name)
    classes = {name: cls for name, cls in list_objects()}
    names = args.objects or list(first.values())
    unknown = [n for n in names if n not in classes]
    if unknown:
        p.error(f"unknown objects {unknown}; choose from {sorted(classes)}")
    for name in names:
        stem = classes[name] if first[classes[name]] == name else name
        print(json.dumps(figure(name, Path(args.out) / f"{stem}.png", tuple(args.size))), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
