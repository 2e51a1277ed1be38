"""``dexmots-bench pipeline``: the env as torchrl sees it against the kernels, measured in one run.

Three env-steps/s figures per world count, from the same task env (``make_env(task)``, non-differentiable):

* ``kernel``: ``Simulator.step`` alone with the env's own control of a fixed action (no Python around it);
* ``rollout``: ``env.rollout(T)`` with a 64x64 tanh MLP actor (the env's transforms included);
* ``collector``: a stock torchrl ``Collector`` over the env with the baselines' observation normaliser
  (torchrl's ``VecNorm``, :class:`~dexmots_rl.algorithms.common.RunningObsNorm`) and the same actor,
  ``frames_per_batch = num_envs * T``.

``rollout_fraction`` and ``collector_fraction`` are those divided by ``kernel``: the share of the
simulator's speed a training loop keeps. torch runs with ``--torch-threads`` intra-op threads (1, as
``dexmots-train`` sets them on CPU): idle torch workers spin against the simulator's warp threads.
"""

from __future__ import annotations

import logging
import warnings

import torch

from .bench_setup import measure_rate

__all__ = ["run_pipeline"]

log = logging.getLogger(__name__)


def _actor(env):
    from tensordict.nn import TensorDictModule

    obs, act = env.observation_spec["observation"].shape[-1], env.action_spec.shape[-1]
    net = torch.nn.Sequential(torch.nn.Linear(obs, 64), torch.nn.Tanh(), torch.nn.Linear(64, 64), torch.nn.Tanh(),
                              torch.nn.Linear(64, act), torch.nn.Tanh())
    return TensorDictModule(net.to(env.device), in_keys=["observation"], out_keys=["action"])


def pipeline_row(task: str, num_envs: int, steps: int, min_time: float, device: str = "cpu") -> dict:
    from torchrl.collectors import Collector

    from ..algorithms.common import RunningObsNorm
    from ..envs import make_env

    env = make_env(task, num_envs=num_envs, differentiable=False, seed=0, device=device)
    actor = _actor(env)
    base = env.base_env
    sim = base.sim
    td = env.reset()
    with torch.no_grad():
        control = base.actions(actor(td)["action"])
        q, qd = td["sim", "joint_q"], td["sim", "joint_qd"]
        params = {name: td["sim", "params", name] for name in sim.scene.param_names}

        def kernel() -> int:
            for _ in range(steps):
                sim.step(q, qd, control, params)
            return steps * num_envs

        def rollout() -> int:
            env.rollout(steps, actor, break_when_any_done=False)
            return steps * num_envs

        for fn in (kernel, rollout):
            fn()
        sync = torch.cuda.synchronize if torch.device(device).type == "cuda" else (lambda: None)
        row = {"num_envs": num_envs, "kernel_steps_per_s": measure_rate(kernel, min_time, sync),
               "rollout_steps_per_s": measure_rate(rollout, min_time, sync)}
    normed = make_env(task, num_envs=num_envs, differentiable=False, seed=0, device=device)
    with warnings.catch_warnings():  # VecNorm's "experimental with a batch size", the collector's InitTracker note
        warnings.simplefilter("ignore")
        normed.append_transform(RunningObsNorm(in_keys=["observation"], reduce_batch_dims=True))
        collector = Collector(normed, _actor(normed), frames_per_batch=num_envs * steps, total_frames=-1)
    batches = iter(collector)
    next(batches)  # warm-up

    def collect() -> int:
        return next(batches).numel()

    row["collector_steps_per_s"] = measure_rate(collect, min_time, sync)
    collector.shutdown()
    row["rollout_fraction"] = row["rollout_steps_per_s"] / row["kernel_steps_per_s"]
    row["collector_fraction"] = row["collector_steps_per_s"] / row["kernel_steps_per_s"]
    log.info("pipeline %s %d worlds: %s", task, num_envs, row)
    return row


def run_pipeline(task: str, num_envs=(64, 256), steps: int = 50, min_time: float = 2.0, device: str = "cpu",
                 torch_threads: int | None = 1) -> dict:
    """Every row for ``task`` (see the module docstring). ``torch_threads``: torch's intra-op threads during
    the run (None: torch's default), as ``dexmots-train``'s ``torch_threads`` sets them."""
    previous = torch.get_num_threads()
    if torch_threads is not None:
        torch.set_num_threads(torch_threads)
    try:
        rows = [pipeline_row(task, n, steps, min_time, device) for n in num_envs]
    finally:
        torch.set_num_threads(previous)
    return {"task": task, "steps_per_chunk": steps, "torch_threads": torch.get_num_threads() if torch_threads is None
            else torch_threads, "rows": rows}
