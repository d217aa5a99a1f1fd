#!/usr/bin/env python
"""Paddle against disk: does the fast disk model move like the paper's paddle robot at every swarm size?

For each swarm size, robot model and wave side, the wave policy (with each model's default hold) runs
Navigation episodes on ``--seeds``; the tool prints the median projected displacement per cell and checks
what the disk model must show to stand in for the paddle model:

* the two models agree on the sign of the wave's displacement, each with the side it uses by default;
* the disk's median lies within 0.5-2x of the paddle's.

Paddle episodes of hundreds of robots take minutes, so every finished episode is appended to ``--cache``
(JSON lines) and a rerun only computes the missing ones; change ``--cache`` (or delete it) after changing a
model. ``--json`` writes the table as data.

    python tools/model_agreement.py                                   # N = 9 25 49 100 225, seeds 0-4
    python tools/model_agreement.py --models paddle --workers 1 --cache /tmp/paddle.jsonl
    python tools/model_agreement.py --sizes 9 25 --steps 500 --seeds 0-1
"""

from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np
from episode_cache import append_episode, load_episodes
from wave_sweep import projected_displacement

from dpr.cli import parse_seeds
from dpr.envs import MAX_EPISODE_STEPS
from dpr.policies.wave import MODEL_DEFAULTS, START_SIDES

ENV_ID = "dpr/Navigation-v0"
MODELS = ("paddle", "disk")
RATIO_RANGE = (0.5, 2.0)


def cell_key(model: str, n_robots: int, side: str, hold: int, steps: int, seed: int) -> str:
    return f"{model}/{n_robots}/{side}/{hold}/{steps}/{seed}"


def run_cells(cells: list[tuple], steps: int, workers: int, cache_path: Path | None) -> dict[str, float]:
    """Projected displacement of every ``(model, n, side, hold, seed)`` cell, from the cache or computed."""
    results = {key: record["displacement"] for key, record in load_episodes(cache_path).items()}
    todo = [cell for cell in cells if cell_key(*cell[:4], steps, cell[4]) not in results]
    print(f"{len(cells) - len(todo)} cached, {len(todo)} to run", file=sys.stderr, flush=True)
    # the slowest (largest paddle swarms) first, so that the pool ends together
    todo.sort(key=lambda cell: -cell[1] * (30 if cell[0] == "paddle" else 1))
    with ProcessPoolExecutor(workers) as pool:
        futures = {
            pool.submit(projected_displacement, ENV_ID, model, n, steps, hold, side, seed): (model, n, side, hold, seed)
            for model, n, side, hold, seed in todo
        }
        for done, future in enumerate(as_completed(futures), 1):
            model, n, side, hold, seed = futures[future]
            key = cell_key(model, n, side, hold, steps, seed)
            results[key] = float(future.result())
            append_episode(cache_path, {"key": key, "displacement": results[key]})
            print(f"[{done}/{len(todo)}] {key}: {results[key]:.1f}", file=sys.stderr, flush=True)
    return results


def agreement_table(results: dict[str, float], sizes, seeds, steps: int, models) -> list[dict]:
    rows = []
    for n in sizes:
        row: dict = {"n_robots": n}
        for model in models:
            hold = MODEL_DEFAULTS[model]["hold_steps"]
            row[f"{model}_default_side"] = MODEL_DEFAULTS[model]["start_side"]
            for side in START_SIDES:
                values = [results[cell_key(model, n, side, hold, steps, s)] for s in seeds]
                row[f"{model}_{side}"] = float(np.median(values))
            row[f"{model}_default"] = row[f"{model}_{row[f'{model}_default_side']}"]
        if set(models) == set(MODELS):
            paddle, disk = row["paddle_default"], row["disk_default"]
            row["same_sign"] = bool(np.sign(paddle) == np.sign(disk))
            row["ratio"] = disk / paddle if paddle else float("nan")
            row["agrees"] = row["same_sign"] and RATIO_RANGE[0] <= row["ratio"] <= RATIO_RANGE[1]
        rows.append(row)
    return rows


def print_table(rows: list[dict], models) -> None:
    header = ["N"]
    for model in models:
        header += [f"{model} near", f"{model} far", f"{model} default"]
    both = set(models) == set(MODELS)
    if both:
        header += ["disk / paddle", "agrees"]
    print("| " + " | ".join(header) + " |")
    print("|" + "---:|" * len(header))
    for row in rows:
        cells = [str(row["n_robots"])]
        for model in models:
            cells += [f"{row[f'{model}_near']:+.1f}", f"{row[f'{model}_far']:+.1f}", row[f"{model}_default_side"]]
        if both:
            cells += [f"{row['ratio']:.2f}x", "yes" if row["agrees"] else "**no**"]
        print("| " + " | ".join(cells) + " |")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[9, 25, 49, 100, 225])
    parser.add_argument("--models", nargs="+", choices=MODELS, default=list(MODELS))
    parser.add_argument("--seeds", type=parse_seeds, default=parse_seeds("0-4"))
    parser.add_argument("--steps", type=int, default=MAX_EPISODE_STEPS)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--cache", type=Path, default=None, help="JSON-lines file of finished episodes (resume)")
    parser.add_argument("--json", type=Path, default=None, help="write the table's rows here")
    args = parser.parse_args()
    if any(n < 2 for n in args.sizes):
        parser.error("--sizes: every swarm needs at least 2 robots for a wave")
    cells = [
        (model, n, side, MODEL_DEFAULTS[model]["hold_steps"], seed)
        for model in args.models
        for n in args.sizes
        for side in START_SIDES
        for seed in args.seeds
    ]
    results = run_cells(cells, args.steps, args.workers, args.cache)
    rows = agreement_table(results, args.sizes, args.seeds, args.steps, args.models)
    print(f"{ENV_ID}, wave policy with each model's default hold, {args.steps} steps, seeds {args.seeds}")
    print("median projected displacement; 'default' = the side each model uses by default at that N")
    print_table(rows, args.models)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0 if all(row.get("agrees", True) for row in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
