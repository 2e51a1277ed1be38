"""``dexmots-bench compile``: build every kernel of a task's scene ahead of time, for CUDA without a GPU.

    dexmots-bench compile --device cuda --arch 90 --task allegro_rotate
    dexmots-bench compile --device cuda --arch 90 --all [--dtypes float32 float64]

Each task's simulator kernels (the substep and the observation, forward and adjoint, specialised for its
scene and float type) and the renderer's are compiled into warp's kernel cache, PTX for ``--arch`` with
``--device cuda`` (what a GPU with that compute capability loads; no GPU or CUDA driver needed), the host
build with ``--device cpu``. Tasks that share a scene share its modules, so those compile once. The JSON
result names every module with its seconds, whether it was already cached, and on failure the kernel and
the compiler's message; the command exits non-zero when any module failed.
"""

from __future__ import annotations

import logging
import time

import torch

from ..envs import list_tasks, task_contact, task_scene

__all__ = ["DTYPES", "run_compile"]

log = logging.getLogger(__name__)

DTYPES = {"float32": torch.float32, "float64": torch.float64}


def compile_task(task: str, device: str = "cuda", arch: int = 90, dtypes=("float32",)) -> dict:
    """Compile one task's kernels for each float type; the result dict of one task."""
    from ..sim import Simulator
    from ..sim.aot import compile_kernels, compile_renderer

    start = time.perf_counter()
    scene, law = task_scene(task), task_contact(task)
    rows = []
    for name in dtypes:
        if name not in DTYPES:
            raise ValueError(f"dtypes: {name!r} is not one of {', '.join(DTYPES)}")
        # a one-world CPU simulator builds the task's kernel namespace (nothing is compiled or launched)
        sim = Simulator(scene, 1, device="cpu", dtype=DTYPES[name], contact=law)
        rows += [dict(row, dtype=name) for row in compile_kernels(sim, device, arch)]
    rows.append(dict(compile_renderer(device, arch), dtype="float32"))
    for row in rows:
        if row["ok"]:
            log.info("%s %s %s: %.1f s%s", task, row["dtype"], row["kernel"], row["seconds"],
                     " (cached)" if row["cached"] else "")
        else:
            log.error("%s %s: kernel %s failed to compile for %s:\n%s", task, row["dtype"], row["kernel"],
                      device, row["error"])
    return {"task": task, "device": device, "arch": arch if device == "cuda" else None, "kernels": rows,
            "seconds": time.perf_counter() - start, "ok": all(r["ok"] for r in rows)}


def run_compile(tasks, device: str = "cuda", arch: int = 90, dtypes=("float32",)) -> dict:
    """Compile ``tasks`` (a task name, or a list of them); one task's result dict for a name, otherwise
    ``{"tasks": [...], "seconds", "ok"}``."""
    if isinstance(tasks, str):
        return compile_task(tasks, device, arch, dtypes)
    unknown = [t for t in tasks if t not in list_tasks()]
    if unknown:
        raise ValueError(f"task {unknown[0]!r} is not registered; tasks: {', '.join(list_tasks())}")
    start = time.perf_counter()
    results = [compile_task(t, device, arch, dtypes) for t in tasks]
    return {"device": device, "arch": arch if device == "cuda" else None, "tasks": results,
            "seconds": time.perf_counter() - start, "ok": all(r["ok"] for r in results)}
