"""Buffers and recorded launches for one env step of an :class:`~dexmots_rl.sim._articulated.ArticulatedSimulator`.

As in sim/_stepper.py, every array of an :class:`ArticulatedTrajectory` holds the whole env step: row
``s * N + w`` is world ``w`` at substep ``s`` (the states have ``substeps + 1`` row blocks, the per-substep
intermediates ``substeps``). Each row is written by one launch of the step, so the arrays are allocated once,
the launches (and their adjoints, in reverse order) are recorded once with every buffer bound and replayed on
each use, and the reverse pass reads exactly what the forward one wrote, with no ``wp.Tape``. The only buffers
that need clearing before a step are the ones the contact kernels add into. Worlds are split into one block per
CPU core, each block's launches run in a thread of their own (:func:`~dexmots_rl.sim._stepper.run_blocks`); on a
GPU there is one block and each recorded launch replays through ``Launch.launch``.

The reverse pass is mostly the finger contact's adjoint; two things keep it small without changing a result:
the adjoint launch returns at once for a sphere that touched nothing in the forward pass (the forward launch
marks the others), and only each body's nearest geom is differentiated (_hand_kernels.py).
"""

from __future__ import annotations

import dataclasses

import torch
import warp as wp

from ._object_model import MAX_SAMPLES
from ._stepper import prepared, run_blocks, world_blocks

__all__ = ["ArticulatedTrajectory", "StepArrays"]

# the torch-visible buffers, by name: the state trajectories (hand, object), the running means over substeps (the
# hand's wrench on the object, its normal force), the step's inputs (tau, q_target, kp, kd, packed parameters,
# the wrench on each body), the observation, the mean generalised force on each part joint
TORCH_FIELDS = ("hq", "hqd", "oq", "oqd", "wrench", "normal", "tau", "q_target", "kp", "kd", "params", "ext",
                "pose", "tips", "joint_wrench")
CONTROL_FIELDS = TORCH_FIELDS[6:12]  # the step's inputs after the state, in Trajectory.load's order
# the warp-only buffers, by group (ArticulatedTrajectory.__init__ documents each)
WARP_GROUPS = ("frames", "links", "table", "hand", "total", "scratch", "solve", "final", "variant")


@dataclasses.dataclass
class StepArrays:
    """What one step's launches bind, by name: every torch buffer (:data:`TORCH_FIELDS`) as a warp array, and
    the warp-only groups (:data:`WARP_GROUPS`; ``variant`` a one-array group); the forward arrays, or their
    adjoints."""

    tensors: dict[str, wp.array]
    groups: dict[str, list]


class ArticulatedTrajectory:
    """One env step of ``sim.num_worlds`` worlds; ``save`` keeps the adjoint buffers and launches (recorded at
    the first :meth:`backward`). Reusable: :meth:`load` the inputs, :meth:`forward`, read :meth:`outputs`."""

    def __init__(self, sim, save: bool = True):
        self.sim, self.save = sim, save
        n, steps, z = sim.num_worlds, sim.substeps, sim._zeros
        self.n, self.steps = n, steps
        k, h, tree = sim.kernels, sim.hand_kernels, sim.tree
        fingers = sim.scene.num_fingers
        nu, nb, nparts = sim.nu, tree.num_bodies, max(tree.num_parts, 1)
        rows, sub_rows = (steps + 1) * n, steps * n
        # torch-visible buffers: the state trajectories (hand, object), the running means over substeps (the
        # hand's wrench on the object, its normal force, its generalised force on each joint), the step's inputs,
        # the observation
        # (rows: substeps + 1 row blocks of n worlds for the trajectories, n for the inputs and the observation)
        self.hq, self.hqd = z(rows, nu), z(rows, nu)  # rad, rad/s: the hand's joints
        self.oq, self.oqd = z(rows, tree.nq), z(rows, tree.nv)  # the object's coordinates (ObjectTree's layout)
        self.wrench, self.normal = z(rows, 6), z(rows)  # N, N m (world frame, about the base origin); N
        self.joint_wrench = z(rows, nparts)  # N m or N: along each part joint
        # tau (N m), q_target (rad), kp (N m/rad), kd (N m s/rad) [n, nu]; packed parameters [n, P]; wrench on
        # each object body [n, 6 B] (N, N m; the planner's acts on the base)
        self.controls = [z(n, nu), z(n, nu), z(n, nu), z(n, nu), z(n, sim.num_params), z(n, 6 * nb)]
        self.pose, self.tips = z(n, sim.num_bodies * 7), z(n, sim.scene.num_fingers * 3)  # m + wxyz; m
        self._torch = dict(zip(TORCH_FIELDS, [self.hq, self.hqd, self.oq, self.oqd, self.wrench, self.normal,
                                              *self.controls, self.pose, self.tips, self.joint_wrench]))

        def new(dtype, width, count=sub_rows):
            return wp.zeros((count, width), dtype=dtype, device=sim.device)

        # per-substep intermediates: frames (x, R, c, v, w), table contact (f, t, Kvv, Kvw, Kww), the fingers'
        # contact (gen, f, t, normal, which spheres touched), each body's total contact (f, t), the solve's scratch
        self.frames = [new(k.vec3, nb), new(k.mat33, nb), new(k.vec3, nb), new(k.vec3, nb), new(k.vec3, nb)]
        self.links = [new(k.vec3, nu), new(k.mat33, nu), new(k.vec3, nu)]  # each hand link's x, R, joint axis
        self.table = [new(k.vec3, nb), new(k.vec3, nb), new(k.mat33, nb), new(k.mat33, nb), new(k.mat33, nb)]
        self.hand = [new(k.dtype, nu), new(k.vec3, nb), new(k.vec3, nb),
                     wp.zeros(sub_rows, dtype=k.dtype, device=sim.device),
                     new(wp.int32, len(sim.scene.point_radius))]
        self.total = [new(k.vec3, nb), new(k.vec3, nb)]
        self.scratch = [new(k.vec3, nb), new(k.mat33, nb), new(k.vec3, nb), new(k.vec3, nb), new(k.vec3, nb),
                        new(k.vec3, nb), new(k.vec3, nparts), new(k.vec3, nparts)]
        # each finger's solve, kept for the reverse pass: (M + diag)^-1 and the joint accelerations
        self.solve = [new(h.matJ, fingers), new(h.vecJ, fingers)]
        self.final_frames = [new(k.vec3, nb, n), new(k.mat33, nb, n), new(k.vec3, nb, n), new(k.vec3, nb, n),
                             new(k.vec3, nb, n)]
        # each world's object variant this step (the packed parameters' last column with K > 1; else zeros)
        self.variant = torch.zeros(n, dtype=torch.int32, device=sim.torch_device)
        self._warp = dict(zip(WARP_GROUPS, [self.frames, self.links, self.table, self.hand, self.total, self.scratch,
                                            self.solve, self.final_frames, [wp.from_torch(self.variant)]]))
        self.accumulated = self.table + self.hand  # the contact kernels add into these
        self.blocks = world_blocks(n, sim.device)
        self._forward_cmds = {lo: self._launches(self._bind(), lo, hi) for lo, hi in self.blocks}
        self._reverse_cmds = None  # per block, the recorded adjoint launches (at the first backward)
        self._residual_buffers = []  # their hand_residual launches' outputs and seeds
        self._adj_torch_zeroed: list[wp.array] = []  # warp views of adj_torch
        self.adj_torch: dict[str, torch.Tensor] | None = None  # adjoints of _torch, by name (the simulator's)
        self.adj_warp: dict[str, list] | None = None  # adjoints of _warp, by group
        self.lease = 0  # bumped whenever the simulator's pool hands this trajectory out or takes it back

    def _bind(self, torch_arrays=None, warp_groups=None) -> StepArrays:
        """The arrays the launches read: :attr:`_torch` and :attr:`_warp` (or their adjoints), by name."""
        torch_arrays = self._torch if torch_arrays is None else torch_arrays
        warp_groups = self._warp if warp_groups is None else warp_groups
        return StepArrays({name: wp.from_torch(t) for name, t in torch_arrays.items()},
                          {name: list(group) for name, group in warp_groups.items()})

    def _launches(self, arrays, lo: int, hi: int, adjoint_arrays=None):
        """The launches of worlds [lo, hi), recorded and :func:`prepared`: the substeps then the observation's
        frames and observation, or, given ``adjoint_arrays`` (bound as ``arrays``), their adjoints in reverse."""
        sim, n, k, h = self.sim, self.n, self.sim.kernels, self.sim.hand_kernels
        dim, wdt = hi - lo, k.dtype
        dt, weight = wdt(sim.sub_dt), wdt(1.0 / self.steps)
        num_points = len(sim.scene.point_radius)
        num_links = sim.scene.num_fingers * sim.scene.joints_per_finger
        points_per_link = num_points // num_links
        # the finger contact's links per thread: on a CPU a world's all (a thread's entry costs, in the adjoint
        # launch most of all), on a GPU one (a thread each)
        links_per_thread = 1 if wp.get_device(sim.device).is_cuda else num_links

        def launches(a: StepArrays, model, hand_model, palm_model, only_touching):
            t, g = a.tensors, a.groups
            hq, hqd, oq, oqd = t["hq"], t["hqd"], t["oq"], t["oqd"]
            wrench, normal, joint_wrench, pose, tips = t["wrench"], t["normal"], t["joint_wrench"], t["pose"], t["tips"]
            frames, links, table, hand = g["frames"], g["links"], g["table"], g["hand"]
            total, scratch, solve, final = g["total"], g["scratch"], g["solve"], g["final"]
            variant = g["variant"][0][lo:hi]

            def rows(arr, s):  # substep s's rows of this block
                return arr[s * n + lo: s * n + hi]

            block = [t[name][lo:hi] for name in CONTROL_FIELDS]
            out = []
            for s in range(self.steps):
                fr, tb, lk = [rows(x, s) for x in frames], [rows(x, s) for x in table], [rows(x, s) for x in links]
                gen, hand_f, hand_t, step_normal, touching = [rows(x, s) for x in hand]
                state = [rows(x, s) for x in (hq, hqd, oq, oqd)]
                nxt = [rows(x, s + 1) for x in (hq, hqd, oq, oqd)]
                tot = [rows(x, s) for x in total]
                out.append((k.frames, dim, [model, variant, state[2], state[3], *fr]))
                out.append((h.link_frames, (dim, sim.scene.num_fingers), [hand_model, state[0], *lk]))
                if k.table:
                    out.append((k.table_contact, (dim, sim.tree.num_bodies),
                                [model, variant, block[4], k.table_mu_col, *fr, dt, MAX_SAMPLES, *tb]))
                if sim.palm_kernels is not None:  # the palm's push adds to the table's
                    out.append((sim.palm_kernels.palm_contact, (dim, sim.tree.num_bodies),
                                [palm_model, variant, block[4], -1, *fr, dt, MAX_SAMPLES, *tb]))  # its own mu
                out.append((h.finger_contact, (dim, num_links // links_per_thread),
                            [hand_model, variant, block[4], state[1], *lk, *fr, gen, hand_f, hand_t, step_normal,
                             touching,
                             only_touching, points_per_link, links_per_thread, dt]))
                out.append((k.sum_contacts, dim, [model, variant, tb[0], tb[1], hand_f, hand_t, fr[0], fr[1], fr[2],
                                                  rows(wrench, s), rows(normal, s), rows(joint_wrench, s),
                                                  step_normal, weight, *tot, rows(wrench, s + 1),
                                                  rows(normal, s + 1), rows(joint_wrench, s + 1)]))
                out.append((k.substep, dim, [model, variant, state[2], state[3], block[4], block[5], *tot, *tb[2:], dt,
                                             *[rows(x, s) for x in scratch], nxt[2], nxt[3]]))
                out.append((h.hand_substep, (dim, sim.scene.num_fingers),
                            [hand_model, state[0], state[1], *block[:4], gen, *lk, dt, nxt[0], nxt[1],
                             *[rows(x, s) for x in solve]]))
            last = [rows(x, self.steps) for x in (hq, oq, oqd)]
            fin = [x[lo:hi] for x in final]
            out.append((k.frames, dim, [model, variant, last[1], last[2], *fin]))
            out.append((h.observe, dim, [hand_model, last[0], fin[0], fin[1], pose[lo:hi], tips[lo:hi]]))
            return out

        if adjoint_arrays is None:
            plan = launches(arrays, sim.model, sim.hand_model, sim.palm_model, 0)
            self.kernel_names = [kernel.func.__name__ for kernel, _, _ in plan]  # the launches' (the adjoints':
            # reversed), for a per-kernel profile (benchmarks/articulated_kernels.py)
            return [prepared(wp.launch(kernel, dim=d, inputs=args, device=sim.device, record_cmd=True))
                    for kernel, d, args in plan]
        # the finger contact's adjoint skips the spheres that touched nothing (their adjoint is zero: most of
        # them, and most of the reverse pass's time otherwise)
        forward = launches(arrays, sim.model, sim.hand_model, sim.palm_model, 1)
        palm_adjoint = None if sim.palm_kernels is None else sim.palm_kernels.Model()
        adjoint = launches(adjoint_arrays, k.Model(), h.Model(), palm_adjoint, 0)  # null model adjoints
        # the hand's solve has no generated adjoint: hand_residual's gradient (seeded with ones) is its adjoint,
        # from its inputs, its saved solve and the adjoints of its outputs (read as values)
        # (kept by the trajectory: a recorded launch holds its arrays' addresses, not the arrays)
        residual = wp.zeros((dim, sim.scene.num_fingers), dtype=wdt, device=sim.device)
        seed = wp.full((dim, sim.scene.num_fingers), wdt(1.0), dtype=wdt, device=sim.device)
        self._residual_buffers.extend([residual, seed])
        cmds = []
        for (kernel, d, args), (_, _, adj_args) in zip(reversed(forward), reversed(adjoint)):
            adj_args = [x if isinstance(x, wp.array) or hasattr(x, "_cls") else type(x)(0) for x in adj_args]
            if kernel is h.hand_substep:
                (inputs, _, solved), (adj_inputs, adj_outputs, adj_solved) = (
                    (a[:12], a[12:14], a[14:]) for a in (args, adj_args))
                kernel = h.hand_residual
                args = [*inputs, *solved, *adj_outputs, residual]
                adj_args = [*adj_inputs, *adj_solved, *adj_outputs, seed]
            cmds.append(wp.launch(kernel, dim=d, inputs=args, adj_inputs=adj_args, adjoint=True, device=sim.device,
                                  record_cmd=True))
        return [prepared(cmd) for cmd in cmds]

    def load(self, q, qd, controls) -> None:
        """The step's inputs: ``q``, ``qd`` and (tau, q_target, kp, kd, packed params, object wrench)."""
        n, nu = self.n, self.sim.nu
        with torch.no_grad():
            self.hq[:n].copy_(q[:, :nu])
            self.oq[:n].copy_(q[:, nu:])
            self.hqd[:n].copy_(qd[:, :nu])
            self.oqd[:n].copy_(qd[:, nu:])
            for buf, t in zip(self.controls[:5], controls[:5]):
                buf.copy_(t)
            self.controls[5][:, :6].copy_(controls[5])  # the planner's wrench acts on the base; the parts get none
            if self.sim.num_variants > 1:  # "variant" is the last packed parameter (ArticulatedScene.param_names)
                self.variant.copy_(controls[4][:, -1].round())
        for arr in self.accumulated:
            arr.zero_()

    def forward(self) -> None:
        run_blocks(lambda lo, hi: [launch() for launch in self._forward_cmds[lo]], self.blocks)

    def outputs(self) -> list[torch.Tensor]:
        """(q, qd, wrench, contact force, pose, tips, joint wrench): :class:`~dexmots_rl.sim._articulated.
        ArticulatedStepOutput`."""
        last, sim = self.steps * self.n, self.sim
        return [torch.cat([self.hq[last:], self.oq[last:]], 1), torch.cat([self.hqd[last:], self.oqd[last:]], 1),
                self.wrench[last:].clone(), self.normal[last:].clone(),
                self.pose.clone().view(-1, sim.num_bodies, 7), self.tips.clone().view(-1, sim.scene.num_fingers, 3),
                self.joint_wrench[last:, :sim.tree.num_parts].clone()]

    def backward(self, grad_outputs, needed=None) -> list[torch.Tensor]:
        """Adjoints of (q, qd, wrench, contact force, pose, tips, joint wrench) -> adjoints of (joint_q,
        joint_qd, tau, q_target, kp, kd, packed params, object wrench). ``needed`` (which inputs need a gradient;
        the knob stepper's protocol, see :class:`~dexmots_rl.sim.SimStep`) is not used: every adjoint comes at
        once."""
        if not self.save:
            raise RuntimeError("this trajectory was run without its adjoint buffers")
        n, nu, last = self.n, self.sim.nu, self.steps * self.n
        if self._reverse_cmds is None:
            # one set of adjoint buffers serves every trajectory of the simulator (reverse passes run one at a
            # time, each zeroes them first), so a pool of N steps in flight holds N + 1 sets of buffers, not 2 N
            shared = self.sim._adjoint_buffers
            if shared is None:
                shared = ({name: torch.zeros_like(t) for name, t in self._torch.items()},
                          {name: [wp.zeros_like(a) for a in group] for name, group in self._warp.items()})
                self.sim._adjoint_buffers = shared
            self.adj_torch, self.adj_warp = shared
            # zeroed by warp (a memset each): torch splits a buffer this size over its OpenMP threads, which then
            # spin on the cores the warp blocks need (as sim/_stepper.py's)
            self._adj_torch_zeroed = [wp.from_torch(t) for t in self.adj_torch.values()]
            adjoint = self._bind(self.adj_torch, self.adj_warp)
            self._reverse_cmds = {lo: self._launches(self._bind(), lo, hi, adjoint) for lo, hi in self.blocks}
        if wp.get_device(self.sim.device).is_cpu:
            for a in self._adj_torch_zeroed:
                a.zero_()
        else:  # on torch's stream, ordered with the copies below
            for t in self.adj_torch.values():
                t.zero_()
        for group in self.adj_warp.values():
            for a in group:
                a.zero_()
        adj = self.adj_torch
        a_hq, a_hqd, a_oq, a_oqd, a_wrench, a_normal = (adj[name] for name in TORCH_FIELDS[:6])
        a_pose, a_tips, a_joint_wrench = adj["pose"], adj["tips"], adj["joint_wrench"]
        q_grad, qd_grad, wrench_grad, normal_grad, pose_grad, tips_grad, joint_wrench_grad = grad_outputs
        if q_grad is not None:
            a_hq[last:].copy_(q_grad[:, :nu])
            a_oq[last:].copy_(q_grad[:, nu:])
        if qd_grad is not None:
            a_hqd[last:].copy_(qd_grad[:, :nu])
            a_oqd[last:].copy_(qd_grad[:, nu:])
        parts = self.sim.tree.num_parts
        for target, g in ((a_wrench[last:], wrench_grad), (a_normal[last:], normal_grad), (a_pose, pose_grad),
                          (a_tips, tips_grad), (a_joint_wrench[last:, :parts], joint_wrench_grad)):
            if g is not None:
                target.copy_(g.reshape(target.shape))
        run_blocks(lambda lo, hi: [launch() for launch in self._reverse_cmds[lo]], self.blocks)
        controls = [adj[name] for name in CONTROL_FIELDS]
        return [torch.cat([a_hq[:n], a_oq[:n]], 1), torch.cat([a_hqd[:n], a_oqd[:n]], 1),
                *[c.clone() for c in controls[:5]], controls[5][:, :6].clone()]
