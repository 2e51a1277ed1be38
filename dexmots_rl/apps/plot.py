"""``dexmots-plot``: the paper's figures from the simulator and from training runs.

    dexmots-plot landscape --task screw_claw --out landscape.png [--grid 21] [--span 0.5] [--json]
    dexmots-plot curves RUN_DIR [RUN_DIR ...] --out curves.png [--keys success_rate reward] [--smooth 5]

``landscape``: the one-step objective near contact over the two distal joint actions, pose-only vs
pose + wrench, with gradient arrows from the simulator (paper Fig. 4; :mod:`.landscape`); the
per-panel numbers (objective range, median and max ``|∂J/∂a|``) are printed, as JSON with ``--json``.
``curves``: learning curves from torchrl ``CSVLogger`` run directories (``<run>/<exp>/scalars/*.csv``).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import sys

__all__ = ["build_parser", "main"]

log = logging.getLogger(__name__)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="dexmots-plot", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="figure", required=True)
    p = sub.add_parser("landscape", help="one-step objective landscape near contact (paper Fig. 4)")
    p.add_argument("--task", default="screw_claw")
    p.add_argument("--out", default="landscape.png")
    p.add_argument("--grid", type=int, default=21, help="odd number of actions per axis")
    p.add_argument("--span", type=float, default=0.5, help="half width of the grid (action units)")
    p.add_argument("--contact-steps", type=int, default=2, help="closing steps after the first contact")
    p.add_argument("--twist", type=float, default=0.0, help="scripted twist action while closing")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true", help="print the panel numbers as one JSON object")
    p = sub.add_parser("curves", help="learning curves from CSVLogger run directories")
    p.add_argument("run_dirs", nargs="+")
    p.add_argument("--out", default="curves.png")
    p.add_argument("--keys", nargs="*", default=None, help="scalar names to plot (default: all)")
    p.add_argument("--smooth", type=int, default=1, help="moving-average window (points)")
    return parser


def main(argv: list[str] | None = None) -> None:
    """Console entry point."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(message)s")
    from ..viz import plots
    from .landscape import landscape_data

    if args.figure == "curves":
        try:
            plots.plot_curves(args.run_dirs, keys=args.keys, out=args.out, smooth=args.smooth)
        except (FileNotFoundError, KeyError) as exc:
            raise SystemExit(f"dexmots-plot curves: {exc}") from None
        return
    with contextlib.redirect_stdout(sys.stderr):  # warp reports kernel compilation with print()
        data = landscape_data(args.task, grid=args.grid, span=args.span, contact_steps=args.contact_steps,
                              twist=args.twist, seed=args.seed)
        fig = plots.plot_landscape(data, out=args.out)
    result = {"task": args.task, "out": args.out, "grid": args.grid, "settle_steps": data["settle_steps"],
              "contact_force_range": [data["contact_force_min"], data["contact_force_max"]],
              "scales": {k: data[k] for k in ("pose_scale", "force_scale", "torque_scale")},
              "panels": fig.landscape_summary}
    if args.json:
        print(json.dumps(result))
    else:
        for name, s in result["panels"].items():
            print(f"{name:>14}: objective range {s['range']:.3g}, median |dJ/da| {s['median_grad']:.3g}, "
                  f"max {s['max_grad']:.3g}")


if __name__ == "__main__":
    main()
