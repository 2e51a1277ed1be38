"""``dexmots-train``: train a policy on a task (hydra app; configs packaged as ``dexmots_rl.configs``).

    dexmots-train                                   # screw_claw, AHAC: the configs' defaults
    dexmots-train task=screw_claw algo=shac seed=1 algo.iterations=100
    dexmots-train task.action=torque task.reward.lambda_f=0.5     # any field of the task's typed config
    dexmots-train resume=runs/screw_claw_ahac_seed0 # continue from the last checkpoint
    dexmots-train algo=ppo task.goal=pose           # model-free baselines: algo=ppo | sac | pgdm
    dexmots-train algo=mpc                          # sampling MPC + gradient refinement: evaluation only
    dexmots-train --cfg job                         # print the composed config
    torchrun --nproc_per_node 2 -m dexmots_rl.apps.train task.num_envs=32   # data parallel

``task=<name>`` composes the task's typed config (``dexmots_rl.envs.task_config(name)``, registered in
hydra's ConfigStore): the trainer trains exactly ``make_env(name)``. The method is ``algo=<name>``
(:mod:`dexmots_rl.algorithms.registry`).
"""

from __future__ import annotations

import importlib.util
import logging
import sys
from pathlib import Path

__all__ = ["CONFIG_DIR", "config_dir", "main", "run"]


def config_dir() -> Path:
    """The hydra config directory: the installed ``dexmots_rl.configs`` package data (a wheel or an
    editable install maps the repository's ``configs/`` there). A source tree's own ``configs/`` comes first:
    an editable install maps ``dexmots_rl.configs`` to the checkout it was installed from, which is not the
    one imported when running from another git worktree."""
    root = Path(__file__).resolve().parents[2]
    if (root / "pyproject.toml").is_file() and (root / "configs" / "config.yaml").is_file():
        return root / "configs"
    spec = importlib.util.find_spec("dexmots_rl.configs")
    if spec is not None and spec.submodule_search_locations:
        return Path(next(iter(spec.submodule_search_locations)))
    return root / "configs"


CONFIG_DIR = config_dir()


def run(cfg, overrides: list[str] | None = None) -> dict:
    """Train with the method ``cfg.algo.name`` (after the tasks are registered); ``overrides``: the
    command line's, which a resume compares with its checkpoint (:func:`dexmots_rl.algorithms.rundir.resume_config`)."""
    import torch

    from ..algorithms.registry import train
    from .config_keys import refuse_undeclared_train_keys

    refuse_undeclared_train_keys(cfg, CONFIG_DIR)
    threads = cfg.get("torch_threads")
    if threads is not None:
        if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
            raise ValueError(f"torch_threads must be a positive integer or null, got {threads!r}")
        if str(cfg.device).startswith("cpu"):
            torch.set_num_threads(threads)
    return train(cfg, overrides)


def main() -> None:
    """Console entry point."""
    import hydra
    from omegaconf import DictConfig

    from .. import envs  # noqa: F401  (registers the tasks' configs with hydra)
    from ..algorithms.checkpoint import CheckpointError
    from ..atomic import dumps_json
    from ._cli import os_errors_as_one_line

    from .config_keys import refuse_undeclared_command_line

    try:  # one line naming the known keys, not hydra's advice to add a '+' (which adds nothing)
        refuse_undeclared_command_line(sys.argv[1:], CONFIG_DIR)
    except ValueError as e:
        raise SystemExit(f"dexmots-train: {e}") from None

    @hydra.main(config_path=str(CONFIG_DIR), config_name="config", version_base="1.3")
    def _app(cfg: DictConfig) -> None:
        logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(asctime)s %(message)s")
        from hydra.core.hydra_config import HydraConfig

        try:
            with os_errors_as_one_line("dexmots-train"):
                result = run(cfg, list(HydraConfig.get().overrides.task))
        except (ValueError, CheckpointError) as e:
            raise SystemExit(f"dexmots-train: {e}") from None
        if result.get("interrupted"):
            print(f"dexmots-train: {result['interrupted']} at iteration {result['iteration']}: checkpoint saved; "
                  f"continue with: dexmots-train resume={result['run_dir']}", file=sys.stderr)
            raise SystemExit(130 if result["interrupted"] == "SIGINT" else 143)
        if result:
            print(dumps_json(result))
            written = [name for name in ("metrics.json", "metrics.jsonl", "checkpoints/last.pt")
                       if (Path(result["run_dir"]) / name).exists()]  # algo=mpc learns nothing: no checkpoint
            print(f"results in {result['run_dir']} ({', '.join(written)})", file=sys.stderr)

    _app()


if __name__ == "__main__":
    main()
