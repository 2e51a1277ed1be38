"""dexmots-bench diagnose: its fields, first- against zeroth-order agreement on a smooth case, its policy sources."""

from __future__ import annotations

import json
import math

import pytest
import torch
from omegaconf import OmegaConf

from dexmots_rl.apps.bench import run
from dexmots_rl.apps.bench_diagnose import _initial_config, fo_zo_agreement

ROW_FIELDS = ("horizon", "return_median", "grad_first_median", "grad_first_p90", "grad_all_median", "grad_all_p90",
              "capped_share", "nonfinite_share", "fo_zo_cosine", "fo_zo_norm_ratio", "zo_self_cosine",
              "fo_self_cosine", "cosine_ceiling")


def test_diagnose_reports_every_field_and_its_gradient_follows_the_smoothed_return_on_the_claw():
    # the claw's first steps from its pre-grasp start are smooth: an exact first-order gradient must agree with
    # the antithetic zeroth-order estimate up to the latter's sampling noise (its ceiling)
    result = run(["diagnose", "--task", "screw_claw", "--num-envs", "4", "--horizons", "1", "2", "--pairs", "64",
                  "--quiet"])
    json.dumps(result)
    assert result["task"] == "screw_claw" and result["action"] == "vi" and result["worlds"] == 4 * 2 * 64
    assert result["source"]["policy"].startswith("initial") and result["adjoint_clip"] == 10.0
    assert result["exploration_scale_median"] == pytest.approx(math.exp(-1.0), rel=1e-5)  # ahac's init_log_std
    assert [r["horizon"] for r in result["rows"]] == [1, 2]
    for row in result["rows"]:
        assert set(ROW_FIELDS) <= set(row)
        assert 0.0 <= row["capped_share"] <= 1.0 and row["nonfinite_share"] == 0.0
        assert row["fo_zo_cosine"] >= 0.85, row
        assert 0.75 <= row["fo_zo_norm_ratio"] <= 1.25, row
        assert row["cosine_ceiling"] >= 0.85, row
    assert result["rows"][1]["growth_per_step_in_rollout"] > 0 and result["growth_per_step"] > 0
    explore = result["exploration"]
    assert len(explore["action_names"]) == len(explore["share_near_plus_one"]) == 8
    assert explore["action_names"][4].startswith("stiffness:")
    assert len(explore["stiffness_share_at_stiff_end"]) == len(explore["stiffness_coverage"]) == 4
    assert all(0.0 <= c <= 1.0 for c in explore["stiffness_coverage"])


def test_fo_zo_agreement_sees_a_biased_first_order_gradient():
    # a linear return R = g.u: the ZO estimate converges to g; a first-order gradient pointing elsewhere is caught
    generator = torch.Generator().manual_seed(0)
    starts, pairs, dim = 3, 512, 4
    g = torch.tensor([1.0, -2.0, 0.5, 0.0])
    scale = torch.full((starts, dim), 0.3)
    noise = torch.randn(starts, pairs, dim, generator=generator)
    ret = torch.stack([(scale.unsqueeze(1) * noise * g).sum(-1), -(scale.unsqueeze(1) * noise * g).sum(-1)], -1)
    exact = fo_zo_agreement(g.expand(starts, pairs, 2, dim), ret, noise, scale)
    assert exact["fo_zo_cosine"] > 0.95 and exact["fo_zo_norm_ratio"] == pytest.approx(1.0, abs=0.1)
    assert exact["fo_self_cosine"] == pytest.approx(1.0) and exact["cosine_ceiling"] > 0.95
    wrong = fo_zo_agreement(torch.tensor([0.0, 0.0, 0.0, 1.0]).expand(starts, pairs, 2, dim), ret, noise, scale)
    assert wrong["fo_zo_cosine"] < 0.2


def _run_dir(tmp_path, metrics: bool):
    cfg = _initial_config("screw_claw")
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(cfg))
    if metrics:
        rows = [{"iteration": i, "env_steps": 100 * i, "clip_share": 0.01 * i, "grad_norm": 1.0, "horizon": 32,
                 "episode_success": None, "skipped_updates": 0, "clipped_adjoints": 5 * i} for i in range(1, 5)]
        rows.insert(2, {"iteration": 2, "eval_success_rate": 0.0})  # an evaluation row: not a training row
        (run_dir / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return cfg, run_dir


def test_diagnose_of_an_archived_run_without_checkpoint_summarises_its_training_log(tmp_path):
    _, run_dir = _run_dir(tmp_path, metrics=True)
    result = run(["diagnose", "--run", str(run_dir), "--num-envs", "1", "--horizons", "1", "--pairs", "2", "-q"])
    assert result["task"] == "screw_claw" and result["source"]["checkpoint"] is None
    log = result["training_log"]
    assert log["iterations_logged"] == 4 and log["last_iteration"] == 4 and log["clipped_adjoints"] == 20
    assert log["clip_share"]["max"] == pytest.approx(0.04) and log["clip_share"]["median"] == pytest.approx(0.025)


def test_diagnose_of_a_checkpoint_uses_its_policy(tmp_path):
    from dexmots_rl.algorithms.checkpoint import save_checkpoint
    from dexmots_rl.algorithms.networks import make_networks
    from dexmots_rl.envs import make_env

    cfg, run_dir = _run_dir(tmp_path, metrics=False)
    env = make_env("screw_claw", num_envs=1, differentiable=False)
    actor, _, norm = make_networks(env.observation_spec["observation"].shape[-1], env.action_spec.shape[-1],
                                   tuple(cfg.algo.hidden), math.log(0.2), layer_norm=cfg.algo.layer_norm)
    (run_dir / "checkpoints").mkdir()
    save_checkpoint(run_dir / "checkpoints" / "last.pt",
                    {"task": "screw_claw", "algo": "ahac", "config": OmegaConf.to_container(cfg, resolve=True),
                     "modules": {"actor": actor.state_dict(), "norm": norm.state_dict()}, "counters": {"iteration": 7}})
    result = run(["diagnose", "--run", str(run_dir), "--num-envs", "1", "--horizons", "1", "--pairs", "2", "-q"])
    assert result["source"]["policy"] == "ahac checkpoint" and result["source"]["iteration"] == 7
    assert result["exploration_scale_median"] == pytest.approx(0.2, rel=1e-5)  # the checkpoint's, not the config's


@pytest.mark.parametrize("argv, field", [
    (["--task", "screw_claw", "--adjoint-clip", "0.5"], "--adjoint-clip"),
    (["--task", "screw_claw", "--pairs", "1"], "--pairs"),
    (["--task", "screw_claw", "--horizons", "0"], "--horizons"),
    (["--run", "no/such/run"], "--run"),
    ([], "--task"),
])
def test_diagnose_refuses_bad_input_naming_the_field(argv, field):
    with pytest.raises(ValueError, match=field):
        run(["diagnose", *argv, "-q"])


def test_diagnose_refuses_a_task_the_run_did_not_train(tmp_path):
    _, run_dir = _run_dir(tmp_path, metrics=False)
    with pytest.raises(ValueError, match="--task jar"):
        run(["diagnose", "--task", "jar", "--run", str(run_dir), "-q"])
