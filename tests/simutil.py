"""Constants and small helpers shared by the tests (fixtures live in conftest.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from dexmots_rl.assets import asset_path
from dexmots_rl.sim import Control, Simulator

ASSETS = Path(__file__).resolve().parent / "assets"
CHAIN3D = ASSETS / "chain3d.xml"
CLAW = asset_path("claw_screw.xml")

# claw joint order (MJCF): right proximal, right distal, left proximal, left distal, knob hinge
CLAW_OPEN_Q = (1.2, -0.5, -1.2, 0.5, 0.0)  # fingers spread wide: no finger-knob contact
CLAW_CONTACT_Q = (0.5, -0.6, -0.5, 0.6, 0.0)  # distal links pressed against the knob


def batch_state(sim: Simulator, q, qd=None):
    """Every world of ``sim`` at configuration ``q`` and velocity ``qd`` (default zero); fresh tensors."""
    n = sim.num_worlds
    q = torch.as_tensor(np.asarray(q, dtype=np.float64), dtype=sim.dtype).expand(n, sim.nq).clone()
    if qd is None:
        qd = torch.zeros(n, sim.nv, dtype=sim.dtype)
    else:
        qd = torch.as_tensor(np.asarray(qd, dtype=np.float64), dtype=sim.dtype).expand(n, sim.nv).clone()
    return q, qd


def claw_params(values: torch.Tensor) -> dict:
    """The knob's named parameters from a ``[N, 2]`` (or ``[2]``) tensor of (damping, friction); the
    spring is off. Differentiable in ``values``."""
    values = values.reshape(-1, 2)
    zero = torch.zeros_like(values[:, :1])
    return {"joint_damping": values[:, 0:1], "joint_friction": values[:, 1:2], "joint_stiffness": zero,
            "joint_rest": zero}


def torque(tau: torch.Tensor) -> Control:
    """Pure torque control (no PD terms)."""
    z = torch.zeros_like(tau)
    return Control(tau, z, z, z)


def mujoco_model(path, constraints: bool = False):
    """The MuJoCo model of a scene, by default with every constraint (contacts, limits, frictionloss) off."""
    import mujoco

    m = mujoco.MjModel.from_xml_path(str(path))
    if not constraints:
        m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
    return m


def mujoco_forward(m, q, qd, tau=None):
    """(qacc, full mass matrix, qfrc_bias, data) of MuJoCo at one state."""
    import mujoco

    d = mujoco.MjData(m)
    d.qpos[:] = q
    d.qvel[:] = qd
    if tau is not None:
        d.qfrc_applied[: len(tau)] = tau
    mujoco.mj_forward(m, d)
    M = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, M)
    return d.qacc.copy(), M, d.qfrc_bias.copy(), d
