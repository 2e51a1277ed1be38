"""BestPolicy: snapshots at the best training success, rollback after a collapse, checkpoint round trip,
and its use in SHAC/AHAC training (``algo.keep_best``)."""

from __future__ import annotations

import json
import math

import pytest
import torch
from test_train import _cfg, _rows

from dexmots_rl.algorithms.best_policy import BestPolicy
from dexmots_rl.algorithms.checkpoint import load_checkpoint
from dexmots_rl.algorithms.validation import validate_run_config
from dexmots_rl.apps.train import run as train


def _keeper(window=3, drop=0.3):
    net = torch.nn.Linear(3, 2)
    opt = torch.optim.Adam(net.parameters(), lr=0.1)
    return net, opt, BestPolicy({"actor": net}, {"actor": opt}, window=window, rollback_drop=drop)


def _train_step(net, opt):
    opt.zero_grad()
    net(torch.ones(1, 3)).sum().backward()
    opt.step()


def test_snapshot_follows_the_best_window_and_ignores_iterations_without_episodes():
    net, opt, keeper = _keeper(window=2)
    for s in (0.1, float("nan"), 0.5):
        keeper.observe(s)
        _train_step(net, opt)
    assert keeper.best_score == pytest.approx(0.3) and keeper.best_iteration == 3
    keeper.observe(0.2)  # window (0.5, 0.2): 0.35 > 0.3, a new best
    at_best = {k: v.clone() for k, v in net.state_dict().items()}
    _train_step(net, opt)
    keeper.observe(0.3)  # (0.2, 0.3): 0.25, neither a new best nor a collapse
    assert keeper.best_score == pytest.approx(0.35) and keeper.rollbacks == 0
    assert not all(torch.equal(v, at_best[k]) for k, v in net.state_dict().items())
    keeper.restore()
    assert all(torch.equal(v, at_best[k]) for k, v in net.state_dict().items())
    assert len(keeper.recent) == 0


def test_collapse_rolls_back_modules_and_optimizer_state():
    net, opt, keeper = _keeper(window=2, drop=0.3)
    keeper.observe(0.9), keeper.observe(0.9)
    weights = net.weight.detach().clone()
    _train_step(net, opt)
    _train_step(net, opt)
    assert not torch.equal(net.weight, weights)
    assert keeper.observe(0.5) is False  # (0.9, 0.5) = 0.7: within the drop
    assert keeper.observe(0.4) is True  # (0.5, 0.4) = 0.45 < 0.9 - 0.3
    assert torch.equal(net.weight, weights) and keeper.rollbacks == 1
    assert opt.state_dict()["state"] == {}  # Adam had taken no step at the best
    assert math.isnan(keeper.score)


def test_no_rollback_when_drop_is_none_and_state_round_trip():
    net, opt, keeper = _keeper(window=1, drop=None)
    for s in (0.8, 0.0, 0.0):
        assert keeper.observe(s) is False
        _train_step(net, opt)
    assert keeper.rollbacks == 0 and keeper.best_iteration == 1
    net2, opt2, keeper2 = _keeper(window=1, drop=None)
    keeper2.load_state_dict(keeper.state_dict())
    keeper2.restore()
    keeper.restore()
    torch.testing.assert_close(net2.state_dict(), net.state_dict())


@pytest.mark.parametrize("override, field", [("algo.best_window=0", "algo.best_window"),
                                             ("algo.rollback_drop=2.0", "algo.rollback_drop"),
                                             ("algo.keep_best=1", "algo.keep_best")])
def test_bad_keep_best_options_name_the_field(tmp_path, override, field):
    with pytest.raises(ValueError, match=field.replace(".", r"\.")):
        validate_run_config(_cfg(tmp_path / "run", override))


def test_training_records_the_final_policy_and_checkpoints_the_keeper(tmp_path):
    result = train(_cfg(tmp_path / "run", "algo.iterations=4", "algo.best_window=1", "algo.rollback_drop=null"))
    final = json.loads((tmp_path / "run" / "metrics.json").read_text())["final_policy"]
    assert final == result["final_policy"] and final["source"] in ("last", "best") and final["rollbacks"] == 0
    assert all(r["rollbacks"] == 0 for r in _rows(tmp_path / "run"))
    best = load_checkpoint(tmp_path / "run" / "checkpoints" / "last.pt")["best"]
    assert best["seen"] == 4 and best["best_iteration"] == final["best_iteration"]
    if best["best_iteration"] is not None:  # some 6-step episodes finished in the 4-step rollouts
        assert best["best_score"] == final["best_train_success"]
    off = train(_cfg(tmp_path / "off", "algo.iterations=1", "algo.keep_best=false"))
    assert off["final_policy"] == {"source": "last"}
