"""What compaction buys: files, bytes and read time of a 10,000-episode dataset before and after ``compact``.

Records a state-only dataset with ``dpr collect``'s own pipeline (wave policy, dpr/Navigation-v0, disk model,
N = 9 robots, episodes cut at 20 steps so that 10,000 of them record in a few minutes), then measures, before and
after :func:`dpr.datasets.lerobot.compact`: the number of files and their bytes, the time for
:class:`~dpr.datasets.lerobot.LeRobotReader` to open the dataset, and the time to read every episode (every
column) through it. Times are the best of ``--repeats`` runs with a warm page cache.

    python tools/bench_dataset_files.py                         # 10,000 episodes x 20 steps into a temp folder
    python tools/bench_dataset_files.py --episodes 200 --steps 20 --out /tmp/bench-ds --json bench.json
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

from dpr.datasets.collect import CollectSpec, RolloutWorkers, collect
from dpr.datasets.lerobot import LeRobotReader, compact


def files_and_bytes(root: Path) -> tuple[int, int, int]:
    """(all files, parquet files, bytes of all files) under ``root``."""
    files = [p for p in root.rglob("*") if p.is_file()]
    return len(files), sum(p.suffix == ".parquet" for p in files), sum(p.stat().st_size for p in files)


def best_of(repeats: int, run) -> float:
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        run()
        times.append(time.perf_counter() - started)
    return min(times)


def measure(root: Path, repeats: int) -> dict:
    files, parquet, size = files_and_bytes(root)
    open_seconds = best_of(repeats, lambda: LeRobotReader(root))

    def read_all() -> None:
        reader = LeRobotReader(root)
        frames = sum(len(episode["index"]) for episode in reader.iter_episodes())
        assert frames == reader.num_frames

    return {
        "files": files,
        "parquet_files": parquet,
        "bytes": size,
        "open_s": open_seconds,
        "open_and_read_all_s": best_of(repeats, read_all),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=10_000)
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--n-robots", type=int, default=9)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, help="record here and keep it (default: a temp folder, deleted)")
    parser.add_argument("--json", type=Path, help="also write the results here")
    args = parser.parse_args(argv)

    folder = args.out or Path(tempfile.mkdtemp(prefix="dpr-bench-files-"))
    root = folder / "ds"
    try:
        if root.exists():
            shutil.rmtree(root)
        spec = CollectSpec(env_id="dpr/Navigation-v0", n_robots=args.n_robots, robot_model="disk", steps=args.steps)
        started = time.perf_counter()
        summary = collect(root, spec, episodes=args.episodes, workers=RolloutWorkers(args.workers))
        record_s = time.perf_counter() - started
        before = measure(root, args.repeats)
        started = time.perf_counter()
        compact(root)
        compact_s = time.perf_counter() - started
        after = measure(root, args.repeats)
    finally:
        if args.out is None:
            shutil.rmtree(folder, ignore_errors=True)

    results = {
        "episodes": summary.episodes_total,
        "frames": summary.frames_total,
        "steps_per_episode": args.steps,
        "n_robots": args.n_robots,
        "robot_model": "disk",
        "record_s": record_s,
        "compact_s": compact_s,
        "before": before,
        "after": after,
    }
    print(
        f"{results['episodes']} episodes x {args.steps} steps ({results['frames']} frames), N={args.n_robots} disk, "
        f"recorded in {record_s:.0f} s, compacted in {compact_s:.1f} s"
    )
    print("| layout | files (parquet) | MiB | open | open + read every episode |")
    print("|---|---:|---:|---:|---:|")
    for name, m in (("per-episode files (as recorded)", before), ("compacted", after)):
        print(
            f"| {name} | {m['files']} ({m['parquet_files']}) | {m['bytes'] / 2**20:.1f} | {m['open_s']:.2f} s | "
            f"{m['open_and_read_all_s']:.2f} s |"
        )
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
