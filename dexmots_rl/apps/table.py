"""``dexmots-table``: the paper's comparison (Table 2, Fig. 3b, Fig. 3c) in one command — tasks × methods ×
seeds as a hydra multirun of ``dexmots-train`` runs, then the table and the plots.

    dexmots-table                                        # preset=small: screw_claw + allegro_rotate, 3 seeds
    dexmots-table preset=suite                           # every paper and tool task, every method (2 cores, ~8 h)
    dexmots-table preset=paper launcher=submitit_slurm +launcher_params.partition=gpu +launcher_params.timeout_min=60
    dexmots-table seeds=[0] tasks=[screw_claw] methods=[dexmots,ppo] budget.wall_clock_s=30
    dexmots-table preset=suite report_only=true          # the table of the runs finished so far, launching nothing
    dexmots-table 'method_overrides.ppo=["algo.total_frames=64","algo.frames_per_batch=32"]'   # per-method overrides

How it works (configs/table/: ``config.yaml`` and the ``preset`` group):

1. The spec is checked before anything runs (:mod:`.table_spec`): names, seeds, budget, override lists, then
   every pending run's ``dexmots-train`` config is composed and validated, so a typo fails at once naming the
   field or the run. ``methods=all`` / ``tasks=all`` take what exists today (the rest is noted in table.md).
2. Runs whose directory already holds a final evaluation of the same whole config (task, method, action, seed,
   budget, every override: compared with the run's ``config.yaml``) are skipped (an interrupted sweep restarts
   where it stopped; a run of another config, e.g. a smoke run in the same sweep directory, is run again); the others are launched through **hydra's launcher plugins** on dexmots-train's own config, in
   multirun mode: ``joblib`` (n_jobs processes on this machine), ``submitit_slurm`` (one SLURM job per run),
   ``submitit_local`` or ``basic`` (this process). Each run gets ``torch_threads`` = ``threads_per_job`` and
   the same number of simulator threads (``DEXMOTS_CPU_THREADS``), by default cores // n_jobs, so parallel
   runs do not oversubscribe the cores (one thread per run changes float reduction order:
   configs/config.yaml, ``torch_threads``). An unfinished run restarts from scratch (``overwrite=true``).
3. Every run of a task has the same budget, ``budget`` or the task's ``task_budgets`` entry
   (``wall_clock_s`` of training, evaluations excluded, ``cpu_s`` of the run process's CPU time, likewise,
   and/or ``env_steps``:
   :mod:`dexmots_rl.algorithms.budget`; table.md states it, per task when the tasks' differ) and the same
   final evaluation (``eval.episodes`` deterministic episodes, success = the task's threshold at the episode end); the
   learning curves come from periodic evaluations (``eval.every`` per method in the preset,
   ``eval.curve_episodes`` episodes each).
4. Outputs in ``sweep_dir``: ``runs.csv`` (one row per run), ``table.md`` (Table 2's layout and the time to
   90 % success: :mod:`dexmots_rl.apps.table_writer`; the same runs at an equal number of env steps, and a
   planner's cost per evaluation episode: :mod:`dexmots_rl.apps.table_views`), ``curves_<task>.png`` (Fig. 3c) and
   ``action_space_<task>.png`` (Fig. 3b: :mod:`dexmots_rl.viz.table_plots`). A progress bar on stderr (on a
   terminal) counts finished runs; the table is printed at the end.

The launch uses hydra 1.3's config loader and launcher API (``hydra._internal``: the plugins' own entry
points; hydra-core is pinned below 1.4).
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import os
import shlex
import sys
import threading
from pathlib import Path


__all__ = ["closing_message", "main", "run_table", "train_job"]

log = logging.getLogger(__name__)

LAUNCHERS = ("joblib", "submitit_slurm", "submitit_local", "basic")
POLL_S = 5.0  # how often the progress bar looks for newly finished runs


def train_job(cfg) -> dict:
    """The hydra task function of one run, in the launcher's worker: ``dexmots-train``'s :func:`.train.run`
    with the simulator's threads set from ``torch_threads`` (the worker may be a fresh process)."""
    threads = cfg.get("torch_threads")
    if threads is not None and str(cfg.device).startswith("cpu"):
        os.environ["DEXMOTS_CPU_THREADS"] = str(threads)
    importlib.import_module("dexmots_rl.envs")  # registers the tasks in this process
    from .train import run

    with contextlib.redirect_stdout(sys.stderr):  # warp reports kernel compilation with print()
        return run(cfg)


def _threads(cfg, cores: int) -> int | None:
    from .table_spec import SweepSpecError

    if cfg.launcher not in LAUNCHERS:
        raise SweepSpecError(f"launcher must be one of {', '.join(LAUNCHERS)}, got {cfg.launcher!r}")
    n_jobs = cfg.n_jobs
    if isinstance(n_jobs, bool) or not isinstance(n_jobs, int) or n_jobs < 1:
        raise SweepSpecError(f"n_jobs must be a positive integer, got {n_jobs!r}")
    threads = cfg.threads_per_job
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int) or threads < 1):
        raise SweepSpecError(f"threads_per_job must be null or a positive integer, got {threads!r}")
    if cfg.launcher in ("joblib", "basic"):
        parallel = n_jobs if cfg.launcher == "joblib" else 1
        if threads is None:
            return max(1, cores // parallel)
        if parallel * threads > cores:
            log.warning("n_jobs %d x threads_per_job %d > %d cores: the runs will wait on each other",
                        parallel, threads, cores)
        return threads
    return threads if threads is not None else (cfg.launcher_params or {}).get("cpus_per_task")


def _train_multirun_config(cfg, sweep_dir: Path):
    """dexmots-train's config loader and its multirun config with the chosen launcher and ``sweep_dir``."""
    from hydra._internal.config_loader_impl import ConfigLoaderImpl
    from hydra._internal.utils import create_config_search_path
    from hydra.types import RunMode
    from omegaconf import OmegaConf, open_dict
    from omegaconf.errors import OmegaConfBaseException

    from .table_spec import SweepSpecError, _quoted
    from .train import CONFIG_DIR

    loader = ConfigLoaderImpl(config_search_path=create_config_search_path(str(CONFIG_DIR)))
    master = loader.load_configuration("config", [
        f"hydra/launcher={cfg.launcher}", "hydra/hydra_logging=none", "hydra.job.name=dexmots-table",
        f"hydra.sweep.dir={_quoted(sweep_dir.resolve())}"], run_mode=RunMode.MULTIRUN)
    params = dict(cfg.launcher_params or {})
    if cfg.launcher == "joblib":
        params.setdefault("n_jobs", cfg.n_jobs)
    with open_dict(master.hydra):  # the launcher's own fields only (its structured config rejects others)
        for key, value in params.items():
            try:
                OmegaConf.update(master, f"hydra.launcher.{key}", value, merge=False)
            except OmegaConfBaseException:
                fields = [k for k in master.hydra.launcher if not k.startswith("_")]
                raise SweepSpecError(f"launcher_params.{key}: the {cfg.launcher} launcher has no field {key!r}; "
                                     f"its fields: {', '.join(fields)}") from None
    return loader, master


def _composed(loader, master, runs) -> list:
    """``runs`` with their :func:`.table_spec.run_identity` (each run's dexmots-train config composed now, so
    a bad override fails before any run)."""
    import dataclasses

    from .table_spec import SweepSpecError, run_identity

    out = []
    for run in runs:
        try:
            out.append(dataclasses.replace(run, identity=run_identity(loader.load_sweep_config(master,
                                                                                               list(run.overrides)))))
        except Exception as e:  # hydra's errors name the key
            raise SweepSpecError(f"run {run.name}: {e}".splitlines()[0]) from None
    return out


def _check_composes(loader, master, runs) -> None:
    """Validate each run's dexmots-train config now, so a bad value fails before any run."""
    from ..algorithms.validation import validate_run_config
    from .table_spec import SweepSpecError
    from .config_keys import refuse_undeclared_train_keys
    from .train import CONFIG_DIR

    for run in runs:
        try:
            composed = loader.load_sweep_config(master, list(run.overrides))
            refuse_undeclared_train_keys(composed, CONFIG_DIR)
            validate_run_config(composed)
        except Exception as e:  # hydra's and the validator's errors name the key
            raise SweepSpecError(f"run {run.name}: {e}".splitlines()[0]) from None


class _SweepProgress:
    """A progress bar of finished runs, refreshed from their run directories by a polling thread (the launchers
    block until the whole sweep is done)."""

    def __init__(self, pending, done: int, total: int, enabled: bool):
        from ..progress import progress_bar
        from .table_spec import finished_metrics

        self._finished = finished_metrics
        self.pending, self.seen = list(pending), 0
        self.bar = progress_bar(total=total, initial=done, desc="dexmots-table", unit="run", disable=not enabled,
                               file=sys.stderr, dynamic_ncols=True)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._poll, daemon=True)

    def _refresh(self) -> None:
        done = sum(self._finished(r) is not None for r in self.pending)
        if done > self.seen:
            self.bar.update(done - self.seen)
            self.seen = done

    def _poll(self) -> None:
        while not self._stop.wait(POLL_S):
            self._refresh()

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self._refresh()
        self.bar.close()


def _launch(loader, master, runs) -> dict[str, str]:
    """Run ``runs`` through the configured hydra launcher; returns run name -> error of the runs that raised."""
    from hydra._internal.callbacks import Callbacks
    from hydra.core.plugins import Plugins
    from hydra.core.utils import JobStatus
    from hydra.types import HydraContext

    context = HydraContext(config_loader=loader, callbacks=Callbacks(master))
    launcher = Plugins.instance().instantiate_launcher(hydra_context=context, task_function=train_job, config=master)
    returns = launcher.launch([list(r.overrides) for r in runs], initial_job_idx=0)
    failures = {}
    for run, ret in zip(runs, returns):
        if ret.status == JobStatus.FAILED:
            err = ret._return_value  # the exception (reading .return_value would raise it)
            failures[run.name] = f"{type(err).__name__}: {err}".splitlines()[0]
    return failures


def _report(spec, rows: list[dict], failures: dict, outputs: list[str]) -> str:
    from .table_views import NOT_RECORDED, equal_steps_table, planning_cost_table
    from .table_writer import (NO_TRAINING, action_space_table, budget_cell, budget_text, machines_text,
                               markdown_table, quoted_table, time_to_success_table)

    tasks = [(t, spec.task_labels[t]) for t in spec.tasks]
    budgets = {t: spec.budget_of(t) for t in spec.tasks}
    per_task = len({budget_cell(b) for b in budgets.values()}) > 1  # then a Budget column states each
    methods = [(m.name, m.label) for m in spec.methods]
    table_rows = [r for r in rows if r["experiment"] == "table"]
    machines = machines_text(table_rows)  # the machines, commits and dates the runs had
    episodes = sorted({r["episodes"] for r in table_rows if r["episodes"] is not None})
    ep_text = "–".join(str(e) for e in (episodes[0], episodes[-1])) if len(episodes) > 1 else (
        str(episodes[0]) if episodes else "the")
    lines = [f"# dexmots-table: {spec.sweep_dir.name}", "",
             f"Success rate (% of {ep_text} evaluation episodes, success: the task's threshold at the episode end), "
             f"mean ± s.d. over seeds {', '.join(map(str, spec.seeds))}. {budget_text(budgets, table_rows)}",
             "", markdown_table(table_rows, tasks, methods, seeds=len(spec.seeds),
                                budgets={t: budget_cell(b) for t, b in budgets.items()} if per_task else None), "",
             *([machines, ""] if machines else []),
             f"Training {_clock_words(budgets)} to 90 % success (mean over the runs that reached it, from the "
             "periodic and final evaluations; (reached/finished runs)):", "",
             time_to_success_table(table_rows, tasks, methods), "",
             "The same runs at an equal number of env steps per task (the fewest any trained run of the task "
             "collected, last column, with that run): success %, mean ± s.d. over seeds, of each run's last "
             "evaluation at or before that count, read from its curve; in brackets the env steps of the "
             "evaluations read and their episodes (a periodic evaluation runs eval.curve_episodes episodes, the "
             "final one eval.episodes, so a cell read from periodic ones is noisier), and n when some runs had "
             "none by then. A method that trains nothing shows its success beside its planning CPU seconds per "
             f"evaluation episode ({NOT_RECORDED}: runs made before the planning's CPU time was measured):", "",
             equal_steps_table(table_rows, tasks, methods), ""]
    for name, label in methods:
        if any(r["method"] == name and r["status"] == "finished" and r["stopped_by"] == NO_TRAINING
               for r in table_rows):
            lines += [f"{label} learns nothing and plans in every evaluation episode: its success beside the "
                      "planning per episode (mean over seeds; forward sim steps, CPU and wall seconds; the wall "
                      "seconds of runs sharing the cores include waiting):", "",
                      planning_cost_table(table_rows, tasks, name), ""]
    if any(spec.paper_table.get(t) for t in spec.tasks):
        lines += ["The paper's own Table 2 on the same tasks, quoted (not measured here: its simulator and hand "
                  "models, its training budgets, five seeds; success % at its tasks' thresholds):", "",
                  quoted_table(spec.paper_table, tasks, methods), ""]
    for task in spec.ablation_tasks:
        lines += [f"Success by action space on {spec.task_labels[task]} (Fig. 3b; % per seed, in seed order: "
                  "mean ± s.d., and the mean time to 90 % of the runs that got there):", "",
                  action_space_table(rows, task, [(m, spec.method(m).label) for m in spec.ablation_methods],
                                     spec.actions), ""]
    if outputs:
        lines += ["Figures: " + ", ".join(outputs), ""]
    notes = list(spec.notes)
    missing = [f"{r['task']}/{r['method']}/{r['action']}/seed{r['seed']}" for r in rows if r["status"] != "finished"]
    if missing:
        shown = [f"{name} ({failures[name]})" if name in failures else name for name in missing[:10]]
        notes.append(f"{len(missing)} of {len(rows)} runs not finished: {'; '.join(shown)}"
                     + ("; ..." if len(missing) > 10 else ""))
    if notes:
        lines += ["Notes:", *[f"- {n}" for n in notes], ""]
    return "\n".join(lines)


def _clock_words(budgets) -> str:
    from .table_writer import budget_clock

    clocks = {budget_clock(b) for b in budgets.values()}
    return "CPU time of the run's process" if clocks == {"cpu_s"} else (
        "wall-clock" if clocks == {"wall_clock_s"} else "time (each task's budget clock)")


def _figures(spec, runs, rows: list[dict]) -> list[str]:
    from ..viz.table_plots import plot_action_spaces, plot_learning_curves
    from .table_writer import action_space_runs, budget_clock, learning_curve

    import matplotlib.pyplot as plt

    finished = {(r["task"], r["method"], r["action"], r["seed"]) for r in rows if r["status"] == "finished"}
    written = []
    for task in spec.tasks:
        curves = {m.name: [learning_curve(r.run_dir) for r in runs
                           if r.experiment == "table" and r.task == task and r.method == m.name
                           and (r.task, r.method, r.action, r.seed) in finished] for m in spec.methods}
        if any(curves.values()):
            out = spec.sweep_dir / f"curves_{task}.png"
            plt.close(plot_learning_curves({m: c for m, c in curves.items() if c},
                                           {m.name: m.label for m in spec.methods}, spec.task_labels[task], out,
                                           time_key=budget_clock(spec.budget_of(task))))
            written.append(out.name)
    for task in spec.ablation_tasks:
        out = spec.sweep_dir / f"action_space_{task}.png"
        methods = [(m, spec.method(m).label) for m in spec.ablation_methods]
        values = {key: [100 * float(r["success"]) for r in done] for key, done in action_space_runs(rows, task).items()}
        plt.close(plot_action_spaces(values, spec.task_labels[task], methods, spec.actions, out))
        written.append(out.name)
    return written


def run_table(cfg) -> dict:
    """Check the spec, run what is not finished, write runs.csv, table.md and the figures; returns
    ``{"sweep_dir", "runs", "launched", "skipped", "failed", "table"}``."""
    from .. import envs
    from .table_writer import NO_TRAINING, learning_curve, run_row, write_csv
    from .table_views import add_equal_steps, planning_cost
    from ..algorithms.registry import list_algorithms
    from .config_keys import refuse_undeclared_table_keys
    from .table_spec import finished_metrics, replaced_runs, sweep_spec
    from .train import CONFIG_DIR

    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    refuse_undeclared_table_keys(cfg, CONFIG_DIR / "table")
    threads = _threads(cfg, cores)
    spec = sweep_spec(cfg, list_algorithms(), envs.list_tasks(),
                      {t: envs.task_config(t).action for t in envs.list_tasks()})
    loader, master = _train_multirun_config(cfg, spec.sweep_dir)
    runs = _composed(loader, master, spec.runs(threads))
    pending = [r for r in runs if finished_metrics(r) is None]
    _check_composes(loader, master, pending)
    for name, differs in replaced_runs(pending).items():
        log.warning("dexmots-table: %s holds a finished run of another config (%s): running it again", name, differs)
    log.info("dexmots-table: %d runs in %s (%d finished, skipped; %d to run with the %s launcher, %s threads each)",
             len(runs), spec.sweep_dir, len(runs) - len(pending), len(pending), cfg.launcher, threads or "default")
    failures, interrupted = {}, False
    if pending and cfg.get("report_only"):
        log.info("dexmots-table: report_only: %d runs not finished are left out", len(pending))
    elif pending:
        with _SweepProgress(pending, len(runs) - len(pending), len(runs), bool(cfg.progress)):
            try:
                failures = _launch(loader, master, pending)
            except KeyboardInterrupt:
                interrupted = True
    rows = []
    for run in runs:
        metrics = finished_metrics(run)
        status = "finished" if metrics is not None else ("failed" if run.name in failures else "missing")
        row = run_row(run, metrics, status)
        if metrics is not None and row["stopped_by"] == NO_TRAINING:  # a planner: its cost per episode
            row.update(planning_cost(metrics))
        rows.append(row)
    rows = add_equal_steps(rows, lambda run_dir: learning_curve(spec.sweep_dir / run_dir))  # runs.csv's: relative
    write_csv(rows, spec.sweep_dir / "runs.csv")
    report = _report(spec, rows, failures, _figures(spec, runs, rows))
    (spec.sweep_dir / "table.md").write_text(report)
    launched = 0 if cfg.get("report_only") else len(pending)
    return {"sweep_dir": str(spec.sweep_dir), "runs": len(runs), "launched": launched,
            "skipped": len(runs) - len(pending), "failed": sorted(failures), "interrupted": interrupted,
            "unfinished": [run.name for run, r in zip(runs, rows) if r["status"] != "finished"], "table": report}


def closing_message(result: dict, report_only: bool, overrides: list[str]) -> str | None:
    """What dexmots-table exits with when the sweep is not complete (None: it is), with the command that
    completes it; ``overrides``: the command line's."""
    if result["interrupted"]:
        return "dexmots-table: interrupted; rerun the same command to continue (finished runs are skipped)"
    missing = result["unfinished"]
    if not missing:
        return None
    shown = ", ".join(missing[:5]) + (f" and {len(missing) - 5} more" if len(missing) > 5 else "")
    if report_only:
        command = shlex.join(["dexmots-table", *(o for o in overrides if o.lstrip("+").split("=")[0] != "report_only")])
        return (f"dexmots-table: {len(missing)} of {result['runs']} runs not finished ({shown}); report_only=true "
                f"launched none; run them (finished runs are skipped) with: {command}")
    return (f"dexmots-table: {len(missing)} runs did not finish ({shown}; {len(result['failed'])} raised, table.md "
            "says why); rerun the same command to retry them")


def main() -> None:
    """Console entry point."""
    import hydra
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import DictConfig

    importlib.import_module("dexmots_rl.envs")  # registers the tasks' configs with hydra
    from ._cli import os_errors_as_one_line
    from .config_keys import TABLE_FREE_SECTIONS, refuse_undeclared_command_line
    from .table_spec import SweepSpecError
    from .train import CONFIG_DIR

    try:  # one line naming the known keys, not hydra's advice to add a '+' (which adds nothing)
        refuse_undeclared_command_line(sys.argv[1:], CONFIG_DIR / "table", free=TABLE_FREE_SECTIONS)
    except ValueError as e:
        raise SystemExit(f"dexmots-table: {e}") from None

    @hydra.main(config_path=str(CONFIG_DIR / "table"), config_name="config", version_base="1.3")
    def _app(cfg: DictConfig) -> None:
        logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(asctime)s %(message)s")
        try:
            with os_errors_as_one_line("dexmots-table"):
                result = run_table(cfg)
        except SweepSpecError as e:
            raise SystemExit(f"dexmots-table: {e}") from None
        print(result["table"])
        print(f"dexmots-table: {result['runs']} runs ({result['skipped']} already finished, {result['launched']} "
              f"launched); results in {result['sweep_dir']} (table.md, runs.csv, *.png)", file=sys.stderr)
        message = closing_message(result, bool(cfg.report_only), list(HydraConfig.get().overrides.task))
        if message:
            raise SystemExit(message)

    _app()


if __name__ == "__main__":
    main()
