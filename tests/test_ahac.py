"""AdaptiveHorizon: the dual rule, clipping, truncation of a rollout, checkpointing."""

from __future__ import annotations

import doctest
import io

import pytest
import torch
from tensordict import TensorDict

import dexmots_rl.objectives.ahac as ahac_module
from dexmots_rl.objectives import AdaptiveHorizon
from toy_envs import PointMassEnv


def forces(value: float, n: int = 4, t: int = 16) -> torch.Tensor:
    return torch.full((n, t, 1), float(value))


def test_defaults_and_exact_update_rule():
    ahac = AdaptiveHorizon()
    assert (ahac.horizon_min, ahac.horizon_max, ahac.contact_threshold, ahac.lr) == (8, 64, 500.0, 5e-4)
    assert ahac.horizon == 64 and float(ahac.nu) == 0.0
    c = torch.tensor([[100.0, 900.0], [300.0, 1700.0]])  # [N=2, T=2]: world means 200, 1300 -> s = 750
    ahac.update(c)
    assert float(ahac.nu) == pytest.approx(5e-4 * (750.0 - 500.0))
    assert float(ahac.last_contact) == pytest.approx(750.0) and int(ahac.num_updates) == 1
    ahac_max = AdaptiveHorizon(world_reduction="max")
    ahac_max.update(c)  # world max 300, 1700 -> s = 1000
    assert float(ahac_max.nu) == pytest.approx(5e-4 * 500.0)


def test_horizon_shrinks_under_stiff_contact_and_grows_back_clipped():
    ahac = AdaptiveHorizon(horizon_min=8, horizon_max=64, contact_threshold=500.0, lr=0.02)
    horizons = [ahac.update(forces(1000.0)) for _ in range(20)]  # +10 per update in nu
    assert horizons[0] == 54 and all(a >= b for a, b in zip(horizons, horizons[1:]))
    assert horizons[-1] == 8 and float(ahac.nu) == pytest.approx(ahac.nu_max)  # clipped, no wind-up
    horizons = [ahac.update(forces(0.0)) for _ in range(20)]  # -10 per update
    assert horizons[0] == 18 and all(a <= b for a, b in zip(horizons, horizons[1:]))
    assert horizons[-1] == 64 and float(ahac.nu) == 0.0  # the dual stays >= 0
    # exactly at the threshold nothing moves
    ahac.update(forces(500.0))
    assert ahac.horizon == 64


def test_force_shapes_and_nonfinite_worlds():
    ahac = AdaptiveHorizon(lr=1e-3)
    ahac.update(forces(800.0)[..., 0])  # [N, T]
    nu = float(ahac.nu)
    ahac2 = AdaptiveHorizon(lr=1e-3)
    vec = torch.zeros(4, 16, 3)
    vec[..., 0], vec[..., 1] = 480.0, 640.0  # |c| = 800
    ahac2.update(vec)  # [N, T, 3]: the vector norm
    assert float(ahac2.nu) == pytest.approx(nu)
    bad = forces(800.0, n=5)
    bad[0] = float("nan")  # a blown-up world is ignored
    ahac3 = AdaptiveHorizon(lr=1e-3)
    ahac3.update(bad)
    assert float(ahac3.nu) == pytest.approx(nu)
    with pytest.raises(ValueError):
        ahac.update(torch.zeros(16))


def test_invalid_arguments():
    with pytest.raises(ValueError):
        AdaptiveHorizon(horizon_min=0)
    with pytest.raises(ValueError):
        AdaptiveHorizon(horizon_min=16, horizon_max=8)
    with pytest.raises(ValueError):
        AdaptiveHorizon(world_reduction="median")
    with pytest.raises(ValueError):
        AdaptiveHorizon(horizon_init=100)
    assert AdaptiveHorizon(horizon_init=32).horizon == 32


def test_state_dict_round_trip():
    ahac = AdaptiveHorizon(lr=0.01)
    for _ in range(3):
        ahac.update(forces(1200.0))
    buffer = io.BytesIO()
    torch.save(ahac.state_dict(), buffer)
    buffer.seek(0)
    restored = AdaptiveHorizon(lr=0.01)
    restored.load_state_dict(torch.load(buffer))
    assert restored.horizon == ahac.horizon < 64
    assert torch.equal(restored.nu, ahac.nu) and int(restored.num_updates) == 3
    assert restored.update(forces(0.0)) == ahac.update(forces(0.0))


def _contact_rollout(per_step: list[float], n: int = 2) -> TensorDict:
    c = torch.tensor(per_step).expand(n, -1).unsqueeze(-1)
    t = c.shape[1]
    return TensorDict({"observation": torch.arange(t).expand(n, t).unsqueeze(-1).float(),
                       "next": {"object": {"contact_force": c}}}, batch_size=[n, t])


def test_truncate_rollout_before_first_stiff_step():
    ahac = AdaptiveHorizon(horizon_min=4, horizon_max=16)
    forces_per_step = [0.0] * 16
    forces_per_step[10] = forces_per_step[12] = 900.0
    rollout = _contact_rollout(forces_per_step)
    assert ahac.stiff_step(rollout) == 10
    cut = ahac.truncate_rollout(rollout)
    assert cut.shape == torch.Size([2, 10])
    assert torch.equal(cut["observation"], rollout["observation"][:, :10])
    early = [0.0] * 16
    early[1] = 900.0
    assert ahac.truncate_rollout(_contact_rollout(early)).shape[-1] == 4  # never below horizon_min
    assert ahac.truncate_rollout(_contact_rollout([0.0] * 16)).shape[-1] == 16  # no stiff contact
    assert ahac.truncate_rollout(_contact_rollout(early[:3])).shape[-1] == 3  # shorter than the minimum
    renamed = TensorDict({"f": rollout["next", "object", "contact_force"]}, batch_size=[2, 16])
    assert ahac.truncate_rollout(renamed, contact_key="f").shape[-1] == 10


def test_update_from_env_rollout():
    env = PointMassEnv(num_envs=4, max_episode_steps=20, init_range=1.9, wall_radius=1.0)
    with torch.no_grad():
        rollout = env.rollout(12, auto_reset=False, break_when_any_done=False, tensordict=env.reset())
    ahac = AdaptiveHorizon(contact_threshold=0.0, lr=1.0)
    ahac.update_from_rollout(rollout)
    expected = rollout["next", "object", "contact_force"].squeeze(-1).mean().double()
    assert float(ahac.last_contact) == pytest.approx(float(expected)) and float(ahac.nu) > 0


def test_docstring_example_runs():
    result = doctest.testmod(ahac_module, extraglobs={"torch": torch})
    assert result.attempted > 0 and result.failed == 0


def test_capped_share_dual_shortens_the_horizon_and_lets_it_grow_back():
    ahac = AdaptiveHorizon(horizon_min=8, horizon_max=64, horizon_init=32, clip_share_target=0.02, clip_share_lr=20.0)
    assert ahac.update_clip_share(0.12) == 30  # mu = 20 * (0.12 - 0.02) = 2
    assert float(ahac.mu) == pytest.approx(2.0)
    horizons = [ahac.update_clip_share(0.5) for _ in range(10)]  # +9.6 per update
    assert all(a >= b for a, b in zip(horizons, horizons[1:])) and horizons[-1] == 8
    assert float(ahac.mu) == pytest.approx(ahac.nu_max)  # clipped: no wind-up
    assert ahac.update_clip_share(float("nan")) == 8  # no evidence: unchanged
    horizons = [ahac.update_clip_share(0.0) for _ in range(200)]  # -0.4 per update
    assert all(a <= b for a, b in zip(horizons, horizons[1:])) and horizons[-1] == 32  # back to the contact dual's
    assert float(ahac.mu) == 0.0
    ahac.update(forces(0.0))  # the contact dual still lengthens it on its own
    assert ahac.horizon == 32 and float(ahac.nu) < 32
    off = AdaptiveHorizon(horizon_init=32)
    assert off.update_clip_share(0.9) == 32 and "mu" not in off.state_dict()  # off: old checkpoints' keys
    with pytest.raises(ValueError, match="clip_share_target"):
        AdaptiveHorizon(clip_share_target=1.5)
    with pytest.raises(ValueError, match="clip_share_lr"):
        AdaptiveHorizon(clip_share_target=0.02, clip_share_lr=-1.0)
    restored = AdaptiveHorizon(horizon_init=32, clip_share_target=0.02)
    ahac.update_clip_share(0.3)
    restored.load_state_dict(ahac.state_dict())
    assert torch.equal(restored.mu, ahac.mu) and restored.horizon == ahac.horizon


@pytest.mark.parametrize("target", [None, 0.02])
def test_training_horizon_follows_a_forced_high_capped_share(tmp_path, target):
    """screw_claw, 4 worlds: a cap at the median world (adjoint_clip=1) caps a large share of adjoints; with
    ``horizon_clip_target`` the horizon falls to its minimum, without it the contact dual lengthens it."""
    from test_train import _cfg, _rows

    from dexmots_rl.apps.train import run as train

    train(_cfg(tmp_path / "run", "algo=ahac", "algo.iterations=3", "algo.horizon=6", "algo.horizon_min=2",
               "algo.horizon_max=8", "algo.adjoint_clip=1.0", f"algo.horizon_clip_target={target or 'null'}"))
    rows = _rows(tmp_path / "run")
    assert all(r["clip_share"] > 0.1 for r in rows)
    horizons = [r["horizon"] for r in rows]
    assert horizons[0] == 6
    if target is None:
        assert all(a <= b for a, b in zip(horizons, horizons[1:]))
    else:
        assert horizons[1:] == [2, 2]
