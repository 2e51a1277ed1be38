"""Runnable wrapper: ``python benchmarks/throughput.py [options]`` == ``dexmots-bench throughput [options]``.

The logic is in :mod:`dexmots_rl.apps.bench_throughput`; see ``dexmots-bench throughput --help``.
"""

from __future__ import annotations

import sys

from dexmots_rl.apps.bench import main

__all__: list[str] = []

if __name__ == "__main__":
    main(["throughput", *sys.argv[1:]])
