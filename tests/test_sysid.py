"""System identification (dexmots_rl.sysid): gradients w.r.t. the named parameters, recovery of known damping and
friction from a synthetic recording, bad input, and the identified file loaded back into the task."""

import json

import numpy as np
import pytest
import torch

from dexmots_rl.envs import make_env
from dexmots_rl.sim import ArticulatedSimulator
from dexmots_rl.sysid import ShootingProblem, identify, load_trajectories, save_npz, synthetic_trajectories
from dexmots_rl.apps.sysid import run as sysid_cli

TRUTH = {"joint_damping": 0.5, "joint_friction": 0.6}


@pytest.fixture(scope="module")
def knob_data():
    """The claw turning the knob (scripted grasp-and-twist plus noise), 4 worlds x 48 steps, with 1e-4 rad of
    angle noise: the recording the identification replays."""
    return synthetic_trajectories("screw_claw", TRUTH, worlds=4, steps=48, seed=0, angle_noise=1e-4)


def _central_differences(loss, x: torch.Tensor, eps: float = 1e-6) -> np.ndarray:
    """[len(x)] central differences of the scalar ``loss`` at ``x``."""
    fd = np.zeros(len(x))
    for i in range(len(x)):
        plus, minus = x.clone(), x.clone()
        plus[i] += eps
        minus[i] -= eps
        fd[i] = (loss(plus) - loss(minus)) / (2 * eps)
    return fd


def test_residual_jacobian_matches_central_differences(knob_data):
    """d(residuals)/d(log damping, log friction) through the knob's contact, float64: the exact Jacobian (one copy
    of each segment per residual, one reverse pass) against central differences."""
    problem = ShootingProblem(knob_data, list(TRUTH), segment_steps=4, max_segments=3, validation=0.0)
    z = problem.space.to_z([0.4, 0.7])
    _, jac = problem.jacobian(z, "ad")
    eps, fd = 1e-6, np.zeros_like(jac)
    for i in range(len(z)):
        plus, minus = z.copy(), z.copy()
        plus[i] += eps
        minus[i] -= eps
        fd[:, i] = (problem.jacobian(plus, "fd")[0] - problem.jacobian(minus, "fd")[0]) / (2 * eps)
    assert np.abs(fd).max() > 1e-2
    np.testing.assert_allclose(jac, fd, rtol=1e-4, atol=1e-4 * np.abs(fd).max())


def test_start_state_gradients_match_central_differences(knob_data):
    """With free_starts the objective's gradient w.r.t. the segments' start offsets (and the parameters) comes from
    the same reverse pass: against central differences in float64. Only L-BFGS estimates them."""
    problem = ShootingProblem(knob_data, list(TRUTH), segment_steps=4, max_segments=3, validation=0.0,
                              free_starts=True)
    x = torch.as_tensor(np.concatenate([problem.space.to_z([0.4, 0.7]),
                                        0.3 * np.random.default_rng(0).standard_normal(problem.num_start_variables)]))
    _, grad = problem.loss_and_grad(x)
    fd = _central_differences(lambda v: problem.loss_and_grad(v)[0].item(), x)
    np.testing.assert_allclose(grad.numpy(), fd, rtol=1e-4, atol=1e-5 * np.abs(fd).max())
    with pytest.raises(ValueError, match="^free_starts: only method=lbfgs"):
        identify(problem, "gn", iterations=1)


@pytest.mark.slow  # the tool scene's float64 build
def test_articulated_parameter_gradients_match_central_differences():
    """An articulated object's joint parameters (damping, friction, stiffness, rest of the spray bottle's trigger)
    get gradients through the hand-and-object step, in float64, equal to central differences."""
    from test_articulated import _closing, _scene

    sim = ArticulatedSimulator(_scene("spray_bottle_a"), 1, dtype=torch.float64)
    q, qd = sim.initial_state()
    qd[:, -1] = 0.5  # the trigger moving: damping and friction act
    params, ctrl = sim.default_params(), _closing(sim)
    names = [n for n in sim.param_names if n != "variant"]

    def loss(values):
        p = params.clone()
        for i, name in enumerate(names):
            p[name] = values[i].reshape(1, 1)
        q1, qd1 = q, qd
        for _ in range(2):
            out = sim.step(q1, qd1, ctrl, p)
            q1, qd1 = out.joint_q, out.joint_qd
        return q1[0, sim.nu:].sum() + 0.1 * qd1[0, sim.nu:].sum()

    x = torch.tensor([float(params[n]) for n in names], dtype=torch.float64) + 0.05
    xg = x.clone().requires_grad_(True)
    loss(xg).backward()
    eps, fd = 1e-6, np.zeros(len(names))
    with torch.no_grad():
        for i in range(len(names)):
            plus, minus = x.clone(), x.clone()
            plus[i] += eps
            minus[i] -= eps
            fd[i] = (loss(plus) - loss(minus)).item() / (2 * eps)
    assert np.abs(fd).max() > 1e-4
    np.testing.assert_allclose(xg.grad.numpy(), fd, rtol=1e-4, atol=1e-6 * np.abs(fd).max())


@pytest.mark.slow  # the tool scene's float64 build
def test_replay_loss_gradient_wrt_masses_and_contact_friction_matches_central_differences():
    """The replay loss's gradient w.r.t. the log of the spray bottle's masses (its base's and its trigger's) and of
    the contact friction coefficients (the fingers' on it, the table's under it), in float64, while the hand
    operates it: against central differences, each one non-zero (the data says something of every one)."""
    names = ["object/mass", "object/trigger/mass", "hand/friction", "table/friction"]
    data = synthetic_trajectories("spray_bottle", {}, worlds=2, steps=12, seed=0, position_noise=0.0,
                                  angle_noise=0.0)
    problem = ShootingProblem(data, names, segment_steps=4, max_segments=3, validation=0.0)
    assert problem.space.log.all()  # positive: identified through their logarithm
    x = torch.as_tensor(problem.space.to_z(problem.space.initial * np.array([1.3, 0.8, 0.7, 1.2])))
    _, grad = problem.loss_and_grad(x)
    fd = _central_differences(lambda v: problem.loss(v.numpy()), x)
    assert (np.abs(fd) > 1e-6 * np.abs(fd).max()).all() and np.abs(fd).max() > 1e-3, fd
    np.testing.assert_allclose(grad.numpy(), fd, rtol=1e-4, atol=1e-6 * np.abs(fd).max())


@pytest.mark.parametrize("method", ["gn", "lbfgs"])
@pytest.mark.parametrize("scale", [0.5, 2.0])
def test_recovers_known_damping_and_friction(knob_data, method, scale):
    problem = ShootingProblem(knob_data, list(TRUTH), segment_steps=8, seed=0,
                              initial={k: v * scale for k, v in TRUTH.items()})
    result = identify(problem, method, iterations=30)
    errors = result.relative_errors()
    assert max(errors.values()) < 0.03, errors
    assert result.validation_error["identified"]["rms"] < result.validation_error["initial"]["rms"]
    assert result.condition_number < 1e6 and not result.unidentifiable


def test_bad_input_is_one_error_naming_it(tmp_path, knob_data):
    with pytest.raises(ValueError, match="no such file"):
        load_trajectories(tmp_path / "missing.mcap")
    with pytest.raises(ValueError, match=r"unknown parameter 'joint_mass'.*joint_damping, joint_friction"):
        ShootingProblem(knob_data, ["joint_damping", "joint_mass"])
    path = tmp_path / "knob.npz"
    save_npz(knob_data, path, num_hand_dofs=4)
    data = load_trajectories(path)
    data.dt *= 2
    with pytest.raises(ValueError, match="^dt: "):
        ShootingProblem(data, list(TRUTH))
    arrays = dict(np.load(path))
    del arrays["kp"]
    np.savez(tmp_path / "no_kp.npz", **arrays)
    with pytest.raises(ValueError, match="missing array 'kp'"):
        load_trajectories(tmp_path / "no_kp.npz")
    with pytest.raises(SystemExit, match="dexmots-sysid: .*unknown parameter 'nope'"):
        sysid_cli(["--data", str(path), "--params", "nope", "--out", str(tmp_path / "x.json")])
    assert not (tmp_path / "x.json").exists()


def test_record_identify_and_train_on_the_identified_model(tmp_path):
    """The README's flow: dexmots-record (one knob: fixed damping and friction, float32) -> dexmots-sysid from an
    initial guess at x2 (parameter file and report) -> make_env(task.object_params=<file>) simulates every world
    with the identified values instead of its randomised ones."""
    from dexmots_rl.apps.record import run as record

    data = tmp_path / "knob.mcap"
    record(["task=screw_claw", "task.damping_range=[0.5,0.5]", "task.friction_range=[0.6,0.6]", "num_envs=2",
            "steps=32", f"out={data}"])
    out = tmp_path / "knob.json"
    summary = sysid_cli(["--data", str(data), "--params", "joint_damping", "joint_friction", "--out", str(out),
                         "--iterations", "10", "--init", "joint_damping=1.0", "joint_friction=1.2", "--method", "gn"])
    assert (tmp_path / "knob_report" / "report.txt").is_file() and (tmp_path / "knob_report" / "params.png").is_file()
    values = json.loads(out.read_text())["params"]
    assert summary["values"] == values and max(summary["relative_error"].values()) < 0.01, summary
    env = make_env("screw_claw", num_envs=3, object_params=str(out))
    td = env.reset()
    assert torch.allclose(td["sim", "params", "joint_damping"], torch.tensor(values["joint_damping"]))
    assert torch.allclose(td["sim", "params", "joint_friction"], torch.tensor(values["joint_friction"]))
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"format": "dexmots-object-params", "version": 1, "params": {"mass": 1.0}}))
    with pytest.raises(ValueError, match=r"task.object_params: .*bad.json names parameter 'mass'"):
        make_env("screw_claw", num_envs=1, object_params=str(bad))
