"""The benchmark poses of ``operate`` and the tool tasks (:meth:`OperateObjectEnv.bench_poses`), built per scene.

``dexmots-bench grad`` needs a state where the fingers touch the object, an action that keeps them pressing,
a state far from it, and the loss's target. On these scenes (the Allegro hand palm-down over a library object
on its table) they are:

- touching: the object's first pre-grasp (its shipped file, or ``task.pregrasps``) with the object at rest,
  squeezed by :data:`SQUEEZE_FORCE` per fingertip with a grasp region, pressed into its part along the region's
  inward normal (:func:`~dexmots_rl.envs.object_pregrasp.squeeze_torque`; on the spray bottle and the drawer
  this moves the operated joint a few per cent of its travel in 32 steps, the base under 2 mm);
- throughput (``dexmots-bench throughput``): from the touching pose squeezed, where the task's episodes start
  (from the open hand the squeeze leaves some tools untouched);
- free: :data:`EXTENDED`, held there by :data:`RELEASE` (a palm-down hand's fingers droop onto the object
  within half a second of zero torque);
- the loss: the operated joint toward the task's goal, at the reference's speed (the goal's distance over
  ``ramp_steps``), and a free base held where it stands within the task's ``max_base_shift`` and
  ``max_base_tilt``.
"""

from __future__ import annotations

import numpy as np

from ...config import BenchPoses
from .hand import THUMB_ROTATION_MIN

__all__ = ["EXTENDED", "RELEASE", "SQUEEZE_FORCE", "operate_bench_poses"]

SQUEEZE_FORCE = 1.0  # N per fingertip: keeps every contact (a few N in all) without pushing a free tool away
# rad: every finger straightened back to near its extension limit, the thumb out at the palm's side
EXTENDED = (0.0, -0.19, -0.17, -0.22) * 3 + (THUMB_ROTATION_MIN, -0.1, -0.18, -0.16)
RELEASE = (0.0, -0.3, -0.3, -0.3) * 3 + (-0.3,) * 4  # actions: hold EXTENDED against gravity


def operate_bench_poses(env) -> BenchPoses:
    """:class:`~dexmots_rl.envs.BenchPoses` of an ``operate`` env's scene (object variant 0; the module
    docstring says what each is). Raises :class:`~dexmots_rl.envs.pregrasp.PregraspError` for an object
    without pre-grasps (a URDF's need ``task.pregrasps``)."""
    from ...object_pregrasp import squeeze_torque

    c, sim = env.config, env.sim
    if env.object_asset is None:
        raise ValueError("bench poses need the object's description: build the env from task.object")
    pregrasps = env._pregrasps
    if pregrasps is None:  # task.initial=open: the pre-grasps are read for the benchmark alone
        pregrasps = env._read_pregrasps(env.instance_names[0])
    hand = pregrasps[0].double().cpu().numpy()
    torque = squeeze_torque(sim.scene, env.object_asset, hand, SQUEEZE_FORCE, env.joint_name)
    gear = np.asarray(sim.scene.actuator_gear, dtype=np.float64)
    squeeze = np.clip(np.divide(torque, gear, out=np.zeros_like(torque), where=gear != 0), -1.0, 1.0)
    obj = tuple(float(x) for x in sim.tree.q0)
    squeeze = tuple(float(x) for x in squeeze)
    return BenchPoses(
        open_q=(*(float(x) for x in hand), *obj),  # the throughput window starts where the episodes do
        close_action=squeeze,
        touch_q=(*(float(x) for x in hand), *obj),
        free_q=(*EXTENDED, *obj),
        squeeze_action=squeeze,
        release_action=RELEASE,
        joint=env.joint_index,
        goal=env.goal_value,
        goal_speed=(env.goal_value - env.joint_rest) / (c.ramp_steps * sim.dt),
        base_tolerance=(c.max_base_shift, c.max_base_tilt) if sim.tree.free else None,
    )
