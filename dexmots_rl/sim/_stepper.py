"""Launching one env step (all substeps) over blocks of worlds, forward and reverse.

Every array of a :class:`Trajectory` holds the whole env step: row ``s * N + w`` is world ``w`` after
``s`` substeps. Each row is written exactly once, so one set of warp arrays serves every substep, the
adjoint launches can run over the same arrays in reverse substep order, and nothing is allocated per
substep. The reverse pass is driven by hand (adjoint launches) rather than by ``wp.Tape``: same kernels,
same adjoints, a fraction of the Python overhead.

Two ways to run the recorded launches:

* CPU (default there): worlds are split into one block per core; each block's launches run in their own
  thread (a warp CPU launch runs on one core and releases the GIL), through :func:`prepared` calls.
* graphs (always on CUDA): one launch per kernel over all worlds; the forward launches of the step, and
  separately its reverse launches, are captured once as a graph (``wp.ScopedCapture``) and replayed with
  ``wp.capture_launch`` on torch's current stream, so the torch copies before and after a step are
  ordered with it on the GPU and nothing waits on the host. ``Simulator.graphs = True`` selects this on
  CPU too (warp replays a CPU graph in C++; the tests run the graph path that way).
"""

from __future__ import annotations

import ctypes
import os
from concurrent.futures import ThreadPoolExecutor

import torch
import warp as wp

__all__ = ["Trajectory", "capture_graph", "cpu_threads", "launch_stream", "replay_graph", "run_blocks",
           "world_blocks"]

MIN_WORLDS_PER_THREAD = 32  # below this a second CPU thread costs more than it saves
_POOL: ThreadPoolExecutor | None = None


def cpu_threads() -> int:
    """CPU threads a step may use: ``DEXMOTS_CPU_THREADS`` if set, else the cores this process may run on.
    A warp CPU launch runs on one core; on a machine shared with other jobs, fewer threads than cores
    avoids blocks that wait on each other for a core (measured: 10x slower steps with 2 threads on
    one free core)."""
    env = os.environ.get("DEXMOTS_CPU_THREADS")
    if env:
        if not env.isdigit() or int(env) < 1:
            raise ValueError(f"DEXMOTS_CPU_THREADS must be a positive integer, got {env!r}")
        return int(env)
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def world_blocks(num_worlds: int, device) -> list[tuple[int, int]]:
    threads = cpu_threads() if device.is_cpu else 1
    blocks = max(1, min(threads, num_worlds // MIN_WORLDS_PER_THREAD))
    bounds = [round(i * num_worlds / blocks) for i in range(blocks + 1)]
    return list(zip(bounds[:-1], bounds[1:]))


def run_blocks(fn, blocks):
    global _POOL
    if len(blocks) == 1:
        fn(*blocks[0])
        return
    if _POOL is None or _POOL._max_workers < len(blocks) - 1:
        _POOL = ThreadPoolExecutor(len(blocks) - 1)
    futures = [_POOL.submit(fn, lo, hi) for lo, hi in blocks[1:]]
    fn(*blocks[0])  # the calling thread takes the first block (one hand-off fewer)
    for future in futures:
        future.result()


def prepared(cmd):
    """A callable that runs the recorded warp launch ``cmd``.

    On CPU, ``Launch.launch()`` packs the kernel's ctypes argument struct field by field on every call
    (about 18 us for the substep kernel: more than the kernel itself for a few worlds, and 34 launches
    per differentiable env step). The arguments of a recorded launch never change, so pack them once,
    the way warp 1.19's ``invoke`` does, and call the compiled entry point directly. Anything else
    (CUDA, tiled CPU launches) keeps ``cmd.launch``.
    """
    try:  # warp internals (pinned to 1.19): anything unexpected falls back to the public call
        if not cmd.device.is_cpu or cmd.block_dim > 1:
            return cmd.launch
        params, labels = cmd.params, [arg.label for arg in cmd.kernel.adj.args]
        entry = cmd.hooks.backward if cmd.adjoint else cmd.hooks.forward
    except AttributeError:
        return cmd.launch

    def pack(offset):
        fields = [(name, type(params[offset + i])) for i, name in enumerate(labels)]
        struct = type("ArgsStruct", (ctypes.Structure,), {"_fields_": fields})()
        for i, (name, _) in enumerate(fields):
            setattr(struct, name, params[offset + i])
        return struct

    structs = [params[0], pack(1)] + ([pack(1 + len(labels))] if cmd.adjoint else [])
    refs = [ctypes.byref(x) for x in structs]

    def run():
        entry(*refs)

    run.structs = structs  # the packed arguments live as long as the callable
    return run


_TORCH_STREAMS: dict = {}  # (device, cuda stream handle) -> wp.Stream wrapping it


def launch_stream(device):
    """The warp stream to launch on so that work is ordered with torch's: torch's current CUDA stream
    (wrapped once per stream handle; no host synchronisation), or None on CPU."""
    if device.is_cpu:
        return None
    torch_stream = torch.cuda.current_stream(torch.device("cuda", device.ordinal))
    key = (device.ordinal, torch_stream.cuda_stream)
    stream = _TORCH_STREAMS.get(key)
    if stream is None:
        stream = _TORCH_STREAMS[key] = wp.Stream(device, cuda_stream=torch_stream.cuda_stream)
        stream._torch_stream = torch_stream  # keep torch's stream object alive with its wrapper
    return stream


def capture_graph(device, launches):
    """A graph of recorded warp launches (``wp.launch(..., record_cmd=True)``), for :func:`replay_graph`.
    On CUDA the capture runs on a stream of its own (the legacy default stream, torch's default, cannot
    be captured); the graph does not depend on it afterwards."""
    if device.is_cpu:
        with wp.ScopedCapture(device=device) as capture:
            for cmd in launches:
                cmd.launch()
        return capture.graph
    stream = wp.Stream(device)
    with wp.ScopedCapture(stream=stream) as capture:
        for cmd in launches:
            cmd.launch(stream)
    graph = capture.graph
    graph.capture_stream = stream
    return graph


def replay_graph(graph, device) -> None:
    """Replay a :func:`capture_graph` graph (on CUDA: on torch's current stream, asynchronously)."""
    wp.capture_launch(graph, stream=launch_stream(device))


class Trajectory:
    """Buffers and launches for one env step of ``sim.num_worlds`` worlds.

    A trajectory is reusable: its launches (forward, and the adjoint ones when ``save``) are recorded
    once, with every buffer bound, and replayed on each use, which keeps Python out of the per-step
    cost. The simulator pools taped trajectories and takes one back after its backward pass.
    """

    def __init__(self, sim, save: bool = True):
        n, s_count, z = sim.num_worlds, sim.substeps, sim._zeros
        self.sim, self.n, self.save = sim, n, save
        rows = (s_count + 1) * n
        # per-call results the reverse pass replays instead of recomputing (see _kernels.py); row = output
        # row of the substep. Left empty for gradient-free steps.
        k, scene = sim.kernels, sim.scene
        points = scene.num_hand_dofs * scene.points_per_link
        saved_rows = rows if save else 0
        self.saved = k.Saved()
        self.saved.finger = wp.empty((saved_rows, scene.num_fingers), dtype=k.vec7, device=sim.device)
        self.saved.contact = wp.empty((saved_rows, points), dtype=k.vecC, device=sim.device)
        self.saved.sdf = wp.empty((saved_rows, points), dtype=k.vec4, device=sim.device)
        self.saved.sdf_jac = wp.empty((saved_rows, points), dtype=k.mat43, device=sim.device)
        self.saved.law = wp.empty((saved_rows, points), dtype=k.mat43, device=sim.device)
        self.saved.inertia = wp.empty((saved_rows, scene.num_hand_dofs), dtype=k.matJJ1, device=sim.device)
        # state trajectories and the per-step inputs: tau, q_target, kp, kd, params, object_wrench
        self.q, self.qd, self.wrench, self.cforce = z(rows, sim.nq), z(rows, sim.nv), z(rows, 6), z(rows)
        self.controls = [z(n, sim.nu), z(n, sim.nu), z(n, sim.nu), z(n, sim.nu), z(n, sim.num_params), z(n, 6)]
        self.pose, self.tips = z(n, sim.num_bodies * 7), z(n, sim.scene.num_fingers * 3)
        self.graphs = bool(sim.graphs)
        self.blocks = [(0, n)] if self.graphs else world_blocks(n, sim.device)
        self.w_traj, self.w_acc, self.w_controls, self.w_final, self.w_obs = self._wrap(
            self.q, self.qd, self.wrench, self.cforce, self.controls, self.pose, self.tips)
        if self.graphs:
            self._forward_graph = capture_graph(sim.device, self._launches(0, n))
        else:
            self._forward_cmds = {lo: [prepared(c) for c in self._launches(lo, hi)] for lo, hi in self.blocks}
        self._reverse_cmds = None  # recorded at the first backward pass (a graph, or per-block calls)
        self.lease = 0  # bumped whenever the simulator's pool hands this trajectory out or takes it back

    def _wrap(self, q, qd, wrench, cforce, controls, pose, tips):
        last = self.sim.substeps * self.n
        return ([wp.from_torch(q), wp.from_torch(qd)], [wp.from_torch(wrench), wp.from_torch(cforce)],
                [wp.from_torch(t) for t in controls], [wp.from_torch(q[last:]), wp.from_torch(qd[last:])],
                [wp.from_torch(pose), wp.from_torch(tips)])

    def load(self, q, qd, controls) -> None:
        n = self.n
        with torch.no_grad():
            self.q[:n].copy_(q)
            self.qd[:n].copy_(qd)
            for buf, t in zip(self.controls, controls):
                buf.copy_(t)

    def _substep_args(self, s: int, lo: int):
        sim = self.sim
        return [sim.model, *self.w_traj, *self.w_controls, *self.w_acc, self.saved, lo, s * self.n,
                (s + 1) * self.n, sim.sub_dt, 1.0 / sim.substeps]

    def _launches(self, lo: int, hi: int, adjoint: bool = False):
        """The recorded launches of block [lo, hi): the substeps then the observation, or, with
        ``adjoint``, their adjoints in reverse order."""
        sim, dim = self.sim, hi - lo
        observe_args = [sim.model, *self.w_final, *self.w_obs, lo]
        if not adjoint:
            out = [wp.launch(sim.kernels.substep, dim=dim, inputs=self._substep_args(s, lo), device=sim.device,
                             record_cmd=True) for s in range(sim.substeps)]
            out.append(wp.launch(sim.kernels.observe, dim=dim, inputs=observe_args, device=sim.device,
                                 record_cmd=True))
            return out
        adj_traj, adj_acc, adj_controls, adj_final, adj_obs = self._adj_wrapped
        adj_model = sim.adjoint_model
        out = [wp.launch(sim.kernels.observe, dim=dim, inputs=observe_args, device=sim.device, adjoint=True,
                         adj_inputs=[adj_model, *adj_final, *adj_obs, 0], record_cmd=True)]
        for s in reversed(range(sim.substeps)):
            out.append(wp.launch(sim.kernels.substep, dim=dim, inputs=self._substep_args(s, lo), device=sim.device,
                                 adjoint=True, record_cmd=True,
                                 adj_inputs=[adj_model, *adj_traj, *adj_controls, *adj_acc, sim.kernels.Saved(),
                                             0, 0, 0, 0.0, 0.0]))
        return out

    def forward(self) -> None:
        if self.graphs:
            replay_graph(self._forward_graph, self.sim.device)
            return
        run_blocks(lambda lo, hi: [launch() for launch in self._forward_cmds[lo]], self.blocks)

    def outputs(self) -> list[torch.Tensor]:
        last, sim = self.sim.substeps * self.n, self.sim
        return [self.q[last:].clone(), self.qd[last:].clone(), self.wrench[last:].clone(), self.cforce[last:].clone(),
                self.pose.clone().view(-1, sim.num_bodies, 7), self.tips.clone().view(-1, sim.scene.num_fingers, 3)]

    def backward(self, grad_outputs, needed=None) -> list[torch.Tensor | None]:
        """Reverse pass: adjoints of (q, qd, wrench, contact_force, pose, tips) -> adjoints of
        (joint_q, joint_qd, tau, q_target, kp, kd, params, object_wrench); ``needed`` (8 flags, default
        all) marks the ones to return, the others come back as None."""
        if not self.save:
            raise RuntimeError("this trajectory was run without saving the reverse pass's intermediates")
        n, last = self.n, self.sim.substeps * self.n
        if self._reverse_cmds is None:
            # adjoints of the same buffers, views of one flat buffer zeroed before each reverse pass
            like = [self.q, self.qd, self.wrench, self.cforce, *self.controls, self.pose, self.tips]
            self._adj_flat = torch.zeros(sum(t.numel() for t in like), dtype=self.q.dtype, device=self.q.device)
            views = [v.view(t.shape) for v, t in zip(self._adj_flat.split([t.numel() for t in like]), like)]
            self.adj, self.adj_controls, self.adj_obs = views[:4], views[4:10], views[10:]
            self._adj_wrapped = self._wrap(*self.adj, self.adj_controls, *self.adj_obs)
            # zeroed by warp (one memset): torch would split a buffer this size over its OpenMP threads,
            # which then spin on the cores the warp blocks need (measured: reverse pass 4 -> 6.5 ms)
            self._w_adj_flat = wp.from_torch(self._adj_flat)
            if self.graphs:
                self._reverse_cmds = capture_graph(self.sim.device, self._launches(0, n, adjoint=True))
            else:
                self._reverse_cmds = {lo: [prepared(c) for c in self._launches(lo, hi, adjoint=True)]
                                      for lo, hi in self.blocks}
        if self.sim.device.is_cpu:
            self._w_adj_flat.zero_()
        else:  # on torch's stream, ordered with the copies below and the graph after them
            self._adj_flat.zero_()
        for target, g in zip(self.adj + self.adj_obs, grad_outputs):
            if g is not None:
                rows = target[last:] if target.shape[0] != n else target
                rows.copy_(g.reshape(rows.shape))
        if self.graphs:
            replay_graph(self._reverse_cmds, self.sim.device)
        else:
            run_blocks(lambda lo, hi: [launch() for launch in self._reverse_cmds[lo]], self.blocks)
        # views of the adjoint buffers, valid until the next reverse pass (SimStep copies them as it zeroes the
        # worlds whose gradient is not finite)
        grads = [self.adj[0][:n], self.adj[1][:n], *self.adj_controls]
        needed = [True] * len(grads) if needed is None else needed
        return [g if need else None for g, need in zip(grads, needed)]
