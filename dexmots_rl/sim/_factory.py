"""The simulator of a scene: :func:`make_simulator` picks the class that steps it, so callers never branch on the
scene's kind."""

from __future__ import annotations

import torch

from ._articulated import ArticulatedScene, ArticulatedSimulator
from ._hand_sim import HandSimulator
from ._model import ContactParams, SceneModel
from ._simulator import Simulator

__all__ = ["make_simulator"]


def make_simulator(scene: SceneModel | ArticulatedScene, *, num_worlds: int, device: str | torch.device = "cpu",
                   dtype: torch.dtype = torch.float32, substeps: int = 16, dt: float | None = None,
                   contact: ContactParams | None = None, adjoint_clip: float | None = None) -> HandSimulator:
    """``num_worlds`` worlds of ``scene`` (what :func:`~dexmots_rl.sim.load_scene` returns) on ``device``: a
    :class:`~dexmots_rl.sim.Simulator` for a knob or cube scene, an :class:`~dexmots_rl.sim.ArticulatedSimulator`
    for a hand and an articulated object; both step ``(joint_q, joint_qd, control, params)`` the same way.

    ``substeps`` physics substeps per env step of ``dt`` seconds (default: ``substeps`` x the MJCF's timestep);
    ``contact``: the fingers' contact law (default :class:`~dexmots_rl.sim.ContactParams`); ``adjoint_clip``: the
    training option :class:`~dexmots_rl.sim.HandSimulator` documents (None: exact gradients).

    Example:
        >>> from dexmots_rl.assets import asset_path
        >>> from dexmots_rl.sim import load_scene, make_simulator
        >>> sim = make_simulator(load_scene(asset_path("claw_screw.xml")), num_worlds=2)
        >>> type(sim).__name__, sim.nq
        ('Simulator', 5)
    """
    kind = ArticulatedSimulator if isinstance(scene, ArticulatedScene) else Simulator
    if not isinstance(scene, (ArticulatedScene, SceneModel)):
        raise TypeError(f"make_simulator needs a scene from load_scene, got {type(scene).__name__}")
    return kind(scene, num_worlds, device=str(device), dtype=dtype, substeps=substeps, dt=dt, contact=contact,
                adjoint_clip=adjoint_clip)
