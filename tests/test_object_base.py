"""Operable objects: a static base (body ``object_base``) whose boxes the finger spheres touch, plus one
moving part on a sprung hinge (body ``object``), on the claw scissors scene ``tests/assets/claw_scissors.xml``
(the held blade and the pivot block are the base; the moving blade is the object).

Float64 throughout (one kernel specialisation: the claw with two base boxes).
No ``from __future__ import annotations`` here: warp reads the probe kernel's annotations.
"""

from pathlib import Path

import numpy as np
import pytest
import torch
import warp as wp

from dexmots_rl.sim import Control, Simulator, load_scene
from dexmots_rl.sim.model import AssetError
from simutil import CLAW, batch_state

ASSET = Path(__file__).parent / "assets" / "claw_scissors.xml"
# joint order: right proximal, right distal, left proximal, left distal, blade hinge
OPEN_Q = (1.2, -0.5, -1.2, 0.5, -0.1745)  # fingers spread: far from both blades and the pivot
NEAR_Q = (0.0, 0.0, -0.1, 0.2, -0.1745)  # left finger straight ahead, 0.19 m from the held blade
LEFT_PROXIMAL, LEFT_DISTAL, BLADE = 2, 3, 4


@pytest.fixture(scope="module")
def scene():
    return load_scene(ASSET)


@pytest.fixture(scope="module")
def make_sim(scene):
    cache = {}

    def make(num_worlds: int) -> Simulator:
        if num_worlds not in cache:
            cache[num_worlds] = Simulator(scene, num_worlds=num_worlds, dtype=torch.float64)
        return cache[num_worlds]

    return make


def _press(sim, tau_left):
    """Torque ``tau_left`` [N] on the left proximal joint (toward the held blade, negative), the left
    distal held straight by a PD drive."""
    n = sim.num_worlds
    tau = torch.zeros(n, 4, dtype=torch.float64)
    tau[:, LEFT_PROXIMAL] = torch.as_tensor(tau_left, dtype=torch.float64)
    target, kp, kd = torch.zeros_like(tau), torch.zeros_like(tau), torch.zeros_like(tau)
    target[:, LEFT_DISTAL], kp[:, LEFT_DISTAL], kd[:, LEFT_DISTAL] = 0.2, 400.0, 20.0
    return Control(tau, target, kp, kd)


def _quat_to_mat(wxyz):
    w, x, y, z = wxyz
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _penetration(scene, body_pose):
    """Deepest penetration (m; negative: a gap) of any finger sphere into any base box, by the exact
    (unsmoothed) box distance, for one world's body poses [B, 7]."""
    worst = -np.inf
    P = scene.points_per_link
    for link in range(scene.num_hand_dofs):
        x, R = body_pose[link, :3], _quat_to_mat(body_pose[link, 3:])
        for k in range(P):
            rad = scene.point_radius[link * P + k]
            if rad == 0:
                continue
            p = x + R @ scene.point_pos[link * P + k]
            for b in range(scene.num_base_boxes):
                d = np.abs(scene.base_box_rot[b].T @ (p - scene.base_box_pos[b])) - scene.base_box_half[b]
                worst = max(worst, rad - (np.linalg.norm(np.maximum(d, 0)) + min(d.max(), 0.0)))
    return worst


def test_base_boxes_are_read_in_the_world_frame(scene):
    import mujoco

    m = mujoco.MjModel.from_xml_path(str(ASSET))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "fixed_blade")
    assert scene.num_base_boxes == 2
    np.testing.assert_allclose(scene.base_box_pos[0], d.geom_xpos[g])
    np.testing.assert_allclose(scene.base_box_rot[0], d.geom_xmat[g].reshape(3, 3))
    np.testing.assert_allclose(scene.base_box_half[0], [0.3, 0.04, 0.1])
    # the moving part hinges in the base's frame, with its spring
    np.testing.assert_allclose(scene.object_base_pos, [1.2, 0.0, 0.15], atol=1e-12)
    assert scene.object_stiffness == 10.0 and scene.object_rest == pytest.approx(np.radians(-10))
    assert load_scene(CLAW).num_base_boxes == 0  # scenes without object_base are unchanged


@pytest.mark.parametrize("edit,message", [
    (('name="pivot" type="box"', 'name="pivot" type="sphere"'), "only boxes"),
    (('<body name="object_base" pos="0.9 0 0.15">', '<body name="object_base" pos="0.9 0 0.15"><joint type="slide"/>'),
     "without joints"),
])
def test_bad_bases_are_rejected(tmp_path, edit, message):
    path = tmp_path / "bad.xml"
    path.write_text(ASSET.read_text().replace(*edit))
    with pytest.raises(AssetError, match=message):
        load_scene(path)


def _box_sdf_kernel(ns):
    @wp.kernel(module="unique")
    def probe(m: ns.Model, b: int, p: wp.array(dtype=ns.vec3), weight: wp.array(dtype=ns.vec4),
              out: wp.array(dtype=wp.float64)):
        i = wp.tid()
        out[i] = wp.dot(ns.base.box_sdf(m, b, p[i]), weight[i])

    return probe


def test_box_sdf_is_exact_on_faces_and_its_adjoint_matches_finite_differences(make_sim):
    sim = make_sim(1)
    ns, rng, half = sim.kernels, np.random.default_rng(3), sim.scene.base_box_half[0]
    probe = _box_sdf_kernel(ns)
    # random points within 3 cm of the surface, one in two near an edge or corner
    pts = []
    while len(pts) < 40:
        p = rng.uniform(-1.2, 1.2, 3) * half
        g = np.sort(np.concatenate([p - half, -p - half]))[::-1]
        if abs(g[0]) < 0.03 and (g[0] - g[1] < 0.02 or len(pts) % 2):
            pts.append(p)
    pts = np.asarray(pts)
    n = len(pts)

    def run(x, weight, tape=None):
        xa = wp.array(x, dtype=ns.vec3, requires_grad=tape is not None)
        out = wp.zeros(n, dtype=wp.float64, requires_grad=tape is not None)
        wa = wp.array(weight, dtype=ns.vec4)
        if tape is None:
            wp.launch(probe, dim=n, inputs=[sim.model, 0, xa, wa], outputs=[out])
            return out.numpy()
        with tape:
            wp.launch(probe, dim=n, inputs=[sim.model, 0, xa, wa], outputs=[out])
        tape.backward(grads={out: wp.ones(n, dtype=wp.float64)})
        return xa.grad.numpy()

    # on a face the smooth distance is the face distance plus s ln(1 + sum of the other faces' weights): at
    # the +y face centre, 1 cm out, 8e-7 m (the other faces are 10+ smoothing lengths below)
    face = np.array([0.0, half[1] + 0.01, 0.0])
    s = sim.contact.surface_smoothing
    expected = s * np.log(np.exp(np.concatenate([face - half, -face - half]) / s).sum())
    dist = wp.zeros(1, dtype=wp.float64)
    wp.launch(probe, dim=1, inputs=[sim.model, 0, wp.array(face[None], dtype=ns.vec3),
                                    wp.array([[1.0, 0, 0, 0]], dtype=ns.vec4)], outputs=[dist])
    assert dist.numpy()[0] == pytest.approx(expected, abs=1e-12)
    assert expected - 0.01 < 1e-6
    weight = rng.uniform(-1, 1, (n, 4))
    ad, fd, eps = run(pts, weight, wp.Tape()), np.zeros((n, 3)), 1e-6
    for c in range(3):
        step = np.zeros_like(pts)
        step[:, c] = eps
        fd[:, c] = (run(pts + step, weight) - run(pts - step, weight)) / (2 * eps)
    assert np.abs(fd).max() > 1.0  # the normal's derivative (~1 / smoothing) near edges is exercised
    np.testing.assert_allclose(ad, fd, rtol=1e-5, atol=1e-6 * np.abs(fd).max())


def test_finger_pressed_into_the_base_feels_a_normal_force_and_stops(make_sim, scene):
    """(a) The left finger driven into the held blade stops on it: at rest the contact force balances the
    joint torque and the spheres sit within a few mm of the surface; the moving blade feels nothing."""
    sim = make_sim(2)
    q, qd = batch_state(sim, NEAR_Q)
    torques = [-30.0, -120.0]
    control, params = _press(sim, torques), sim.default_params()
    for _ in range(90):  # 1.5 s
        out = sim.step(q, qd, control, params)
        q, qd = out.joint_q, out.joint_qd
    assert float(qd[:, :4].abs().max()) < 1e-2  # at rest
    assert (out.wrench == 0).all()  # no contact with the moving part: the base pushes the finger only
    for w, tau in enumerate(torques):
        force, pen = float(out.contact_force[w]), _penetration(scene, out.body_pose[w].numpy())
        # the contact sits 0.4 .. 0.95 m from the proximal joint
        assert -tau / 0.95 < force < -tau / 0.4, (tau, force)
        # touching, at most a few mm deep (the penalty law: ~ force / stiffness - ln 2 / sharpness)
        assert -0.01 < pen < 0.01, (tau, pen)
    print(f"rest: contact force {out.contact_force.tolist()} N, penetration "
          f"{[_penetration(scene, out.body_pose[w].numpy()) for w in range(2)]} m")


def test_finger_away_from_the_base_feels_nothing(make_sim):
    """(b) Fingers swinging in free space, outside the contact band of every base box: exactly zero."""
    sim = make_sim(2)
    q, qd = batch_state(sim, OPEN_Q, (2.0, -1.0, -2.0, 1.0, 0.0))
    q[1] = torch.tensor(NEAR_Q, dtype=torch.float64)
    qd[1] = 0.0
    tau = torch.tensor([[5.0, 0.0, -5.0, 0.0], [0.0, 0.0, 0.0, 0.0]], dtype=torch.float64)
    z = torch.zeros_like(tau)
    for _ in range(10):
        out = sim.step(q, qd, Control(tau, z, z, z), sim.default_params())
        q, qd = out.joint_q, out.joint_qd
        # every sphere in the band gets a positive normal force (softplus > 0), so an exact zero means
        # no sphere was in contact and the fingers' generalised contact forces were zero too
        assert (out.contact_force == 0).all()
        assert (out.wrench == 0).all()
    assert float(qd[0, :4].abs().min()) > 0  # the open fingers did move (freely)


H = 3
EPS = 1e-6


def _rollout_loss(sim, q, qd, tau, weights):
    """Per-world loss of H steps pressing the left finger into the held blade; tau [N, H, 4] adds to
    the press."""
    loss = torch.zeros(q.shape[0], dtype=torch.float64)
    base = _press(sim, -40.0)
    for t in range(H):
        control = Control(base.tau + tau[:, t], base.q_target, base.kp, base.kd)
        out = sim.step(q, qd, control, sim.default_params())
        q, qd = out.joint_q, out.joint_qd
        wq, wqd, wc, wtip = weights[t]
        loss = loss + (q * wq).sum(-1) + 0.1 * (qd * wqd).sum(-1) + 0.01 * out.contact_force * wc
        loss = loss + (out.fingertips * wtip).sum((-1, -2))
    return loss


def test_gradients_through_base_contact_match_finite_differences(make_sim):
    """(c) AD against central differences (batched over worlds: world 2k / 2k+1 move input k by +-eps)
    of a loss over H env steps in which the left finger presses on the held blade."""
    gen = torch.Generator().manual_seed(5)
    q0 = torch.tensor((0.0, 0.0, -0.345, 0.24, -0.1745), dtype=torch.float64)
    qd0 = 0.3 * (2 * torch.rand(5, generator=gen, dtype=torch.float64) - 1)
    tau0 = 5.0 * (2 * torch.rand(H, 4, generator=gen, dtype=torch.float64) - 1)
    base = torch.cat([q0, qd0, tau0.reshape(-1)])
    dim = base.numel()
    weights = [tuple(2 * torch.rand(*s, generator=gen, dtype=torch.float64) - 1 for s in ((5,), (5,), (1,), (2, 3)))
               for _ in range(H)]

    def split(x):
        return x[:, :5], x[:, 5:10], x[:, 10:].reshape(-1, H, 4)

    sim1 = make_sim(1)
    x = base.clone()[None].requires_grad_(True)
    (g_ad,) = torch.autograd.grad(_rollout_loss(sim1, *split(x), weights).sum(), x)
    g_ad = g_ad[0]
    xs = base.repeat(2 * dim, 1)
    idx = torch.arange(dim)
    xs[2 * idx, idx] += EPS
    xs[2 * idx + 1, idx] -= EPS
    with torch.no_grad():
        lv = _rollout_loss(make_sim(2 * dim), *split(xs), weights)
        # the rollout really is in contact with the base (and only the base) at every step
        q, qd, tau = split(base[None])
        ctl = _press(sim1, -40.0)
        for t in range(H):
            out = sim1.step(q, qd, Control(ctl.tau + tau[:, t], ctl.q_target, ctl.kp, ctl.kd), sim1.default_params())
            q, qd = out.joint_q, out.joint_qd
            assert float(out.contact_force) > 10.0 and (out.wrench == 0).all()
    g_fd = (lv[0::2] - lv[1::2]) / (2 * EPS)
    rel = float((g_ad - g_fd).norm() / g_fd.norm())
    big = g_fd.abs() > 1e-6 * g_fd.abs().max()
    elem = ((g_ad - g_fd).abs() / g_fd.abs())[big]
    print(f"FD vs AD: norm-wise rel err {rel:.2e}, element-wise median {float(elem.median()):.2e}, "
          f"max {float(elem.max()):.2e}")
    assert rel < 1e-5
    assert float(elem.median()) < 1e-5
    torch.testing.assert_close(g_ad, g_fd, rtol=1e-4, atol=1e-6 * float(g_fd.abs().max()))


def test_sprung_part_returns_to_its_rest_position(make_sim, scene):
    """(d) The moving blade released from an angle returns to joint_rest (the MJCF springref in world 0, a
    per-world parameter in world 1); the fingers stay open and nothing touches."""
    sim = make_sim(2)
    q, qd = batch_state(sim, OPEN_Q)
    q[:, BLADE] = -0.6
    params = sim.default_params()
    params["joint_rest"][1] = 0.1
    rest = torch.tensor([scene.object_rest, 0.1], dtype=torch.float64)
    for _ in range(180):  # 3 s
        out = sim.step(q, qd, sim.zero_control(), params)
        q, qd = out.joint_q, out.joint_qd
        assert (out.contact_force == 0).all()
    err = (q[:, BLADE] - rest).abs()
    print(f"spring: |q - rest| after 3 s {err.tolist()} rad")
    assert float(err.max()) < 5e-3
    assert float(qd[:, BLADE].abs().max()) < 2e-2
    torch.testing.assert_close(q[:, :4], batch_state(sim, OPEN_Q)[0][:, :4])  # the hand did not move
