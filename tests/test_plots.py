"""Figures: the objective landscape (paper Fig. 4) and learning curves from CSVLogger run dirs."""

from __future__ import annotations

import json

import numpy as np
import pytest
from torchrl.record.loggers.csv import CSVLogger

from dexmots_rl.apps.plot import main as plot_main
from dexmots_rl.apps.landscape import landscape_data
from dexmots_rl.viz.plots import load_scalars, plot_curves, plot_landscape

GRID = 5


@pytest.fixture(scope="module")
def landscape():
    return landscape_data("screw_claw", grid=GRID, span=0.5, seed=0)


def test_landscape_data_shapes_and_gradients(landscape):
    d = landscape
    assert d["u"].shape == d["v"].shape == (GRID,)
    for key in ("J_pose", "J_pose_wrench", "theta", "torque"):
        assert d[key].shape == (GRID, GRID) and np.isfinite(d[key]).all(), key
    for key in ("grad_pose", "grad_pose_wrench"):
        assert d[key].shape == (GRID, GRID, 2) and np.isfinite(d[key]).all(), key
    c = GRID // 2
    # the reference is the centre action: both objectives peak there (1 and 2)
    assert d["J_pose"][c, c] == pytest.approx(1.0) and d["J_pose_wrench"][c, c] == pytest.approx(2.0)
    assert d["contact_force_min"] > 0  # every grid action is evaluated in contact
    assert np.abs(d["grad_pose_wrench"]).max() > 0
    assert d["joint_names"] == ["right_distal", "left_distal"]


def test_landscape_figure_has_two_titled_panels(landscape, tmp_path):
    out = tmp_path / "figs" / "landscape.png"
    fig = plot_landscape(landscape, out=out)
    panels = [ax for ax in fig.axes if ax.get_title()]
    assert len(panels) == 2 and len(fig.axes) == 3  # two panels and the shared colour bar
    assert panels[0].get_title().startswith("pose only") and panels[1].get_title().startswith("pose + wrench")
    assert out.is_file() and out.stat().st_size > 1000
    assert set(fig.landscape_summary) == {"pose only", "pose + wrench"}


def test_landscape_rejects_bad_grids():
    with pytest.raises(ValueError, match="odd"):
        landscape_data(grid=4)
    with pytest.raises(ValueError, match="span"):
        landscape_data(grid=3, span=0.0)


def _fake_run(root, name, values):
    logger = CSVLogger(exp_name="exp", log_dir=str(root / name))
    for step, (r, s) in enumerate(values):
        logger.log_scalar("reward", r, step=step * 100)
        logger.log_scalar("success_rate", s, step=step * 100)
    return root / name


def test_curves_from_csvlogger_run_dirs(tmp_path):
    a = _fake_run(tmp_path, "run_a", [(0.1, 0.0), (0.5, 0.2), (0.9, 0.6)])
    b = _fake_run(tmp_path, "run_b", [(0.2, 0.0), (0.4, 0.1)])
    runs = load_scalars([a, b])
    assert set(runs) == {"run_a", "run_b"}
    np.testing.assert_allclose(runs["run_a"]["reward"], [[0, 0.1], [100, 0.5], [200, 0.9]])
    fig = plot_curves([a, b], out=tmp_path / "curves.png")
    assert sorted(ax.get_title() for ax in fig.axes) == ["reward", "success_rate"]
    assert len(fig.axes[0].get_lines()) == 2
    assert (tmp_path / "curves.png").stat().st_size > 1000
    fig = plot_curves([a], keys=["success_rate"], smooth=2)
    assert [ax.get_title() for ax in fig.axes] == ["success_rate"]


def test_the_final_evaluation_ends_the_evaluation_curves(tmp_path):
    """The logger holds the periodic evaluations; the final one (metrics.json, at the run's last iteration) is
    their last point, also for a run that evaluated only at the end."""
    run = tmp_path / "run"
    logger = CSVLogger(exp_name="logs", log_dir=str(run))
    for iteration, success in ((10, 0.2), (20, 0.6)):
        logger.log_scalar("eval_success_rate", success, step=iteration)
        logger.log_scalar("eval_reward", success - 1, step=iteration)
    (run / "metrics.json").write_text(json.dumps({"success_rate": 0.9, "reward": -0.05, "iterations": 25,
                                                  "episodes": 100, "env_steps": 9000}))
    only_final = _fake_run(tmp_path, "only_final", [(0.1, 0.0)])
    (only_final / "metrics.json").write_text(json.dumps({"success_rate": 0.5, "iterations": 3}))
    runs = load_scalars([run, only_final])
    np.testing.assert_allclose(runs["run"]["eval_success_rate"], [[10, 0.2], [20, 0.6], [25, 0.9]])
    np.testing.assert_allclose(runs["run"]["eval_reward"], [[10, -0.8], [20, -0.4], [25, -0.05]])
    assert "eval_episodes" not in runs["run"] and "eval_env_steps" not in runs["run"]
    np.testing.assert_allclose(runs["only_final"]["eval_success_rate"], [[3, 0.5]])
    fig = plot_curves([run], keys=["eval_success_rate"])
    np.testing.assert_allclose(fig.axes[0].get_lines()[0].get_xydata()[-1], [25, 0.9])


def test_curves_errors_are_clear(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match="no scalar CSV"):
        load_scalars([tmp_path / "empty"])
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_scalars([tmp_path / "missing"])
    run = _fake_run(tmp_path, "run", [(0.1, 0.0)])
    with pytest.raises(KeyError, match="available"):
        plot_curves([run], keys=["nope"])
    with pytest.raises(SystemExit, match="no scalar CSV"):
        plot_main(["curves", str(tmp_path / "empty"), "--out", str(tmp_path / "x.png")])


def test_cli(tmp_path, capsys):
    run = _fake_run(tmp_path, "run", [(0.1, 0.0), (0.3, 0.5)])
    plot_main(["curves", str(run), "--out", str(tmp_path / "c.png")])
    assert (tmp_path / "c.png").is_file()
    plot_main(["landscape", "--grid", "3", "--out", str(tmp_path / "l.png"), "--json"])
    result = json.loads(capsys.readouterr().out)
    assert (tmp_path / "l.png").is_file() and set(result["panels"]) == {"pose only", "pose + wrench"}
