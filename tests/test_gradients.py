"""Gradients of SimStep (warp tape adjoints) against central finite differences, in float64.

A rollout of H=4 env steps (16 substeps each) maps (initial q, qd, object params, torques per step) to a
scalar loss built from joint_q, the contact wrench on the object, the contact force and the fingertips at
every step. The finite differences are batched over worlds: world 2k / 2k+1 hold the base input with
coordinate k moved by +eps / -eps, so one rollout gives every central difference at once.
"""

from __future__ import annotations

import pytest
import torch

from simutil import CLAW_CONTACT_Q, CLAW_OPEN_Q, batch_state, claw_params, torque

H = 4
EPS = 1e-6


def _case(name: str):
    """Base inputs for one world: q, qd, params [damping, friction], tau [H, 4]."""
    gen = torch.Generator().manual_seed(7)
    q0 = CLAW_OPEN_Q if name == "open" else CLAW_CONTACT_Q
    q = torch.tensor(q0, dtype=torch.float64) + 0.02 * torch.rand(5, generator=gen, dtype=torch.float64)
    qd = 0.5 * (2 * torch.rand(5, generator=gen, dtype=torch.float64) - 1)
    params = torch.tensor([0.6, 0.4], dtype=torch.float64)
    tau = 20.0 * (2 * torch.rand(H, 4, generator=gen, dtype=torch.float64) - 1)
    return q, qd, params, tau


def _loss_weights(sim):
    gen = torch.Generator().manual_seed(11)

    def r(*shape):
        return 2 * torch.rand(*shape, generator=gen, dtype=torch.float64) - 1

    return [(r(sim.nq), r(sim.nv), r(6), r(1), r(sim.scene.num_fingers, 3)) for _ in range(H)]


def _rollout_loss(sim, q, qd, params, tau, weights):
    """Per-world loss [N]; q, qd: [N, 5], params [N, 2], tau [N, H, 4]."""
    loss = torch.zeros(q.shape[0], dtype=torch.float64)
    for t in range(H):
        out = sim.step(q, qd, torque(tau[:, t]), claw_params(params))
        q, qd = out.joint_q, out.joint_qd
        wq, wqd, ww, wc, wtip = weights[t]
        loss = loss + (q * wq).sum(-1) + 0.1 * (qd * wqd).sum(-1) + 0.01 * (out.wrench * ww).sum(-1)
        loss = loss + 0.01 * out.contact_force * wc + (out.fingertips * wtip).sum((-1, -2))
    return loss


def _flatten(q, qd, params, tau):
    return torch.cat([q, qd, params, tau.reshape(-1)])


def _unflatten(x):
    n = x.shape[0]
    return x[:, :5], x[:, 5:10], x[:, 10:12], x[:, 12:].reshape(n, H, 4)


@pytest.fixture(scope="module", params=["open", "contact"])
def ad_and_fd(request, make_claw_sim):
    q, qd, params, tau = _case(request.param)
    base = _flatten(q, qd, params, tau)
    dim = base.numel()
    # AD on one world
    sim1 = make_claw_sim(1)
    weights = _loss_weights(sim1)
    x = base.clone()[None].requires_grad_(True)
    loss = _rollout_loss(sim1, *_unflatten(x), weights).sum()
    (grad_ad,) = torch.autograd.grad(loss, x)
    # central differences batched over 2 * dim worlds
    simfd = make_claw_sim(2 * dim)
    xs = base.repeat(2 * dim, 1)
    idx = torch.arange(dim)
    xs[2 * idx, idx] += EPS
    xs[2 * idx + 1, idx] -= EPS
    with torch.no_grad():
        lv = _rollout_loss(simfd, *_unflatten(xs), weights)
    grad_fd = (lv[0::2] - lv[1::2]) / (2 * EPS)
    # how much contact the rollout saw (from the unperturbed AD run)
    with torch.no_grad():
        sim_q, sim_qd, sim_p, sim_tau = _unflatten(base[None])
        cforce = 0.0
        for t in range(H):
            out = sim1.step(sim_q, sim_qd, torque(sim_tau[:, t]), claw_params(sim_p))
            sim_q, sim_qd = out.joint_q, out.joint_qd
            cforce = max(cforce, float(out.contact_force.max()))
    return request.param, grad_ad[0], grad_fd, cforce


def test_rollout_touches_the_knob_only_in_the_contact_case(ad_and_fd):
    name, _, _, cforce = ad_and_fd
    if name == "open":
        assert cforce == 0.0
    else:
        assert cforce > 10.0


def test_gradients_match_finite_differences(ad_and_fd):
    name, g_ad, g_fd, _ = ad_and_fd
    assert torch.isfinite(g_ad).all() and torch.isfinite(g_fd).all()
    scale = g_fd.abs().max()
    assert scale > 0
    # norm-wise: a wrong adjoint for any input block shows up here (a correct one agrees to ~1e-9; the
    # wrong adjoints seen so far were off by 1e-5 .. 1e-4)
    assert float((g_ad - g_fd).norm() / g_fd.norm()) < 1e-7, name
    # element-wise, on the entries that are not negligible
    big = g_fd.abs() > 1e-6 * scale
    rel = ((g_ad - g_fd).abs() / g_fd.abs())[big]
    assert float(rel.median()) < 1e-5, name
    assert float(rel.max()) < 1e-3, name
    torch.testing.assert_close(g_ad, g_fd, rtol=1e-4, atol=1e-6 * float(scale))


@pytest.mark.parametrize("block,sl", [("q", slice(0, 5)), ("qd", slice(5, 10)), ("params", slice(10, 12)),
                                      ("tau", slice(12, None))])
def test_every_input_block_gets_a_gradient(ad_and_fd, block, sl):
    """Each input block matters for the loss, so each block's gradient is checked above for real."""
    name, g_ad, g_fd, _ = ad_and_fd
    assert float(g_fd[sl].abs().max()) > 1e-4, (name, block)
    torch.testing.assert_close(g_ad[sl], g_fd[sl], rtol=1e-4, atol=1e-6 * float(g_fd.abs().max()))


def test_pd_drive_gradients_match_finite_differences(make_claw_sim):
    """Position control: gradients w.r.t. the PD targets and gains (integrated implicitly) against FD."""
    from dexmots_rl.sim import Control

    gen = torch.Generator().manual_seed(5)
    target = torch.tensor([0.8, -0.7, -0.8, 0.7], dtype=torch.float64)
    kp = 400.0 + 100.0 * torch.rand(4, generator=gen, dtype=torch.float64)
    kd = 20.0 + 10.0 * torch.rand(4, generator=gen, dtype=torch.float64)
    base = torch.cat([target, kp, kd])
    w = 2 * torch.rand(5, generator=gen, dtype=torch.float64) - 1

    def loss(x, sim):
        q, qd = batch_state(sim, CLAW_CONTACT_Q)
        total = torch.zeros(x.shape[0], dtype=torch.float64)
        for _ in range(2):
            out = sim.step(q, qd, Control(torch.zeros_like(x[:, :4]), x[:, :4], x[:, 4:8], x[:, 8:]),
                           sim.default_params())
            q, qd = out.joint_q, out.joint_qd
            total = total + (q * w).sum(-1) + 0.01 * out.contact_force
        return total

    x = base.clone()[None].requires_grad_(True)
    (g_ad,) = torch.autograd.grad(loss(x, make_claw_sim(1)).sum(), x)
    dim = base.numel()
    xs = base.repeat(2 * dim, 1)
    idx = torch.arange(dim)
    eps = torch.cat([torch.full((4,), EPS), torch.full((8,), 1e-4)]).to(torch.float64)  # gains are O(100)
    xs[2 * idx, idx] += eps
    xs[2 * idx + 1, idx] -= eps
    with torch.no_grad():
        lv = loss(xs, make_claw_sim(2 * dim))
    g_fd = (lv[0::2] - lv[1::2]) / (2 * eps)
    assert float(g_fd[:4].abs().min()) > 1e-3 and float(g_fd[4:].abs().max()) > 1e-6
    # a correct adjoint agrees to ~5e-10 here; the wrong adjoints seen so far gave 3e-7 .. 1e-4
    assert float((g_ad[0] - g_fd).norm() / g_fd.norm()) < 5e-8
    torch.testing.assert_close(g_ad[0], g_fd, rtol=1e-5, atol=1e-7 * float(g_fd.abs().max()))


def test_knob_angle_gradient_wrt_torques(make_claw_sim):
    """d(final knob angle)/d(finger torques) is zero without contact and nonzero with it."""
    sim = make_claw_sim(2)
    q, qd = batch_state(sim, CLAW_OPEN_Q)
    q[1] = torch.tensor(CLAW_CONTACT_Q, dtype=torch.float64)
    # an asymmetric push so that the knob actually turns in the contact world
    tau = torch.tensor([[30.0, -20.0, 10.0, 5.0]] * 2, dtype=torch.float64).requires_grad_(True)
    q_t, qd_t = q, qd
    for _ in range(3):
        out = sim.step(q_t, qd_t, torque(tau), sim.default_params())
        q_t, qd_t = out.joint_q, out.joint_qd
    (g,) = torch.autograd.grad(q_t[:, 4].sum(), tau)
    assert float(g[0].abs().max()) == 0.0
    assert float(g[1].abs().max()) > 1e-6


def test_no_tape_without_grad(make_claw_sim):
    sim = make_claw_sim(2)
    q, qd = batch_state(sim, CLAW_CONTACT_Q)
    out = sim.step(q, qd, torque(torch.ones(2, 4, dtype=torch.float64)), sim.default_params())
    for name, t in zip(out.names, out):
        assert not t.requires_grad and t.grad_fn is None, name
    assert q.grad is None and qd.grad is None
    # with an input that requires grad, every output is attached to the graph
    tau = torch.ones(2, 4, dtype=torch.float64, requires_grad=True)
    out = sim.step(q, qd, torque(tau), sim.default_params())
    for name, t in zip(out.names, out):
        assert t.requires_grad and t.grad_fn is not None, name


def test_nan_world_gradients_are_zeroed(make_claw_sim):
    """A NaN in one world's state gives zeros, not NaN, where its gradient would be NaN (the right finger's
    joints, whose outputs are all NaN), and leaves the other worlds' gradients untouched."""
    sim = make_claw_sim(3)
    q, qd = batch_state(sim, CLAW_CONTACT_Q)
    tau = torch.tensor([[10.0, -5.0, 3.0, 2.0]] * 3, dtype=torch.float64)

    def grads(q_in):
        q_in = q_in.clone().requires_grad_(True)
        t = tau.clone().requires_grad_(True)
        out = sim.step(q_in, qd, torque(t), sim.default_params())
        loss = out.joint_q.sum() + out.wrench.sum() + out.fingertips.sum()
        loss.backward()
        return out, q_in.grad, t.grad

    _, gq_clean, gt_clean = grads(q)
    q_bad = q.clone()
    q_bad[1, 0] = float("nan")
    with pytest.warns(RuntimeWarning, match="non-finite gradient"):
        out, gq, gt = grads(q_bad)
    assert torch.isnan(out.joint_q[1, :2]).all()  # the right finger of world 1 is NaN ...
    assert torch.isfinite(gq).all() and torch.isfinite(gt).all()  # ... yet no NaN gradient comes back
    assert float(gq[1, :2].abs().max()) == 0.0 and float(gt[1, :2].abs().max()) == 0.0
    assert float(gq_clean[1, :2].abs().min()) > 0.0  # (a clean world has nonzero gradients there)
    torch.testing.assert_close(gq[[0, 2]], gq_clean[[0, 2]], rtol=0, atol=0)
    torch.testing.assert_close(gt[[0, 2]], gt_clean[[0, 2]], rtol=0, atol=0)


@pytest.fixture(scope="module")
def tool_sim():
    from dexmots_rl.sim import make_simulator
    from test_articulated import _scene

    return make_simulator(_scene("spray_bottle_a"), num_worlds=3, dtype=torch.float64)


@pytest.mark.parametrize("kind", ["claw", pytest.param("tool", marks=pytest.mark.slow)])  # the tool: float64 build
def test_a_world_whose_gradient_is_not_finite_gets_zero_and_is_counted(kind, request):
    """An adjoint that overflows in one world (here: an infinite output gradient in world 1) gives that world a zero
    gradient, counted per world in ``nonfinite_gradient_steps`` and warned about; the other worlds' gradients are
    exactly the ones they get alone (every scene, whatever ``adjoint_clip``)."""
    sim = request.getfixturevalue("make_claw_sim")(3) if kind == "claw" else request.getfixturevalue("tool_sim")
    q, qd = sim.initial_state()
    if kind == "claw":
        q, qd = batch_state(sim, CLAW_CONTACT_Q)

    def grads(upstream):
        tau = torch.full((3, sim.nu), 0.1, dtype=torch.float64, requires_grad=True)
        q_in = q.clone().requires_grad_(True)
        out = sim.step(q_in, qd, torque(tau), sim.default_params())
        (out.joint_q * upstream).sum().backward()
        return tau.grad, q_in.grad

    before = sim.nonfinite_gradient_steps.clone()
    clean_tau, clean_q = grads(torch.ones(3, sim.nq, dtype=torch.float64))
    assert torch.equal(sim.nonfinite_gradient_steps, before)
    upstream = torch.ones(3, sim.nq, dtype=torch.float64)
    upstream[1, 0] = float("inf")
    with pytest.warns(RuntimeWarning, match="1 of 3 worlds had a non-finite gradient"):
        tau_grad, q_grad = grads(upstream)
    assert (tau_grad[1] == 0).all() and (q_grad[1] == 0).all()
    assert torch.equal(tau_grad[[0, 2]], clean_tau[[0, 2]]) and torch.equal(q_grad[[0, 2]], clean_q[[0, 2]])
    assert float(clean_tau[1].abs().max()) > 0  # (world 1's clean gradient is not zero anyway)
    assert (sim.nonfinite_gradient_steps - before).tolist() == [0, 1, 0]


def test_taped_and_untaped_steps_agree(make_claw_sim):
    """The gradient-free fast path and the differentiable path compute the same step, bit for bit."""
    sim = make_claw_sim(4)
    q, qd = batch_state(sim, CLAW_CONTACT_Q, [0.2, -0.1, -0.3, 0.4, 0.5])
    q[0] = torch.tensor(CLAW_OPEN_Q, dtype=torch.float64)
    tau = 30 * (2 * torch.rand(4, 4, generator=torch.Generator().manual_seed(3), dtype=torch.float64) - 1)
    plain = sim.step(q, qd, torque(tau), sim.default_params())
    taped = sim.step(q, qd, torque(tau.clone().requires_grad_(True)), sim.default_params())
    assert float(plain.contact_force[1:].min()) > 0.0
    for name, a, b in zip(plain.names, plain, taped):
        assert torch.equal(a, b.detach()), name


def test_pooled_trajectories_are_reused_and_released(claw_scene):
    """Taped steps share pooled trajectories: one goes back after its backward pass (and gives the same
    gradient when reused), one whose graph is dropped without a backward pass goes back too, and two
    live graphs never share one."""
    import gc

    from dexmots_rl.sim import Simulator

    sim = Simulator(claw_scene, num_worlds=2, dtype=torch.float64)
    q, qd = batch_state(sim, CLAW_CONTACT_Q)
    tau0 = torch.tensor([[10.0, -5.0, 3.0, 2.0]] * 2, dtype=torch.float64)

    def taped_step():
        tau = tau0.clone().requires_grad_(True)
        return tau, sim.step(q, qd, torque(tau), sim.default_params())

    def grad_of_one_step():
        tau, out = taped_step()
        (out.joint_qd.sum() + out.wrench.sum()).backward()
        return tau.grad

    first = grad_of_one_step()
    assert len(sim._pool) == 1
    reused = sim._pool[0]
    second = grad_of_one_step()
    assert sim._pool == [reused] and float(first.abs().max()) > 0
    assert torch.equal(first, second)

    (tau_a, out_a), (tau_b, out_b) = taped_step(), taped_step()
    assert sim._pool == []  # both live graphs hold a trajectory, and not the same one
    del out_a
    gc.collect()
    assert len(sim._pool) == 1  # dropped without backward: released
    (out_b.joint_qd.sum() + out_b.wrench.sum()).backward()
    assert torch.equal(tau_b.grad, first)
    del out_b
    gc.collect()
    assert len(sim._pool) == 2 and sim._pool[0] is not sim._pool[1]  # released once, not twice


def test_adjoint_clip_caps_only_the_outlier_world(make_claw_sim):
    """With ``adjoint_clip`` a world whose gradient is far above the median world's is scaled down to
    ``adjoint_clip`` x the median (all of its input gradients by one factor); the others are exact."""
    exact_sim, clipped_sim = make_claw_sim(5), make_claw_sim(5, adjoint_clip=10.0)
    q, qd = batch_state(exact_sim, CLAW_CONTACT_Q)
    tau = torch.tensor([[10.0, -5.0, 3.0, 2.0]] * 5, dtype=torch.float64)
    weight = torch.tensor([1.0, 2.0, 1.5, 1e6, 0.5], dtype=torch.float64)  # world 3's loss dwarfs the others

    def grads(sim):
        q_in, qd_in, t = (x.clone().requires_grad_(True) for x in (q, qd, tau))
        out = sim.step(q_in, qd_in, torque(t), sim.default_params())
        ((out.joint_q.sum(-1) + out.joint_qd.sum(-1)) * weight).sum().backward()
        return q_in.grad, qd_in.grad, t.grad

    before = clipped_sim.clipped_adjoints
    (gq, gqd, gt), (cq, cqd, ct) = grads(exact_sim), grads(clipped_sim)
    assert clipped_sim.clipped_adjoints - before == 1
    others = [0, 1, 2, 4]
    for exact, clipped in ((gq, cq), (gqd, cqd), (gt, ct)):
        torch.testing.assert_close(clipped[others], exact[others], rtol=0, atol=0)
    norms = torch.cat([gq, gqd], -1).norm(dim=-1)
    factor = 10.0 * norms.median() / norms[3]
    assert float(factor) < 1e-3  # the clip really acted
    for exact, clipped in ((gq, cq), (gqd, cqd), (gt, ct)):
        torch.testing.assert_close(clipped[3], exact[3] * factor)
    torch.testing.assert_close(torch.cat([cq, cqd], -1)[3].norm(), 10.0 * norms.median())


def test_adjoint_clip_must_be_at_least_one(claw_scene):
    from dexmots_rl.sim import Simulator

    with pytest.raises(ValueError, match="adjoint_clip"):
        Simulator(claw_scene, num_worlds=2, adjoint_clip=0.5)
