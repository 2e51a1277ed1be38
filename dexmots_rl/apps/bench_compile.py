"""``dexmots-bench compile``: build every kernel of a task's scene ahead of time, for CUDA without a GPU.

    dexmots-bench compile --device cuda --arch 90 --task allegro_rotate
    dexmots-bench compile --device cuda --arch 90 --all [--dtypes float32 float64] [--jobs 4]
    dexmots-bench compile --device cuda --arch 0 --task screw_claw   # this machine's GPU: its own build

Each task's simulator kernels (the substep and the observation, forward and adjoint, specialised for its
scene and float type) and the renderer's are compiled into warp's kernel cache, PTX for ``--arch`` with
``--device cuda`` (what a GPU with that compute capability loads; no GPU or CUDA driver needed; ``--arch 0``:
the build this machine's GPU loads, compiled and loaded on it), the host build with ``--device cpu``. A
module compiles on one core, so ``--jobs`` compiles each (task, float type) in a process of its own. Tasks that share a scene share its modules, so those compile once. The JSON
result names every module with its seconds, whether it was already cached, and on failure the kernel and
the compiler's message; the command exits non-zero when any module failed.
"""

from __future__ import annotations

import concurrent.futures
import logging
import multiprocessing
import time

import torch

from ..envs import list_tasks, task_contact, task_scene

__all__ = ["DTYPES", "run_compile"]

log = logging.getLogger(__name__)

DTYPES = {"float32": torch.float32, "float64": torch.float64}


def compile_task(task: str, device: str = "cuda", arch: int | None = 90, dtypes=("float32",),
                 render: bool = True) -> dict:
    """Compile one task's kernels for each float type (``arch`` None: this machine's GPU) and, with
    ``render``, the renderer's; the result dict of one task."""
    from ..sim import compile_scene

    start = time.perf_counter()
    rows = compile_scene(task_scene(task), device=device, arch=arch, dtypes=[DTYPES[name] for name in dtypes],
                         contact=task_contact(task), render=render)
    for row in rows:
        if row["ok"]:
            log.info("%s %s %s: %.1f s%s", task, row["dtype"], row["kernel"], row["seconds"],
                     " (cached)" if row["cached"] else "")
        else:
            log.error("%s %s: kernel %s failed to compile for %s:\n%s", task, row["dtype"], row["kernel"],
                      device, row["error"])
    return {"task": task, "device": device, "arch": arch if device == "cuda" else None, "kernels": rows,
            "seconds": time.perf_counter() - start, "ok": all(r["ok"] for r in rows)}


def _compile_job(job: tuple) -> dict:
    logging.basicConfig(level=logging.WARNING)  # a worker process: failures still reach stderr
    return compile_task(*job)


def run_compile(tasks, device: str = "cuda", arch: int | None = 90, dtypes=("float32",), jobs: int = 1) -> dict:
    """Compile ``tasks`` (a task name, or a list of them); one task's result dict for a name, otherwise
    ``{"tasks": [...], "seconds", "ok"}``. ``jobs`` > 1: each (task, float type) in its own process."""
    names = [tasks] if isinstance(tasks, str) else list(tasks)
    unknown = [t for t in names if t not in list_tasks()]
    if unknown:
        raise ValueError(f"task {unknown[0]!r} is not registered; tasks: {', '.join(list_tasks())}")
    bad = [d for d in dtypes if d not in DTYPES]
    if bad:
        raise ValueError(f"dtypes: {bad[0]!r} is not one of {', '.join(DTYPES)}")
    arch = None if device == "cuda" and not arch else arch
    start = time.perf_counter()
    if jobs <= 1:
        results = [compile_task(t, device, arch, dtypes) for t in names]
    else:
        work = [(t, device, arch, (d,), i == 0) for t in names for i, d in enumerate(dtypes)]
        with concurrent.futures.ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
            parts = list(pool.map(_compile_job, work))
        results = []
        for t in names:  # one result per task, its float types' rows together
            mine = [p for p in parts if p["task"] == t]
            results.append(dict(mine[0], kernels=[r for p in mine for r in p["kernels"]],
                                seconds=max(p["seconds"] for p in mine), ok=all(p["ok"] for p in mine)))
    if isinstance(tasks, str):
        return results[0]
    return {"device": device, "arch": arch if device == "cuda" else None, "tasks": results,
            "seconds": time.perf_counter() - start, "ok": all(r["ok"] for r in results)}
