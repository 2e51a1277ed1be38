"""Real PartNet-Mobility objects as a user meets them: does each load, rest on the table, run ``operate``, and
stay within its energy under contact?

    python benchmarks/real_objects.py /path/to/partnet_folders                 # every <folder>/mobility.urdf
    python benchmarks/real_objects.py /path/to/partnet_folders --seconds 10 --steps 40 --energy-steps 50

The data set is licensed for non-commercial research only, so the objects are not in the repository: give a
folder of downloaded object folders (each with ``mobility.urdf`` and ``textured_objs/``). Per object, one JSON
line: ``load`` ("ok" or the loader's one-line error), ``class``, ``rest_shift_mm`` (the base's largest distance
from where it stood over ``--seconds`` simulated seconds alone on the table, no hand: the object simulator) and
``rest_joint`` (the largest joint motion, rad or m), ``operate`` ("ok" when ``make_env("operate", object=...)``
builds with its defaults, pre-grasps included, and ``--steps`` steps of random actions keep every state finite,
else the error), ``pregrasps`` (how the episodes start), and from benchmarks/energy.py (bang-bang fingers for
``--energy-steps`` steps): ``max_energy_excess_j`` (the largest energy gain beyond the motors' work, J) against
``release_j`` (what the hand's links give by falling), ``worlds_making_energy``, ``peak_base_speed`` (m/s) and
``fallen_worlds`` (objects knocked off). A last line sums up: the share that loads, the share that runs ``operate``
and the share that rests within 1 mm.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

import torch

REST_LIMIT_MM = 1.0


def rest(asset, seconds: float) -> dict:
    """The object alone on the table for ``seconds``: its base's largest shift (mm) and joints' motion."""
    from dexmots_rl.sim import ObjectSimulator, load_object_tree

    tree, _ = load_object_tree(asset)
    sim = ObjectSimulator(tree, 1)
    q, qd = sim.initial_state()
    start, params = q.clone(), sim.default_params()
    shift, moved = 0.0, 0.0
    with torch.no_grad():
        for _ in range(round(seconds / sim.dt)):
            q, qd = sim.step(q, qd, params)
            if tree.free:
                shift = max(shift, float((q[0, :3] - start[0, :3]).norm()))
            if tree.num_parts:
                moved = max(moved, float((q[0, 7 * tree.free:] - start[0, 7 * tree.free:]).abs().max()))
    return {"rest_shift_mm": round(shift * 1000, 3), "rest_joint": round(moved, 4),
            "rest_finite": bool(torch.isfinite(q).all())}


def operate(urdf: Path, steps: int, seed: int) -> dict:
    """``make_env("operate", object=urdf)`` with its defaults, then ``steps`` random actions."""
    from dexmots_rl.envs import make_env

    env = make_env("operate", num_envs=4, object=str(urdf), seed=seed, raw=True, differentiable=False)
    td = env.reset()
    gen = torch.Generator().manual_seed(seed)
    for _ in range(steps):
        td["action"] = 2 * torch.rand(env.action_spec.shape, generator=gen) - 1
        td = env.step(td)["next"]
    finite = bool(torch.isfinite(td["sim", "joint_q"]).all())
    return {"operate": "ok" if finite else "non-finite state",
            "pregrasps": "found" if env._pregrasps is not None else "open start"}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path, help="a folder of PartNet-Mobility object folders")
    parser.add_argument("--seconds", type=float, default=10.0, help="simulated seconds at rest")
    parser.add_argument("--steps", type=int, default=40, help="random-action steps of operate")
    parser.add_argument("--energy-steps", type=int, default=50, help="bang-bang steps (0: skip)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    sys.path.insert(0, str(Path(__file__).parent))
    from energy import measure

    from dexmots_rl.assets.objects.urdf import load_urdf

    urdfs = sorted(args.folder.glob("*/mobility.urdf"))
    if not urdfs:
        parser.error(f"{args.folder}: no <object>/mobility.urdf in it")
    rows = []
    for urdf in urdfs:
        row = {"object": urdf.parent.name}
        started = time.perf_counter()
        try:
            asset = load_urdf(urdf)
        except ValueError as error:
            row["load"] = str(error).splitlines()[0]
            rows.append(row)
            print(json.dumps(row), flush=True)
            continue
        row.update({"load": "ok", "class": asset.object_class, "size_m": round(asset.params["size"], 3),
                    "mass_kg": round(sum(g.mass for p in asset.parts for g in p.geoms), 3)})
        row.update(rest(asset, args.seconds))
        try:
            row.update(operate(urdf, args.steps, args.seed))
            if args.energy_steps:
                found = measure("operate", 4, args.energy_steps, args.seed, {"object": str(urdf)})
                row.update({k: found[k] for k in ("max_energy_excess_j", "worlds_making_energy", "release_j",
                                                  "peak_base_speed", "fallen_worlds")})
        except Exception as error:  # noqa: BLE001 - a benchmark reports every object's failure and goes on
            row["operate"] = f"{type(error).__name__}: {str(error).splitlines()[0]}"
        row["seconds"] = round(time.perf_counter() - started, 1)
        rows.append(row)
        print(json.dumps(row), flush=True)
    loaded = [r for r in rows if r["load"] == "ok"]
    print(json.dumps({"objects": len(rows), "load": f"{len(loaded)}/{len(rows)}",
                      "operate": f"{sum(r.get('operate') == 'ok' for r in rows)}/{len(rows)}",
                      "rest_within_1mm": f"{sum(r.get('rest_shift_mm', 1e9) < REST_LIMIT_MM for r in rows)}/{len(rows)}",
                      "max_rest_shift_mm": max((r["rest_shift_mm"] for r in loaded), default=None)}))


if __name__ == "__main__":
    main()
