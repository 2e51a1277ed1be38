"""Ahead-of-time compilation of a scene's kernels, for CUDA on a machine without a GPU.

Warp generates one source per module and compiles it with NVRTC (CUDA) or clang (CPU); a module's
generated code holds every kernel's forward and adjoint, so compiling it checks both. The artifacts
go to warp's kernel cache (``WARP_CACHE_PATH``, default ``~/.cache/warp/<version>``), so a second compile
of an unchanged module is a file check: PTX for a given compute capability (no GPU needed), or the build
this machine's CPU or GPU loads, compiled and loaded exactly as a run does (a run then finds it cached).

:func:`compile_kernels` compiles the modules of a :class:`~dexmots_rl.sim.Simulator`'s kernels (the
substep and the observation, specialised for its scene and float type), :func:`compile_renderer` and
:func:`compile_mesh_renderer` the renderers', :func:`compile_scene` all of a scene's; one row per module says how
long it took, whether the cache already had it, and, on failure, the compiler's message (NVRTC prints its log on
the process's stderr, which is captured at the file-descriptor level for the duration of the build).
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
import time

import torch
import warp as wp

__all__ = ["compile_scene", "compile_kernels", "compile_renderer", "compile_mesh_renderer", "simulator_kernels",
           "warp_versions"]


def warp_versions() -> dict:
    """warp's version and, where a CUDA driver is present, the driver's and warp's CUDA toolkit's."""
    def as_text(version):
        if not version:
            return None
        return ".".join(str(x) for x in version) if isinstance(version, tuple) else str(version)

    driver = wp.get_cuda_driver_version() if wp.is_cuda_available() else None
    return {"warp": wp.__version__, "cuda_driver": as_text(driver),
            "warp_cuda_toolkit": as_text(wp.get_cuda_toolkit_version())}


def simulator_kernels(sim) -> dict[str, object]:
    """Every warp kernel of a simulator's kernel namespaces (an articulated scene's hand kernels too), by
    attribute name (``substep``, ``observe``, ...)."""
    spaces = [sim.kernels] + sim.more_kernels
    return {name: value for space in spaces for name, value in vars(space).items() if isinstance(value, wp.Kernel)}


@contextlib.contextmanager
def _native_stderr(sink: list[str]):
    """Redirect file descriptor 2 (where NVRTC and clang print their logs) into ``sink[0]``."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            sink.append(tmp.read().decode("utf-8", errors="replace"))


def _compile_module(module, label: str, device: str, arch: int | None) -> dict:
    start = time.perf_counter()
    wall_start = time.time()
    log: list[str] = []
    row = {"kernel": label, "module": module.name}
    try:
        with _native_stderr(log):
            if device == "cuda" and arch is not None:
                paths = wp.compile_aot_module(module, arch=arch, use_ptx=True)
            else:  # this machine's CPU or GPU: built and loaded exactly as a run loads it (same cache entry)
                wp.load_module(module, device=device)
                paths = None
    except Exception as error:  # the compiler's failure, reported per kernel (the caller decides the exit code)
        message = "\n".join(part for part in (str(error), (log[0] if log else "").strip()) if part)
        row.update(seconds=time.perf_counter() - start, cached=False, ok=False, error=message)
        return row
    if paths is None:
        row.update(seconds=time.perf_counter() - start, cached=None, ok=True)
        return row
    artifact = paths[-1]
    row.update(seconds=time.perf_counter() - start, cached=os.path.getmtime(artifact) < wall_start, ok=True,
               artifact=str(artifact))
    return row


def _check_device(device: str) -> None:
    if device not in ("cuda", "cpu"):
        raise ValueError(f"device must be 'cuda' or 'cpu', got {device!r}")


def compile_kernels(sim, device: str = "cuda", arch: int | None = 90) -> list[dict]:
    """Compile the modules of ``sim``'s kernels for ``device`` (``"cuda"``: PTX for compute capability
    ``arch``, no GPU needed, or with ``arch=None`` this machine's GPU's own build; ``"cpu"``: the host
    build; both of these are loaded as a run loads them, so the run finds them in the cache). Returns one row per module: ``kernel`` (its
    kernels' names), ``module``, ``seconds``, ``cached``, ``ok``, and ``error`` (the exception and the
    compiler's log) or ``artifact`` (the compiled file)."""
    _check_device(device)
    modules: dict[int, tuple[object, list[str]]] = {}
    for name, kernel in simulator_kernels(sim).items():
        modules.setdefault(id(kernel.module), (kernel.module, []))[1].append(name)
    return [_compile_module(module, "+".join(names), device, arch if device == "cuda" else None)
            for module, names in modules.values()]


def compile_scene(scene, *, device: str = "cuda", arch: int | None = 90, dtypes=(torch.float32,), contact=None,
                  render: bool = True) -> list[dict]:
    """Compile the kernels that simulate ``scene`` (a :func:`~dexmots_rl.sim.load_scene` scene) in each float type
    of ``dtypes`` with the contact law ``contact`` and, with ``render``, the kernels of the renderer that draws it
    (:func:`~dexmots_rl.sim.make_renderer`'s); :func:`compile_kernels`' rows, each with its ``dtype``
    (``"float32"``...)."""
    from ._articulated_scene import ArticulatedScene
    from ._factory import make_simulator

    rows = []
    for dtype in dtypes:
        # a one-world CPU simulator builds the scene's kernel namespace (nothing is compiled or launched)
        sim = make_simulator(scene, num_worlds=1, device="cpu", dtype=dtype, contact=contact)
        name = str(dtype).removeprefix("torch.")
        rows += [dict(row, dtype=name) for row in compile_kernels(sim, device, arch)]
    if render:  # an articulated object's scene is drawn by the mesh renderer, the others by the analytic one
        compile_one = compile_mesh_renderer if isinstance(scene, ArticulatedScene) else compile_renderer
        rows.append(dict(compile_one(device, arch), dtype="float32"))
    return rows


def compile_renderer(device: str = "cuda", arch: int | None = 90) -> dict:
    """Compile the analytic renderer's kernels (one module, the same for every knob and cube scene); a row as
    :func:`compile_kernels`'s."""
    from . import _render_kernels as render_kernels

    return _compile_kernel_module(render_kernels, device, arch)


def compile_mesh_renderer(device: str = "cuda", arch: int | None = 90) -> dict:
    """Compile the mesh renderer's kernels (one module, the same for every articulated-object scene); a row as
    :func:`compile_kernels`'s."""
    from . import _render_mesh_kernels as render_mesh_kernels

    return _compile_kernel_module(render_mesh_kernels, device, arch)


def _compile_kernel_module(module, device: str, arch: int | None) -> dict:
    _check_device(device)
    names = [name for name, value in vars(module).items() if isinstance(value, wp.Kernel)]
    return _compile_module(wp.get_module(module.__name__), "+".join(names), device,
                           arch if device == "cuda" else None)
