#!/usr/bin/env python
"""Scale benchmarks: vectorised envs across processes, per-robot step cost, and a 1000-robot episode.

* (a) ``vec``: throughput (env steps/s summed over envs) of ``gym.make_vec(..., vectorization_mode="async")``
  with 1 and with 2 worker processes, paddle model, N=9, random actions; the ratio 2-env / 1-env
  (target >= 1.7 on a 2-core machine). Each configuration is run ``--repeats`` times, interleaved, and the
  best run is kept (the capacity of the machine, least disturbed by other processes).
* (b) ``sizes``: disk model, N in ``--sizes`` (100, 400, 1000), random actions and the wave policy:
  microseconds per robot-step (wall time of env step + policy / steps / N, fastest of ``--size-repeats``
  runs); target: the largest N costs at most 2x the smallest per robot-step.
* (c) ``episode``: a ``--episode-robots`` (1000) disk-model swarm runs a ``--episode-steps`` (2500) wave-policy
  Navigation episode. Checked at every step: no ``physics_error`` in info, no tunnelling (no robot's centre
  ever inside another robot's contracted disk: every pair of centres at least one contracted radius apart;
  past that, the solver may push a pair out on the wrong side, through each other), touching contracted
  robots within ``--tolerance`` (5) units of contact (every pair of centres at least ``2 * contracted radius
  - tolerance`` apart), and a positive projected displacement at the end. The largest overlap with the
  robots' actual radii is reported beside them. Reports the wall time of the episode (env + policy; the
  checks are timed apart).

    python tools/bench_scale.py [--parts vec sizes episode] [--json out.json] [--profile]

``--profile`` adds a cProfile of the largest swarm's wave-policy steps (top functions by own time), to see
where a missed per-robot target goes.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import os
import pstats
import sys
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import dpr  # noqa: F401  (registers the ids)
from dpr.envs import MAX_EPISODE_STEPS, PHYSICS_ERROR
from dpr.policies.wave import WavePolicy
from dpr.sim.neighbours import pairs_within

ENV_ID = "dpr/Navigation-v0"
PARTS = ("vec", "sizes", "episode")
VEC_TARGET = 1.7
SIZE_TARGET = 2.0


def load() -> list[float]:
    """1, 5 and 15 minute load averages: how busy the machine was (other processes skew timings)."""
    return [round(x, 2) for x in os.getloadavg()]


# -- (a) processes ---------------------------------------------------------------------------------------
def vec_throughput(num_envs: int, steps: int, seed: int) -> float:
    """Env steps per second (summed over the envs) of an async vector env, paddle model, N=9."""
    envs = gym.make_vec(ENV_ID, num_envs=num_envs, vectorization_mode="async", n_robots=9, robot_model="paddle")
    try:
        envs.reset(seed=seed)
        actions = np.random.default_rng(seed).integers(0, 2, size=(steps + 10, num_envs, 9)).astype(np.int8)
        for action in actions[:10]:  # warm-up: workers running, caches built
            envs.step(action)
        started = time.perf_counter()
        for action in actions[10:]:
            envs.step(action)
        elapsed = time.perf_counter() - started
    finally:
        envs.close()
    return num_envs * steps / elapsed


def bench_vec(steps: int, repeats: int) -> dict:
    runs: dict[int, list[float]] = {1: [], 2: []}
    for repeat in range(repeats):  # interleaved, so that load changes hit both alike
        for num_envs in runs:
            runs[num_envs].append(vec_throughput(num_envs, steps, seed=repeat))
    best = {k: max(v) for k, v in runs.items()}
    ratio = best[2] / best[1]
    return {
        "steps_per_env": steps,
        "repeats": repeats,
        "steps_per_s": {str(k): [round(x, 1) for x in v] for k, v in runs.items()},
        "best_steps_per_s": {str(k): round(v, 1) for k, v in best.items()},
        "ratio": round(ratio, 3),
        "target": VEC_TARGET,
        "met": ratio >= VEC_TARGET,
    }


# -- (b) swarm size ----------------------------------------------------------------------------------------
def step_cost(n_robots: int, policy_name: str, steps: int, warmup: int, seed: int, profile: bool = False) -> dict:
    """Mean wall time of env step + policy at ``n_robots``, disk model."""
    env = gym.make(ENV_ID, n_robots=n_robots, robot_model="disk")
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    if policy_name == "wave":
        policy = WavePolicy.from_env(env)
        policy.reset()
    else:
        actions = iter(rng.integers(0, 2, size=(warmup + steps, n_robots)).astype(np.int8))

        def policy(_):
            return next(actions)

    for _ in range(warmup):
        obs, *_ = env.step(policy(obs))
    profiler = cProfile.Profile() if profile else None
    if profiler:
        profiler.enable()
    started = time.perf_counter()
    for _ in range(steps):
        obs, _, terminated, truncated, info = env.step(policy(obs))
        if terminated or truncated:
            raise RuntimeError(f"episode ended during the benchmark at N={n_robots}: {info}")
    elapsed = time.perf_counter() - started
    result = {
        "n_robots": n_robots,
        "policy": policy_name,
        "steps": steps,
        "ms_per_step": round(elapsed / steps * 1e3, 3),
        "us_per_robot_step": round(elapsed / steps / n_robots * 1e6, 3),
    }
    if profiler:
        profiler.disable()
        text = io.StringIO()
        pstats.Stats(profiler, stream=text).sort_stats("tottime").print_stats(15)
        result["profile"] = text.getvalue()
    env.close()
    return result


def bench_sizes(sizes: list[int], steps: int, warmup: int, repeats: int, profile: bool) -> dict:
    rows = []
    for policy_name in ("random", "wave"):
        for n in sizes:
            # the same seeded run ``repeats`` times; the fastest is kept (least disturbed by other processes)
            runs = [step_cost(n, policy_name, steps, warmup, seed=0) for _ in range(repeats)]
            best = min(runs, key=lambda r: r["ms_per_step"])
            best["runs_ms_per_step"] = [r["ms_per_step"] for r in runs]
            if profile and n == max(sizes) and policy_name == "wave":
                best["profile"] = step_cost(n, policy_name, steps, warmup, seed=0, profile=True)["profile"]
            rows.append(best)
    verdict = {}
    for policy_name in ("random", "wave"):
        cost = {r["n_robots"]: r["us_per_robot_step"] for r in rows if r["policy"] == policy_name}
        ratio = cost[max(sizes)] / cost[min(sizes)]
        verdict[policy_name] = {"ratio": round(ratio, 3), "target": SIZE_TARGET, "met": ratio <= SIZE_TARGET}
    return {"rows": rows, "repeats": repeats, "largest_over_smallest": verdict}


# -- (c) a large episode -----------------------------------------------------------------------------------
def closest_pairs(swarm) -> tuple[float, tuple[float, float], float]:
    """Smallest centre distance over all robot pairs with that pair's radii, and the largest overlap of two
    robots' actual disks (radius sum minus centre distance)."""
    pairs = pairs_within(swarm.position, 2 * swarm.expanded_radius)
    if len(pairs) == 0:
        return float("inf"), (0.0, 0.0), 0.0
    delta = swarm.position[pairs[:, 0]] - swarm.position[pairs[:, 1]]
    distance = np.sqrt(np.einsum("ij,ij->i", delta, delta))
    radius = getattr(swarm, "radius", np.full(swarm.n, swarm.contracted_radius))
    overlap = radius[pairs[:, 0]] + radius[pairs[:, 1]] - distance
    closest = int(distance.argmin())
    i, j = pairs[closest]
    return float(distance[closest]), (float(radius[i]), float(radius[j])), float(overlap.max())


def bench_episode(
    n_robots: int,
    steps: int,
    tolerance: float,
    seed: int,
    start_radius: float | None = None,
    start_side: str | None = None,
    hold_steps: int | None = None,
) -> dict:
    """One wave-policy episode of a large disk swarm. ``start_radius`` puts the swarm's centre that far from the
    goal (default: the env's 450-550, which a 1000-robot swarm covers); ``start_side``/``hold_steps`` override
    the disk model's wave defaults (hold 4, near side)."""
    kwargs = {} if start_radius is None else {"start_radius": (start_radius, start_radius)}
    env = gym.make(ENV_ID, n_robots=n_robots, robot_model="disk", max_episode_steps=steps, **kwargs)
    obs, _ = env.reset(seed=seed)
    overrides = {k: v for k, v in (("start_side", start_side), ("hold_steps", hold_steps)) if v is not None}
    policy = WavePolicy.from_env(env, **overrides)
    policy.reset()
    swarm = env.unwrapped.world.swarm  # one World per episode: this swarm lives as long as the episode
    min_allowed = 2 * swarm.contracted_radius - tolerance  # touching contracted robots, less the tolerance
    tunnelling_below = swarm.contracted_radius  # a centre inside another robot's disk
    min_distance, closest_radii, max_overlap = closest_pairs(swarm)
    closest_step = 0
    step_time = check_time = 0.0
    done_steps, errors, info, end = 0, [], {}, "truncated"
    for _ in range(steps):
        started = time.perf_counter()
        obs, _, terminated, truncated, info = env.step(policy(obs))
        checked = time.perf_counter()
        step_time += checked - started
        done_steps += 1
        if PHYSICS_ERROR in info:
            errors.append(info[PHYSICS_ERROR])
        distance, radii, overlap = closest_pairs(swarm)
        if distance < min_distance:
            min_distance, closest_radii, closest_step = distance, radii, done_steps
        max_overlap = max(max_overlap, overlap)
        check_time += time.perf_counter() - checked
        if terminated or truncated:
            end = "terminated" if terminated else "truncated"
            break
    env.close()
    ok = {
        "no_physics_error": not errors,
        "no_tunnelling": min_distance >= tunnelling_below,
        "contact_within_tolerance": min_distance >= min_allowed,
        "moved_toward_goal": info.get("projected_displacement", 0.0) > 0.0,
    }
    return {
        "n_robots": n_robots,
        "start_radius": start_radius,
        "wave": {"start_side": policy.start_side, "hold_steps": policy.hold_steps},
        "steps": done_steps,
        "end": end,
        "wall_s": round(step_time, 2),
        "check_s": round(check_time, 2),
        "ms_per_step": round(step_time / done_steps * 1e3, 3),
        "min_centre_distance": round(min_distance, 3),
        "tunnelling_below": round(tunnelling_below, 3),
        "min_allowed_distance": round(min_allowed, 3),
        "closest_pair_radii": [round(r, 2) for r in closest_radii],
        "closest_pair_step": closest_step,
        "max_overlap_actual_radii": round(max_overlap, 3),
        "projected_displacement": round(float(info.get("projected_displacement", 0.0)), 2),
        "net_displacement": round(float(info.get("net_displacement", 0.0)), 2),
        "is_success": bool(info.get("is_success", False)),
        "physics_errors": errors[:3],
        "checks": ok,
        "met": all(ok.values()),
    }


# -- report ------------------------------------------------------------------------------------------------
def markdown(results: dict) -> str:
    lines = [f"cores: {os.cpu_count()}, load average before each part: {results['load']}", ""]
    if "vec" in results:
        v = results["vec"]
        lines += [
            "| async envs (paddle, N=9) | env steps/s (best) | runs |",
            "|---|---|---|",
            *(f"| {k} | {v['best_steps_per_s'][k]} | {v['steps_per_s'][k]} |" for k in ("1", "2")),
            "",
            f"ratio 2/1: **{v['ratio']}** (target >= {v['target']}: {'met' if v['met'] else 'MISSED'})",
            "",
        ]
    if "sizes" in results:
        s = results["sizes"]
        lines += ["| policy | N (disk) | ms/step (best) | us/robot-step | runs ms/step |", "|---|---|---|---|---|"]
        lines += [
            f"| {r['policy']} | {r['n_robots']} | {r['ms_per_step']} | {r['us_per_robot_step']} "
            f"| {r['runs_ms_per_step']} |"
            for r in s["rows"]
        ]
        lines.append("")
        for name, verdict in s["largest_over_smallest"].items():
            state = "met" if verdict["met"] else "MISSED"
            lines.append(
                f"{name}: largest/smallest per robot-step **{verdict['ratio']}** "
                f"(target <= {verdict['target']}: {state})"
            )
        lines.append("")
    if "episode" in results:
        e = results["episode"]
        lines += [
            "| N (disk) | start radius | wave | steps | end | wall s (env+policy) | ms/step | min centre distance "
            "(tunnelling below; contact tolerance) | max overlap (actual radii) | projected displacement | checks |",
            "|---|---|---|---|---|---|---|---|---|---|---|",
            f"| {e['n_robots']} | {e['start_radius'] or '450-550'} | {e['wave']['start_side']}, hold "
            f"{e['wave']['hold_steps']} | {e['steps']} | {e['end']} | {e['wall_s']} | {e['ms_per_step']} | "
            f"{e['min_centre_distance']} (tunnelling below {e['tunnelling_below']}; contact tolerance "
            f"{e['min_allowed_distance']}: {'within' if e['checks']['contact_within_tolerance'] else 'beyond'}; radii "
            f"{e['closest_pair_radii']}, step "
            f"{e['closest_pair_step']}) | {e['max_overlap_actual_radii']} | "
            f"{e['projected_displacement']} | {'all passed' if e['met'] else e['checks']} |",
            "",
        ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--parts", nargs="+", choices=PARTS, default=list(PARTS))
    parser.add_argument("--vec-steps", type=int, default=1000, help="timed steps per vector env run (a)")
    parser.add_argument("--repeats", type=int, default=3, help="interleaved runs of each vector env (a)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[100, 400, 1000], help="swarm sizes (b)")
    parser.add_argument("--size-steps", type=int, default=200, help="timed steps per size (b)")
    parser.add_argument("--warmup", type=int, default=20, help="untimed steps before timing (b)")
    parser.add_argument("--size-repeats", type=int, default=3, help="runs of each size, the fastest kept (b)")
    parser.add_argument("--episode-robots", type=int, default=1000, help="swarm size of the episode (c)")
    parser.add_argument("--episode-steps", type=int, default=MAX_EPISODE_STEPS, help="episode length (c)")
    parser.add_argument(
        "--tolerance",
        type=float,
        default=5.0,
        help="how far two touching contracted robots may press into each other (c; pass/fail)",
    )
    parser.add_argument(
        "--episode-start-radius",
        type=float,
        help="distance of the swarm's start from the goal (c; default: the env's, shifted out for large swarms)",
    )
    parser.add_argument(
        "--episode-side", choices=("near", "far"), help="wave start side (c; default: the disk model's)"
    )
    parser.add_argument("--episode-hold", type=int, help="wave hold steps (c; default: the disk model's)")
    parser.add_argument("--profile", action="store_true", help="cProfile the largest wave-policy size (b)")
    parser.add_argument("--json", type=Path, help="also write the results to this JSON file")
    args = parser.parse_args(argv)
    for name in ("vec_steps", "repeats", "size_steps", "size_repeats", "episode_robots", "episode_steps"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1")
    if any(n < 1 for n in args.sizes):
        parser.error("--sizes must be >= 1")

    results: dict = {"cpu_count": os.cpu_count(), "load": {}}
    if "vec" in args.parts:
        results["load"]["vec"] = load()
        results["vec"] = bench_vec(args.vec_steps, args.repeats)
    if "sizes" in args.parts:
        results["load"]["sizes"] = load()
        results["sizes"] = bench_sizes(args.sizes, args.size_steps, args.warmup, args.size_repeats, args.profile)
    if "episode" in args.parts:
        results["load"]["episode"] = load()
        results["episode"] = bench_episode(
            args.episode_robots,
            args.episode_steps,
            args.tolerance,
            seed=0,
            start_radius=args.episode_start_radius,
            start_side=args.episode_side,
            hold_steps=args.episode_hold,
        )

    print(markdown(results))
    for row in results.get("sizes", {}).get("rows", []):
        if "profile" in row:
            print(f"profile, wave policy, N={row['n_robots']}:\n{row['profile']}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
