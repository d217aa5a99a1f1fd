#!/usr/bin/env python
"""Throughput of the batched disk engine beside the pymunk disk env, measured in one run (ratios, not absolutes).

Env steps per second at N=9 for each K (swarms stepped together), and robot-steps per second at larger N (K*N
robots near ``--robots`` in all), with the pymunk disk env (one process) in the same run. Each rate is timed over
``--seconds`` after one warm-up step; the wave's targets drive both. Prints a markdown table.

    python tools/bench_batched.py                                 # torch.set_num_threads(2)
    python tools/bench_batched.py --ks 1 64 1024 --sizes 100 1000 --seconds 2
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
import torch

from dpr.sim.batched import BatchedDiskWorld, SolverSettings
from dpr.sim.world import grid_centres


def _timed(step, seconds: float) -> float:
    """Calls of ``step`` per second, after one warm-up call."""
    step()
    count, started = 0, time.perf_counter()
    while True:
        step()
        count += 1
        elapsed = time.perf_counter() - started
        if elapsed >= seconds and count >= 2:
            return count / elapsed


def pymunk_rate(n_robots: int, seconds: float) -> float:
    """Env steps per second of the pymunk disk env (Navigation), wave actions."""
    import gymnasium as gym

    import dpr  # noqa: F401
    from dpr.policies.wave import WavePolicy

    env = gym.make("dpr/Navigation-v0", robot_model="disk", n_robots=n_robots, max_episode_steps=10**9)
    policy = WavePolicy.from_env(env)
    state = {"obs": env.reset(seed=0)[0]}

    def step():
        state["obs"] = env.step(policy(state["obs"]))[0]

    rate = _timed(step, seconds)
    env.close()
    return rate


def batched_rate(k: int, n: int, seconds: float, **kwargs) -> float:
    """Control steps per second of a batched world of K swarms of N (each step steps all K)."""
    world = BatchedDiskWorld(k, n, **kwargs)
    centres = torch.tensor(grid_centres(n, (500.0, 0.0)), dtype=torch.float32).expand(k, n, 2)
    world.reset(torch.ones(k, dtype=torch.bool), centres, torch.zeros(k, n, dtype=torch.bool))
    band = (torch.arange(n) % int(np.ceil(np.sqrt(n)))).expand(k, n)  # a wave across the grid's columns
    clock = {"step": 0}

    def step():
        phase = (clock["step"] // 4) % int(band.max() + 1)
        world.step((band == phase).float())
        clock["step"] += 1

    return _timed(step, seconds)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ks", type=int, nargs="+", default=[1, 64, 1024, 4096, 16384])
    parser.add_argument("--sizes", type=int, nargs="+", default=[100, 1000, 10000])
    parser.add_argument("--robots", type=int, default=10000, help="K*N at the larger sizes")
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--compile", action="store_true", help="torch.compile the physics (minutes of compiling)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    kwargs = {"device": args.device, "solver": SolverSettings(compile=args.compile)}
    print(f"torch {torch.__version__}, {args.threads} threads, device {args.device}, compile {args.compile}")
    print(
        "| N | K | pymunk env steps/s | batched env steps/s | batched / pymunk | robot-steps/s (batched) "
        "| µs per robot-step |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|")
    reference = pymunk_rate(9, args.seconds)
    for k in args.ks:
        rate = batched_rate(k, 9, args.seconds, **kwargs) * k
        cells = f"| 9 | {k} | {reference:.0f} | {rate:.0f} | {rate / reference:.1f}x"
        print(f"{cells} | {rate * 9:.0f} | {1e6 / (rate * 9):.2f} |", flush=True)
    for n in args.sizes:
        k = max(1, args.robots // n)
        reference = pymunk_rate(n, args.seconds) if n <= 1000 else float("nan")
        rate = batched_rate(k, n, args.seconds, **kwargs) * k
        cells = f"| {n} | {k} | {reference:.1f} | {rate:.1f} | {rate / reference:.1f}x"
        print(f"{cells} | {rate * n:.0f} | {1e6 / (rate * n):.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
