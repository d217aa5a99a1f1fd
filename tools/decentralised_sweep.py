"""Centralised against decentralised wave: median projected displacement over seeds, per robot model and N.

The centralised wave is ``WavePolicy.from_env`` (it bins the robots along the goal direction from the swarm's
centre); the decentralised one is ``DecentralisedWavePolicy.for_env`` (every robot decides from its own local
observation: its distance to the goal and the shared clock). Both run in the same centralised env, so the physics
is the same. Prints a markdown table, median (min to max) over seeds:

    python tools/decentralised_sweep.py                                  # small default: 5 seeds x 500 steps
                                                                         # (paddle N=9, 25, 49; disk N=9, 100, 400)
    python tools/decentralised_sweep.py --seeds 0-19 --steps 2500        # the full run
    python tools/decentralised_sweep.py --models disk --sizes 9 100 400 --n-phases 3 4 6
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import gymnasium as gym
import numpy as np

from dpr.cli import parse_seeds
from dpr.policies.decentralised import DEFAULT_N_PHASES, DecentralisedWavePolicy
from dpr.policies.wave import START_SIDES, WavePolicy
from dpr.rollout import roll_out

CENTRALISED = "centralised"
DEFAULT_SIZES = {"paddle": [9, 25, 49], "disk": [9, 100, 400]}


def projected_displacement(
    env_id: str, robot_model: str, n_robots: int, steps: int, policy: str, n_phases: int, side: str | None, seed: int
) -> float:
    import dpr  # noqa: F401  (registers the ids in worker processes)

    env = gym.make(env_id, n_robots=n_robots, robot_model=robot_model, max_episode_steps=steps)
    try:
        if policy == CENTRALISED:
            actor = WavePolicy.from_env(env)
        else:
            actor = DecentralisedWavePolicy.for_env(env, n_phases=n_phases, **({"start_side": side} if side else {}))
        result = roll_out(env, actor, seed)
    finally:
        env.close()
    return result.metrics.projected_displacement


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="dpr/Navigation-v0")
    parser.add_argument("--models", nargs="+", choices=tuple(DEFAULT_SIZES), default=list(DEFAULT_SIZES))
    parser.add_argument("--sizes", type=int, nargs="+", help="swarm sizes (default: 9 25 49 paddle, 9 100 400 disk)")
    parser.add_argument("--seeds", type=parse_seeds, default=parse_seeds("0-4"))
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--n-phases", type=int, nargs="+", default=[DEFAULT_N_PHASES])
    parser.add_argument("--sides", nargs="+", choices=START_SIDES, help="wave directions (default: the model's)")
    parser.add_argument("--no-centralised", action="store_true", help="skip the centralised wave")
    parser.add_argument("--workers", type=int, default=2, help="processes (1: run in this one)")
    args = parser.parse_args(argv)

    variants = [] if args.no_centralised else [(CENTRALISED, 0, None)]
    variants += [("decentralised", p, side) for p in args.n_phases for side in (args.sides or [None])]
    grid = [(model, n) for model in args.models for n in (args.sizes or DEFAULT_SIZES[model])]
    started = time.perf_counter()
    jobs = {
        (model, n, variant, seed): (args.env, model, n, args.steps, *variant, seed)
        for model, n in grid
        for variant in variants
        for seed in args.seeds
    }
    if args.workers <= 1:
        results = {key: projected_displacement(*job) for key, job in jobs.items()}
    else:
        with ProcessPoolExecutor(args.workers) as pool:
            futures = {key: pool.submit(projected_displacement, *job) for key, job in jobs.items()}
            results = {key: future.result() for key, future in futures.items()}
    elapsed = time.perf_counter() - started
    seeds = (
        f"{args.seeds[0]}-{args.seeds[-1]}"
        if args.seeds == list(range(args.seeds[0], args.seeds[-1] + 1))
        else args.seeds
    )
    print(
        f"{args.env}, {args.steps} steps, seeds {seeds}: projected displacement, median (min to max); {elapsed:.0f} s"
    )
    print("| model | N | policy | n_phases | side | median (min to max) |")
    print("|---|---:|---|---:|---|---|")
    for model, n in grid:
        for variant in variants:
            values = np.array([results[(model, n, variant, seed)] for seed in args.seeds])
            policy, n_phases, side = variant
            phases = "" if policy == CENTRALISED else str(n_phases)
            side = side or "default"
            summary = f"{np.median(values):.1f} ({values.min():.1f} to {values.max():.1f})"
            print(f"| {model} | {n} | {policy} | {phases} | {side} | {summary} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
