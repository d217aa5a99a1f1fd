"""Characterise the wave policy per robot model: projected displacement for each hold and wave direction.

The wave's hold and start side that move a model toward the goal are measured, not assumed
(``dpr.policies.wave.MODEL_DEFAULTS`` holds the outcome). Prints a markdown table of the median (min-max)
projected displacement over seeds:

    python tools/wave_sweep.py --robot-model disk --holds 2 4 6 10 --seeds 0-4
    python tools/wave_sweep.py --robot-model paddle --holds 4 10 --steps 2500 --workers 2
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor

import gymnasium as gym
import numpy as np

from dpr.cli import parse_seeds
from dpr.envs import MAX_EPISODE_STEPS
from dpr.policies.wave import START_SIDES, WavePolicy
from dpr.rollout import roll_out


def projected_displacement(
    env_id: str, robot_model: str, n_robots: int, steps: int, hold: int, side: str, seed: int
) -> float:
    import dpr  # noqa: F401  (registers the ids in worker processes)

    env = gym.make(env_id, n_robots=n_robots, robot_model=robot_model, max_episode_steps=steps)
    try:
        result = roll_out(env, WavePolicy.from_env(env, hold_steps=hold, start_side=side), seed)
    finally:
        env.close()
    return result.metrics.projected_displacement


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="dpr/Navigation-v0")
    parser.add_argument("--robot-model", choices=("paddle", "disk"), default="disk")
    parser.add_argument("--n-robots", type=int, default=9)
    parser.add_argument("--holds", type=int, nargs="+", default=[2, 4, 6, 10])
    parser.add_argument("--sides", nargs="+", choices=START_SIDES, default=list(START_SIDES))
    parser.add_argument("--seeds", type=parse_seeds, default=parse_seeds("0-4"))
    parser.add_argument("--steps", type=int, default=MAX_EPISODE_STEPS)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    grid = [(hold, side) for hold in args.holds for side in args.sides]
    with ProcessPoolExecutor(args.workers) as pool:
        futures = {
            (hold, side, seed): pool.submit(
                projected_displacement, args.env, args.robot_model, args.n_robots, args.steps, hold, side, seed
            )
            for hold, side in grid
            for seed in args.seeds
        }
        results = {key: future.result() for key, future in futures.items()}
    print(f"{args.env}, {args.robot_model}, N={args.n_robots}, {args.steps} steps, seeds {args.seeds}")
    print("| hold | start side | median (min-max) projected displacement |")
    print("|---:|---|---|")
    for hold, side in grid:
        values = np.array([results[(hold, side, seed)] for seed in args.seeds])
        print(f"| {hold} | {side} | {np.median(values):.1f} ({values.min():.1f} to {values.max():.1f}) |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
