#!/usr/bin/env python
"""Batched engine against pymunk: does ``dpr.sim.batched`` move the disk swarm as the pymunk disk model does?

For each case (task, N) both engines run the wave (the disk model's: hold 4, near side first) from the same
starts: each seed's pymunk env is reset, and its robot centres, dead robots, walls and ball seed one swarm of the
batched world, all seeds stepped together. The tool prints, per case, the median projected displacement of the
agent (the swarm's centre, or the ball) over the seeds in each engine, their ratio, and the deepest robot-robot
overlap seen (sampled every ``--overlap-every`` steps). The batched engine agrees when the ratio lies in
0.9-1.1 and its overlap is no deeper than pymunk's (within 0.5 units).

Episodes are cached (JSON lines, ``--cache``; the batched ones keyed by the engine's source and solver settings):
a rerun only computes the missing ones, so a stopped run goes on where it stopped. ``--chunk`` steps the batched
seeds that many at a time, each chunk cached as it ends (swarms are independent, so a chunk's size changes a swarm's
trajectory only at the level of float rounding, which a long episode may still amplify).

    python tools/batched_agreement.py --cases navigation:9 --seeds 5000-5019
    python tools/batched_agreement.py                      # every case, seeds 5000-5099 (N=1000: --big-seeds)
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import torch

from dpr.cli import parse_seeds
from dpr.sim.neighbours import pairs_and_distances

CASES = {  # name: (env id, env kwargs)
    "navigation": ("dpr/Navigation-v0", {}),
    "gate": ("dpr/Gate-v2", {}),
    "unresponsive": ("dpr/Unresponsive-v0", {}),
    "manipulation": ("dpr/Manipulation-v0", {}),
}
DEFAULT_CASES = ["navigation:9", "gate:9", "unresponsive:9", "manipulation:9", "navigation:100", "navigation:1000"]
RATIO_RANGE = (0.9, 1.1)
HOLD_STEPS = 4  # DiskSwarm.wave_hold_steps
BIN_WIDTH = 60.0  # dpr.policies.wave.BIN_WIDTH


def _make_env(task: str, n_robots: int, steps: int):
    import gymnasium as gym

    import dpr  # noqa: F401  (registers the ids in worker processes)

    env_id, kwargs = CASES[task]
    return gym.make(env_id, robot_model="disk", n_robots=n_robots, max_episode_steps=steps, **kwargs)


def pymunk_start(task: str, n_robots: int, seed: int) -> dict:
    """What the batched world needs to start where the pymunk env starts for ``seed``."""
    env = _make_env(task, n_robots, 1)
    env.reset(seed=seed)
    base = env.unwrapped
    world = base.world
    start = {
        "centres": world.swarm.position.tolist(),
        "dead": world.dead.tolist(),
        "walls": [w.tolist() for w in world.walls],
        "goal": base.goal.tolist(),
        "object": None if world.object_body is None else world.object_pose[0:2].tolist(),
        "object_radius": None if world.object_spec is None else world.object_spec.size,
    }
    env.close()
    return start


def _overlap(position: np.ndarray, radius: np.ndarray) -> float:
    pairs, distance = pairs_and_distances(position, 2 * float(radius.max()))
    if len(pairs) == 0:
        return 0.0
    return float(max(0.0, (radius[pairs[:, 0]] + radius[pairs[:, 1]] - distance).max()))


def pymunk_episode(task: str, n_robots: int, seed: int, steps: int, overlap_every: int) -> dict:
    """The wave's projected displacement and deepest robot overlap in one pymunk episode."""
    from dpr.policies.wave import WavePolicy

    env = _make_env(task, n_robots, steps)
    policy = WavePolicy.from_env(env)
    observation, _ = env.reset(seed=seed)
    swarm = env.unwrapped.world.swarm
    overlap = 0.0
    for step in range(steps):
        observation, _, terminated, truncated, info = env.step(policy(observation))
        if step % overlap_every == 0:
            overlap = max(overlap, _overlap(swarm.position, swarm.radius))
        if terminated or truncated:
            break
    env.close()
    return {"displacement": float(info["projected_displacement"]), "overlap": overlap}


class BatchedWave:
    """:class:`dpr.policies.wave.WavePolicy` for K swarms at once (hold ``hold``, near side first)."""

    def __init__(self, goal: torch.Tensor, n_robots: int, hold: int = HOLD_STEPS, bin_width: float = BIN_WIDTH):
        k = len(goal)
        self.goal, self.hold, self.bin_width = goal, hold, bin_width
        self.bins = torch.zeros(k, n_robots, dtype=torch.long)
        self.phases = torch.zeros(k, dtype=torch.long)
        self.step_in_cycle = torch.zeros(k, dtype=torch.long)

    def __call__(self, position: torch.Tensor) -> torch.Tensor:
        replan = self.step_in_cycle >= self.phases * self.hold
        relative = position - self.goal[:, None]
        centre = relative.mean(dim=1)
        direction = centre / torch.linalg.vector_norm(centre, dim=-1, keepdim=True)
        distance = (relative * direction[:, None]).sum(-1).abs()
        bins = torch.div(
            distance - distance.min(dim=1, keepdim=True).values, self.bin_width, rounding_mode="floor"
        ).long()
        self.bins = torch.where(replan[:, None], bins, self.bins)
        self.phases = torch.where(replan, self.bins.max(dim=1).values + 1, self.phases)
        self.step_in_cycle = torch.where(replan, 0, self.step_in_cycle)
        phase = torch.div(self.step_in_cycle, self.hold, rounding_mode="floor")
        self.step_in_cycle += 1
        return (self.bins == phase[:, None]).float()


def batched_episodes(starts: list[dict], steps: int, overlap_every: int, **world_kwargs) -> dict:
    """Every start as one swarm of one batched world, stepped together under the wave."""
    from dpr.sim.batched import BatchedDiskWorld, SolverSettings

    k, n = len(starts), len(starts[0]["centres"])
    walls = [s["walls"] for s in starts]
    n_walls = len(walls[0])
    radius = starts[0]["object_radius"]
    world = BatchedDiskWorld(k, n, n_walls=n_walls, object_radius=radius, solver=SolverSettings(**world_kwargs))
    world.reset(
        torch.ones(k, dtype=torch.bool),
        torch.tensor([s["centres"] for s in starts]),
        torch.tensor([s["dead"] for s in starts]),
        walls=torch.tensor(walls).reshape(k, n_walls, 4, 2) if n_walls else None,
        object_position=torch.tensor([s["object"] for s in starts]) if radius is not None else None,
    )
    goal = torch.tensor([s["goal"] for s in starts], dtype=torch.float32)
    wave = BatchedWave(goal, n)

    def agent() -> torch.Tensor:
        return world.object_position.clone() if radius is not None else world.centre_of_mass

    first = agent().double()
    overlap = torch.zeros(k)
    for step in range(steps):
        world.step(wave(world.position))
        if step % overlap_every == 0:
            overlap = torch.maximum(overlap, world.max_overlap())
    to_goal = goal.double() - first
    to_goal = to_goal / torch.linalg.vector_norm(to_goal, dim=-1, keepdim=True)
    displacement = ((agent().double() - first) * to_goal).sum(-1)
    return {"displacement": displacement.tolist(), "overlap": overlap.tolist(), "sane": world.is_sane().tolist()}


def engine_fingerprint(world_kwargs: dict) -> str:
    """A short hash of the batched engine's source and the solver settings: what a cached batched episode is
    only valid for."""
    digest = hashlib.sha256(json.dumps(world_kwargs, sort_keys=True).encode())
    for path in sorted((Path(__file__).resolve().parents[1] / "dpr" / "sim" / "batched").glob("*.py")):
        digest.update(path.read_bytes())
    return digest.hexdigest()[:12]


def cached_batched_episodes(
    starts: list[dict], keys: list[str], cache: dict, cache_path: Path | None, chunk: int, **kw
) -> dict:
    """:func:`batched_episodes` over the starts whose keys the cache lacks, ``chunk`` at a time (0: all at once),
    each chunk appended to the cache as it ends; the episodes of every key."""
    todo = [i for i, key in enumerate(keys) if key not in cache]
    size = chunk or max(len(todo), 1)
    for first in range(0, len(todo), size):
        picked = todo[first : first + size]
        result = batched_episodes([starts[i] for i in picked], **kw)
        for j, i in enumerate(picked):
            _remember(cache, cache_path, {"key": keys[i], **{name: values[j] for name, values in result.items()}})
    return {name: [cache[key][name] for key in keys] for name in ("displacement", "overlap", "sane")}


def ratio_interval(reference: np.ndarray, ours: np.ndarray, resamples: int = 2000) -> list[float]:
    """A 95% bootstrap interval of median(ours) / median(reference), the seeds resampled in pairs (both engines
    start each seed alike): how far the ratio moves with the draw of starts alone."""
    generator = np.random.default_rng(0)
    picks = generator.integers(0, len(reference), size=(resamples, len(reference)))
    ratios = np.median(ours[picks], axis=1) / np.median(reference[picks], axis=1)
    return [float(v) for v in np.percentile(ratios, [2.5, 97.5])]


def _remember(cache: dict, path: Path | None, record: dict) -> None:
    """``record`` into ``cache`` under its key, and appended to the cache file ``path`` (when given) at once."""
    cache[record["key"]] = record
    if path:
        with path.open("a") as f:
            f.write(json.dumps(record) + "\n")


def _load_cache(path: Path | None) -> dict:
    if path is None or not path.exists():
        return {}
    return {r["key"]: r for r in map(json.loads, path.read_text().splitlines()) if r}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", nargs="+", default=DEFAULT_CASES, help="task:N, task one of " + ", ".join(CASES))
    parser.add_argument("--seeds", type=parse_seeds, default=parse_seeds("5000-5099"))
    parser.add_argument("--big-seeds", type=parse_seeds, default=parse_seeds("5000-5009"), help="seeds when N >= 1000")
    parser.add_argument("--steps", type=int, default=2500)
    parser.add_argument("--overlap-every", type=int, default=10)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--iterations", type=int, default=None, help="batched solver iterations (default: its own)")
    parser.add_argument("--relaxation", type=float, default=None, help="batched over-relaxation (default: its own)")
    parser.add_argument("--cache", type=Path, default=Path("runs/agreement/pymunk.jsonl"))
    parser.add_argument("--batched-cache", type=Path, default=Path("runs/agreement/batched.jsonl"))
    parser.add_argument("--chunk", type=int, default=0, help="batched seeds stepped at a time (0: all)")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    torch.set_num_threads(args.workers)
    solver = {} if args.iterations is None else {"iterations": args.iterations}
    if args.relaxation is not None:
        solver["relaxation"] = args.relaxation
    world_kwargs = solver
    for path in (args.cache, args.batched_cache):
        path.parent.mkdir(parents=True, exist_ok=True)
    cache, batched_cache = _load_cache(args.cache), _load_cache(args.batched_cache)
    fingerprint = engine_fingerprint(world_kwargs)
    rows = []
    for case in args.cases:
        task, n = case.split(":")
        n = int(n)
        seeds = args.big_seeds if n >= 1000 else args.seeds
        keys = [f"{task}/{n}/{args.steps}/{args.overlap_every}/{seed}" for seed in seeds]
        todo = [(key, seed) for key, seed in zip(keys, seeds) if key not in cache]
        started = time.perf_counter()
        with ProcessPoolExecutor(args.workers) as pool:
            starts = list(pool.map(pymunk_start, [task] * len(seeds), [n] * len(seeds), seeds))
            futures = {
                key: pool.submit(pymunk_episode, task, n, seed, args.steps, args.overlap_every) for key, seed in todo
            }
            for key, future in futures.items():
                _remember(cache, args.cache, {"key": key, **future.result()})
        pymunk_seconds = time.perf_counter() - started
        started = time.perf_counter()
        batched = cached_batched_episodes(
            starts, [f"{key}/{fingerprint}" for key in keys], batched_cache, args.batched_cache, args.chunk,
            steps=args.steps, overlap_every=args.overlap_every, **world_kwargs,
        )  # fmt: skip
        batched_seconds = time.perf_counter() - started
        reference = np.array([cache[key]["displacement"] for key in keys])
        ours = np.array(batched["displacement"])
        row = {
            "case": case,
            "seeds": len(seeds),
            "pymunk_median": float(np.median(reference)),
            "batched_median": float(np.median(ours)),
            "pymunk_overlap": max(cache[key]["overlap"] for key in keys),
            "batched_overlap": float(max(batched["overlap"])),
            "batched_sane": bool(all(batched["sane"])),
            "pymunk_seconds": pymunk_seconds,
            "batched_seconds": batched_seconds,
        }
        row["ratio"] = row["batched_median"] / row["pymunk_median"] if row["pymunk_median"] else float("nan")
        row["ratio_ci95"] = ratio_interval(reference, ours)
        row["pymunk_displacements"], row["batched_displacements"] = reference.tolist(), ours.tolist()
        row["agrees"] = (
            RATIO_RANGE[0] <= row["ratio"] <= RATIO_RANGE[1]
            and row["batched_overlap"] <= row["pymunk_overlap"] + 0.5
            and row["batched_sane"]
        )
        rows.append(row)
        summary = {k: v for k, v in row.items() if not k.endswith("displacements")}
        print(json.dumps(summary), file=sys.stderr, flush=True)
    print(f"wave (hold {HOLD_STEPS}, near side), {args.steps} steps; median projected displacement over the seeds")
    print(
        "| case | seeds | pymunk | batched | batched / pymunk [95% CI] | max overlap pymunk | max overlap batched "
        "| agrees |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---|")
    for r in rows:
        print(
            f"| {r['case']} | {r['seeds']} | {r['pymunk_median']:+.1f} | {r['batched_median']:+.1f} | "
            f"{r['ratio']:.2f} [{r['ratio_ci95'][0]:.2f}, {r['ratio_ci95'][1]:.2f}] | "
            f"{r['pymunk_overlap']:.2f} | {r['batched_overlap']:.2f} | {'yes' if r['agrees'] else '**no**'} |"
        )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0 if all(r["agrees"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
