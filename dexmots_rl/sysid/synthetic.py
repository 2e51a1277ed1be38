"""Synthetic recordings with known parameters: the data the identification tests and ``dexmots-bench sysid`` use.

A task's env (float64, no mirror) runs ``worlds`` episodes with the object's parameters set to ``truth``, the
hand driven by the task's scripted controller plus noise where it has one, else by smoothed random actions of
the task's own action space; the recorded coordinates (the hand's joints and the object's) then get measurement
noise (``position_noise`` metres on positions and slides, ``angle_noise`` radians on hinges and a base's
rotation). Velocities are kept as simulated.
"""

from __future__ import annotations

import numpy as np
import torch

from ..envs import DexEnv, ScriptedPolicy, make_env, task_entry
from .data import CONTROL_FIELDS, Trajectories
from .problem import coordinate_kinds, coordinate_scales

__all__ = ["synthetic_trajectories"]


def _noisy(q: np.ndarray, kinds: list[str], position: float, angle: float, rng) -> np.ndarray:
    """``q`` [..., D] with Gaussian noise by coordinate kind; a quaternion is renormalised after its noise."""
    out = q + rng.standard_normal(q.shape) * coordinate_scales(kinds, position, angle)
    quat = [i for i, k in enumerate(kinds) if k == "quaternion"]
    if quat:
        block = out[..., quat]
        out[..., quat] = block / np.linalg.norm(block, axis=-1, keepdims=True)
    return out


def synthetic_trajectories(task: str, truth: dict[str, float], *, worlds: int = 4, steps: int = 60, seed: int = 0,
                           position_noise: float = 1e-3, angle_noise: float = 1e-2, action_noise: float = 0.3,
                           **overrides) -> Trajectories:
    """Simulate ``worlds`` episodes of ``steps`` steps of ``task`` with the named parameters at ``truth``; see the
    module docstring. ``overrides``: task config fields (e.g. ``object="jar_a"``)."""
    has_script = task_entry(task).env_class.scripted_action is not DexEnv.scripted_action
    overrides = {"mirror": False, **({"action": "torque"} if has_script else {}), **overrides}
    env = make_env(task, num_envs=worlds, raw=True, differentiable=False, seed=seed, dtype=torch.float64,
                   **overrides)
    scripted = ScriptedPolicy(env) if has_script else None
    gen = torch.Generator().manual_seed(seed)
    td = env.reset()
    known = env.sim.scene.param_names
    for name, value in truth.items():
        if name not in known:
            raise ValueError(f"unknown parameter {name!r}; this scene's parameters are: {', '.join(known)}")
        td["sim", "params", name] = torch.full((worlds, 1), float(value), dtype=torch.float64)
    nu = env.sim.nu
    qs, qds = [td["sim", "joint_q"].clone()], [td["sim", "joint_qd"].clone()]
    controls = {k: [torch.full((worlds, nu), float("nan"), dtype=torch.float64)] for k in CONTROL_FIELDS}
    action = torch.zeros(worlds, env.actions.action_dim, dtype=torch.float64)
    for _ in range(steps):
        noise = action_noise * torch.randn(worlds, env.actions.action_dim, generator=gen, dtype=torch.float64)
        if scripted is not None:
            action = (scripted(td.clone())["action"] + noise).clamp(-1, 1)
        else:  # a random walk of the task's actions: coherent pushes rather than jitter
            action = (0.8 * action + noise).clamp(-1, 1)
        td["action"] = action
        control = env.actions(action)
        td = env.step(td)["next"]
        qs.append(td["sim", "joint_q"].clone())
        qds.append(td["sim", "joint_qd"].clone())
        for k in CONTROL_FIELDS:
            controls[k].append(getattr(control, k).detach().clone())
    joint_q = torch.stack(qs).numpy()
    rng = np.random.default_rng(seed)
    joint_q = _noisy(joint_q, coordinate_kinds(env.sim), position_noise, angle_noise, rng)
    params = {name: np.full((steps + 1, worlds, 1), float(td["sim", "params", name][0, 0]))
              for name in known}
    config = {"name": task, **overrides}
    return Trajectories(joint_q=joint_q, joint_qd=torch.stack(qds).numpy(),
                        control={k: torch.stack(v).numpy() for k, v in controls.items()},
                        episode=np.zeros(steps + 1, dtype=np.int64), dt=float(env.sim.dt), task=config, params=params,
                        source=f"synthetic {task}")
