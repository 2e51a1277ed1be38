"""The algorithm registry: each method's name, its training function, its hydra config and the loader of
the policy its checkpoints hold. ``dexmots-train algo=<name>`` runs :func:`algorithm(name).train
<Algorithm>`, ``dexmots-eval`` / ``dexmots-record`` rebuild a policy with :func:`policy_from_checkpoint`,
``dexmots-table`` lists the methods it can run.

Adding a method: a module of this package with ``train(cfg, overrides=None) -> dict`` (writing its run
through :class:`~.rundir.RunDirectory`, which also says whether it resumes) and, if it saves a policy,
``load_policy(checkpoint, env)``; its defaults in ``configs/algo/<name>.yaml``; one entry in
:data:`ALGORITHMS`.

Example:
    >>> from dexmots_rl.algorithms.registry import algorithm, list_algorithms
    >>> list_algorithms()
    ['ahac', 'mpc', 'pgdm', 'ppo', 'sac', 'shac']
    >>> algorithm("ahac").train is algorithm("shac").train, algorithm("mpc").load_policy is None
    (True, True)
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable, Optional

from ..envs import make_env
from . import mpc, pgdm, ppo, sac, shac
from .checkpoint import CheckpointError, latest_checkpoint, load_checkpoint

__all__ = ["ALGORITHMS", "Algorithm", "algorithm", "list_algorithms", "policy_from_checkpoint", "train"]


@dataclasses.dataclass(frozen=True)
class Algorithm:
    """A registered method."""

    name: str
    #: ``(cfg, overrides) -> metrics dict``: runs ``cfg`` (hydra's composed config); ``overrides``: the command
    #: line's, which a resume compares with its checkpoint
    train: Callable
    #: the hydra config of its defaults: ``configs/algo/<config>.yaml`` (``dexmots-train algo=<config>``)
    config: str
    #: ``(checkpoint dict, plain task env) -> policy``; None: the method saves no policy (a planner)
    load_policy: Optional[Callable] = None


ALGORITHMS: dict[str, Algorithm] = {a.name: a for a in (
    Algorithm("shac", shac.train, "shac", shac.load_policy),
    Algorithm("ahac", shac.train, "ahac", shac.load_policy),  # SHAC with the adaptive horizon
    Algorithm("ppo", ppo.train, "ppo", ppo.load_policy),
    Algorithm("sac", sac.train, "sac", sac.load_policy),
    Algorithm("pgdm", pgdm.train, "pgdm", pgdm.load_policy),
    Algorithm("mpc", mpc.train, "mpc"),
)}


def list_algorithms() -> list[str]:
    """The registered method names, sorted."""
    return sorted(ALGORITHMS)


def algorithm(name: str) -> Algorithm:
    """The registered method ``name``; a ``ValueError`` listing the known ones otherwise."""
    if name not in ALGORITHMS:
        raise ValueError(f"algo {name!r} is unknown; known: {', '.join(list_algorithms())}")
    return ALGORITHMS[name]


def train(cfg, overrides: list[str] | None = None) -> dict:
    """Run ``cfg`` with its method; on resume, with the method of the checkpoint's run (the run directory
    then checks that ``cfg`` asks for nothing else, :func:`.rundir.resume_config`)."""
    name = cfg.algo.name
    if cfg.resume:
        name = load_checkpoint(latest_checkpoint(cfg.resume)).get("algo", name)
    return algorithm(name).train(cfg, overrides)


def policy_from_checkpoint(path, device="cpu"):
    """``(policy, checkpoint dict)`` rebuilt from a checkpoint file or a run directory, on the plain task
    env of the checkpoint's task config (what ``evaluate_policy`` runs)."""
    path = Path(path)
    data = load_checkpoint(latest_checkpoint(path) if path.is_dir() else path)
    if data.get("algo") not in ALGORITHMS:
        raise CheckpointError(f"checkpoint {path}: unknown algo {data.get('algo')!r}; "
                              f"known: {', '.join(list_algorithms())}")
    entry = ALGORITHMS[data["algo"]]
    if entry.load_policy is None:
        raise CheckpointError(f"checkpoint {path}: algo {entry.name!r} saves no policy")
    env = make_env(data["config"]["task"], num_envs=1, differentiable=False, seed=0, device=device)
    return entry.load_policy(data, env), data
