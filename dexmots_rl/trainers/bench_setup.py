"""Per-task scenes, poses and controls shared by the ``dexmots-bench`` benchmarks.

A benchmark needs more than the env's MJCF: a pose from which closing the hand makes contact (for
throughput), a pose already touching the object and one far from it (for gradient checks), and the
action that squeezes the object. They are written down here, per task, in the MJCF's joint order.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Callable

import torch

from ..envs.screw_claw import INITIAL_POSES as SCREW_CLAW_POSES

__all__ = ["BenchTask", "BENCH_TASKS", "bench_task", "load_task_scene", "device_name", "measure_rate"]


@dataclasses.dataclass(frozen=True)
class BenchTask:
    """Poses and actions (hand dofs then object q; actions in [-1, 1] per actuator) for one task."""

    open_q: tuple[float, ...]  # hand open, not touching; closing from here makes contact
    close_action: tuple[float, ...]  # strong closing action used from ``open_q`` (throughput)
    touch_q: tuple[float, ...]  # fingers already on the object (gradients with contact)
    free_q: tuple[float, ...]  # fingers far from the object (gradients without contact)
    squeeze_action: tuple[float, ...]  # moderate closing action that keeps ``touch_q`` in contact


# screw_claw joint order: right proximal, right distal, left proximal, left distal, knob angle.
# Closing is negative on the right finger and positive on the left (see the MJCF joint ranges).
BENCH_TASKS: dict[str, BenchTask] = {
    "screw_claw": BenchTask(
        open_q=(1.047, 0.0, -1.047, 0.0, 0.0),
        close_action=(-1.0, -0.5, 1.0, 0.5),
        touch_q=(*SCREW_CLAW_POSES["grasp"], 0.0),  # the env's grasp start: resting on the knob (~6 N)
        free_q=(1.2, -0.5, -1.2, 0.5, 0.0),
        squeeze_action=(-0.5, -0.5, 0.5, 0.5),
    ),
}


def bench_task(task: str) -> BenchTask:
    """The :class:`BenchTask` for ``task``; raises ``ValueError`` naming the known tasks."""
    if task not in BENCH_TASKS:
        raise ValueError(f"no benchmark set-up for task {task!r}; known: {', '.join(sorted(BENCH_TASKS))}")
    return BENCH_TASKS[task]


def load_task_scene(task: str):
    """``(SceneModel, asset path)`` of a registered task's MJCF."""
    from ..assets import asset_path
    from ..envs import TASKS
    from ..sim import load_scene

    bench_task(task)
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; known tasks: {', '.join(sorted(TASKS))}")
    path = asset_path(TASKS[task].asset)
    return load_scene(path), path


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
