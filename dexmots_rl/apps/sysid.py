"""``dexmots-sysid``: identify an object's physical parameters from recorded trajectories, through the simulator.

    dexmots-sysid data=run.mcap params=joint_damping,joint_friction out=knob.json
    dexmots-sysid data=traj.npz params=hinge/damping,hinge/friction method=gn out=door.json
    dexmots-train task=screw_claw task.object_params=knob.json                 # train on the identified model

Arguments are ``key=value`` tokens (a leading ``--`` is accepted): ``data`` (an MCAP recording from
``dexmots-record`` / ``dexmots-eval --record``, or a ``.npz``: layout in :mod:`dexmots_rl.sysid.data`), ``params``
(comma-separated names of the scene's ``("sim", "params", ...)`` parameters), ``out`` (the parameter file, JSON;
``task.object_params`` reads it), ``method`` (``lbfgs``: L-BFGS on the gradient through the simulator; ``gn``:
Gauss-Newton on the exact Jacobian; ``fd-gn`` and ``cmaes``: the finite-difference and gradient-free
references), ``iterations`` (30), ``segment_steps`` (8: env steps per shooting segment), ``validation`` (0.25:
the share of segments held out), ``max_segments`` (none), ``seed`` (0), ``init.<name>=<value>`` (an initial guess;
default the scene's nominal value), ``bounds.<name>=<low>,<high>``, ``position_scale`` (0.001 m) and
``angle_scale`` (0.01 rad): the measurement noise the residuals are divided by, ``free_starts`` (false; with
``lbfgs``: the segments' start positions are estimated too, for noisy data), and ``report`` (a folder; default
``<out without .json>_report``). Prints one JSON line: the values, their standard deviations, the condition
number, the unidentifiable parameters and the replay errors; the report folder holds the text and the plots.
"""

from __future__ import annotations

import json
import logging
import sys
from pathlib import Path

from ._cli import errors_as_one_line, printed_help

__all__ = ["DEFAULTS", "parse_overrides", "run", "main"]

log = logging.getLogger(__name__)

DEFAULTS = {"data": None, "params": None, "out": None, "method": "lbfgs", "iterations": 30, "segment_steps": 8,
            "validation": 0.25, "max_segments": None, "seed": 0, "position_scale": 1e-3, "angle_scale": 1e-2,
            "free_starts": False, "report": None}
_INTS, _FLOATS = ("iterations", "segment_steps", "max_segments", "seed"), ("validation", "position_scale",
                                                                          "angle_scale")


def _number(key: str, value: str, kind):
    try:
        return kind(value)
    except ValueError:
        raise ValueError(f"{key} must be {'an integer' if kind is int else 'a number'}, got {value!r}") from None


def parse_overrides(tokens: list[str]) -> dict:
    """``["key=value", ...]`` -> the options (with ``"init"`` and ``"bounds"`` dicts); unknown keys are errors."""
    opts = {**DEFAULTS, "init": {}, "bounds": {}}
    for token in tokens:
        key, sep, value = token.removeprefix("--").partition("=")
        group, dot, name = key.partition(".")
        if sep and dot and group in ("init", "bounds") and name:
            if group == "init":
                opts["init"][name] = _number(key, value, float)
            else:
                pair = [_number(key, v, float) for v in value.split(",")]
                if len(pair) != 2:
                    raise ValueError(f"{key} must be <low>,<high>, got {value!r}")
                opts["bounds"][name] = tuple(pair)
            continue
        key = key.replace("-", "_")
        if not sep or key not in DEFAULTS:
            raise ValueError(f"bad argument {token!r}: expected key=value with key one of {', '.join(DEFAULTS)}, "
                             "init.<name> or bounds.<name>")
        if key == "free_starts":
            if value.lower() not in ("true", "false"):
                raise ValueError(f"free_starts must be true or false, got {value!r}")
            opts[key] = value.lower() == "true"
            continue
        opts[key] = (_number(key, value, int) if key in _INTS else _number(key, value, float) if key in _FLOATS
                     else value)
    for key in ("data", "params", "out"):
        if not opts[key]:
            raise ValueError(f"{key} is required (e.g. data=run.mcap params=joint_damping,joint_friction out=knob.json)")
    opts["params"] = [p.strip() for p in opts["params"].split(",") if p.strip()]
    return opts


def run(argv: list[str] | None = None) -> dict:
    """Parse, identify, write the parameter file and the report; return (and print) the summary."""
    from ..envs.object_params import write_object_params
    from ..sysid import METHODS, ShootingProblem, identify, load_trajectories, write_report

    with errors_as_one_line("dexmots-sysid"):
        opts = parse_overrides(list(sys.argv[1:] if argv is None else argv))
        if opts["method"] not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)}, got {opts['method']!r}")
        traj = load_trajectories(opts["data"])
        problem = ShootingProblem(traj, opts["params"], segment_steps=opts["segment_steps"],
                                  validation=opts["validation"], seed=opts["seed"], initial=opts["init"],
                                  bounds=opts["bounds"], max_segments=opts["max_segments"],
                                  position_scale=opts["position_scale"], angle_scale=opts["angle_scale"],
                                  free_starts=opts["free_starts"])
        result = identify(problem, opts["method"], iterations=opts["iterations"], seed=opts["seed"])
        out = Path(opts["out"])
        report = Path(opts["report"] or out.with_name(out.stem + "_report"))
        write_report(result, problem, report)
        write_object_params(out, traj.task["name"], result.values, std=result.std, data=str(opts["data"]),
                            method=result.method, condition_number=result.condition_number,
                            unidentifiable=result.unidentifiable)
    summary = {k: v for k, v in result.summary().items() if k in ("values", "std", "condition_number", "unidentifiable",
                                                                  "validation_error", "relative_error", "cost")}
    summary.update(out=str(out), report=str(report))
    return summary


def main(argv: list[str] | None = None) -> None:
    if printed_help("dexmots-sysid", __doc__, argv):
        return
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(asctime)s %(message)s")
    print(json.dumps(run(argv)))
