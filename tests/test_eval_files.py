"""dexmots-eval keeps one result file per object set in the run directory: evaluating on the held-out objects
does not replace the evaluation on the training objects."""

from __future__ import annotations

import argparse
import json

from dexmots_rl.algorithms.checkpoint import CheckpointError
from dexmots_rl.apps import eval as eval_app


def _evaluate(run_dir, objects):
    """dexmots-eval's own path from a checkpoint to its file, with a stand-in policy and evaluation."""
    checkpoint = {"task": "valve", "algo": "ahac", "iteration": 3,
                  "config": {"task": {"name": "valve", "object": "valve_a", "objects": None}}}
    args = argparse.Namespace(checkpoint=str(run_dir), device="cpu", objects=objects, episodes=2, seed=0,
                              record=None, record_worlds=0, out=None)
    eval_app._run(args, lambda actor, task_cfg, *a, **k: {"success_rate": 0.5},
                  lambda path, device: (None, checkpoint), CheckpointError)


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
