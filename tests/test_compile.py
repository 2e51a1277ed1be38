"""dexmots-bench compile: kernels built ahead of time for CUDA on a machine without a GPU, and a failure
reported with the kernel's name and the compiler's message."""

from __future__ import annotations

import json
import os

import pytest

from dexmots_rl.apps import bench
from dexmots_rl.apps.bench_compile import run_compile


@pytest.mark.slow  # CUDA code generation of the renderer (CI also builds the scenes' kernels for CUDA)
def test_renderer_compiles_to_ptx_without_a_gpu():
    from dexmots_rl.sim._aot import compile_renderer

    row = compile_renderer("cuda", arch=90)
    assert row["ok"], row.get("error")
    assert row["artifact"].endswith(".sm90.ptx") and os.path.getsize(row["artifact"]) > 0
    assert "render_kernel" in row["kernel"]
    again = compile_renderer("cuda", arch=90)  # the cache answers the second time
    assert again["cached"] and again["artifact"] == row["artifact"]


def test_a_failing_compile_names_the_kernel_and_the_compiler_message(monkeypatch, capsys):
    import warp as wp

    def broken(module, **kwargs):
        os.write(2, b"kernel.cu(12): error: identifier \"oops\" is undefined\n")
        raise RuntimeError("CUDA kernel build failed with error code 6")

    monkeypatch.setattr(wp, "compile_aot_module", broken)
    result = run_compile("screw_claw", "cuda", 90)
    assert result["ok"] is False
    failed = [row for row in result["kernels"] if not row["ok"]]
    assert {row["kernel"] for row in failed} >= {"substep", "observe"}
    for row in failed:
        assert "error code 6" in row["error"] and 'identifier "oops" is undefined' in row["error"]
    with pytest.raises(SystemExit) as exit_info:
        bench.main(["compile", "--task", "screw_claw", "--device", "cuda", "--quiet"])
    assert exit_info.value.code == 1
    printed = json.loads(capsys.readouterr().out)
    assert printed["task"] == "screw_claw" and printed["ok"] is False


@pytest.mark.slow  # two fresh processes
def test_several_tasks_compile_side_by_side_into_one_result():
    result = bench.run(["compile", "--device", "cpu", "--task", "screw_claw", "screw_claw", "--jobs", "2", "--quiet"])
    assert result["ok"] and [t["task"] for t in result["tasks"]] == ["screw_claw", "screw_claw"]
    for task in result["tasks"]:
        assert {r["kernel"] for r in task["kernels"]} >= {"substep", "observe"}


def test_compile_rejects_an_unknown_task():
    with pytest.raises(ValueError, match="not registered"):
        run_compile(["screw_claw", "no_such_task"], "cuda", 90)
    with pytest.raises(SystemExit):
        bench.build_parser().parse_args(["compile", "--task", "no_such_task"])


def test_compile_all_builds_every_registered_task_into_one_result(monkeypatch):
    from dexmots_rl.apps import bench_compile
    from dexmots_rl.envs import list_tasks

    seen = []

    def one_task(task, device, arch, dtypes, render=True):  # what compile_task returns, without compiling
        seen.append((task, device, arch, tuple(dtypes)))
        return {"task": task, "device": device, "arch": arch, "kernels": [], "seconds": 0.0, "ok": True}

    monkeypatch.setattr(bench_compile, "compile_task", one_task)
    result = bench.run(["compile", "--all", "--device", "cuda", "--arch", "90", "--quiet"])
    assert seen == [(task, "cuda", 90, ("float32",)) for task in list_tasks()]
    assert [t["task"] for t in result["tasks"]] == list_tasks() and result["ok"] and result["arch"] == 90
