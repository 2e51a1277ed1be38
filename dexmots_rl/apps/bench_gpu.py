"""``dexmots-bench gpu``: every figure of the library on one GPU, in one run, into one JSON file.

    dexmots-bench gpu --out gpu_check.json                      # defaults sized for one H100/H200, < 8 min
    dexmots-bench gpu --device cpu --num-envs 2 --rgb-envs 2 --train-seconds 2 ...   # the same run, tiny (tests)

In order, each section timed (``seconds``) and written to the JSON file as soon as it is done (a run
cut short keeps what it measured):

1. ``machine``: GPU, driver, CUDA, warp and torch versions, CPU, cores, commit, date, command.
2. ``compile``: every kernel the run needs, built in parallel (one process per task and float type; a
   module compiles on one core), so the sections below find them cached.
3. ``throughput``: env-steps/s of the simulator (``fwd``, ``fwdbwd``, taped forward / reverse ms) on each
   ``--tasks`` at each ``--num-envs`` (:mod:`.bench_throughput`, without MuJoCo), the RGB 64x64 rows at
   ``--rgb-envs``, and the torchrl env rollout and Collector (:mod:`.bench_pipeline`) at each ``--num-envs``.
4. ``grad``: AD against central finite differences in float64 on the device (:mod:`.bench_grad`,
   screw_claw, ``--grad-horizon``).
5. ``agreement``: the CPU and the device step the same worlds with the same actions for ``--agree-steps``
   env steps, in float64; the largest joint-state difference at a few steps and at the end.
6. ``train``: screw_claw with AHAC at ``--train-envs`` worlds for ``--train-seconds`` of training, then its
   evaluation (dexmots-train's defaults otherwise; :func:`.bench_setup.train_one`).
"""

from __future__ import annotations

import concurrent.futures
import logging
import os
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import torch

from ..atomic import atomic_write_json
from ..provenance import provenance
from .bench_setup import bench_task, device_name, load_task_scene, train_one

__all__ = ["GOALS", "GPU_TASKS", "machine_info", "run_agreement", "run_gpu_check"]

log = logging.getLogger(__name__)

# the tasks the throughput and pipeline sections run by default: the knob and cube scenes and a tool scene
GPU_TASKS = ("screw_claw", "allegro_rotate", "repose_cube", "spray_bottle")
# the figures the run is judged against on one H100/H200 (benchmarks, not tests): env-steps/s at 16,384 worlds
GOALS = {"screw_claw_fwd_steps_per_s": 400_000, "allegro_rotate_fwd_steps_per_s": 100_000,
         "spray_bottle_fwd_steps_per_s": 500_000, "fwdbwd_over_fwd": 0.25, "rgb_steps_per_s": 9_000,
         "ahac_screw_claw_success": 0.9}
AGREE_TOLERANCE = 1e-6  # largest |q_cpu - q_device| (rad, m) after the rollout, float64


def machine_info(device: str) -> dict:
    """Versions and hardware of this run (GPU name, driver and CUDA versions on a CUDA device)."""
    from ..sim import warp_versions

    info = {"device": device_name(device), "torch": torch.__version__, "torch_cuda": torch.version.cuda,
            **warp_versions(), **provenance(),
            "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]])}
    if torch.device(device).type == "cuda":
        props = torch.cuda.get_device_properties(torch.device(device))
        info.update(gpu_memory_gib=props.total_memory / 2**30, compute_capability=f"{props.major}.{props.minor}")
    return info


def run_agreement(task: str = "screw_claw", device: str = "cuda", steps: int = 100, num_envs: int = 16,
                  seed: int = 0) -> dict:
    """Step the same worlds on the CPU and on ``device`` (float64, the task's open pose, the closing action
    plus uniform noise drawn on the CPU) and compare the joint states: the largest absolute difference
    after 1, 10 and every ``steps`` steps."""
    from ..sim import Control, make_simulator
    from ..envs import task_contact

    setup, (scene, _) = bench_task(task), load_task_scene(task)
    generator = torch.Generator().manual_seed(seed)
    nu = scene.num_hand_dofs
    noise = 0.2 * (2 * torch.rand(steps, num_envs, nu, generator=generator, dtype=torch.float64) - 1)
    gear = torch.as_tensor(scene.actuator_gear, dtype=torch.float64)
    torques = (torch.tensor(setup.close_action, dtype=torch.float64) + noise).clamp(-1, 1) * gear
    trajectories = []
    for dev in ("cpu", device):
        sim = make_simulator(scene, num_worlds=num_envs, device=dev, dtype=torch.float64, contact=task_contact(task))
        opts = dict(dtype=torch.float64, device=sim.torch_device)
        q = torch.tensor(setup.open_q, **opts).expand(num_envs, sim.nq).contiguous()
        qd = torch.zeros(num_envs, sim.nv, **opts)
        zero, params, states = torch.zeros(num_envs, nu, **opts), sim.default_params(), []
        for tau in torques.to(sim.torch_device):
            out = sim.step(q, qd, Control(tau, zero, zero, zero), params)
            q, qd = out.joint_q, out.joint_qd
            states.append(torch.cat([q, qd], -1))
        trajectories.append(torch.stack(states).cpu())  # one copy at the end, not one per step
    diff = (trajectories[0] - trajectories[1]).abs().amax((1, 2))  # [steps]
    at = sorted({1, min(10, steps), steps})
    return {"task": task, "device": device_name(device), "dtype": "float64", "num_envs": num_envs, "steps": steps,
            "max_abs_diff_at_step": {str(s): float(diff[s - 1]) for s in at}, "max_abs_diff": float(diff.max()),
            "tolerance": AGREE_TOLERANCE, "agree": bool(diff.max() <= AGREE_TOLERANCE)}


class _Report:
    """The result dict, rewritten to ``path`` after every section (a run cut short keeps what it measured)."""

    def __init__(self, path: str | None):
        self.path, self.data = (Path(path) if path else None), {}

    def section(self, name: str, fn):
        start = time.perf_counter()
        log.info("gpu check: %s", name)
        value = fn()
        self.data[name] = value
        self.data.setdefault("seconds", {})[name] = time.perf_counter() - start
        if self.path is not None:
            atomic_write_json(self.path, self.data, indent=1)
        return value


def _goals(data: dict) -> dict:
    def fwd(task, key="fwd_steps_per_s", obs="state"):
        rows = [r for t in data.get("throughput", []) if t["task"] == task and t["obs"] == obs for r in t["rows"]]
        return max(rows, key=lambda r: r["num_envs"])[key] if rows else None

    met = {}
    for task in ("screw_claw", "allegro_rotate", "spray_bottle"):
        value = fwd(task)
        if value is not None:
            met[f"{task}_fwd_steps_per_s"] = value >= GOALS[f"{task}_fwd_steps_per_s"]
            met[f"{task}_fwdbwd_over_fwd"] = fwd(task, "fwdbwd_steps_per_s") / value >= GOALS["fwdbwd_over_fwd"]
    rgb = [r["fwd_steps_per_s"] for t in data.get("throughput", []) if t["obs"] == "rgb" for r in t["rows"]]
    if rgb:
        met["rgb_steps_per_s"] = min(rgb) >= GOALS["rgb_steps_per_s"]
    if "train" in data:
        met["ahac_screw_claw_success"] = data["train"]["success_rate"] >= GOALS["ahac_screw_claw_success"]
    return met


def run_gpu_check(device: str = "cuda", tasks=GPU_TASKS,
                  num_envs=(1024, 4096, 16384), rgb_envs: int = 4096, min_time: float = 0.5,
                  pipeline_steps: int = 32, grad_horizon: int = 8, grad_draws: int = 4, agree_steps: int = 100,
                  agree_envs: int = 16, train_envs: int = 1024, train_seconds: float = 180.0,
                  train_overrides=(), eval_episodes: int = 100, compile_jobs: int | None = None,
                  run_dir: str = "runs/gpu_check", out: str | None = "gpu_check.json") -> dict:
    """The whole check (see the module docstring); returns the dict also written to ``out``."""
    from ..sim import check_device
    from .bench_compile import run_compile
    from .bench_grad import run_grad
    from .bench_pipeline import run_pipeline
    from .bench_throughput import run_throughput

    check_device(device)
    report = _Report(out)
    report.section("machine", lambda: machine_info(device))
    cuda = torch.device(device).type == "cuda"
    jobs = compile_jobs or min(8, os.cpu_count() or 1)
    need = list(dict.fromkeys([*tasks, "screw_claw"]))
    # the device's float32 kernels of every task, its float64 ones of the claw (grad, agreement), the CPU's
    # float64 claw (agreement): all compiled side by side, each (task, float type) in a process of its own
    target, arch = ("cuda", 0) if cuda else ("cpu", None)
    batches = [(need, target, arch, ("float32",), jobs), (["screw_claw"], target, arch, ("float64",), jobs)]
    if cuda:
        batches.append((["screw_claw"], "cpu", None, ("float64",), jobs))

    def compile_all():
        if jobs <= 1:
            return [run_compile(*batch) for batch in batches]
        with concurrent.futures.ThreadPoolExecutor(len(batches)) as pool:  # each batch runs its own processes
            return list(pool.map(lambda batch: run_compile(*batch), batches))

    report.section("compile", compile_all)

    def throughput():
        rows = [run_throughput(t, list(num_envs), device, min_time=min_time, mujoco=False) for t in tasks]
        rows += [run_throughput(t, [rgb_envs], device, min_time=min_time, obs="rgb", mujoco=False) for t in tasks]
        return rows

    report.section("throughput", throughput)
    report.section("pipeline", lambda: [run_pipeline(t, list(num_envs), pipeline_steps, min_time, device, None)
                                        for t in tasks])
    report.section("grad", lambda: run_grad("screw_claw", [grad_horizon], device=device, draws=grad_draws))
    report.section("agreement", lambda: run_agreement("screw_claw", device, agree_steps, agree_envs))
    args = SimpleNamespace(task="screw_claw", algo="ahac", device=device, overrides=[
        f"task.num_envs={train_envs}", f"budget.wall_clock_s={train_seconds}",
        f"eval.episodes={eval_episodes}", "overwrite=true", *train_overrides])
    report.section("train", lambda: train_one(args, 0, run_dir))
    report.data["goals"], report.data["goals_met"] = dict(GOALS), _goals(report.data)
    if report.path is not None:
        atomic_write_json(report.path, report.data, indent=1)
    return report.data
