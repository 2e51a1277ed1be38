"""Where the substep kernel spends its time, by warp function and by Python statement of the kernel.

    python benchmarks/kernel_profile.py --task allegro_rotate --num-envs 256 --seconds 15
    python benchmarks/kernel_profile.py --task allegro_rotate --reverse --addresses 30   # the reverse pass
    python benchmarks/kernel_profile.py --task spray_bottle --kernel finger_contact --reverse   # a tool scene's

Needs Linux ``perf`` (``apt-get install linux-perf``) and binutils; runs on CPU with one simulator thread.

Warp loads a CPU module's object file into memory itself, so ``perf`` sees its samples as anonymous
"[JIT]" addresses without symbols. This script rebuilds the task's kernels with line tables
(``-debug-info-kind=line-tables-only``, a clang cc1 flag passed through warp's ``cpu_compiler_flags``; the
module hash changes, so the cached production build is left alone), finds where the object's ``.ltext``
section was placed by matching a few byte windows of one function against the process's executable
mappings, samples the forward loop with ``perf record -p``, and maps each sample back through
``addr2line -i`` to the generated C++ and from there to the Python statement warp wrote above it
(``<L n>`` comments). The share of samples in libm (``expf``, ``logf``, ``tanhf``) is reported apart:
those calls are not attributed to a statement.

Prints the shares by function, by statement and by library, and the hottest instructions (``rep movs``
there are struct arguments copied by value into functions clang did not inline). Code between a function's
header and its first statement is reported as "(entry: locals initialised)": warp value-initialises every
local (and, in an adjoint, every adjoint variable) of a frame on entry. ``--reverse`` samples the reverse
pass of one taped step (the adjoint launches) instead of the forward step.
"""

from __future__ import annotations

import argparse
import bisect
import collections
import glob
import os
import re
import subprocess
import sys
import tempfile
import time

LINE_TABLES = "-march=native -debug-info-kind=line-tables-only -dwarf-version=4"


def _run(*cmd: str) -> str:
    return subprocess.run(cmd, capture_output=True, text=True, check=True).stdout


def _section_base(obj: str, section: str, symbol_hint: str) -> int:
    """Address at which this process's JIT placed ``section`` of ``obj``: the most common offset at which
    24-byte windows of the hinted function are found (uniquely) in an anonymous executable mapping."""
    func = next(line.split() for line in _run("nm", "-S", obj).splitlines()
                if symbol_hint in line and "adj_" not in line)
    with tempfile.NamedTemporaryFile() as raw:
        subprocess.run(["objcopy", "-O", "binary", f"--only-section={section}", obj, raw.name], check=True)
        code = open(raw.name, "rb").read()
    start, size = int(func[0], 16), int(func[1], 16)
    windows = [(o, code[start + o:start + o + 24]) for o in range(64, min(size, 4096) - 24, 200)]
    with open("/proc/self/maps") as maps, open("/proc/self/mem", "rb") as mem:
        for line in maps:
            fields = line.split()
            if "x" not in fields[1] or (len(fields) > 5 and fields[5].startswith("/")):
                continue
            lo, hi = (int(x, 16) for x in fields[0].split("-"))
            try:
                mem.seek(lo)
                data = mem.read(hi - lo)
            except (OSError, ValueError, OverflowError):
                continue
            hits = collections.Counter()
            for offset, window in windows:
                k = data.find(window)
                if k >= 0 and data.find(window, k + 1) < 0:
                    hits[lo + k - offset - start] += 1
            if hits:
                return hits.most_common(1)[0][0]
    raise RuntimeError(f"the code of {symbol_hint} was not found in this process's executable mappings")


def _statement(cpp_lines: list[str], line: int) -> tuple[str, str]:
    """(warp function, Python statement) that generated C++ line ``line`` (1-based) belongs to."""
    j = line - 1
    while j > 0 and "<L " not in cpp_lines[j] and not cpp_lines[j].startswith("static"):
        j -= 1
    k = j
    while k > 0 and not cpp_lines[k].startswith("static"):
        k -= 1
    func = re.sub(r"build_\w+?__locals__", "", cpp_lines[k].split("(")[0].split()[-1])
    if j == k:  # between a function's header and its first statement: its locals' initialisation
        return func, "(entry: locals initialised)"
    return func, cpp_lines[j].strip().lstrip("/ ").split("<L")[0].strip()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="allegro_rotate")
    ap.add_argument("--num-envs", type=int, default=256)
    ap.add_argument("--seconds", type=float, default=15.0, help="seconds of sampling")
    ap.add_argument("--top", type=int, default=25)
    ap.add_argument("--addresses", type=int, default=0,
                    help="also print the N hottest instructions with their inline chains")
    ap.add_argument("--reverse", action="store_true",
                    help="profile the reverse pass (the substeps' adjoint launches) instead of the forward step")
    ap.add_argument("--kernel", default="substep",
                    help="the kernel whose module is mapped (a tool scene's: finger_contact, hand_residual, "
                         "substep, ...); samples in the others count as outside the module")
    args = ap.parse_args()
    os.environ["DEXMOTS_CPU_THREADS"] = "1"
    import warp as wp

    wp.config.cpu_compiler_flags = LINE_TABLES  # before the kernels are built
    from dexmots_rl.apps.bench_setup import bench_env
    from dexmots_rl.apps.bench_throughput import SimBench

    env = bench_env(args.task)  # dexmots-bench throughput's bench state
    bench = SimBench(env.sim.scene, env.bench_poses(), args.num_envs, "cpu", 16, 30, 10, contact=env.sim.contact)
    kernel = next(getattr(space, args.kernel) for space in [bench.sim.kernels, *getattr(bench.sim, "more_kernels", [])]
                  if hasattr(space, args.kernel))
    module = kernel.module
    chunk, what = bench.forward_chunk, "forward"
    if args.reverse:
        chunk, what = bench.reverse_chunk(), "reverse pass"
    chunk()  # loads every module the timed chunks run (an adjoint's at its first reverse pass)
    cache = wp.config.kernel_cache_dir
    objs = sorted(glob.glob(os.path.join(cache, f"wp_{module.name}_*", "*.o")), key=os.path.getmtime)
    if not objs:
        raise RuntimeError(f"no object file of {module.name} under {cache}")
    obj = objs[-1]
    cpp = open(glob.glob(os.path.join(os.path.dirname(obj), "*.cpp"))[0]).read().splitlines()
    base = _section_base(obj, ".ltext", "finger_step_0" if args.kernel == "substep" and "finger_step_0" in
                         _run("nm", obj) else args.kernel)
    size = int(next(line.split()[2] for line in _run("objdump", "-h", obj).splitlines()
                    if line.split()[1:2] == [".ltext"]), 16)

    with tempfile.TemporaryDirectory() as tmp:
        data = os.path.join(tmp, "perf.data")
        perf = subprocess.Popen(["perf", "record", "-F", "4000", "-p", str(os.getpid()), "-o", data],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(1.0)
        steps, start = 0, time.perf_counter()
        while time.perf_counter() - start < args.seconds:
            steps += chunk()
        rate = steps / (time.perf_counter() - start)
        perf.send_signal(2)
        perf.wait()
        samples = _run("perf", "script", "-i", data, "-F", "ip,dso").splitlines()

    kernel, other = [], collections.Counter()
    for line in samples:
        fields = line.split()
        ip = int(fields[0], 16) - base
        if 0 <= ip < size:
            kernel.append(ip)
        else:
            other[os.path.basename(fields[1].strip("()")) if len(fields) > 1 else "?"] += 1
    total = len(kernel) + sum(other.values())
    uniq = sorted(set(kernel))
    chains, cur = collections.defaultdict(list), None
    for line in _run("addr2line", "-i", "-a", "-e", obj, "-j", ".ltext", *map(hex, uniq)).splitlines():
        if line.startswith("0x"):
            cur = int(line, 16)
        else:
            chains[cur].append(line)
    by_func, by_stmt = collections.Counter(), collections.Counter()
    counts = collections.Counter(kernel)
    for ip, n in counts.items():
        loc = next((c for c in chains.get(ip, []) if ".cpp:" in c), "?:0")
        num = loc.rpartition(":")[2].split()[0]
        func, stmt = _statement(cpp, int(num)) if num.isdigit() and int(num) > 0 else ("?", "?")
        by_func[func] += n
        by_stmt[f"{func}: {stmt}"] += n
    hot, ins_at = collections.Counter(), {}
    asm = _run("objdump", "-d", "--no-show-raw-insn", "-j", ".ltext", obj)
    for line in asm.splitlines():
        head, _, ins = line.partition(":")
        try:
            addr = int(head.strip(), 16)
        except ValueError:
            continue
        if addr in counts:
            hot[ins.strip()[:60]] += counts[addr]
            ins_at[addr] = ins.strip()[:60]

    def pct(n):
        return f"{100.0 * n / total:5.1f} %"

    print(f"{args.task}, {args.num_envs} worlds, one thread: {rate:,.0f} env-steps/s {what}; {total} samples, "
          f"{pct(len(kernel))} in the kernel module")
    print("\nby library (outside the kernel module):")
    for name, n in other.most_common(6):
        print(f"  {pct(n)}  {name}")
    print("\nby warp function (inlined callees count in their caller's lines):")
    for name, n in by_func.most_common(10):
        print(f"  {pct(n)}  {name}")
    print(f"\nby Python statement (top {args.top}):")
    for name, n in by_stmt.most_common(args.top):
        print(f"  {pct(n)}  {name[:150]}")
    copies = sum(n for ins, n in hot.items() if ins.startswith("rep movs"))
    print(f"\nstruct arguments copied by value (rep movs): {pct(copies)}")
    if args.addresses:
        print(f"\nhottest {args.addresses} instructions (innermost inline frame first):")
        for ip, n in counts.most_common(args.addresses):
            frames = [c.rpartition("/")[2] for c in chains.get(ip, []) if ".cpp:" in c]
            print(f"  {pct(n)}  {hex(ip)}  {ins_at.get(ip, '?'):40s}  {' < '.join(frames)[:120]}")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
