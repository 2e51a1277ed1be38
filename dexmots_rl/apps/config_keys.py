"""Keys no config declares: hydra composes ``+group.key=value`` (the spelling its own error advises for a key
it does not know) into the config without a word, so a typo would train to the end and be ignored. The console
scripts compare what they were given with what their configs declare and refuse the first unknown key, naming
the keys it could have been, before any work. A key given without ``+`` is refused the same way before hydra
composes (:func:`refuse_undeclared_command_line`), so it is one line, not hydra's advice to add a ``+``.

Example:
    >>> from omegaconf import OmegaConf
    >>> given = OmegaConf.create({"seed": 0, "algo": {"name": "sac", "utd_ratio": 0.1, "utd_ration": 1.0}})
    >>> known = OmegaConf.create({"seed": 0, "algo": {"name": "sac", "utd_ratio": 0.1}})
    >>> try:
    ...     refuse_unknown_keys(given, known)
    ... except ValueError as e:
    ...     print(e)
    algo.utd_ration: no such key in algo (a '+' adds none either); its keys: name, utd_ratio
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from pathlib import Path
from typing import Collection

__all__ = ["TABLE_FREE_SECTIONS", "declared_config", "refuse_undeclared_command_line", "refuse_undeclared_table_keys",
           "refuse_undeclared_train_keys", "refuse_unknown_keys", "unknown_keys"]

#: dexmots-table's sections whose keys are the user's (task, method and launcher field names)
TABLE_FREE_SECTIONS = ("method_catalog", "task_labels", "task_budgets", "task_overrides", "method_overrides",
                       "paper_table", "launcher_params")


def unknown_keys(given, known, free: Collection[str] = (), prefix: str = "") -> list[str]:
    """Dotted keys of ``given`` absent from ``known`` (mappings, nested), not descending into the dotted keys
    in ``free`` (sections whose keys are the user's: task names, launcher fields, ...)."""
    out = []
    for key in given:
        path = f"{prefix}{key}"
        if path in free or key == "hydra":
            continue
        if key not in known:
            out.append(path)
        elif isinstance(given[key], Mapping) and isinstance(known[key], Mapping):
            out += unknown_keys(given[key], known[key], free, f"{path}.")
    return out


def refuse_unknown_keys(given, known, free: Collection[str] = (), section_names: Mapping[str, str] = {}) -> None:
    """``ValueError`` naming the first key of ``given`` that ``known`` lacks and the keys of its section;
    ``section_names``: a section's words in the message (e.g. ``{"algo": "algo (sac)"}``)."""
    unknown = unknown_keys(given, known, free)
    if not unknown:
        return
    section, _, _ = unknown[0].rpartition(".")
    node = known
    for part in filter(None, section.split(".")):
        node = node[part]
    keys = ", ".join(sorted(k for k in node if k != "hydra"))
    where = section_names.get(section, section) or "the config"
    raise ValueError(f"{unknown[0]}: no such key in {where} (a '+' adds none either); its keys: {keys}")


@functools.lru_cache(maxsize=None)
def declared_config(config_dir: str, overrides: tuple[str, ...] = ()):
    """The config ``config.yaml`` of ``config_dir`` composes with the group choices ``overrides`` (e.g.
    ``("task=stapler", "algo=sac")``, recipes included), as the package declares it, no command line applied
    (hydra 1.3's config loader, as dexmots-table's launch uses)."""
    from hydra._internal.config_loader_impl import ConfigLoaderImpl
    from hydra._internal.utils import create_config_search_path
    from hydra.types import RunMode

    loader = ConfigLoaderImpl(config_search_path=create_config_search_path(config_dir))
    return loader.load_configuration("config", list(overrides), run_mode=RunMode.RUN)


def refuse_undeclared_train_keys(cfg, config_dir) -> None:
    """``ValueError`` naming a key of ``cfg`` that dexmots-train's configs (``config_dir``) do not declare for its
    task and method (a ``+algo.<typo>=...``); ``task.*`` is its typed config's to check."""
    from ..algorithms.registry import algorithm

    name = cfg.algo.name
    declared = declared_config(str(config_dir), (f"task={cfg.task.name}", f"algo={algorithm(name).config}"))
    refuse_unknown_keys(cfg, declared, free=("task",), section_names={"algo": f"algo={name}"})


def refuse_undeclared_table_keys(cfg, config_dir) -> None:
    """:class:`.table_spec.SweepSpecError` naming a key dexmots-table's ``config_dir/config.yaml`` does not
    declare."""
    from .table_spec import SweepSpecError

    try:
        refuse_unknown_keys(cfg, declared_config(str(config_dir)), free=TABLE_FREE_SECTIONS)
    except ValueError as e:
        raise SweepSpecError(str(e)) from None


def refuse_undeclared_command_line(argv: list[str], config_dir, free: Collection[str] = ()) -> None:
    """``ValueError`` naming the first ``key=value`` of a hydra app's command line ``argv`` (its flags, ``+``,
    ``++``, ``~`` and ``hydra.*`` overrides aside) that the config of ``config_dir``, with the command line's
    group choices (``task=...``, ``algo=...``), does not declare, and the keys of its section; keys under
    ``free`` sections are the user's."""
    from hydra._internal.utils import get_args_parser
    from hydra.core.override_parser.overrides_parser import OverridesParser

    try:
        overrides = OverridesParser.create().parse_overrides(get_args_parser().parse_args(argv).overrides)
    except Exception:  # hydra's own parsing reports a malformed override
        return
    config_dir = Path(config_dir)
    groups = {p.name for p in config_dir.iterdir() if p.is_dir() and not p.name.startswith("_")}
    groups |= {"task"} & {o.key_or_group for o in overrides}  # the tasks' typed configs (hydra's ConfigStore)
    plain = [o for o in overrides if not (o.is_add() or o.is_force_add() or o.is_delete())]
    choices = tuple(o.input_line for o in plain if o.key_or_group in groups and not o.is_sweep_override())
    given: dict = {}
    for o in plain:
        if o.key_or_group in groups or o.key_or_group.startswith("hydra."):
            continue
        node, *path = given, *o.key_or_group.split(".")
        for part in path[:-1]:
            node = node.setdefault(part, {})
        node.setdefault(path[-1], None)
    refuse_unknown_keys(given, declared_config(str(config_dir), choices), free=free)
