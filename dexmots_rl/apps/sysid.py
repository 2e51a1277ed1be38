"""``dexmots-sysid``: identify an object's physical parameters from recorded trajectories, through the simulator.

    dexmots-sysid --data run.mcap --params joint_damping joint_friction --out knob.json
    dexmots-sysid --data traj.npz --params hinge/damping hinge/friction --method gn --out door.json
    dexmots-train task=screw_claw task.object_params=knob.json                 # train on the identified model

``--data``: an MCAP recording from ``dexmots-record`` / ``dexmots-eval --record``, or a ``.npz`` (layout in
:mod:`dexmots_rl.sysid.data`); ``--params``: names of the scene's ``("sim", "params", ...)`` parameters;
``--out``: the parameter file (JSON) ``task.object_params`` reads. ``--method``: ``lbfgs`` (L-BFGS on the
gradient through the simulator), ``gn`` (Gauss-Newton on the exact Jacobian), ``fd-gn`` and ``cmaes`` (the
finite-difference and gradient-free references). ``--init NAME=VALUE``: initial guesses (default the scene's
nominal values); ``--bounds NAME=LOW,HIGH``; ``--position-scale`` (m) and ``--angle-scale`` (rad): the
measurement noise the residuals are divided by; ``--free-starts``: with ``lbfgs``, the segments' start
positions are estimated too (noisy data); ``--report``: a folder (default ``<out without .json>_report``).
Prints one JSON line: the values, their standard deviations, the condition number, the unidentifiable
parameters and the replay errors; the report folder holds the text and the plots.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from ._cli import errors_as_one_line

__all__ = ["build_parser", "run", "main"]

log = logging.getLogger(__name__)


def _named_values(kind, metavar: str):
    """An argparse type: ``NAME=VALUE`` -> ``(NAME, kind(VALUE))``, its error naming ``metavar``."""
    def parse(token: str):
        name, sep, value = token.partition("=")
        try:
            if not (sep and name):
                raise ValueError
            return name, kind(value)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {metavar}, got {token!r}") from None
    return parse


def _low_high(value: str) -> tuple[float, float]:
    low, high = (float(v) for v in value.split(","))  # anything but two numbers: ValueError
    return low, high


def build_parser() -> argparse.ArgumentParser:
    from ..sysid import METHODS

    p = argparse.ArgumentParser(prog="dexmots-sysid", description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True, help="an MCAP recording or a .npz of trajectories")
    p.add_argument("--params", nargs="+", required=True, metavar="NAME",
                   help="the scene's parameters to identify (e.g. joint_damping joint_friction)")
    p.add_argument("--out", required=True, help="the parameter file to write (JSON; task.object_params reads it)")
    p.add_argument("--method", default="lbfgs", choices=METHODS)
    p.add_argument("--iterations", type=int, default=30)
    p.add_argument("--segment-steps", type=int, default=8, help="env steps per shooting segment")
    p.add_argument("--validation", type=float, default=0.25, help="the share of segments held out")
    p.add_argument("--max-segments", type=int, default=None)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--init", nargs="+", default=[], metavar="NAME=VALUE", type=_named_values(float, "NAME=VALUE"),
                   help="initial guesses (default: the scene's nominal values)")
    p.add_argument("--bounds", nargs="+", default=[], metavar="NAME=LOW,HIGH",
                   type=_named_values(_low_high, "NAME=LOW,HIGH"),
                   help="search bounds (default x0.01-x100 of the guess, +-2 around it for a rest position)")
    p.add_argument("--position-scale", type=float, default=1e-3, help="position noise of the data (m)")
    p.add_argument("--angle-scale", type=float, default=1e-2, help="angle noise of the data (rad)")
    p.add_argument("--free-starts", action="store_true", help="lbfgs: estimate the segments' start positions too")
    p.add_argument("--report", default=None, help="the report folder (default: <out without .json>_report)")
    return p


def run(argv: list[str] | None = None) -> dict:
    """Parse, identify, write the parameter file and the report; return (and print) the summary."""
    from ..envs.object_params import write_object_params
    from ..sysid import ShootingProblem, identify, load_trajectories, write_report

    args = build_parser().parse_args(argv)
    with errors_as_one_line("dexmots-sysid"):
        traj = load_trajectories(args.data)
        problem = ShootingProblem(traj, args.params, segment_steps=args.segment_steps, validation=args.validation,
                                  seed=args.seed, initial=dict(args.init), bounds=dict(args.bounds),
                                  max_segments=args.max_segments, position_scale=args.position_scale,
                                  angle_scale=args.angle_scale, free_starts=args.free_starts)
        result = identify(problem, args.method, iterations=args.iterations, seed=args.seed)
        out = Path(args.out)
        report = Path(args.report or out.with_name(out.stem + "_report"))
        write_report(result, problem, report)
        write_object_params(out, traj.task["name"], result.values, std=result.std, data=str(args.data),
                            method=result.method, condition_number=result.condition_number,
                            unidentifiable=result.unidentifiable)
    summary = {k: v for k, v in result.summary().items() if k in ("values", "std", "condition_number", "unidentifiable",
                                                                  "validation_error", "relative_error", "cost")}
    summary.update(out=str(out), report=str(report))
    return summary


def main(argv: list[str] | None = None) -> None:
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(asctime)s %(message)s")
    print(json.dumps(run(argv)))
