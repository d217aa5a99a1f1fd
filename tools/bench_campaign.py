#!/usr/bin/env python
"""Campaign scale-out: wall time of one pipeline preset (default ``tiny``) with 1, 2... workers, on the local
backend and on Ray, each into a fresh folder, and the speed-up over one worker. Every run must print the same
results tables as the one-worker run (the stages run on one CPU each, so where they ran changes nothing).

    python tools/bench_campaign.py                                  # tiny, local, 1 and 2 workers
    python tools/bench_campaign.py --workers 1 2 8 16 --backends local ray
    python tools/bench_campaign.py --preset small --workers 1 2 --json campaign.json

Runs are made one after another, in the order given; compare ratios measured in one invocation.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def tables(report: Path) -> list[str]:
    return [line for line in (report / "results.md").read_text().splitlines() if line.startswith("|")]


def run(preset: str, workers: int, backend: str, out: Path) -> float:
    """Wall seconds of ``dpr pipeline --preset PRESET`` with ``workers`` on ``backend`` into ``out``."""
    command = [sys.executable, "-m", "dpr.cli", "pipeline", "--preset", preset, "--out", str(out)]
    command += ["--workers", str(workers), "--backend", backend]
    env = {**os.environ, "SDL_VIDEODRIVER": "dummy", "RAY_AUTH_MODE": "disabled"}
    started = time.perf_counter()
    result = subprocess.run(command, env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - started
    if result.returncode:
        sys.exit(f"{' '.join(command)} failed:\n{result.stderr[-3000:]}")
    return seconds


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--preset", default="tiny", help="the pipeline preset to run (default tiny)")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="worker counts (default 1 2)")
    parser.add_argument("--backends", nargs="+", default=["local"], choices=["local", "ray"])
    parser.add_argument("--json", type=Path, help="also write the rows to this JSON file")
    args = parser.parse_args(argv)
    rows, reference = [], None
    with tempfile.TemporaryDirectory(prefix="dpr-bench-campaign-") as folder:
        for backend in args.backends:
            for workers in args.workers:
                out = Path(folder) / f"{backend}-{workers}"
                seconds = run(args.preset, workers, backend, out)
                if reference is None:
                    reference = (seconds, tables(out / "report"))
                same = tables(out / "report") == reference[1]
                rows.append({"backend": backend, "workers": workers, "seconds": round(seconds, 1), "same": same})
                rows[-1]["speedup"] = round(reference[0] / seconds, 2)
                speedup = rows[-1]["speedup"]
                print(f"{backend:5} {workers:3} workers: {seconds:6.1f} s, {speedup:.2f}x, same tables: {same}")
    print("\n| backend | workers | wall s | speed-up over the first run | same tables |\n|---|---:|---:|---:|---|")
    for row in rows:
        print(f"| {row['backend']} | {row['workers']} | {row['seconds']} | {row['speedup']}x | {row['same']} |")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0 if all(row["same"] for row in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
