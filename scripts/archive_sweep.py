"""Keep a ``dexmots-table`` sweep's results, without its checkpoints, in a folder fit for git.

    python scripts/archive_sweep.py tables/suite results/suite      # copy the finished runs there
    dexmots-table preset=suite sweep_dir=results/suite              # resumes from them (elsewhere, later)

For every finished run (a ``metrics.json`` next to its ``config.yaml``) under ``<sweep>/runs/``, the archive gets
``config.yaml`` and ``metrics.json`` as they are and ``metrics.jsonl`` cut to the rows the learning curves read (each
periodic evaluation and the training row before it), so a run takes a few kB instead of megabytes. That is what
``dexmots-table`` needs to skip a run (the whole config compared, the final evaluation) and to draw its curves; the
sweep's ``runs.csv`` (its ``run_dir`` column relative to the sweep, whatever machine wrote it), ``table.md`` and
figures are copied too. Runs already in the archive are replaced.
"""

from __future__ import annotations

import argparse
import csv
import json
import logging
import shutil
from pathlib import Path

from dexmots_rl.apps.table_writer import sweep_relative

log = logging.getLogger("archive_sweep")

def curve_rows(lines: list[str]) -> list[str]:
    """The rows of a ``metrics.jsonl`` that its learning curve reads: each evaluation row and the training row
    of the same iteration before it (torn lines of a killed run are dropped)."""
    rows = []
    for line in lines:
        try:
            rows.append(json.loads(line))
        except ValueError:
            continue
    kept, last_train = [], {}
    for row in rows:
        if "eval_success_rate" in row:
            train = last_train.get(row.get("iteration"))
            if train is not None:
                kept.append(train)
            kept.append(row)
        elif "env_steps" in row:
            last_train[row.get("iteration")] = row
    return [json.dumps(row) for row in kept]


def archive_run(run_dir: Path, out_dir: Path) -> None:
    out_dir.mkdir(parents=True, exist_ok=True)
    for name in ("config.yaml", "metrics.json"):
        shutil.copyfile(run_dir / name, out_dir / name)
    jsonl = run_dir / "metrics.jsonl"
    lines = jsonl.read_text().splitlines() if jsonl.is_file() else []
    (out_dir / "metrics.jsonl").write_text("".join(row + "\n" for row in curve_rows(lines)))


def copy_runs_csv(src: Path, dst: Path) -> None:
    """``src`` to ``dst`` with each ``run_dir`` relative to the sweep (an older sweep wrote absolute paths)."""
    with open(src, newline="") as f:
        reader = csv.DictReader(f)
        fields, rows = reader.fieldnames or [], list(reader)
    if "run_dir" not in fields:
        shutil.copyfile(src, dst)
        return
    with open(dst, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=fields)
        writer.writeheader()
        writer.writerows({**row, "run_dir": sweep_relative(row["run_dir"]) if row["run_dir"] else ""} for row in rows)


def archive(sweep: Path, out: Path) -> int:
    """Copy ``sweep``'s finished runs and tables into ``out``; returns the number of runs copied."""
    if not (sweep / "runs").is_dir():
        raise SystemExit(f"{sweep}: not a dexmots-table sweep directory (no runs/ folder)")
    copied = 0
    for metrics in sorted((sweep / "runs").glob("**/metrics.json")):
        run_dir = metrics.parent
        if not (run_dir / "config.yaml").is_file():
            continue
        archive_run(run_dir, out / run_dir.relative_to(sweep))
        copied += 1
    if (sweep / "runs.csv").is_file():
        copy_runs_csv(sweep / "runs.csv", out / "runs.csv")
    if (sweep / "table.md").is_file():
        shutil.copyfile(sweep / "table.md", out / "table.md")
    for figure in sweep.glob("*.png"):
        shutil.copyfile(figure, out / figure.name)
    return copied


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sweep", type=Path, help="the sweep directory (dexmots-table's sweep_dir)")
    parser.add_argument("out", type=Path, help="the archive folder")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    log.info("archived %d finished runs of %s in %s", archive(args.sweep, args.out), args.sweep, args.out)


if __name__ == "__main__":
    main()
