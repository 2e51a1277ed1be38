"""dexmots-eval keeps one result file per object set (and per object-parameter file) in the run directory:
evaluating on the held-out objects does not replace the evaluation on the training objects."""

from __future__ import annotations

import argparse
import json

import pytest

from dexmots_rl.algorithms.checkpoint import CheckpointError
from dexmots_rl.algorithms.evaluation import evaluate_policy
from dexmots_rl.apps import eval as eval_app
from dexmots_rl.envs.object_params import write_object_params


def _evaluate(run_dir, objects, object_params=None, evaluate=None, task=None):
    """dexmots-eval's own path from a checkpoint to its file, with a stand-in policy (and evaluation, unless
    ``evaluate`` is given); returns the task config the evaluation was given."""
    checkpoint = {"task": "valve", "algo": "ahac", "iteration": 3,
                  "config": {"task": task or {"name": "valve", "object": "valve_a", "objects": None}}}
    args = argparse.Namespace(checkpoint=str(run_dir), device="cpu", objects=objects, episodes=2, seed=0,
                              record=None, record_worlds=0, out=None, object_params=object_params)
    seen = {}

    def stand_in(actor, task_cfg, *a, **k):
        seen.update(task_cfg)
        return {"success_rate": 0.5}

    eval_app._run(args, evaluate or stand_in, lambda path, device: (None, checkpoint), CheckpointError)
    return seen


def test_each_object_set_has_its_own_eval_file(tmp_path):
    for objects in (None, "train", "heldout", "valve_a,valve_c"):  # the library's valves
        _evaluate(tmp_path, objects)
    files = {p.name: json.loads(p.read_text()) for p in tmp_path.glob("eval*.json")}
    assert sorted(files) == ["eval.json", "eval_heldout.json", "eval_train.json", "eval_valve_a+valve_c.json"]
    assert files["eval_train.json"]["objects"] == "train" and files["eval_heldout.json"]["objects"] == "heldout"
    assert "objects" not in files["eval.json"]


def test_a_checkpoint_file_writes_beside_its_run(tmp_path):
    assert eval_app.default_out(str(tmp_path / "checkpoints" / "last.pt"), "held/out") == (
        tmp_path / "eval_held_out.json")


def test_object_params_evaluate_on_that_model_in_their_own_file(tmp_path):
    """--object-params: the evaluation worlds simulate the file's values (the task config's object_params), and
    the result goes to its own file beside the run's own evaluation."""
    _evaluate(tmp_path, None)
    params = tmp_path / "true.json"
    write_object_params(params, "valve", {"valve/damping": 0.02})
    task_cfg = _evaluate(tmp_path, None, object_params=str(params))
    assert task_cfg["object_params"] == str(params.resolve())
    files = {p.name: json.loads(p.read_text()) for p in tmp_path.glob("eval*.json")}
    assert sorted(files) == ["eval.json", "eval_params_true.json"]
    assert files["eval_params_true.json"]["object_params"] == str(params.resolve())
    assert "object_params" not in files["eval.json"]


def test_a_bad_object_params_file_is_one_error_and_writes_nothing(tmp_path):
    """A parameter the checkpoint's scene does not have: one line naming the file and the parameter, no file."""
    bad = tmp_path / "bad.json"
    write_object_params(bad, "screw_claw", {"mass": 1.0})
    with pytest.raises(SystemExit, match=r"^dexmots-eval: task.object_params: .*bad.json names parameter 'mass'"):
        _evaluate(tmp_path, None, object_params=str(bad), evaluate=evaluate_policy, task={"name": "screw_claw"})
    assert not list(tmp_path.glob("eval*.json"))
