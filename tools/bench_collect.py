"""Dataset recording benchmarks (the figures in BENCHMARKS.md, measured in one run).

* overhead: the same episodes (same seeds) rolled out bare (env + policy, nothing kept) and recorded with
  ``collect`` into a fresh state-only dataset, both in 1 process and both in 2 worker processes (the
  ``dpr collect`` default); reports recorded / bare wall time.
* workers: the same episodes recorded with ``--workers 1`` and ``--workers 2``; reports the speed-up.
* writer (``--writer``): the recording contract alone on random frames with the env's dataset features (no
  rollout): the time per ``add_frame`` and per ``save_episode`` (wall and CPU time) of a ``--steps``-frame
  episode, best of ``--repeats``.
* environment state (``--environment-state``): what recording ``observation.environment_state`` costs. The same
  episodes recorded with ``collect`` in 1 process as shipped and with the feature taken out (monkeypatched in this
  process: the env's ``environment_state()`` replaced by a stub returning nothing and the feature dropped from the
  dataset, as recorded before it), interleaved, medians of ``--repeats``; reports frames per second of both and
  their ratio. Also the env's ``environment_state()`` alone (best of 5 x 10,000 calls) against a frame's cost in a
  bare rollout.
* scale (``--scale``): a large state-only dataset (default 200 episodes x 2500 steps, N=9, disk model),
  reporting wall time, peak RSS of the recording process and of a worker, and the size on disk; then opens
  it lazily and reads one episode, reporting the reader's RSS.

    python tools/bench_collect.py --robot-model paddle --episodes 4 --steps 2500
    python tools/bench_collect.py --scale --robot-model disk --episodes 200 --steps 2500 --out /tmp/scale
    python tools/bench_collect.py --environment-state --robot-model disk --episodes 8 --steps 2500 --repeats 5
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
import timeit
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import gymnasium as gym
import numpy as np

import dpr  # noqa: F401  (registers the ids)
import dpr.datasets.collect as collect_module
from dpr.datasets import features as F
from dpr.datasets.collect import CollectSpec, RolloutWorkers, collect
from dpr.datasets.features import dataset_features
from dpr.datasets.lerobot import LeRobotWriter
from dpr.envs import MAX_EPISODE_STEPS, ParticleSwarmEnv
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
        collect(folder / "ds", spec, episodes=episodes, workers=RolloutWorkers(workers))
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


@contextmanager
def without_environment_state():
    """``collect`` in this process as it recorded before ``observation.environment_state``: the env's
    ``environment_state()`` is a stub returning nothing (its rollout hook still appends that), and the feature is
    neither in the dataset's features nor in the saved frames."""
    nothing = np.zeros(0, dtype=np.float32)
    saved = (
        collect_module.dataset_features,
        collect_module.save_record,
        ParticleSwarmEnv.environment_state,
        ParticleSwarmEnv.environment_state_names,
    )
    features, save = saved[0], saved[1]
    collect_module.dataset_features = lambda *args, **kwargs: {
        k: v for k, v in features(*args, **kwargs).items() if k != F.ENVIRONMENT_STATE
    }
    collect_module.save_record = lambda writer, spec, record, *rest: save(
        writer, spec, replace(record, environment_states=None), *rest
    )
    ParticleSwarmEnv.environment_state = lambda self: nothing
    ParticleSwarmEnv.environment_state_names = property(lambda self: [])
    try:
        yield
    finally:
        (
            collect_module.dataset_features,
            collect_module.save_record,
            ParticleSwarmEnv.environment_state,
            ParticleSwarmEnv.environment_state_names,
        ) = saved


def bench_environment_state(spec: CollectSpec, episodes: int, repeats: int) -> dict:
    """Recording frames per second with and without ``observation.environment_state`` (1 process, interleaved,
    medians), and the env's ``environment_state()`` per call against a bare rollout's time per frame."""
    timed_collect(replace(spec, steps=10), 1, workers=1)  # warm-up: imports, first env, first dataset
    shipped, without = [], []
    for repeat in range(repeats):  # interleaved, each first in every other repeat
        for variant in (0, 1) if repeat % 2 == 0 else (1, 0):
            if variant == 0:
                shipped.append(timed_collect(spec, episodes, workers=1))
            else:
                with without_environment_state():
                    without.append(timed_collect(spec, episodes, workers=1))
    frames = episodes * spec.steps
    a, b = statistics.median(shipped), statistics.median(without)
    env = spec.make_env()
    try:
        policy = make_policy(spec.policy, env)
        started = time.perf_counter()
        steps = roll_out(env, policy, 0).steps
        frame_s = (time.perf_counter() - started) / steps
        call_s = min(timeit.repeat(env.unwrapped.environment_state, number=10_000, repeat=5)) / 10_000
        names = env.unwrapped.environment_state_names
    finally:
        env.close()
    return {
        "env": spec.env_id,
        "environment_state_names": names,
        "frames": frames,
        "with_s": a,
        "without_s": b,
        "with_frames_per_s": frames / a,
        "without_frames_per_s": frames / b,
        "with_over_without_time": a / b,
        "environment_state_us": call_s * 1e6,
        "bare_frame_us": frame_s * 1e6,
        "environment_state_over_frame": call_s / frame_s,
    }


def bench_scale(spec: CollectSpec, episodes: int, out: Path, workers: int) -> dict:
    if out.exists():
        raise SystemExit(f"--out: {out} already exists; the scale benchmark records into a new folder")
    started = time.perf_counter()
    summary = collect(out, spec, episodes=episodes, workers=RolloutWorkers(workers))
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
    parser.add_argument(
        "--environment-state",
        action="store_true",
        help="time recording with and without observation.environment_state instead",
    )
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
    elif args.environment_state:
        results = {"environment_state": bench_environment_state(spec, args.episodes, args.repeats)}
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
