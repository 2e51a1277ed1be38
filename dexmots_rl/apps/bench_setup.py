"""Per-task scenes and poses for the ``dexmots-bench`` benchmarks, and timing helpers.

A benchmark needs more than the env's MJCF: a pose from which closing the hand makes contact (for
throughput), a pose already touching the object and one far from it (for gradient checks), and the
action that squeezes the object. Each task module declares them (``DexEnv.bench``).
"""

from __future__ import annotations

import time
from typing import Callable

import torch

from ..envs import BenchPoses, list_tasks, task_entry, task_scene

__all__ = ["bench_tasks", "bench_task", "load_task_scene", "device_name", "measure_rate"]


def bench_tasks() -> list[str]:
    """The registered tasks that declare bench poses."""
    return [name for name in list_tasks() if task_entry(name).env_class.bench is not None]


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


def measure_rate(chunk: Callable[[], int], min_time: float, sync: Callable[[], None] = lambda: None) -> float:
    """Call ``chunk()`` (returns the env-steps it did) until ``min_time`` seconds passed; env-steps/s."""
    sync()
    steps, start = 0, time.perf_counter()
    while True:
        steps += chunk()
        sync()
        elapsed = time.perf_counter() - start
        if elapsed >= min_time:
            return steps / elapsed
