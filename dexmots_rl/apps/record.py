"""``dexmots-record``: record episodes of a task to an MCAP file (Foxglove, ``dexmots-view``).

    dexmots-record task=screw_claw episodes=2 out=run.mcap                 # scripted controller, 4 worlds
    dexmots-record task=stapler out=stapler.mcap                           # random actions (no controller)
    dexmots-record task=screw_claw policy=random num_envs=8 steps=50 out=random.mcap
    dexmots-record checkpoint=runs/screw_claw_ahac_seed0 episodes=3 out=trained.mcap
    dexmots-record task=screw_claw episodes=20 live=true out=live.mcap     # + dexmots-view live.mcap --live
    dexmots-record task=screw_claw task.damping_range=[0.5,0.5] out=knob.mcap  # a task config field

Arguments are hydra overrides, ``key=value``, of ``configs/record/config.yaml`` (its comments say what each
key does): ``task`` (screw_claw), ``episodes`` (1), ``out`` (run.mcap), ``num_envs`` (4), ``steps`` (the task's
episode length), ``seed`` (0), ``device`` (cpu), ``policy`` (``auto``: the task's scripted controller where it
has one — screw_claw's grasp-and-twist, in torque space — and uniform random actions elsewhere; ``scripted``;
or ``random``), ``checkpoint`` (a ``dexmots-train`` checkpoint file or run directory: its task config builds
the env and its actor acts deterministically) and ``live`` (rewrite the file after every episode);
``task.<field>=<value>`` sets a field of the task's typed config as in ``dexmots-train`` (without a
checkpoint; e.g. ``task.object_params=knob.json`` records the object with those parameters). An unknown key, a
bad value or a ``+key=...`` no config declares fails naming the key. Every episode is a reset followed by
``steps`` steps in every world; the summary is printed as one JSON line.

Example:
    >>> import os, tempfile
    >>> out = os.path.join(tempfile.mkdtemp(), "run.mcap")
    >>> summary = run(["task=screw_claw", "episodes=1", "num_envs=2", "steps=3", f"out={out}"])
    >>> summary["frames"], summary["num_worlds"]
    (4, 2)
"""

from __future__ import annotations

import json
import logging
import sys
from pathlib import Path

from typing import Optional

import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

from ..envs import ScriptedPolicy, make_env, task_config
from ..envs.config import override_config
from ..envs.fields import check_value, rule
from ._policies import POLICIES, choose_policy

__all__ = ["RECORD_FIELDS", "config_options", "parse_overrides", "policy_from_checkpoint", "env_from_checkpoint", "run", "main"]

log = logging.getLogger(__name__)

#: the run keys (``configs/record/config.yaml`` has the defaults) -> (type, rule)
RECORD_FIELDS = {"episodes": (int, rule(ge=1)), "out": (str, None), "num_envs": (int, rule(ge=1)),
                 "steps": (Optional[int], rule(ge=1)), "seed": (int, rule(ge=0)), "device": (str, None),
                 "policy": (str, rule(choices=POLICIES)), "checkpoint": (Optional[str], None), "live": (bool, None)}


def parse_overrides(tokens: list[str]) -> dict:
    """``["key=value", ...]`` (hydra overrides of ``configs/record/config.yaml``; a leading ``--`` is dropped)
    -> the options (:func:`config_options`). ``ValueError`` naming a bad key or value."""
    from hydra import compose, initialize_config_dir

    from .config_keys import refuse_undeclared_command_line
    from .train import CONFIG_DIR

    overrides = [token.removeprefix("--") for token in tokens]
    refuse_undeclared_command_line(overrides, CONFIG_DIR / "record")
    try:
        with initialize_config_dir(config_dir=str(CONFIG_DIR / "record"), version_base="1.3"):
            cfg = compose("config", overrides=overrides)
    except Exception as e:  # hydra's composition errors name the override
        raise ValueError(str(e).splitlines()[0]) from None
    return config_options(cfg, overrides)


def config_options(cfg, overrides: list[str]) -> dict:
    """The options of the composed record config ``cfg``: the keys of :data:`RECORD_FIELDS`, ``task`` (its
    name) and ``task_overrides`` (the task fields the command line ``overrides`` set, typed by the task's
    config). ``ValueError`` naming a bad key or value."""
    from omegaconf import OmegaConf

    from .config_keys import declared_config, refuse_unknown_keys
    from .train import CONFIG_DIR

    refuse_unknown_keys(cfg, declared_config(str(CONFIG_DIR / "record"), (f"task={cfg.task.name}",)), free=("task",))
    values = OmegaConf.to_container(cfg, resolve=True)
    opts = {key: check_value(key, values[key], annotation, key_rule)
            for key, (annotation, key_rule) in RECORD_FIELDS.items()}
    given = dict.fromkeys(o.lstrip("+").partition("=")[0].split(".")[1] for o in overrides
                          if o.lstrip("+").startswith("task."))
    opts.update(task=cfg.task.name, task_overrides={field: values["task"][field] for field in given})
    if opts["checkpoint"] and opts["task_overrides"]:
        raise ValueError(f"task.{next(iter(opts['task_overrides']))}: a checkpoint's own task config builds the env; "
                         "task fields apply without a checkpoint")
    override_config(task_config(opts["task"]), opts["task_overrides"])  # a bad task field fails now, named
    return opts


def _load_checkpoint_module():
    try:
        from ..algorithms import checkpoint, registry
    except ImportError as exc:  # the training stack is not there (or broken): say so, not a bare traceback
        raise RuntimeError(f"loading a checkpoint needs dexmots_rl.algorithms ({exc})") from exc
    return checkpoint, registry


def env_from_checkpoint(path: str | Path, num_envs: int, seed: int = 0, device="cpu", steps: int | None = None):
    """``(env, checkpoint dict)``: a non-differentiable env built from the checkpoint's task config."""
    checkpoint, registry = _load_checkpoint_module()
    path = Path(path)
    data = checkpoint.load_checkpoint(checkpoint.latest_checkpoint(path) if path.is_dir() else path)
    task_cfg = dict(data["config"]["task"])
    if steps is not None:
        task_cfg["max_episode_steps"] = steps
    return registry.make_env(task_cfg, num_envs=num_envs, differentiable=False, seed=seed, device=device), data


def policy_from_checkpoint(path: str | Path, env):
    """Hook: the actor saved in a ``dexmots-train`` checkpoint (file or run directory), ready to act in ``env``.

    Imports :mod:`dexmots_rl.algorithms` lazily (a clear ``RuntimeError`` if they
    are missing). Run it under ``set_exploration_type(DETERMINISTIC)`` for the mean action. Raises
    ``ValueError`` when the actor does not fit ``env``'s observation (build ``env`` with
    :func:`env_from_checkpoint`).
    """
    _, registry = _load_checkpoint_module()
    actor, _ = registry.policy_from_checkpoint(path, device=env.device)
    try:
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            actor(env.reset())
    except RuntimeError as exc:
        raise ValueError(f"the policy in {path} does not fit this env's observation ({exc}); build the env "
                         "from the checkpoint's task config (env_from_checkpoint)") from None
    return actor


def _policy(opts: dict, env):
    if opts["checkpoint"]:
        return policy_from_checkpoint(opts["checkpoint"], env)
    if opts["policy"] == "random":
        return None
    return ScriptedPolicy(env.base_env)


def run(argv: list[str] | dict | None = None) -> dict:
    """Record as ``argv`` says (``key=value`` tokens, None: the command line's, or the options of
    :func:`config_options`); return the summary."""
    from ..viz import EpisodeRecorder

    opts = argv if isinstance(argv, dict) else parse_overrides(list(sys.argv[1:] if argv is None else argv))
    if opts["checkpoint"]:
        env, data = env_from_checkpoint(opts["checkpoint"], opts["num_envs"], opts["seed"], opts["device"],
                                        opts["steps"])
        opts["task"] = data.get("task", opts["task"])
    else:
        opts["policy"] = choose_policy(opts["policy"], opts["task"])
        # the scripted controller acts in torque space; a random policy explores the task's own actions
        action = {"action": "torque"} if opts["policy"] == "scripted" else {}
        env = make_env(opts["task"], num_envs=opts["num_envs"], device=opts["device"], differentiable=False,
                       seed=opts["seed"], **({"max_episode_steps": opts["steps"]} if opts["steps"] else {}),
                       **{**action, **opts["task_overrides"]})
    steps = opts["steps"] or env.base_env.max_episode_steps
    policy = _policy(opts, env)
    rewards, successes = [], []
    with EpisodeRecorder(opts["out"], env, live=opts["live"], task=opts["task"]) as rec:
        for episode in range(opts["episodes"]):
            with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
                rollout = env.rollout(steps, policy, tensordict=env.reset(), auto_reset=False,
                                      break_when_any_done=False)
            rec.record_rollout(rollout)
            rewards.append(float(rollout["next", "reward"].mean()))
            successes.append(float(rollout["next", "success"][:, -1].float().mean()))
            log.info("episode %d: mean reward %.3f, final success %.2f", episode, rewards[-1], successes[-1])
        frames = rec.num_frames
    summary = {"out": str(opts["out"]), "task": opts["task"], "episodes": opts["episodes"],
               "num_worlds": opts["num_envs"], "steps": steps, "frames": frames,
               "policy": "checkpoint" if opts["checkpoint"] else opts["policy"],
               "mean_reward": sum(rewards) / len(rewards), "final_success_rate": sum(successes) / len(successes)}
    return summary


def main(argv: list[str] | None = None) -> None:
    """Console entry point: a hydra app of ``configs/record/config.yaml`` (``--help`` prints the config, ``--cfg
    job`` the composed one); ``argv``: ``key=value`` tokens recorded in this process instead."""
    import hydra

    from .. import envs  # noqa: F401  (registers the tasks' configs with hydra)
    from .config_keys import refuse_undeclared_command_line
    from .train import CONFIG_DIR

    def record(options) -> None:  # options: () -> the options, whose bad input fails here too
        logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(asctime)s %(message)s")
        try:
            summary = run(options())
        except (ValueError, RuntimeError, OSError) as exc:
            raise SystemExit(f"dexmots-record: {exc}") from None
        print(json.dumps(summary))

    if argv is not None:
        record(lambda: parse_overrides(list(argv)))
        return
    try:  # one line naming the known keys, not hydra's advice to add a '+' (which adds nothing)
        refuse_undeclared_command_line(sys.argv[1:], CONFIG_DIR / "record")
    except ValueError as e:
        raise SystemExit(f"dexmots-record: {e}") from None

    @hydra.main(config_path=str(CONFIG_DIR / "record"), config_name="config", version_base="1.3")
    def _app(cfg) -> None:
        from hydra.core.hydra_config import HydraConfig

        record(lambda: config_options(cfg, list(HydraConfig.get().overrides.task)))

    _app()


if __name__ == "__main__":
    main()
