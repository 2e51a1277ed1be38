"""Action spaces: torque/position unchanged, the variable-impedance ("vi") map, gradients w.r.t. actions.

The maps only read the scene description, so most tests use a stand-in for the simulator (no kernel
compile); one test drives the real float32 claw simulator with a "vi" control.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
import torch

from dexmots_rl.envs.actions import ACTION_TYPES, ActionMap

N = 3


@pytest.fixture(scope="module")
def fake_sim(claw_scene):
    return SimpleNamespace(scene=claw_scene, num_worlds=N, nu=claw_scene.num_hand_dofs,
                           dtype=torch.float64, torch_device=torch.device("cpu"))


def test_action_types_and_dims(fake_sim):
    assert ACTION_TYPES == ("torque", "position", "vi")
    nu = fake_sim.nu
    assert ActionMap(fake_sim, "torque").action_dim == nu
    assert ActionMap(fake_sim, "position").action_dim == nu
    assert ActionMap(fake_sim, "vi").action_dim == 2 * nu
    with pytest.raises(ValueError, match="action"):
        ActionMap(fake_sim, "velocity")
    with pytest.raises(ValueError, match="action"):
        ActionMap(fake_sim, "vi")(torch.zeros(N, nu))  # half a vi action


def test_torque_and_position_unchanged(fake_sim, claw_scene):
    nu, f = fake_sim.nu, 20.0
    a = torch.linspace(-1.5, 1.5, N * nu, dtype=torch.float64).reshape(N, nu)
    c = ActionMap(fake_sim, "torque")(a)
    gear = torch.as_tensor(claw_scene.actuator_gear, dtype=torch.float64)
    assert torch.allclose(c.tau, a.clamp(-1, 1) * gear)
    assert not c.kp.any() and not c.kd.any() and not c.q_target.any()
    m = ActionMap(fake_sim, "position", stiffness_frequency=f)
    c = m(a)
    i0 = torch.as_tensor(claw_scene.dof_inertia0, dtype=torch.float64)
    assert torch.allclose(c.q_target, m.lower + 0.5 * (a.clamp(-1, 1) + 1) * (m.upper - m.lower))
    assert torch.allclose(c.kp, (f**2 * i0).expand(N, nu))
    assert torch.allclose(c.kd, (2 * f * i0).expand(N, nu))
    assert not c.tau.any()


def test_vi_targets_and_stiffness_at_bounds(fake_sim, claw_scene):
    nu, f = fake_sim.nu, 12.0
    m = ActionMap(fake_sim, "vi", stiffness_frequency=f)
    i0 = torch.as_tensor(claw_scene.dof_inertia0, dtype=torch.float64)
    assert (i0 > 0).all()
    lo, hi = (f / 4) ** 2 * i0, (2 * f) ** 2 * i0
    assert torch.allclose(m.kp_min, lo) and torch.allclose(m.kp_max, hi)
    # worlds: all -1, all 0, all +1 (targets and stiffness together)
    a = torch.tensor([-1.0, 0.0, 1.0], dtype=torch.float64)[:, None].expand(N, 2 * nu)
    c = m(a)
    assert torch.allclose(c.q_target[0], m.lower) and torch.allclose(c.q_target[2], m.upper)
    assert torch.allclose(c.q_target[1], 0.5 * (m.lower + m.upper))
    assert torch.allclose(c.kp[0], lo) and torch.allclose(c.kp[2], hi)
    assert torch.allclose(c.kp[1], torch.sqrt(lo * hi))  # log-linear: the midpoint is the geometric mean
    assert torch.allclose(c.kp[1], f**2 / 2 * i0)
    # critical damping for every gain: kd = 2 sqrt(kp I0), i.e. damping ratio 1
    assert torch.allclose(c.kd, 2 * torch.sqrt(c.kp * i0))
    assert not c.tau.any()
    # out-of-range actions are clamped like the other spaces
    assert torch.allclose(m(3 * a).kp, c.kp)
    # targets and stiffness are independent halves
    b = torch.zeros(N, 2 * nu, dtype=torch.float64)
    b[:, nu:] = 1.0
    assert torch.allclose(m(b).q_target, c.q_target[1].expand(N, nu)) and torch.allclose(m(b).kp, hi.expand(N, nu))


def test_vi_log_linear_and_monotone(fake_sim):
    m = ActionMap(fake_sim, "vi")
    nu = fake_sim.nu
    s = torch.linspace(-1, 1, 9, dtype=torch.float64)
    a = torch.zeros(9, 2 * nu, dtype=torch.float64)
    a[:, nu:] = s[:, None]
    fake = SimpleNamespace(**{**vars(fake_sim), "num_worlds": 9})
    kp = ActionMap(fake, "vi").stiffness(a[:, nu:])[0]
    logs = kp.log()
    steps = logs[1:] - logs[:-1]
    assert (steps > 0).all() and torch.allclose(steps, steps[0].expand_as(steps))  # equal ratios
    assert torch.allclose(steps[0], torch.full_like(steps[0], math.log(64) / 8))
    assert m.action_dim == 2 * nu


def test_gradients_wrt_action(fake_sim):
    nu = fake_sim.nu
    g = torch.Generator().manual_seed(0)
    a = (torch.rand(N, 2 * nu, generator=g, dtype=torch.float64) * 1.8 - 0.9).requires_grad_()
    m = ActionMap(fake_sim, "vi")
    c = m(a)
    ga = torch.autograd.grad((c.q_target.sum() + c.kp.sum() + c.kd.sum()), a)[0]
    assert torch.isfinite(ga).all() and (ga != 0).all()
    # target half drives q_target only, stiffness half drives kp/kd only
    gt = torch.autograd.grad(m(a).q_target.sum(), a)[0]
    assert (gt[:, :nu] != 0).all() and not gt[:, nu:].any()
    gk = torch.autograd.grad(m(a).kd.sum(), a)[0]
    assert not gk[:, :nu].any() and (gk[:, nu:] > 0).all()
    assert torch.autograd.gradcheck(lambda x: (m(x).q_target, m(x).kp, m(x).kd), (a,))
    for kind in ("torque", "position"):
        x = a[:, :nu].detach().requires_grad_()
        c = ActionMap(fake_sim, kind)(x)
        gx = torch.autograd.grad(c.tau.sum() + c.q_target.sum(), x)[0]
        assert torch.isfinite(gx).all() and (gx != 0).all()


def test_vi_control_drives_the_simulator(make_claw_sim):
    """Stiff and soft vi gains both pull the joints towards the same target; the stiff one gets closer."""
    sim = make_claw_sim(2, dtype=torch.float32)
    m = ActionMap(sim, "vi")
    assert m.action_dim == 2 * sim.nu
    q = torch.zeros(2, sim.nq)
    q[:, : sim.nu] = torch.tensor([1.2, -0.5, -1.2, 0.5])  # open pose, no contact
    qd = torch.zeros(2, sim.nv)
    params = sim.default_params()
    a = torch.zeros(2, 2 * sim.nu)
    a[:, : sim.nu] = 0.8 * torch.sign(torch.tensor([1.0, -1.0, -1.0, 1.0]))  # targets towards the open side
    a[0, sim.nu:], a[1, sim.nu:] = -1.0, 1.0
    c = m(a)
    target = c.q_target[0]
    for _ in range(5):
        out = sim.step(q, qd, c, params)
        q, qd = out.joint_q, out.joint_qd
    assert torch.isfinite(q).all()
    err = (q[:, : sim.nu] - target).abs().sum(-1)
    assert err[1] < err[0]


def test_actions_for_targets_inverts_targets(fake_sim):
    vi = ActionMap(fake_sim, "vi")
    a = torch.tensor([[-1.0, -0.3, 0.4, 1.0]], dtype=vi.lower.dtype)
    torch.testing.assert_close(vi.actions_for_targets(vi.targets(a)), a)


def test_a_task_center_is_the_zero_action_and_keeps_the_full_range(fake_sim):
    lower, upper = ActionMap(fake_sim, "vi").lower, ActionMap(fake_sim, "vi").upper
    center = lower + 0.8 * (upper - lower)  # far from mid-range
    m = ActionMap(fake_sim, "position", center=center.tolist())
    ones = torch.ones(1, fake_sim.nu, dtype=torch.float64)
    torch.testing.assert_close(m.targets(0 * ones)[0], center)
    torch.testing.assert_close(m.targets(-ones)[0], lower)
    torch.testing.assert_close(m.targets(ones)[0], upper)
    a = torch.linspace(-1, 1, 4 * fake_sim.nu, dtype=torch.float64).reshape(4, fake_sim.nu)
    torch.testing.assert_close(m.actions_for_targets(m.targets(a)), a)
    sweep = torch.linspace(-1, 1, 9, dtype=torch.float64)[:, None].expand(9, fake_sim.nu)
    assert (torch.diff(m.targets(sweep), dim=0) > 0).all()  # monotone on both sides of the center
    for bad in (upper.tolist(), center.tolist()[:-1]):  # on a limit; one joint short
        with pytest.raises(ValueError, match="action center"):
            ActionMap(fake_sim, "vi", center=bad)


def test_mean_actions_set_only_the_stiffness_half(fake_sim):
    nu = fake_sim.nu
    vi = ActionMap(fake_sim, "vi").mean_actions(0.5)
    assert vi[:nu].abs().max() == 0 and bool((vi[nu:] == 0.5).all())
    assert ActionMap(fake_sim, "position").mean_actions(0.5).abs().max() == 0  # no stiffness channel
    with pytest.raises(ValueError, match="stiffness"):
        ActionMap(fake_sim, "vi").mean_actions(1.5)
