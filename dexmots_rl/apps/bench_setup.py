"""Per-task scenes and poses for the ``dexmots-bench`` benchmarks, and timing helpers.

A benchmark needs more than the env's MJCF: a pose from which closing the hand makes contact (for
throughput), a pose already touching the object and one far from it (for gradient checks), and the
action that squeezes the object. Each task module declares them (``DexEnv.bench``), or builds them for
its scene (``DexEnv.bench_poses``: ``operate`` and the tool tasks, from their pre-grasps; only the gradient
benchmark runs those).
"""

from __future__ import annotations

import time
from typing import Callable

import torch

from ..envs import BenchPoses, DexEnv, list_tasks, make_env, task_entry, task_scene

__all__ = ["bench_tasks", "grad_bench_tasks", "bench_task", "bench_env", "load_task_scene", "device_name",
           "measure_rate", "measure_rates", "train_one", "TRAIN_GOAL_SUCCESS"]


def bench_tasks() -> list[str]:
    """The registered tasks that declare bench poses."""
    return [name for name in list_tasks() if task_entry(name).env_class.bench is not None]


def grad_bench_tasks() -> list[str]:
    """The registered tasks the gradient benchmark runs: :func:`bench_tasks` and those whose env builds its
    bench poses for its scene (overrides ``DexEnv.bench_poses``)."""
    return [name for name in list_tasks() if task_entry(name).env_class.bench is not None
            or task_entry(name).env_class.bench_poses is not DexEnv.bench_poses]


def bench_env(task: str, **overrides) -> DexEnv:
    """A bare one-world env of ``task`` (config ``overrides``, e.g. ``object=``), without gradients: its
    ``bench_poses()``, ``sim.scene`` and ``sim.contact`` are what a benchmark simulates. Raises ``ValueError``
    naming the benchmarked tasks when the task has no bench poses."""
    if task not in grad_bench_tasks():
        task_entry(task)  # an unknown name: its own error, listing every task
        raise ValueError(f"task {task!r} declares no bench poses; benchmarked tasks: {', '.join(grad_bench_tasks())}")
    return make_env(task, num_envs=1, raw=True, differentiable=False, **overrides)


def bench_task(task: str) -> BenchPoses:
    """The task's :class:`~dexmots_rl.envs.BenchPoses`; raises ``ValueError`` naming the known tasks."""
    poses = task_entry(task).env_class.bench
    if poses is None:
        raise ValueError(f"task {task!r} declares no bench poses; benchmarked tasks: {', '.join(bench_tasks())}")
    return poses


def load_task_scene(task: str):
    """``(SceneModel, asset path)`` of a registered task's MJCF."""
    bench_task(task)
    return task_scene(task), task_entry(task).env_class.asset_path()


def device_name(device: str) -> str:
    """``"cpu"`` or the CUDA device's name."""
    dev = torch.device(device)
    if dev.type == "cuda":
        return torch.cuda.get_device_name(dev)
    return dev.type


def measure_rates(chunk: Callable[[], int], min_time: float,
                  sync: Callable[[], None] = lambda: None) -> tuple[float, float]:
    """Call ``chunk()`` (returns the env-steps it did) until ``min_time`` wall seconds passed; (env-steps per
    wall second, env-steps per CPU-second of this process, every thread counted)."""
    sync()
    steps, start, cpu_start = 0, time.perf_counter(), time.process_time()
    while True:
        steps += chunk()
        sync()
        elapsed = time.perf_counter() - start
        if elapsed >= min_time:
            return steps / elapsed, steps / max(time.process_time() - cpu_start, 1e-9)


def measure_rate(chunk: Callable[[], int], min_time: float, sync: Callable[[], None] = lambda: None) -> float:
    """Env-steps per wall second of :func:`measure_rates`."""
    return measure_rates(chunk, min_time, sync)[0]


TRAIN_GOAL_SUCCESS = 0.9  # the success rate dexmots-bench train reports against (paper: 92.6 +- 6.4 %)


def train_one(args, seed: int, run_dir: str | None) -> dict:
    """Train ``args.task`` with ``args.algo`` (dexmots-train's config plus ``args.overrides``) for one seed."""
    from hydra import compose, initialize_config_dir

    from .train import CONFIG_DIR, run as train

    run_dir = run_dir or f"runs/bench_{args.task}_{args.algo}_seed{seed}"
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose("config", overrides=[f"task={args.task}", f"algo={args.algo}", f"seed={seed}",
                                           f"device={args.device}", f"run_dir={run_dir}", "progress=false",
                                           *args.overrides])
    result = train(cfg)
    if "success_rate" not in result:  # a signal or stop_after ended it before its final evaluation
        at = f" at iteration {result['iteration']}" if "iteration" in result else ""
        why = result.get("interrupted", "stop_after")
        raise SystemExit(f"dexmots-bench: the training in {run_dir} stopped{at} before its evaluation ({why}; a "
                         f"checkpoint was saved); continue with: dexmots-train resume={run_dir}")
    return {"task": args.task, "algo": args.algo, "seed": seed, "success_rate": result["success_rate"],
            "wall_clock_s": result["train_wall_clock_s"], "env_steps": result["env_steps"],
            "mean_final_error": result.get("mean_final_error"), "goal_success_rate": TRAIN_GOAL_SUCCESS,
            "learning_curve": f"{run_dir}/metrics.jsonl"}
