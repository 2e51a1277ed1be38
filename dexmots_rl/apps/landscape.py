"""The objective landscape of the paper's Fig. 4: ``dexmots-plot landscape`` computes it here and draws it
with :func:`dexmots_rl.viz.plots.plot_landscape`.

The screw-claw hand closes on the knob with the scripted controller of
:mod:`dexmots_rl.envs.tasks.screw_claw` until the fingers touch it; from that one state, every action of a
grid over the two distal joints (the other joints keep the scripted action) is stepped once in a batch of
worlds with ``differentiable=True``, and the one-step objectives

* pose only:      ``J_p  = exp(-|θ - θ̄| / pose_scale)``                         (:func:`angle_tracking_reward`)
* pose + wrench:  ``J_pw = J_p + exp(-‖(Δf / force_scale, Δτ / torque_scale)‖)``  (+ :func:`wrench_reward`)

are differentiated through the simulator with respect to the actions (``∂J/∂a``, the arrows). The
reference ``θ̄`` (knob angle) and ``ω̄ = (f̄, τ̄)`` (contact wrench on the knob) are what the grid's centre
action ``a*`` produces. The two panels share one colour scale of ``J - J(a*)`` and one arrow scale, so
what looks flat is flat for the optimiser too; the titles give each panel's range and median ``|∇J|``.
Worlds are doubled (one copy per objective) so one backward pass gives both gradients.
"""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["landscape_data"]

STATE_KEYS = (("sim", "joint_q"), ("sim", "joint_qd"), ("sim", "params"), ("task", "goal"))


def _grid_axis(centre: float, span: float, grid: int) -> np.ndarray:
    """``grid`` values spanning ``2 span`` about ``centre``, shifted to stay inside the action box [-1, 1]."""
    lo = min(max(centre - span, -1.0), 1.0 - 2.0 * span)
    return lo + np.linspace(0.0, 2.0 * span, grid)


def landscape_data(task: str = "screw_claw", grid: int = 21, span: float = 0.5,
                   joints: tuple[int, int] = (1, 3), contact_steps: int = 2, max_settle_steps: int = 60, pose_scale: float | None = None,
                   force_scale: float | None = None, torque_scale: float | None = None, squeeze: float = 0.6,
                   twist: float = 0.0, seed: int = 0, dtype: torch.dtype = torch.float32) -> dict:
    """Objective values and gradients over an action grid from one contact state (module docstring).

    ``joints``: the two action entries on the axes (default: right distal, left distal); ``span``: half
    width of the grid in action units; ``contact_steps``: closing steps taken after the first contact;
    ``pose_scale`` defaults to the task's reward scale (0.5 rad for screw_claw); ``force_scale`` /
    ``torque_scale`` default to ``‖f̄‖`` and ``‖f̄‖ R`` (R: the object's bounding radius), i.e. the wrench
    error relative to the reference contact force; ``squeeze`` / ``twist``: the
    scripted controller's closing and twisting actions (settling and the joints off the axes). Returns numpy arrays ``u``,
    ``v`` [G] (axis values), ``J_pose``, ``J_pose_wrench`` [G, G] (index ``[i, j]`` = ``(u[i], v[j])``),
    ``grad_pose``, ``grad_pose_wrench`` [G, G, 2], ``theta``, ``torque`` [G, G], and scalars.
    """
    if grid < 3 or grid % 2 == 0:
        raise ValueError(f"grid must be an odd integer >= 3 (the centre is the reference), got {grid}")
    if not 0 < span <= 1:
        raise ValueError(f"span must be in (0, 1], got {span}")
    from torchrl.envs.utils import step_mdp

    from ..envs import make_env
    from ..envs.rewards import angle_tracking_reward, wrench_reward
    from ..envs.tasks.screw_claw import scripted_claw_action

    if task != "screw_claw":
        raise ValueError(f"the landscape's scripted closing controller is for screw_claw only, got {task!r}")
    g2 = grid * grid
    n = 2 * g2  # one copy of the grid per objective: a single backward pass gives both gradients
    env = make_env(task, num_envs=n, differentiable=True, seed=seed, raw=True, dtype=dtype, action="torque")
    pose_scale = env.pose_scale if pose_scale is None else pose_scale
    td = env.reset()
    for key in STATE_KEYS:  # every world starts from world 0's state
        value = td.get(key)
        td.set(key, value[:1].expand(value.shape).clone())
    touched, steps = 0, 0
    with torch.no_grad():
        while touched <= contact_steps:
            if steps >= max_settle_steps:
                raise RuntimeError(f"no contact after {max_settle_steps} closing steps")
            action = scripted_claw_action(td.get(("task", "goal")), squeeze, twist).to(dtype).expand(n, -1).contiguous()
            td = step_mdp(env.step(td.set("action", action)))
            steps += 1
            touched += int(td.get(("object", "contact_force"))[0, 0] > 0) if touched == 0 else 1
    base = scripted_claw_action(td.get(("task", "goal"))[:1], squeeze, twist)[0].to(dtype)
    u = _grid_axis(float(base[joints[0]]), span, grid)
    v = _grid_axis(float(base[joints[1]]), span, grid)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    actions = base.repeat(n, 1)
    actions[:, joints[0]] = torch.as_tensor(np.tile(uu.ravel(), 2), dtype=dtype)
    actions[:, joints[1]] = torch.as_tensor(np.tile(vv.ravel(), 2), dtype=dtype)
    actions.requires_grad_(True)
    out = env.step(td.clone().set("action", actions)).get("next")
    theta, wrench = out.get(("object", "q")), out.get(("object", "wrench"))
    centre = (grid // 2) * grid + grid // 2
    theta_ref, wrench_ref = theta[centre].detach(), wrench[centre].detach()
    f_ref = max(float(wrench_ref[:3].norm()), 1e-6)
    force_scale = f_ref if force_scale is None else force_scale
    torque_scale = f_ref * env.scene.object_bound if torque_scale is None else torque_scale
    j_pose = angle_tracking_reward(theta, theta_ref, pose_scale)
    j_pw = j_pose + wrench_reward(wrench, wrench_ref, force_scale, torque_scale)
    (j_pose[:g2].sum() + j_pw[g2:].sum()).backward()
    grad = actions.grad[:, list(joints)].detach().double().numpy()
    axis = torch.as_tensor(env.scene.object_base_rot @ env.scene.object_axis, dtype=dtype)

    def grid_of(x):
        return np.asarray(x.detach().double().numpy()).reshape(grid, grid, *x.shape[1:])

    force = out.get(("object", "contact_force")).detach()
    return {
        "u": u, "v": v,
        "J_pose": grid_of(j_pose[:g2, 0]), "J_pose_wrench": grid_of(j_pw[g2:, 0]),
        "grad_pose": grad[:g2].reshape(grid, grid, 2), "grad_pose_wrench": grad[g2:].reshape(grid, grid, 2),
        "theta": grid_of(theta[:g2, 0]), "torque": grid_of((wrench[:g2, 3:] * axis).sum(-1)),
        "reference_action": base.double().numpy().copy(), "centre": (float(u[grid // 2]), float(v[grid // 2])),
        "joint_names": [env.scene.joint_names[j] for j in joints],
        "settle_steps": steps, "contact_force_min": float(force.min()), "contact_force_max": float(force.max()),
        "pose_scale": float(pose_scale), "force_scale": float(force_scale), "torque_scale": float(torque_scale),
        "task": task,
    }
