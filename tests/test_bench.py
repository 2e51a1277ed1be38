"""dexmots-bench grad: AD vs finite differences and the growth statistics, on a tiny configuration."""

from __future__ import annotations

import math

from dexmots_rl.trainers.bench import format_table, run


def test_grad_bench_rows_agree_with_finite_differences():
    result = run(["grad", "--task", "screw_claw", "--horizons", "1", "4", "--draws", "2", "--num-entries", "4",
                  "--quiet"])
    rows = result["rows"]
    assert [(r["loss_kind"], r["horizon"], r["contact"]) for r in rows] == [
        (kind, h, c) for kind in ("pose", "velocity") for h in (1, 4) for c in (True, False)]
    for row in rows:
        assert row["draws"] == 2
        assert row["median_rel_err"] < 1e-4, row
        assert row["grad_growth_max"] >= row["grad_growth"] >= 1.0 - 1e-12
        assert math.isfinite(row["growth_per_step"]) and row["growth_per_step"] > 0
        assert (row["contact_fraction"] > 0) == row["contact"], row
    # one step: the only action is the last one
    assert all(r["grad_growth"] == 1.0 for r in rows if r["horizon"] == 1)
    assert result["goals_met"]["median_rel_err_with_contact"]
    assert "grad_growth_at_longest_horizon" in result["goals_met"]
    assert "goal grad_growth_at_longest_horizon" in format_table(result)
