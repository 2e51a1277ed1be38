#!/usr/bin/env bash
# The GPU check: on a machine with one CUDA GPU, every figure of the library in one run of under 8 minutes
# (kernels compiled in parallel first), written to one JSON file:
#
#   scripts/gpu_check.sh                        # writes gpu_check_<UTC time>.json in the repository root
#   scripts/gpu_check.sh --out /tmp/h200.json   # any `dexmots-bench gpu` option (dexmots-bench gpu --help)
#
# GPU, driver and warp versions; throughput on screw_claw, allegro_rotate, repose_cube and a tool task
# (spray_bottle) at 1,024 / 4,096 / 16,384 worlds (forward, forward+backward, torchrl rollout and Collector,
# RGB 64x64 at 4,096 worlds); AD against finite differences in float64 on the GPU; CPU/GPU agreement over 100 steps; screw_claw trained with
# AHAC at 1,024 worlds for 3 minutes, then evaluated. The JSON is rewritten after each section, so a run
# cut short keeps what it measured. The same run on CPU at tiny sizes is in the test suite
# (tests/test_gpu_check.py). Environment: PYTHON (default .venv/bin/python, else python3), GPU_CHECK_TIMEOUT
# (seconds, default 900: the whole run is stopped past it).
set -euo pipefail
cd "$(dirname "$0")/.."
if [ -z "${PYTHON:-}" ]; then
    if [ -x .venv/bin/python ]; then PYTHON=.venv/bin/python; else PYTHON=python3; fi
fi
if command -v nvidia-smi >/dev/null 2>&1; then
    nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader >&2 || true
fi
exec timeout "${GPU_CHECK_TIMEOUT:-900}" "$PYTHON" -m dexmots_rl.apps.bench gpu \
    --out "gpu_check_$(date -u +%Y%m%dT%H%M%SZ).json" "$@"
