"""The package's import graph: every import of every module (imports inside functions included, read with
``ast``, nothing imported) goes down the layers, and no two modules import each other, directly or around a
loop.

Layers, bottom to top (a module may import its own layer and the ones below)::

    dexmots_rl.<module>.py                         helpers (atomic, integrity, quaternions...)
    dexmots_rl.assets                              hand and object descriptions
    dexmots_rl.sim                                 the simulator (the only user of warp)
    dexmots_rl.trajectories                        object-centric plans (a scene in, never a task name)
    dexmots_rl.envs                                torchrl envs, tasks (they read plans)
    dexmots_rl.objectives, recording               torchrl losses, MCAP episode recordings
    dexmots_rl.algorithms, sysid                   trainers, evaluation, checkpoints; system identification
    dexmots_rl.apps, viz                           console scripts, viewer and figures: the top

The package's own ``__init__`` (the ``dexmots_rl`` facade) may import anything.

``dexmots_rl.sim`` is a facade too: outside ``sim/`` (the package, the benchmarks, the scripts, the tests) code
imports ``from dexmots_rl.sim import ...``, never a submodule of it; a test of a private internal is listed in
``SIM_INTERNAL_TESTS`` with the reason.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "dexmots_rl"
SIM = "dexmots_rl.sim"
# tests that check a private part of the simulation core itself (not reachable through the facade), and why
SIM_INTERNAL_TESTS = {
    "test_articulated.py": "checks the energy of an object tree against MuJoCo's (the tree's kinematics and energy)",
    "test_culling.py": "switches the box-object shortcut off to compare the step with and without it",
    "test_compile.py": "compiles the renderer's kernel module on its own",
    "test_dynamics.py": "checks how worlds are split into CPU blocks",
    "test_hand_adjoints.py": "builds probe kernels on the contact functions (the SDF shape code)",
    "test_sdf_object.py": "builds probe kernels on the contact functions (the SDF shape code)",
    "test_mesh_sdf.py": "builds probe kernels on the finger contact's mesh SDF lookup",
    "test_render.py": "checks the analytic renderer's capsules, labels and reach spheres",
    "test_render_meshes.py": "checks the mesh renderer's labels and compiles its kernel module",
}

HELPERS = 0  # a module directly in dexmots_rl/ (not a subpackage)
LAYERS = {  # the subpackages
    "assets": 1,
    "sim": 2,
    "trajectories": 3,
    "envs": 4,
    "objectives": 5, "recording": 5,
    "algorithms": 6, "sysid": 6,
    "apps": 7, "viz": 7,
}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def _imports(name: str, path: Path, known: set[str]) -> set[str]:
    """The modules of ours that ``name`` imports anywhere in its file (``from . import x`` names module x)."""
    is_package = path.name == "__init__.py"
    package = name if is_package else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            # ``from pkg import name``: the submodule pkg.name when there is one, else pkg itself
            targets = [f"{module}.{alias.name}" if f"{module}.{alias.name}" in known else module
                       for alias in node.names]
        else:
            continue
        for target in targets:
            if target.split(".")[0] != "dexmots_rl":
                continue
            while target and target not in known:  # an attribute of a module: the module
                target = target.rpartition(".")[0]
            if target and target != name:
                found.add(target)
    return found


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    return {name: _imports(name, path, set(modules)) for name, path in modules.items()}


def _layer(module: str) -> int | None:
    parts = module.split(".")
    if len(parts) == 1:
        return None  # the facade
    if (PACKAGE / f"{parts[1]}.py").is_file():
        return HELPERS
    if parts[1] not in LAYERS:
        raise AssertionError(f"{module}: the subpackage dexmots_rl.{parts[1]} has no layer in this test; give it one")
    return LAYERS[parts[1]]


def test_every_import_goes_down_the_layers():
    upward = []
    for module, targets in _graph().items():
        mine = _layer(module)
        for target in targets:
            theirs = _layer(target)
            if mine is not None and theirs is not None and theirs > mine:
                upward.append(f"{module} imports {target}")
            if mine is not None and theirs is None:
                upward.append(f"{module} imports the package facade {target}")
    assert not upward, "imports against the layering:\n" + "\n".join(sorted(upward))


def test_no_import_cycles_between_modules():
    graph = _graph()
    # a package's __init__ importing its own submodules (and them importing siblings through it) is how a
    # package exposes its API, not a cycle between modules: only edges between different files count, and
    # edges into a package's __init__ from inside that package are its re-exports
    edges = {m: {t for t in ts if not m.startswith(t + ".")} for m, ts in graph.items()}
    cycles, state = [], {}

    def visit(node, stack):
        state[node] = "open"
        stack.append(node)
        for nxt in sorted(edges.get(node, ())):
            if state.get(nxt) == "open":
                cycles.append(" -> ".join(stack[stack.index(nxt):] + [nxt]))
            elif nxt not in state:
                visit(nxt, stack)
        stack.pop()
        state[node] = "done"

    for module in sorted(edges):
        if module not in state:
            visit(module, [])
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


def _sim_submodule_imports(path: Path) -> list[str]:
    """``module`` for every import of a submodule of dexmots_rl.sim in ``path`` (absolute or, inside the package,
    relative; ``from dexmots_rl.sim import <submodule>`` counts), read with ``ast``."""
    modules = _modules()
    inside = path.is_relative_to(PACKAGE)
    name = _module_name(path) if inside else ""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            module = node.module or ""
            if node.level:
                base = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
                module = ".".join(base[: len(base) - node.level + 1] + ([module] if module else []))
            targets = [module] + [f"{module}.{alias.name}" for alias in node.names
                                  if f"{module}.{alias.name}" in modules]
        else:
            continue
        found += [t for t in targets if t.startswith(SIM + ".")]
    return found


def test_nothing_outside_sim_imports_a_sim_submodule():
    files = [p for p in sorted(PACKAGE.rglob("*.py")) if not p.is_relative_to(PACKAGE / "sim")]
    files += sorted((ROOT / "benchmarks").rglob("*.py")) + sorted((ROOT / "scripts").rglob("*.py"))
    files += [p for p in sorted((ROOT / "tests").rglob("*.py")) if p.name not in SIM_INTERNAL_TESTS]
    bad = [f"{p.relative_to(ROOT)} imports {m}" for p in files for m in _sim_submodule_imports(p)]
    assert not bad, "import these from dexmots_rl.sim (its facade) instead:\n" + "\n".join(bad)


def test_the_sim_check_sees_submodule_imports(tmp_path):
    sub = sorted(m for m in _modules() if m.startswith(SIM + "."))[0]  # any submodule
    leaf = sub.rpartition(".")[2]
    probe = tmp_path / "probe.py"
    probe.write_text(f"from {sub} import x\nfrom dexmots_rl.sim import {leaf}\nimport {sub}\n"
                     "from dexmots_rl.sim import load_scene\n")
    assert _sim_submodule_imports(probe) == [sub, sub, sub]
    assert all((ROOT / "tests" / name).is_file() for name in SIM_INTERNAL_TESTS)  # the list names real tests


def test_the_graph_sees_imports_inside_functions():
    graph = _graph()
    assert "dexmots_rl.envs" in graph["dexmots_rl"]  # the facade's make_env imports envs on use
    assert "dexmots_rl.sim" in graph["dexmots_rl.trajectories.planner"]  # inside functions only


@pytest.mark.parametrize("package", ["dexmots_rl.algorithms", "dexmots_rl.algorithms.registry", "dexmots_rl.viz",
                                     "dexmots_rl.apps.train"])
def test_imports_in_a_fresh_interpreter(package):
    proc = subprocess.run([sys.executable, "-c", f"import {package}"], capture_output=True, text=True, timeout=300,
                          cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-2000:]

