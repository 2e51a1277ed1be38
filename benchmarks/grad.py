"""Runnable wrapper: ``python benchmarks/grad.py [options]`` == ``dexmots-bench grad [options]``.

The logic is in :mod:`dexmots_rl.apps.bench_grad`; see ``dexmots-bench grad --help``.
"""

from __future__ import annotations

import sys

from dexmots_rl.apps.bench import main

__all__: list[str] = []

if __name__ == "__main__":
    main(["grad", *sys.argv[1:]])
