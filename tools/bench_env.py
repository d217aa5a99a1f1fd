#!/usr/bin/env python
"""Env steps/s vs physics-only steps/s for both robot models at N in {9, 25, 49, 100} (see dpr.bench).

    python tools/bench_env.py [--sizes 9 25 49 100] [--models paddle disk] [--json out.json]

Same as ``dpr bench``; the table is what BENCHMARKS.md holds.
"""

import sys

from dpr.cli import main

if __name__ == "__main__":
    sys.exit(main(["bench", *sys.argv[1:]]))
