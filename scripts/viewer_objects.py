"""Figures of every object class in the viewer: the Allegro hand over the class's first object on the table.

    python scripts/viewer_objects.py                      # docs/figures/objects/viewer_<class>.png
    python scripts/viewer_objects.py --classes valve jar --out /tmp/figs

For each class: the scene of :func:`~dexmots_rl.assets.hand_scene.hand_object_scene_xml`, one world simulated
for ``--steps`` steps from rest with the hand's motors off (:func:`~dexmots_rl.recording.record_simulation`),
opened in ``dexmots-view`` in headless Chromium (``scripts/browser_check.py``), which also checks that the
hand's links, the palm, the table and each of the object's bodies are drawn (prints their pixel counts as
JSON). The PNG is written with a 256-colour palette (well under 200 kB).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import logging
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _browser_check():
    spec = importlib.util.spec_from_file_location("browser_check", ROOT / "scripts" / "browser_check.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def figure(name: str, out: Path, steps: int, size: tuple[int, int]) -> dict:
    """Record object ``name`` with the hand, screenshot it in the viewer into ``out``; the check's result."""
    from PIL import Image

    from dexmots_rl.assets.hand_scene import hand_object_scene_xml
    from dexmots_rl.assets.objects import load_object
    from dexmots_rl.recording import record_simulation
    from dexmots_rl.sim import load_scene, make_simulator

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "scene.xml").write_text(hand_object_scene_xml(load_object(name), folder))
        sim = make_simulator(load_scene(folder / "scene.xml"), num_worlds=1)
        path = record_simulation(sim, steps, folder / f"{name}.mcap")
        shot = folder / "shot.png"
        result = _browser_check().run_check(path, out=shot, size=size, timeout=120, hide_panel=True)
        out.parent.mkdir(parents=True, exist_ok=True)
        Image.open(shot).convert("RGB").quantize(colors=256).save(out, optimize=True)
    result.update(object=name, figure=str(out), bytes=out.stat().st_size)
    return result


def main(argv: list[str] | None = None) -> int:
    from dexmots_rl.assets.objects import list_objects

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=str(ROOT / "docs" / "figures" / "objects"), help="folder of the PNGs")
    p.add_argument("--classes", nargs="*", default=None, help="default: every class")
    p.add_argument("--steps", type=int, default=10, help="simulated steps before the picture")
    p.add_argument("--size", type=int, nargs=2, default=(900, 600), metavar=("W", "H"))
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr)
    first: dict[str, str] = {}
    for name, cls in list_objects():
        first.setdefault(cls, name)
    unknown = set(args.classes or ()) - set(first)
    if unknown:
        p.error(f"unknown classes {sorted(unknown)}; choose from {sorted(first)}")
    ok = True
    for cls in args.classes or first:
        result = figure(first[cls], Path(args.out) / f"viewer_{cls}.png", args.steps, tuple(args.size))
        print(json.dumps({k: result[k] for k in ("object", "figure", "bytes", "pixels", "ok") if k in result}),
              flush=True)
        ok &= bool(result["ok"])
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
