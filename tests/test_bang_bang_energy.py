"""Bang-bang hands against every scene and every library object: contact makes no energy, no body goes through
the table, no world blows up.

From each task's reset every hand joint gets its full motor torque with a random sign per world and joint that
flips every step, or is drawn anew every 3 steps (``benchmarks/energy.py``, which reports the same figures for
64 worlds and 2000 steps). The object's energy (kinetic, gravity, joint springs: sim/_energy.py) may grow by the
work the motors did plus what the hand's links can give by falling (``release_j``), no more. Before the tool
scenes' fingers had the contact law's implicit damping, strikes flung scissors_b's light blade at 6.5 m/s within
these steps (hold 3; in 64 worlds x 2000 steps of the new law none passes 3 m/s).

``repose_cube`` is also struck with variable-impedance actions (stiffest PD targets at opposite ends, flipping
every step): in any one step the cube may gain at most the work the motors can do in it, sum_j effort_j |dq_j|.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest
import torch

import partnet_fixtures as fx
from dexmots_rl.assets.objects import list_objects
from dexmots_rl.envs import list_tasks, make_env

ENERGY_BENCHMARK = Path(__file__).resolve().parents[1] / "benchmarks" / "energy.py"
WORLDS, STEPS = 64, 60  # the old explicit finger law flung scissors_b at 6.5 m/s in world 12 at step 20 (hold 3)
MAX_EXCESS_J = 0.5  # beyond the links' release (penalty energy stored in contacts and stops is left out)
MAX_SPEED = 5.0  # m/s: a free object's peak speed while near the hand
MAX_SPIN = 200.0  # rad/s
MAX_JOINT_SPEED = 200.0  # rad/s or m/s: an object part's
SCENES = [pytest.param(task, {}, id=task) for task in list_tasks() if task != "operate"]
# every library object on `operate` in the slow set: the fast set has each tool class's first instance as its task
SCENES += [pytest.param("operate", {"object": name}, marks=pytest.mark.slow, id=name) for name, _ in list_objects()]


def _energy_benchmark():
    spec = importlib.util.spec_from_file_location("energy_benchmark", ENERGY_BENCHMARK)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("hold", [0, 3], ids=["flip_every_step", "hold_3_steps"])
@pytest.mark.parametrize("task, overrides", SCENES)
def test_bang_bang_makes_no_energy(task, overrides, hold):
    _assert_no_energy_made(_energy_benchmark().measure(task, worlds=WORLDS, steps=STEPS, seed=0, overrides=overrides,
                                                       hold=hold))


def test_fingers_pressed_into_a_heavy_object_make_no_energy(tmp_path, monkeypatch):
    """A strongbox in PartNet-Mobility's layout (a 3 kg body, 70 times its 42 g door), from the open start: the
    hand held over the door's centre starts with its fingers sunk in the body (1.6 kN of contact at the first
    substep). Before the contact's damping was implicit against the finger's mobility too (not the
    body's alone), each substep reversed and grew the pressed fingers' velocity: 81 J made in all 4 worlds within
    20 steps, the body thrown at 9.5 m/s (a real safe of the data set: 126 J, 12 m/s)."""
    monkeypatch.setenv("DEXMOTS_CACHE", str(tmp_path / "cache"))
    urdf = fx.strongbox(tmp_path / "101564")
    _assert_no_energy_made(_energy_benchmark().measure("operate", worlds=4, steps=20, seed=0,
                                                       overrides={"object": str(urdf), "initial": "open"}))


def _assert_no_energy_made(r: dict) -> None:
    assert r["finite"], r
    assert r["max_energy_excess_j"] <= r["release_j"] + MAX_EXCESS_J, r
    assert r["peak_base_speed"] <= MAX_SPEED and r["peak_base_spin"] <= MAX_SPIN, r
    assert r["peak_joint_speed"] <= MAX_JOINT_SPEED, r
    assert r["worlds_outside_physics"] == 0, r  # no object sample through the table, no part through a stop


@pytest.mark.parametrize("hold", [0, 3], ids=["flip_every_step", "hold_3_steps"])
def test_variable_impedance_strikes_do_not_launch_the_cube(hold):
    """``repose_cube`` under ``vi`` actions at ±1 (PD targets at the joints' ends, stiffness at either bound),
    random signs that flip every step (``hold`` 0) or are drawn anew every ``hold`` steps: in no step does the cube
    gain more energy than the motors can do in it, sum_j effort_j |dq_j| (each motor's torque saturates at its
    effort), plus the links' release, and it never spins faster than ``MAX_SPIN``.

    Stepped through the simulator itself: the env resets a world whose joints pass its blow-up speed, which hides
    a launch. With the fingers' friction explicit against the cube, world 0 (hold 0) gained 170 J at step 37 while
    the motors did 0.26 J (34 m/s, 1660 rad/s): squeezed between fingertips and palm, the cube's slip reversed and
    grew every substep."""
    worlds = 16
    env = make_env("repose_cube", num_envs=worlds, seed=0, differentiable=False, action="vi", raw=True)
    sim, nu = env.sim, env.sim.nu
    effort = torch.as_tensor(sim.scene.actuator_effort, dtype=sim.dtype)
    assert (effort > 0).all()  # the bound below needs every motor saturated
    release = float(sim.scene.link_mass.sum()) * 9.81 * 0.2
    td = env.reset()
    q, qd = td["sim", "joint_q"], td["sim", "joint_qd"]
    params = sim.default_params()  # a free cube has no parameters
    gen = torch.Generator().manual_seed(0)
    sign = torch.where(torch.rand(worlds, 2 * nu, generator=gen) < 0.5, -1.0, 1.0)
    for step in range(STEPS):
        out = sim.step(q, qd, env.actions(sign.to(sim.dtype)), params)
        q1, qd1 = out.joint_q, out.joint_qd
        assert torch.isfinite(q1).all() and torch.isfinite(qd1).all()
        gain = sim.object_energy(q1, qd1) - sim.object_energy(q, qd)
        work = (effort * (q1[:, :nu] - q[:, :nu]).abs()).sum(-1)
        assert (gain <= work + release).all(), (step, gain.max().item(), work.max().item())
        assert qd1[:, nu + 3:nu + 6].norm(dim=-1).max() <= MAX_SPIN, step
        q, qd = q1, qd1
        if not hold:
            sign = -sign
        elif (step + 1) % hold == 0:
            sign = torch.where(torch.rand(worlds, 2 * nu, generator=gen) < 0.5, -1.0, 1.0)
