"""Checks of the Allegro hand + knob scene (dexmots_rl/assets/allegro_knob.xml), MuJoCo against our simulator.

    DEXMOTS_WARP_OPT=0 python benchmarks/allegro_check.py            # -O0 kernels: compile in seconds
    python benchmarks/allegro_check.py --steps 60 --contact both

1. MuJoCo compiles the file: nq, nv, nu, hand mass.
2. ``load_scene`` accepts it: fingers x links, sample points per link, object shape and bound.
3. The reference hand poses (GRASP_Q, OPEN_Q, TOUCH_Q, FREE_Q): the smallest signed distance of every
   finger (MuJoCo ``mj_geomDistance`` of its geoms to the knob), and that closing OPEN_Q makes contact.
   Fingertip positions from our ``observe`` against MuJoCo's sites.
4. Our simulator, float64, 4 worlds from GRASP_Q under joint PD control: hold, squeeze, squeeze + twist,
   squeeze - twist; the knob angle every 10 env steps (60 Hz, 16 substeps).
5. The same in MuJoCo (gravity 0, the PD law evaluated at every 1/960 s step on the motors, clipped at the
   effort): the knob should turn the same way. And the hand's joint-space mass matrix: MuJoCo's
   ``mj_fullM`` against one rebuilt from the ``SceneModel`` arrays (what the kernels are given).
Prints one JSON object.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from pathlib import Path

import mujoco
import numpy as np
import torch

ASSET = Path(__file__).resolve().parents[1] / "dexmots_rl" / "assets" / "allegro_knob.xml"

# hand poses, MJCF joint order j0..j15 (index, middle, ring, thumb); found by least squares on MuJoCo's
# kinematics: fingertip spheres 0.5 mm into the knob's faces at 45, 0, -45 deg (index, middle, ring) and
# 180 deg (thumb), every other link >= 3 mm clear of the knob
GRASP_Q = (-0.102, 0.58, 0.67, 0.639, 0.0, 0.494, 0.604, 0.598,
           0.102, 0.58, 0.67, 0.639, 0.919, 1.006, 0.662, 0.787)
TOUCH_Q = GRASP_Q
# GRASP_Q with the fingers' flexion opened by 0.25 rad and the thumb backed off (j13 to 1.15, near its
# 1.163 limit; j14/j15 - 0.2)
OPEN_Q = (-0.102, 0.33, 0.42, 0.389, 0.0, 0.244, 0.354, 0.348,
          0.102, 0.33, 0.42, 0.389, 0.919, 1.15, 0.462, 0.587)
FREE_Q = (0.0,) * 12 + (0.263, 0.0, 0.0, 0.0)  # straight fingers, thumb at its lower j12 limit
# deltas on the targets: squeeze = flex j1-j3 of each finger, thumb j13 toward the knob;
# twist = abduct the fingers (j0, j4, j8: tips to +y) and swing the thumb (j12: tip to -y): +z on the knob
SQUEEZE = (0.0, 0.15, 0.15, 0.15) * 3 + (0.0, -0.15, 0.0, 0.0)
TWIST = (0.3, 0.0, 0.0, 0.0) * 3 + (0.3, 0.0, 0.0, 0.0)
KP = 3.0  # N m / rad: 0.15 rad of squeeze asks 0.45 N m, just under the 0.5 N m effort
FINGERS = ("index", "middle", "ring", "thumb")


def finger_distances(m, d, q) -> dict:
    """Smallest signed distance (m) of each finger's geoms to the knob, MuJoCo's narrow phase."""
    d.qpos[:16], d.qpos[16] = q, 0.0
    mujoco.mj_forward(m, d)
    knob = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "knob")
    out = {}
    for k, f in enumerate(FINGERS):
        bodies = set(range(2 + 4 * k, 6 + 4 * k))
        out[f] = min(mujoco.mj_geomDistance(m, d, g, knob, 0.5, None) for g in range(m.ngeom) if m.geom_bodyid[g] in bodies)
    return out


def mujoco_rollout(m, target, q0, steps, substeps, kd) -> list[float]:
    d = mujoco.MjData(m)
    d.qpos[:16] = q0
    mujoco.mj_forward(m, d)
    gear, angles = m.actuator_gear[:, 0], []
    for s in range(steps * substeps):
        tau = KP * (target - d.qpos[:16]) - kd * d.qvel[:16]
        d.ctrl[:] = np.clip(tau / gear, -1.0, 1.0)
        mujoco.mj_step(m, d)
        if (s + 1) % (10 * substeps) == 0:
            angles.append(round(float(d.qpos[16]), 4))
    return angles


def scene_mass_matrix(s, q) -> np.ndarray:
    """Joint-space mass matrix of the hand rebuilt from the SceneModel arrays (composite Jacobians)."""
    F, J = s.num_fingers, s.joints_per_finger
    M = np.zeros((F * J, F * J))
    for f in range(F):
        R, x = np.asarray(s.finger_base_rot[f]), np.asarray(s.finger_base_pos[f])
        axes, origins = [], []
        for j in range(J):
            i = f * J + j
            x = x + R @ s.link_offset_pos[i]
            R = R @ s.link_offset_rot[i]
            a = R @ s.joint_axis[i]
            R = R @ _axis_rot(s.joint_axis[i], q[i])
            axes.append(a)
            origins.append(x)
            c = x + R @ s.link_com[i]
            Jv, Jw = np.zeros((3, F * J)), np.zeros((3, F * J))
            for k in range(j + 1):
                Jw[:, f * J + k] = axes[k]
                Jv[:, f * J + k] = np.cross(axes[k], c - origins[k])
            Iw = R @ s.link_inertia[i] @ R.T
            M += s.link_mass[i] * Jv.T @ Jv + Jw.T @ Iw @ Jw
    return M + np.diag(s.dof_armature)


def _axis_rot(axis, angle) -> np.ndarray:
    a = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--contact", choices=["default", "allegro", "both"], default="both",
                        help="ContactParams: the project's defaults (sized for the 0.4 m claw) or ones sized "
                             "for the Allegro (stiffness 5e3 N/m, sharpness 1000 /m, smoothing 2 mm)")
    args = parser.parse_args()
    report: dict = {}

    # 1. MuJoCo
    m = mujoco.MjModel.from_xml_path(str(ASSET))
    d = mujoco.MjData(m)
    obj = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "object")
    report["mujoco"] = {"nq": m.nq, "nv": m.nv, "nu": m.nu,
                        "hand_mass": round(float(m.body_mass.sum() - m.body_mass[obj]), 4),
                        "knob_mass": round(float(m.body_mass[obj]), 4),
                        "knob_axial_inertia": float(m.body_inertia[obj][2])}

    # 2. load_scene
    from dexmots_rl.sim import Control, ContactParams, Simulator, load_scene

    s = load_scene(ASSET)
    report["scene"] = {"num_fingers": s.num_fingers, "joints_per_finger": s.joints_per_finger,
                       "points_per_link": s.points_per_link, "object_kind": int(s.object_kind),
                       "object_shape": int(s.object_shape), "object_faces": len(s.object_planes),
                       "object_bound": round(float(s.object_bound), 5), "finger_names": s.finger_names,
                       "effort": sorted(set(np.round(s.actuator_effort, 4).tolist()))}

    # 3. poses
    lo, hi = m.jnt_range[:16, 0], m.jnt_range[:16, 1]
    poses = {"grasp_q": GRASP_Q, "open_q": OPEN_Q, "touch_q": TOUCH_Q, "free_q": FREE_Q}
    report["poses"] = {}
    for name, q in poses.items():
        q = np.array(q)
        report["poses"][name] = {"within_limits": bool(((q >= lo) & (q <= hi)).all()),
                                 "distance_mm": {k: round(v * 1e3, 2) for k, v in finger_distances(m, d, q).items()}}
    # closing from OPEN_Q: interpolate to GRASP_Q + SQUEEZE, report where each finger first touches
    close_to = np.array(GRASP_Q) + np.array(SQUEEZE)
    first = {}
    for t in np.linspace(0, 1, 101):
        dist = finger_distances(m, d, (1 - t) * np.array(OPEN_Q) + t * close_to)
        for k, v in dist.items():
            if v <= 0 and k not in first:
                first[k] = round(float(t), 2)
    report["poses"]["open_to_closed_first_contact_t"] = first

    # 4. our simulator
    dtype = torch.float64
    contacts = {"default": ContactParams(),
                "allegro": dataclasses.replace(ContactParams(), stiffness=5.0e3, sharpness=1000.0,
                                               surface_smoothing=0.002, slip_velocity=0.05)}
    chosen = ["default", "allegro"] if args.contact == "both" else [args.contact]
    g, sq, tw = (torch.tensor(v, dtype=dtype) for v in (GRASP_Q, SQUEEZE, TWIST))
    targets = torch.stack([g, g + sq, g + sq + tw, g + sq - tw])
    cases = ["hold", "squeeze", "squeeze+twist", "squeeze-twist"]
    inertia0 = torch.as_tensor(s.dof_inertia0, dtype=dtype)
    kd = 2.0 * torch.sqrt(KP * inertia0)  # critically damped on the joint's own inertia
    report["sim"] = {}
    for cname in chosen:
        start = time.perf_counter()
        sim = Simulator(s, num_worlds=4, dtype=dtype, contact=contacts[cname])
        q, qd = sim.initial_state()
        q[:, :16] = g
        # fingertips: ours vs MuJoCo's sites at GRASP_Q
        _, tips = sim.observe(q)
        d.qpos[:16], d.qpos[16] = GRASP_Q, 0.0
        mujoco.mj_forward(m, d)
        sites = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, f"{f}_tip") for f in FINGERS]
        tip_err = float(np.abs(tips[0].numpy() - d.site_xpos[sites]).max())
        control = Control(tau=torch.zeros(4, 16, dtype=dtype), q_target=targets.clone(),
                          kp=torch.full((4, 16), KP, dtype=dtype), kd=kd.expand(4, 16).clone())
        params = sim.default_params()
        angles, forces = {c: [] for c in cases}, {c: [] for c in cases}
        for step in range(args.steps):
            out = sim.step(q, qd, control, params)
            q, qd = out.joint_q, out.joint_qd
            if (step + 1) % 10 == 0:
                for w, c in enumerate(cases):
                    angles[c].append(round(float(q[w, 16]), 4))
                    forces[c].append(round(float(out.contact_force[w]), 3))
        report["sim"][cname] = {"tip_error_vs_mujoco_m": tip_err, "knob_angle_every_10_steps": angles,
                                "contact_force_N_every_10_steps": forces,
                                "finite": bool(torch.isfinite(q).all()),
                                "seconds_incl_compile": round(time.perf_counter() - start, 1)}

    # 5. MuJoCo, same control
    kd_np = kd.numpy()
    report["mujoco_rollout"] = {c: mujoco_rollout(m, targets[w].numpy(), np.array(GRASP_Q), args.steps, 16, kd_np)
                                for w, c in enumerate(cases)}
    rng = np.random.default_rng(0)
    qr = lo + (hi - lo) * rng.uniform(size=16)
    d.qpos[:16], d.qpos[16] = qr, 0.0
    mujoco.mj_forward(m, d)
    full = np.zeros((m.nv, m.nv))
    try:  # MuJoCo >= 3.3: mj_fullM(m, d, dst); before: mj_fullM(m, dst, d.qM)
        mujoco.mj_fullM(m, d, full)
    except TypeError:
        mujoco.mj_fullM(m, full, d.qM)
    Mh = full[:16, :16]
    Ms = scene_mass_matrix(s, qr)
    report["mass_matrix"] = {"q": np.round(qr, 3).tolist(),
                             "mujoco_diag": np.round(np.diag(Mh), 6).tolist(),
                             "max_abs_diff_scene_vs_mujoco": float(np.abs(Ms - Mh).max()),
                             "max_cross_finger_entry": float(max(np.abs(Mh[4 * a:4 * a + 4, 4 * b:4 * b + 4]).max()
                                                                 for a in range(4) for b in range(4) if a != b))}
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
