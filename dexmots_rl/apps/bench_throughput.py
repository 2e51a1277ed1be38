"""Throughput: env-steps/s of a task's simulator step (forward, forward+backward) against MuJoCo on one scene.

Any registered task runs: its env's scene (the knob and cube MJCFs; a tool task's or ``operate``'s hand and
library object on its table, whose MJCF MuJoCo loads from ``scene.path``), contact law and bench poses
(:meth:`~dexmots_rl.envs.DexEnv.bench_poses`). Protocol, identical for both simulators: every world starts
from the task's open pose (a tool task: its pre-grasp) with the closing action applied, is stepped
``settle_steps`` env steps until the fingers touch the object, and the timed work is repeated chunks of
``chunk_steps`` env steps restarted from that contact state (so the whole measured window is in contact; the
fraction of steps with contact is measured and reported: MuJoCo's counts contacts of the hand only). One env
step is ``substeps`` physics steps of the MJCF's timestep. Every rate is given per wall second
(``*_steps_per_s``) and per CPU-second of this process, all its threads counted (``*_steps_per_cpu_s``: core
for core, whatever the thread counts ``threads`` and ``mujoco_threads``; on a shared machine it moves less
than the wall rate); ``ratio_vs_mujoco`` and ``ratio_vs_mujoco_per_cpu_s`` are ours forward over MuJoCo's, and
``fwdbwd_cost`` (``fwdbwd_cost_per_cpu_s``) the cost of a forward + backward step in forward steps by the wall
clock (by CPU time).

* ``fwd``: ``Simulator.step`` with no input requiring grad (no tape).
* ``fwdbwd``: each step's ``joint_q`` requires grad; step, then backward of the sum of all outputs.
* ``taped_fwd_ms`` / ``reverse_ms``: one env step's forward kernels with the trajectory kept, and its
  reverse pass, timed alone (milliseconds for all worlds).
* ``mujoco``: ``mujoco.rollout.Rollout`` over N copies of the same ``MjModel`` (CPU, one thread per core,
  the calling thread alone for one world), ``nstep = substeps * chunk_steps``.

With ``obs="rgb"`` our ``fwd``/``fwdbwd`` chunks also render a 64x64 image of every world after each
step (:func:`dexmots_rl.sim.make_renderer`); MuJoCo's rows stay physics only.
"""

from __future__ import annotations

import logging
import os

import numpy as np
import torch

from ..sim import cpu_threads
from .bench_setup import bench_env, device_name, measure_rate, measure_rates

__all__ = ["ROW_KEYS", "SimBench", "MujocoBench", "run_throughput", "run_throughput_all", "throughput_row"]

log = logging.getLogger(__name__)


class SimBench:
    """Our simulator with ``num_envs`` worlds, settled into contact, ready to time."""

    def __init__(self, scene, task, num_envs: int, device: str, substeps: int, settle_steps: int,
                 chunk_steps: int, obs: str = "state", contact=None):
        from ..sim import Control, make_simulator

        self.sim = sim = make_simulator(scene, num_worlds=num_envs, device=device, substeps=substeps, contact=contact)
        self.chunk_steps = chunk_steps
        self.renderer = None
        if obs == "rgb":
            from ..sim import make_renderer

            self.renderer = make_renderer(scene, height=64, width=64, device=device)
        opts = dict(dtype=sim.dtype, device=sim.torch_device)
        gear = torch.as_tensor(scene.actuator_gear, **opts)
        tau = (torch.tensor(task.close_action, **opts) * gear).expand(num_envs, sim.nu).contiguous()
        zero = torch.zeros_like(tau)
        self.control, self.params = Control(tau, zero, zero, zero), sim.default_params()
        q = torch.tensor(task.open_q, **opts).expand(num_envs, sim.nq).contiguous()
        qd = torch.zeros(num_envs, sim.nv, **opts)
        for _ in range(settle_steps):  # the first step compiles the kernels (cached on disk afterwards)
            out = sim.step(q, qd, self.control, self.params)
            q, qd = out.joint_q, out.joint_qd
        self.q0, self.qd0 = q, qd

    def contact_fraction(self) -> float:
        """Fraction of (world, step) pairs in one chunk with a positive contact force."""
        q, qd, touching = self.q0, self.qd0, 0.0
        for _ in range(self.chunk_steps):
            out = self.sim.step(q, qd, self.control, self.params)
            q, qd = out.joint_q, out.joint_qd
            touching += (out.contact_force > 0).double().mean().item()
        return touching / self.chunk_steps

    def _observe(self, q) -> None:
        if self.renderer is not None:
            self.renderer.render_state(self.sim, q)

    def forward_chunk(self) -> int:
        q, qd = self.q0, self.qd0
        for _ in range(self.chunk_steps):
            out = self.sim.step(q, qd, self.control, self.params)
            q, qd = out.joint_q, out.joint_qd
            self._observe(q)
        return self.chunk_steps * self.sim.num_worlds

    def forward_backward_chunk(self) -> int:
        q, qd = self.q0, self.qd0
        for _ in range(self.chunk_steps):
            q = q.detach().requires_grad_(True)
            out = self.sim.step(q, qd, self.control, self.params)
            sum(t.sum() for t in out).backward()
            q, qd = out.joint_q.detach(), out.joint_qd.detach()
            self._observe(q)
        return self.chunk_steps * self.sim.num_worlds


    def _taped_step(self):
        """A taped trajectory of one env step from the settled state, and all-ones output adjoints."""
        traj = self.sim.new_trajectory(save=True)
        c = self.control
        traj.load(self.q0, self.qd0, [c.tau, c.q_target, c.kp, c.kd, self.sim.pack_params(self.params),
                                      self.sim._zeros(self.sim.num_worlds, 6)])
        traj.forward()
        return traj, [torch.ones_like(t) for t in traj.outputs()]

    def reverse_chunk(self):
        """A chunk function that runs the reverse pass of one taped step ``chunk_steps`` times."""
        traj, grads = self._taped_step()

        def chunk() -> int:
            for _ in range(self.chunk_steps):
                traj.backward(grads)
            return self.chunk_steps * self.sim.num_worlds
        return chunk

    def split_ms(self, min_time: float, sync) -> dict:
        """Milliseconds per env step (all worlds, no Python around them) of the taped forward kernels and
        of the reverse pass alone: where ``fwdbwd`` spends its time."""
        traj, grads = self._taped_step()

        def one_step(fn):
            def chunk() -> int:
                fn()
                return 1
            return chunk

        out = {}
        for name, fn in (("taped_fwd_ms", traj.forward), ("reverse_ms", lambda: traj.backward(grads))):
            fn()
            out[name] = 1e3 / measure_rate(one_step(fn), min_time, sync)
        return out


class MujocoBench:
    """MuJoCo rolling out ``num_envs`` copies of the scene from the same contact state, in threads."""

    def __init__(self, path, task, num_envs: int, timestep: float, substeps: int, settle_steps: int,
                 chunk_steps: int):
        import mujoco
        from mujoco import rollout

        self.mujoco = mujoco
        self.model = m = mujoco.MjModel.from_xml_path(str(path))
        m.opt.timestep = timestep
        self.substeps, self.chunk_steps, self.num_envs = substeps, chunk_steps, num_envs
        d = mujoco.MjData(m)
        d.qpos[: len(task.open_q)] = task.open_q
        d.ctrl[:] = task.close_action
        mujoco.mj_step(m, d, nstep=settle_steps * substeps)
        self.spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        state = np.empty(mujoco.mj_stateSize(m, self.spec))
        mujoco.mj_getState(m, d, state, self.spec)
        nstep = chunk_steps * substeps
        self.nthread = nthread = min(os.cpu_count() or 1, num_envs)
        self.pool = rollout.Rollout(nthread=nthread if nthread > 1 else 0)
        self.models = [m] * num_envs
        self.datas = [mujoco.MjData(m) for _ in range(nthread)]
        self.init = np.tile(state, (num_envs, 1))
        self.ctrl = np.tile(np.asarray(task.close_action, dtype=np.float64), (num_envs, nstep, 1))
        self.state_out = np.empty((num_envs, nstep, state.size))
        self.sensor_out = np.empty((num_envs, nstep, m.nsensordata))

    def contact_fraction(self) -> float:
        """Fraction of physics steps of one chunk (from the settled state) with a contact of the hand (a geom of
        the tree that holds the actuated joints: not an object resting on its table)."""
        mujoco, m, d = self.mujoco, self.model, self.mujoco.MjData(self.model)
        hand = m.body_rootid[m.jnt_bodyid[m.actuator_trnid[0, 0]]]
        mujoco.mj_setState(m, d, self.init[0].copy(), self.spec)
        d.ctrl[:] = self.ctrl[0, 0]
        touching = 0
        for _ in range(self.chunk_steps * self.substeps):
            mujoco.mj_step(m, d)
            geoms = np.stack([d.contact.geom1[:d.ncon], d.contact.geom2[:d.ncon]])
            touching += bool((m.body_rootid[m.geom_bodyid[geoms]] == hand).any())
        return touching / (self.chunk_steps * self.substeps)

    def chunk(self) -> int:
        self.pool.rollout(self.models, self.datas, self.init, self.ctrl, skip_checks=True,
                          nstep=self.chunk_steps * self.substeps, state=self.state_out, sensordata=self.sensor_out)
        return self.chunk_steps * self.num_envs

    def close(self) -> None:
        self.pool.close()


ROW_KEYS = ("num_envs", "fwd_steps_per_s", "fwd_steps_per_cpu_s", "fwdbwd_steps_per_s", "fwdbwd_steps_per_cpu_s",
            "mujoco_steps_per_s", "mujoco_steps_per_cpu_s", "ratio_vs_mujoco", "ratio_vs_mujoco_per_cpu_s",
            "fwdbwd_cost", "fwdbwd_cost_per_cpu_s", "contact_fraction", "mujoco_contact_fraction", "taped_fwd_ms",
            "reverse_ms")


def throughput_row(ours: SimBench, mj: MujocoBench | None, min_time: float, sync) -> dict:
    """One world count's row (:data:`ROW_KEYS`; MuJoCo's entries None without ``mj``)."""
    n = ours.sim.num_worlds
    row = {"num_envs": n, "contact_fraction": ours.contact_fraction(),
           "mujoco_contact_fraction": mj.contact_fraction() if mj else None}
    timed = [("fwd", ours.forward_chunk), ("fwdbwd", ours.forward_backward_chunk)]
    timed += [("mujoco", mj.chunk)] if mj else []
    for name, fn in timed:
        fn()  # warm-up: builds replay plans / tapes / thread pools outside the timed window
        row[f"{name}_steps_per_s"], row[f"{name}_steps_per_cpu_s"] = measure_rates(fn, min_time, sync)
        log.info("num_envs=%d %s: %.0f env-steps/s, %.0f per CPU-second", n, name, row[f"{name}_steps_per_s"],
                 row[f"{name}_steps_per_cpu_s"])
    row.update(ours.split_ms(min_time, sync))
    # a forward + backward step in forward steps, by the wall clock and by CPU time
    row["fwdbwd_cost"] = row["fwd_steps_per_s"] / row["fwdbwd_steps_per_s"]
    row["fwdbwd_cost_per_cpu_s"] = row["fwd_steps_per_cpu_s"] / row["fwdbwd_steps_per_cpu_s"]
    if mj is not None:
        row["ratio_vs_mujoco"] = row["fwd_steps_per_s"] / row["mujoco_steps_per_s"]
        row["ratio_vs_mujoco_per_cpu_s"] = row["fwd_steps_per_cpu_s"] / row["mujoco_steps_per_cpu_s"]
    if row["contact_fraction"] == 0 or row["mujoco_contact_fraction"] == 0:
        log.warning("num_envs=%d: no contact in the measured window (ours %.2f, mujoco %s)", n,
                    row["contact_fraction"], row["mujoco_contact_fraction"])
    return {k: row.get(k) for k in ROW_KEYS}


def run_throughput(task: str = "screw_claw", num_envs=(1, 16, 64, 256), device: str = "cpu", substeps: int = 16,
                   min_time: float = 1.0, settle_steps: int = 20, chunk_steps: int = 16, obs: str = "state",
                   mujoco: bool = True, object_name: str | None = None) -> dict:
    """Measure every row (see the module docstring) of any registered task; returns the result dict printed by
    ``dexmots-bench``. ``mujoco=False`` leaves MuJoCo out (its rows' entries are None): ours only, e.g. on a
    GPU. ``object_name``: the library object of ``operate`` or a tool task (None: the task's own)."""
    env = bench_env(task, **({} if object_name is None else {"object": object_name}))
    poses, scene, law = env.bench_poses(), env.sim.scene, env.sim.contact
    sync = torch.cuda.synchronize if torch.device(device).type == "cuda" else (lambda: None)
    rows = []
    for n in num_envs:
        log.info("%s num_envs=%d: settling (the first step compiles the warp kernels when not cached)", task, n)
        ours = SimBench(scene, poses, n, device, substeps, settle_steps, chunk_steps, obs, law)
        mj = MujocoBench(scene.path, poses, n, ours.sim.sub_dt, substeps, settle_steps, chunk_steps) if mujoco else None
        try:
            rows.append(throughput_row(ours, mj, min_time, sync))
        finally:
            if mj is not None:
                mj.close()
    result = {"task": task, "device": device_name(device), "dt": float(ours.sim.sub_dt), "substeps": substeps,
              "obs": obs, "threads": cpu_threads(), "mujoco_threads": mj.nthread if mujoco else None, "rows": rows}
    if hasattr(env.config, "object"):  # operate and the tool tasks: which library object
        result["object"] = env.config.object
    return result


def run_throughput_all(tasks, **options) -> dict:
    """:func:`run_throughput` of each task in ``tasks``, one row per (task, world count) (``task``, its ``object``
    (None: a knob or cube task) and ``dt`` in each row), the options shared."""
    results = [run_throughput(task, **options) for task in tasks]
    first = results[0]
    return {"tasks": list(tasks), "device": first["device"], "substeps": first["substeps"], "obs": first["obs"],
            "threads": first["threads"], "mujoco_threads": first["mujoco_threads"],
            "rows": [{"task": r["task"], "object": r.get("object"), "dt": r["dt"], **row}
                     for r in results for row in r["rows"]]}
