"""scripts/archive_sweep.py: a sweep's finished runs kept small enough for git, and not ignored by it."""

from __future__ import annotations

import importlib.util
import json
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SPEC = importlib.util.spec_from_file_location("archive_sweep", ROOT / "scripts" / "archive_sweep.py")
archive_sweep = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(archive_sweep)


def _run(folder: Path, finished: bool = True) -> None:
    folder.mkdir(parents=True)
    (folder / "config.yaml").write_text("seed: 0\n")
    rows = [{"iteration": 0, "env_steps": 10}, {"iteration": 1, "env_steps": 20},
            {"iteration": 1, "eval_success_rate": 0.5}, {"iteration": 2, "env_steps": 30}]
    (folder / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows) + '{"torn')
    (folder / "checkpoints").mkdir()
    (folder / "checkpoints" / "last.pt").write_bytes(b"0" * 1000)
    if finished:
        (folder / "metrics.json").write_text(json.dumps({"success_rate": 0.5}))


def test_archive_keeps_finished_runs_without_checkpoints_and_only_the_curve_rows(tmp_path):
    sweep, out = tmp_path / "sweep", tmp_path / "archive"
    _run(sweep / "runs" / "stapler" / "dexmots" / "vi" / "seed0")
    _run(sweep / "runs" / "stapler" / "ppo" / "vi" / "seed0", finished=False)
    (sweep / "runs.csv").write_text("task\n")
    assert archive_sweep.archive(sweep, out) == 1
    kept = out / "runs" / "stapler" / "dexmots" / "vi" / "seed0"
    assert sorted(p.name for p in kept.iterdir()) == ["config.yaml", "metrics.json", "metrics.jsonl"]
    rows = [json.loads(line) for line in (kept / "metrics.jsonl").read_text().splitlines()]
    assert rows == [{"iteration": 1, "env_steps": 20}, {"iteration": 1, "eval_success_rate": 0.5}]
    assert not (out / "runs" / "stapler" / "ppo").exists()
    assert (out / "runs.csv").read_text() == "task\n"


def test_the_archived_runs_csv_names_runs_relative_to_the_sweep(tmp_path):
    """A sweep's runs.csv written elsewhere (absolute paths of that machine) is archived with each run_dir relative
    to the sweep, and read back as the archive's own folders; a relative run_dir is kept."""
    from dexmots_rl.apps.table_writer import read_csv

    sweep, out = tmp_path / "sweep", tmp_path / "archive"
    _run(sweep / "runs" / "stapler" / "dexmots" / "vi" / "seed0")
    (sweep / "runs.csv").write_text("task,seed,run_dir\n"
                                    "stapler,0,/home/someone/tables/suite/runs/stapler/dexmots/vi/seed0\n"
                                    "stapler,1,runs/stapler/dexmots/vi/seed1\n")
    archive_sweep.archive(sweep, out)
    assert (out / "runs.csv").read_text().splitlines()[1:] == ["stapler,0,runs/stapler/dexmots/vi/seed0",
                                                              "stapler,1,runs/stapler/dexmots/vi/seed1"]
    assert [r["run_dir"] for r in read_csv(out / "runs.csv")] == [out / "runs/stapler/dexmots/vi/seed0",
                                                                  out / "runs/stapler/dexmots/vi/seed1"]


@pytest.mark.parametrize("path", sorted({*(ROOT / "results").glob("*/runs.csv"), *(ROOT / "docs").glob("**/*runs.csv")}))
def test_the_committed_results_name_no_machine_path(path):
    import csv

    with open(path, newline="") as f:
        run_dirs = [row["run_dir"] for row in csv.DictReader(f)]
    assert run_dirs and all(d.startswith("runs/") for d in run_dirs), path


def test_no_committed_result_or_doc_holds_a_path_of_the_machine_that_made_it():
    """Archived runs (config.yaml, metrics.json), tables and docs name run directories relative to their sweep."""
    import re

    pattern = re.compile(r"(?<![\w.])/(?:work|tmp|root|home)/")
    files = [p for folder in ("results", "docs") for p in (ROOT / folder).rglob("*")
             if p.suffix in (".json", ".yaml", ".csv", ".md") and p.is_file()]
    hits = [str(p.relative_to(ROOT)) for p in files if pattern.search(p.read_text(errors="replace"))]
    assert files and not hits, hits[:5]


def test_archived_runs_under_results_are_not_ignored_by_git():
    """results/<sweep>/runs/ holds the archived runs: git must keep them (every other runs/ folder is ignored)."""
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    probe = ["results/suite/runs/stapler/dexmots/vi/seed0/metrics.json", "runs/screw_claw_ahac/metrics.json"]
    done = subprocess.run(["git", "check-ignore", "--no-index", *probe], cwd=ROOT, capture_output=True, text=True)
    if done.returncode not in (0, 1):  # 0: some ignored, 1: none; anything else: git could not read this checkout
        pytest.skip(f"git check-ignore failed: {done.stderr.strip()}")
    assert done.stdout.split() == [probe[1]]
