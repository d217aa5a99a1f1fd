"""Dataset recording benchmarks (the figures in BENCHMARKS.md, measured in one run).

* overhead: the same episodes (same seeds) rolled out bare (env + policy, nothing kept) and recorded with
  ``collect`` into a fresh state-only dataset, both in 1 process and both in 2 worker processes (the
  ``dpr collect`` default); reports recorded / bare wall time.
* workers: the same episodes recorded with ``--workers 1`` and ``--workers 2``; reports the speed-up.
* writer (``--writer``): the recording contract alone on random frames with the env's dataset features (no
  rollout): the time per ``add_frame`` and per ``save_episode`` (wall and CPU time) of a ``--steps``-frame
  episode, best of ``--repeats``.
* scale (``--scale``): a large state-only dataset (default 200 episodes x 2500 steps, N=9, disk model),
  reporting wall time, peak RSS of the recording process and of a worker, and the size on disk; then opens
  it lazily and reads one episode, reporting the reader's RSS.

    python tools/bench_collect.py --robot-model paddle --episodes 4 --steps 2500
    python tools/bench_collect.py --scale --robot-model disk --episodes 200 --steps 2500 --out /tmp/scale
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import resource
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import dpr  # noqa: F401  (registers the ids)
from dpr.datasets.collect import CollectSpec, collect
from dpr.datasets.features import dataset_features
from dpr.datasets.lerobot import LeRobotWriter
from dpr.envs import MAX_EPISODE_STEPS
from dpr.policies.registry import make_policy
from dpr.rollout import roll_out


def bare_rollout(spec: CollectSpec, seed: int) -> int:
    """Env + policy only (the rollout loop without hooks): what an episode costs when nothing is recorded."""
    env = gym.make(spec.env_id, **spec.make_kwargs())
    try:
        return roll_out(env, make_policy(spec.policy, env), seed).steps
    finally:
        env.close()


def timed_collect(spec: CollectSpec, episodes: int, workers: int) -> float:
    folder = Path(tempfile.mkdtemp(prefix="dpr-bench-"))
    try:
        started = time.perf_counter()
        collect(folder / "ds", spec, episodes=episodes, workers=workers)
        return time.perf_counter() - started
    finally:
        shutil.rmtree(folder)


def timed_bare(spec: CollectSpec, episodes: int, workers: int) -> float:
    """The same episodes rolled out bare, in ``workers`` processes (started the way collect starts them)."""
    started = time.perf_counter()
    if workers <= 1:
        for seed in range(episodes):
            bare_rollout(spec, seed)
    else:
        with multiprocessing.get_context("spawn").Pool(workers) as pool:
            pool.starmap(bare_rollout, [(spec, seed) for seed in range(episodes)])
    return time.perf_counter() - started


def bench_overhead(spec: CollectSpec, episodes: int, repeats: int, workers: int) -> dict:
    bare, recorded = [], []
    for _ in range(repeats):  # interleaved, so that load changes hit both alike
        bare.append(timed_bare(spec, episodes, workers))
        recorded.append(timed_collect(spec, episodes, workers=workers))
    b, r = statistics.median(bare), statistics.median(recorded)
    return {"workers": workers, "bare_s": b, "recorded_s": r, "recorded_over_bare": r / b}


def bench_workers(spec: CollectSpec, episodes: int, repeats: int) -> dict:
    one, two = [], []
    for _ in range(repeats):
        one.append(timed_collect(spec, episodes, workers=1))
        two.append(timed_collect(spec, episodes, workers=2))
    a, b = statistics.median(one), statistics.median(two)
    return {"workers1_s": a, "workers2_s": b, "speedup": a / b}


def bench_scale(spec: CollectSpec, episodes: int, out: Path, workers: int) -> dict:
    if out.exists():
        raise SystemExit(f"--out: {out} already exists; the scale benchmark records into a new folder")
    started = time.perf_counter()
    summary = collect(out, spec, episodes=episodes, workers=workers)
    seconds = time.perf_counter() - started
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # this process: the writer
    children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024  # the largest worker
    size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    # VmHWM, not ru_maxrss: Linux carries a parent's ru_maxrss into a child it forks and execs
    probe = (
        "import re, sys, time; from dpr.datasets.lerobot import LeRobotReader\n"
        "def hwm(): return int(re.search(r'VmHWM:\\s+(\\d+)', open('/proc/self/status').read()).group(1)) / 1024\n"
        "base = hwm(); t = time.perf_counter(); r = LeRobotReader(sys.argv[1]); opened = time.perf_counter() - t\n"
        "e = r.episode(r.num_episodes // 2); print(r.num_frames, opened, base, hwm())"
    )
    import subprocess

    frames, opened, reader_base, reader_rss = subprocess.run(
        [sys.executable, "-c", probe, str(out)], check=True, capture_output=True, text=True
    ).stdout.split()
    return {
        "episodes": summary.episodes_total,
        "frames": summary.frames_total,
        "seconds": seconds,
        "frames_per_s": summary.frames_added / seconds,
        "peak_rss_main_mib": own,
        "peak_rss_worker_mib": children,
        "bytes_on_disk": size,
        "reader_frames": int(frames),
        "reader_open_s": float(opened),
        "reader_peak_rss_mib_after_imports": float(reader_base),
        "reader_peak_rss_mib_after_one_episode": float(reader_rss),
    }


def bench_writer(spec: CollectSpec, repeats: int) -> dict:
    """Best-of-``repeats`` cost of ``add_frame`` (per frame) and ``save_episode`` (per episode) of an episode of
    ``spec.steps`` random frames with the features ``collect`` records for ``spec``'s env."""
    env = spec.make_env()
    try:
        features = dataset_features(env)
        task = env.unwrapped.task_description
    finally:
        env.close()
    rng = np.random.default_rng(0)
    frames = [
        {name: rng.random(feature["shape"]).astype(feature["dtype"]) for name, feature in features.items()}
        for _ in range(spec.steps)
    ]
    adds, saves, save_cpu = [], [], []
    with tempfile.TemporaryDirectory() as folder:
        with LeRobotWriter.create(Path(folder) / "ds", fps=10, features=features, robot_type="paddle") as writer:
            for index in range(repeats):
                start = time.perf_counter()
                for frame in frames:
                    writer.add_frame(frame, task=task)
                added, added_cpu = time.perf_counter(), time.process_time()
                writer.save_episode({"seed": index})
                adds.append((added - start) / spec.steps)
                saves.append(time.perf_counter() - added)
                save_cpu.append(time.process_time() - added_cpu)
    return {
        "frames": spec.steps,
        "add_frame_us": min(adds) * 1e6,
        "save_episode_ms": min(saves) * 1e3,
        "save_episode_cpu_ms": min(save_cpu) * 1e3,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="dpr/Navigation-v0")
    parser.add_argument("--robot-model", choices=("paddle", "disk"), default="paddle")
    parser.add_argument("--n-robots", type=int, default=9)
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument("--steps", type=int, default=MAX_EPISODE_STEPS)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--scale", action="store_true", help="run the scale benchmark instead")
    parser.add_argument("--writer", action="store_true", help="time the dataset writer alone instead")
    parser.add_argument("--out", type=Path, help="dataset folder for --scale (must not exist)")
    parser.add_argument("--workers", type=int, default=2, help="workers for --scale")
    parser.add_argument("--json", type=Path, help="also write the results here")
    args = parser.parse_args()
    spec = CollectSpec(args.env, n_robots=args.n_robots, robot_model=args.robot_model, steps=args.steps)
    if args.scale:
        if args.out is None:
            parser.error("--scale needs --out")
        results = {"scale": bench_scale(spec, args.episodes, args.out, args.workers)}
    elif args.writer:
        results = {"writer": bench_writer(spec, args.repeats)}
    else:
        results = {
            "overhead_1_worker": bench_overhead(spec, args.episodes, args.repeats, workers=1),
            "overhead_2_workers": bench_overhead(spec, args.episodes, args.repeats, workers=2),
            "workers": bench_workers(spec, args.episodes, args.repeats),
        }
    results["config"] = vars(args) | {"out": str(args.out), "json": str(args.json)}
    print(json.dumps(results, indent=2))
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
