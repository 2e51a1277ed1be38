"""The sweep of ``dexmots-table``, checked before anything runs: which runs (task × method × seed, plus the
action-space runs of Fig. 3b), each one's ``dexmots-train`` overrides and run directory, and whether it is
already finished.

A method is an entry of ``method_catalog``: a label and ``dexmots-train`` overrides holding exactly one
``algo=<name>``. A run is identified by (task, method, action, seed) alone, and its directory is
``<sweep_dir>/runs/<task>/<method>/<action>/seed<seed>``: rerunning a sweep finds the runs it already has. A
run is **finished** when its directory holds a ``metrics.json`` with a final evaluation of that task and algo
and the ``config.yaml`` its trainer wrote is the run's whole ``dexmots-train`` config as the spec composes it
today (task, method, action, seed, budget and every override; :func:`run_identity`), so a smoke run of a
few iterations in the same sweep directory is run again, not reused (:func:`finished_metrics`); the
action-space run with a task's default action is the table's run itself.

``tasks: all`` / ``methods: all`` mean the paper's tasks that are registered / the catalog's methods whose algo
``dexmots-train`` has (what was left out is noted in table.md); a name given explicitly must exist, or the
spec fails with a :class:`SweepSpecError` naming the field and the name.

Every method of a task trains under the same budget: ``budget``, or the task's own entry of ``task_budgets``
(its whole budget: ``{wall_clock_s, env_steps, cpu_s}``, a key not given is null). The budget is among a run's
overrides, so it is part of the run's identity: a changed budget runs that task's runs again.

Example:
    >>> from omegaconf import OmegaConf
    >>> cfg = OmegaConf.create({"tasks": ["screw_claw"], "methods": ["dexmots"], "seeds": [],
    ...                         "method_catalog": {"dexmots": {"label": "Ours", "overrides": ["algo=ahac"]}}})
    >>> try:
    ...     sweep_spec(cfg, algos=["ahac"], registered=["screw_claw"], default_actions={"screw_claw": "vi"})
    ... except SweepSpecError as e:
    ...     print(e)
    seeds must be a non-empty list of distinct non-negative integers, got []
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

from ..envs import ACTION_TYPES
from ..algorithms.validation import ALGO_ADDED_WITH_THE_OLD_BEHAVIOUR
from ..envs.config import ADDED_WITH_THE_OLD_BEHAVIOUR

__all__ = ["IDENTITY_IGNORED", "Method", "Run", "SweepSpec", "SweepSpecError", "finished_metrics", "replaced_runs",
           "run_identity", "sweep_spec"]

log = logging.getLogger(__name__)

#: keys the table sets for every run itself: an override of one in the spec would break the comparison or the
#: run directories (budget: the same for all; seed, task, task.action: the sweep's axes; algo: the catalog's)
OWNED_KEYS = ("task", "seed", "algo", "task.action", "run_dir", "resume", "overwrite", "budget", "torch_threads",
              "hydra")

#: a budget's limits (dexmots_rl.algorithms.budget.RunBudget): seconds of training wall-clock, env steps, seconds of
#: the run process's training CPU time
BUDGET_KEYS = ("wall_clock_s", "env_steps", "cpu_s")

#: dexmots-train keys that do not change what a run computes (where it writes, how it reports, its threads):
#: left out of :func:`run_identity`
IDENTITY_IGNORED = ("run_dir", "overwrite", "progress", "torch_threads", "resume", "logger", "checkpoint_every",
                    "hydra")


class SweepSpecError(ValueError):
    """A bad sweep spec; the message names the field."""


@dataclass(frozen=True)
class Method:
    name: str
    label: str
    algo: str
    overrides: tuple[str, ...]


@dataclass(frozen=True)
class Run:
    """One ``dexmots-train`` run of the sweep; ``experiment``: ``table`` (Table 2 and the curves: the task's
    default action) or ``action_space`` (Fig. 3b only)."""

    task: str
    method: str
    algo: str
    action: str
    seed: int
    experiment: str
    run_dir: Path
    overrides: tuple[str, ...]
    #: the run's :func:`run_identity` as the spec composes it (None: not composed; then task and algo are checked)
    identity: Mapping[str, Any] | None = field(default=None, compare=False)

    @property
    def name(self) -> str:
        return f"{self.task}/{self.method}/{self.action}/seed{self.seed}"


@dataclass(frozen=True)
class SweepSpec:
    tasks: tuple[str, ...]
    methods: tuple[Method, ...]
    seeds: tuple[int, ...]
    ablation_tasks: tuple[str, ...]
    ablation_methods: tuple[str, ...]
    actions: tuple[str, ...]
    default_actions: Mapping[str, str]
    budget: Mapping[str, Any]
    sweep_dir: Path
    task_labels: Mapping[str, str]
    run_overrides: tuple[str, ...] = ()
    task_overrides: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    method_overrides: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    #: task -> its own budget (``{"wall_clock_s", "env_steps", "cpu_s"}``), replacing ``budget`` for every method of it
    task_budgets: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    #: task -> method -> (mean, s.d.) in %: the paper's own Table 2, quoted beside the measured one in table.md
    paper_table: Mapping[str, Mapping[str, tuple[float, float]]] = field(default_factory=dict)

    def method(self, name: str) -> Method:
        return next(m for m in self.methods if m.name == name)

    def budget_of(self, task: str) -> Mapping[str, Any]:
        """The training budget of every run of ``task``: its ``task_budgets`` entry, else ``budget``."""
        return self.task_budgets.get(task, self.budget)

    def runs(self, threads: int | None = None) -> list[Run]:
        """Every run, the table's first (task, method, seed order), then the action-space runs not already
        among them; ``threads``: each run's ``torch_threads`` (and simulator threads)."""
        keys = [(t, m.name, self.default_actions[t], s, "table") for t in self.tasks for m in self.methods
                for s in self.seeds]
        seen = {k[:4] for k in keys}
        for t in self.ablation_tasks:
            for m in self.ablation_methods:
                for a in self.actions:
                    for s in self.seeds:
                        if (t, m, a, s) not in seen:
                            seen.add((t, m, a, s))
                            keys.append((t, m, a, s, "action_space"))
        return [self._run(*k, threads) for k in keys]

    def _run(self, task, method_name, action, seed, experiment, threads) -> Run:
        method, budget = self.method(method_name), self.budget_of(task)
        run_dir = (self.sweep_dir / "runs" / task / method_name / action / f"seed{seed}").resolve()
        table_keys = [f"task={task}", f"seed={seed}", f"task.action={action}", f"run_dir={_quoted(run_dir)}",
                      "overwrite=true", "progress=false",  # an unfinished run restarts; the table has the bar
                      f"budget.wall_clock_s={_value(budget.get('wall_clock_s'))}",
                      f"budget.env_steps={_value(budget.get('env_steps'))}",
                      f"budget.cpu_s={_value(budget.get('cpu_s'))}",
                      f"hydra.sweep.subdir={_quoted(run_dir.relative_to(self.sweep_dir.resolve()))}"]
        if threads is not None:
            table_keys.append(f"torch_threads={threads}")
        overrides = (*self.run_overrides, *self.task_overrides.get(task, ()), *method.overrides,
                     *self.method_overrides.get(method_name, ()), *table_keys)
        return Run(task, method_name, method.algo, action, seed, experiment, run_dir, overrides)


def _value(v) -> str:
    return "null" if v is None else str(v)


def _quoted(path) -> str:
    return "'" + str(path).replace("\\", "\\\\").replace("'", "\\'") + "'"


def _plain(v):
    from omegaconf import DictConfig, ListConfig, OmegaConf

    return OmegaConf.to_container(v, resolve=True) if isinstance(v, (DictConfig, ListConfig)) else v


def _names(value, field_name: str, known: Sequence[str], what: str, all_names: Sequence[str] | None = None,
           available: Sequence[str] | None = None, unavailable_why=None) -> tuple[list[str], list[str]]:
    """``value`` as a list of names (``"all"``: ``all_names`` that are available), each known and available;
    returns (names, left out of "all")."""
    if value == "all" and all_names is not None:
        names = [n for n in all_names if available is None or n in available]
        left_out = [n for n in all_names if n not in names]
        if not names:
            raise SweepSpecError(f"{field_name}=all: none of {list(all_names)} is available")
        return names, left_out
    if not isinstance(value, list) or not value or not all(isinstance(n, str) for n in value):
        raise SweepSpecError(f"{field_name} must be a non-empty list of {what} names"
                             f"{' or all' if all_names is not None else ''}, got {value!r}")
    for n in value:
        if n not in known:
            raise SweepSpecError(f"{field_name}: unknown {what} {n!r}; known: {', '.join(known)}")
        if available is not None and n not in available:
            raise SweepSpecError(f"{field_name}: {what} {n!r} {unavailable_why(n)}")
    if len(set(value)) != len(value):
        raise SweepSpecError(f"{field_name} lists a {what} twice: {value}")
    return list(value), []


def _override_list(value, field_name: str) -> tuple[str, ...]:
    """A list of ``dexmots-train`` override strings, parsed by hydra, none setting a key the table owns."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    if value is None:
        return ()
    if not isinstance(value, list) or not all(isinstance(o, str) for o in value):
        raise SweepSpecError(f"{field_name} must be a list of dexmots-train overrides (strings), got {value!r}")
    for text in value:
        try:
            override = OverridesParser.create().parse_override(text)
        except Exception as e:  # hydra's grammar errors are several exception types
            raise SweepSpecError(f"{field_name}: {text!r} is not a hydra override ({e})") from None
        key = override.key_or_group
        if key in OWNED_KEYS or key.split(".")[0] in ("budget", "hydra"):
            raise SweepSpecError(f"{field_name}: {text!r} sets {key}, which dexmots-table sets for every run "
                                 "(use the spec's tasks / seeds / budget / action_ablation / method_catalog)")
    return tuple(value)


def _catalog(value) -> dict[str, Method]:
    if not isinstance(value, dict) or not value:
        raise SweepSpecError(f"method_catalog must map method names to {{label, overrides}}, got {value!r}")
    catalog = {}
    for name, entry in value.items():
        where = f"method_catalog.{name}"
        if not isinstance(entry, dict) or not isinstance(entry.get("label"), str):
            raise SweepSpecError(f"{where} must have a label (string) and overrides, got {entry!r}")
        overrides = entry.get("overrides")
        if not isinstance(overrides, list) or not all(isinstance(o, str) for o in overrides):
            raise SweepSpecError(f"{where}.overrides must be a list of dexmots-train overrides, got {overrides!r}")
        algos = [o.split("=", 1)[1] for o in overrides if o.startswith("algo=")]
        if len(algos) != 1:
            raise SweepSpecError(f"{where}.overrides must hold exactly one algo=<name>, got {overrides}")
        rest = [o for o in overrides if not o.startswith("algo=")]
        catalog[name] = Method(name, entry["label"], algos[0], (f"algo={algos[0]}", *_override_list(rest, where)))
    return catalog


def _per_name(value, field_name: str, known: Sequence[str], what: str) -> dict[str, tuple[str, ...]]:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise SweepSpecError(f"{field_name} must map {what} names to override lists, got {value!r}")
    for name in value:
        if name not in known:
            raise SweepSpecError(f"{field_name}: unknown {what} {name!r}; known: {', '.join(known)}")
    return {name: _override_list(v, f"{field_name}.{name}") for name, v in value.items()}


def _budget(value, field_name: str) -> dict[str, Any]:
    """``{"wall_clock_s", "env_steps", "cpu_s"}`` from a budget mapping, each null or positive (a key not given:
    null)."""
    if not isinstance(value, dict) or set(value) - set(BUDGET_KEYS):
        raise SweepSpecError(f"{field_name} takes {', '.join(BUDGET_KEYS)}, got {value!r}")
    seconds = lambda v: isinstance(v, (int, float)) and math.isfinite(v) and v > 0  # noqa: E731
    for key, ok in (("wall_clock_s", seconds), ("env_steps", lambda v: isinstance(v, int) and v > 0),
                    ("cpu_s", seconds)):
        v = value.get(key)
        if v is not None and (isinstance(v, bool) or not ok(v)):
            raise SweepSpecError(f"{field_name}.{key} must be null or a positive number, got {v!r}")
    return {key: value.get(key) for key in BUDGET_KEYS}


def _task_budgets(value, known: Sequence[str]) -> dict[str, dict[str, Any]]:
    """``task_budgets``: task name -> its whole budget; a name must be a registered or a paper task (a paper
    task not registered yet is left out of ``tasks: all`` with its budget)."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise SweepSpecError(f"task_budgets must map task names to {{{', '.join(BUDGET_KEYS)}}}, got {value!r}")
    out = {}
    for task, entry in value.items():
        if task not in known:
            raise SweepSpecError(f"task_budgets: unknown task {task!r}; known: {', '.join(dict.fromkeys(known))}")
        out[task] = _budget(entry, f"task_budgets.{task}")
    return out


def _paper_table(value, tasks: Sequence[str], methods: Sequence[str]) -> dict[str, dict[str, tuple[float, float]]]:
    """``paper_table``: task -> method -> ``[mean, s.d.]`` (% success), the paper's figures quoted in table.md."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise SweepSpecError(f"paper_table must map task names to {{method: [mean, s.d.]}}, got {value!r}")
    out = {}
    for task, row in value.items():
        if task not in tasks:
            raise SweepSpecError(f"paper_table: unknown task {task!r}; known: {', '.join(dict.fromkeys(tasks))}")
        if not isinstance(row, dict):
            raise SweepSpecError(f"paper_table.{task} must map methods to [mean, s.d.], got {row!r}")
        for method, cell in row.items():
            if method not in methods:
                raise SweepSpecError(f"paper_table.{task}: unknown method {method!r}; known: {', '.join(methods)}")
            if (not isinstance(cell, list) or len(cell) != 2 or not all(
                    isinstance(v, (int, float)) and not isinstance(v, bool) and 0 <= v <= 100 for v in cell)):
                raise SweepSpecError(f"paper_table.{task}.{method} must be [mean, s.d.] in %, got {cell!r}")
        out[task] = {method: (float(cell[0]), float(cell[1])) for method, cell in row.items()}
    return out


def sweep_spec(cfg, algos: Sequence[str], registered: Sequence[str], default_actions: Mapping[str, str]) -> SweepSpec:
    """The checked spec of a ``dexmots-table`` config; ``algos``: what ``dexmots-train`` can run
    (``list_algorithms()``), ``registered``: ``list_tasks()``, ``default_actions``: each task's ``task.action``."""
    c = {k: _plain(cfg.get(k)) for k in cfg.keys()}
    catalog = _catalog(c.get("method_catalog"))

    def why(name):
        return (f"needs algo={catalog[name].algo}, which dexmots-train does not have yet (its algos: "
                f"{', '.join(algos)}); leave it out, or use methods=all (every method that can run)")

    runnable = [n for n, m in catalog.items() if m.algo in algos]
    tasks, tasks_out = _names(c.get("tasks"), "tasks", list(registered), "task", c.get("paper_tasks") or [],
                              list(registered))
    methods, methods_out = _names(c.get("methods"), "methods", list(catalog), "method", list(catalog), runnable,
                                  why)
    seeds = c.get("seeds")
    if (not isinstance(seeds, list) or not seeds or len(set(seeds)) != len(seeds)
            or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in seeds)):
        raise SweepSpecError(f"seeds must be a non-empty list of distinct non-negative integers, got {seeds!r}")
    budget = _budget(c.get("budget") or {}, "budget")
    task_budgets = _task_budgets(c.get("task_budgets"), [*registered, *(c.get("paper_tasks") or [])])
    ablation = c.get("action_ablation") or {}
    if not isinstance(ablation, dict) or set(ablation) - {"tasks", "methods", "actions"}:
        raise SweepSpecError(f"action_ablation takes tasks, methods and actions, got {ablation!r}")
    ab_tasks, ab_methods, actions = [], [], list(ACTION_TYPES)
    if ablation.get("tasks"):
        ab_tasks, _ = _names(ablation["tasks"], "action_ablation.tasks", list(registered), "task")
        ab_methods, _ = _names(ablation.get("methods"), "action_ablation.methods", list(catalog), "method",
                               available=runnable, unavailable_why=why)
        actions, _ = _names(ablation.get("actions"), "action_ablation.actions", list(ACTION_TYPES), "action")
    if c.get("sweep_dir") in (None, ""):
        raise SweepSpecError("sweep_dir must be a directory path")
    notes = []
    if methods_out:
        notes.append(f"not run (algo not in dexmots-train yet): {', '.join(methods_out)}")
    if tasks_out:
        notes.append(f"not run (task not registered yet): {', '.join(tasks_out)}")
    return SweepSpec(
        tasks=tuple(tasks), methods=tuple(catalog[m] for m in methods), seeds=tuple(seeds),
        ablation_tasks=tuple(ab_tasks), ablation_methods=tuple(ab_methods), actions=tuple(actions),
        default_actions={t: default_actions[t] for t in {*tasks, *ab_tasks}},
        budget=budget, task_budgets={t: b for t, b in task_budgets.items() if t in {*tasks, *ab_tasks}},
        sweep_dir=Path(str(c["sweep_dir"])),
        task_labels={t: (c.get("task_labels") or {}).get(t, t) for t in {*tasks, *ab_tasks}},
        run_overrides=_override_list(c.get("run_overrides"), "run_overrides"),
        task_overrides=_per_name(c.get("task_overrides"), "task_overrides", list(registered), "task"),
        method_overrides=_per_name(c.get("method_overrides"), "method_overrides", list(catalog), "method"),
        notes=tuple(notes),
        paper_table=_paper_table(c.get("paper_table"), [*registered, *(c.get("paper_tasks") or [])], list(catalog)))


def run_identity(config) -> dict[str, Any]:
    """What a run computes, from its ``dexmots-train`` config (a DictConfig as composed, or a run directory's
    ``config.yaml`` as loaded): the resolved config without :data:`IDENTITY_IGNORED`."""
    from omegaconf import OmegaConf

    data = OmegaConf.to_container(config, resolve=False) if not isinstance(config, dict) else dict(config)
    kept = {k: v for k, v in data.items() if k not in IDENTITY_IGNORED}
    identity = OmegaConf.to_container(OmegaConf.create(kept), resolve=True)
    if isinstance(identity.get("budget"), dict):  # a limit that is not set is no limit, whether null or absent
        identity["budget"] = {k: v for k, v in identity["budget"].items() if v is not None}
    return identity


def _stored_identity(run: Run) -> dict | None:
    """The identity of ``run``'s saved ``config.yaml`` with the fields it predates filled in (task fields: at
    ``run.identity``'s value; algo fields: at the value those runs had)."""
    from omegaconf import OmegaConf

    try:
        stored = run_identity(OmegaConf.load(run.run_dir / "config.yaml"))
    except Exception:  # absent, torn or not YAML: not this spec's run  # noqa: BLE001
        return None
    identity = run.identity or {}
    for section, added in (("task", {k: v for k, v in (identity.get("task") or {}).items()
                                     if k in ADDED_WITH_THE_OLD_BEHAVIOUR}),
                           ("algo", {k: v for k, v in ALGO_ADDED_WITH_THE_OLD_BEHAVIOUR.items()
                                     if k in (identity.get("algo") or {})})):
        if isinstance(stored.get(section), dict):
            stored[section] = {**added, **stored[section]}
    return stored


def _differences(a: Any, b: Any, prefix: str = "") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        return [d for k in sorted(set(a) | set(b), key=str)
                for d in _differences(a.get(k, "<absent>"), b.get(k, "<absent>"), f"{prefix}{k}.")]
    return [] if a == b else [prefix.rstrip(".")]


def finished_metrics(run: Run) -> dict | None:
    """``run``'s ``metrics.json`` when it holds a final evaluation of the run's task and algo and, when
    ``run.identity`` is known, the run directory's ``config.yaml`` is that identity; else ``None`` (absent,
    torn, another run's, without a success rate, or trained with another config)."""
    try:
        data = json.loads((run.run_dir / "metrics.json").read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("task") != run.task or data.get("algo") != run.algo:
        return None
    rate, episodes = data.get("success_rate"), data.get("episodes")
    if not isinstance(rate, (int, float)) or not 0 <= rate <= 1 or not isinstance(episodes, int) or episodes < 1:
        return None
    if run.identity is not None:
        stored = _stored_identity(run)
        if stored != run.identity:
            differs = "no readable config.yaml" if stored is None else ", ".join(_differences(stored, run.identity))
            log.debug("%s: finished with another config (%s): not this sweep's run", run.name, differs)
            return None
    return data


def replaced_runs(runs: Sequence[Run]) -> dict[str, str]:
    """Run name -> the config keys that differ, for the runs whose directory holds a finished run of another
    config (they will be run again, replacing it)."""
    out = {}
    for run in runs:
        if run.identity is None or not (run.run_dir / "metrics.json").is_file():
            continue
        stored = _stored_identity(run)
        if stored is not None and stored != run.identity:
            out[run.name] = ", ".join(_differences(stored, run.identity)[:5])
    return out
