"""Swarm-size sweep of centralised and decentralised control: median projected displacement and cost per robot-step.

Policies, each run in the same centralised env (so the physics is the same):

* ``centralised``: the wave, ``WavePolicy.from_env`` (it bins the robots along the goal direction from the swarm's
  centre, knowing every robot's position);
* ``decentralised``: ``DecentralisedWavePolicy.for_env`` (every robot decides from its own local observation: its
  distance to the goal and the shared clock), for each ``--n-phases`` and ``--sides``;
* any per-robot model file given to ``--policies`` (``dpr bc-decentralised``, ``dpr finetune-decentralised``): one
  model for every N, run through ``PerRobotPolicyAdapter``, on the robot model it was trained on only;
* any centralised model file whose actor is shared by the robots (``SwarmPolicy``, as the canonical models in
  models/): it reads the whole swarm but acts at any N, on either robot model, with the env kwargs it was trained
  with (its observation, its ``action_repeat``) and as it is on ``--env`` when that is another task of its spaces.

Prints a markdown table per robot model and N: median (min to max) over seeds, % of the centralised wave's median,
and microseconds of wall time per robot-step (env + policy). ``--cache`` keeps every finished episode (paddle
episodes of 100 robots take a minute or more; a model file is known there by its content as well as its path),
``--json`` writes the rows, ``--plot`` draws median against N:

    python tools/decentralised_sweep.py                                  # small default: 5 seeds x 500 steps
                                                                         # (paddle N=9, 25, 49; disk N=9, 100, 400)
    python tools/decentralised_sweep.py --models paddle --sizes 9 16 25 49 100 --seeds 1000-1019 --steps 2500 \\
        --policies centralised decentralised models/decentralised-bc.zip --cache sweep.jsonl --plot sweep.png
    python tools/decentralised_sweep.py --models disk --sizes 9 100 400 --n-phases 3 4 6
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import gymnasium as gym
import numpy as np
from episode_cache import append_episode, load_episodes

from dpr.cli import parse_seeds
from dpr.envs import episode_steps
from dpr.policies.decentralised import DEFAULT_N_PHASES, DecentralisedWavePolicy
from dpr.policies.wave import START_SIDES, WavePolicy
from dpr.rollout import roll_out
from dpr.sim.models import ROBOT_MODELS

CENTRALISED = "centralised"
DECENTRALISED = "decentralised"
DEFAULT_SIZES = {"paddle": [9, 25, 49], "disk": [9, 100, 400]}


def model_file_robot_models(path: str, env_id: str) -> tuple[str, ...]:
    """The robot models the model file at ``path`` runs on here: a per-robot model on the one it was trained on, a
    centralised ``SwarmPolicy`` model on both (checked against ``env_id`` now, so that a task of other spaces is
    refused before any episode). A ValueError naming the file for anything else."""
    from dpr.policies.model_file import has_swarm_actor, model_env_kwargs, read_model_info
    from dpr.policies.per_robot_spec import RobotModelSpec
    from dpr.policies.registry import make_policy

    info = read_model_info(path, "--policies")
    if info.per_robot is not None:
        return (RobotModelSpec.from_info(info, path, "--policies").robot_model,)
    if not has_swarm_actor(path):
        raise ValueError(
            f"--policies: {path} is a centralised model for {info.env_kwargs.get('n_robots', 'its')} robots only; a "
            "sweep over N runs per-robot models and centralised models whose actor is shared by the robots "
            "(SwarmPolicy), which act at any N"
        )
    env = gym.make(env_id, **model_env_kwargs(path, env_id, transfer=True))
    try:
        make_policy(path, env, transfer=True)  # a task whose spaces the model does not fit: refused here, named
    finally:
        env.close()
    return tuple(ROBOT_MODELS)


def run_episode(
    env_id: str, robot_model: str, n_robots: int, steps: int, policy: str, n_phases: int, side: str | None, seed: int
) -> dict:
    """One episode: its projected displacement and the wall time of its steps (env + policy)."""
    import dpr  # noqa: F401  (registers the ids in worker processes)
    from dpr.policies.model_file import model_env_kwargs, read_model_info
    from dpr.policies.registry import make_policy

    kwargs = {"n_robots": n_robots, "robot_model": robot_model}
    if policy not in (CENTRALISED, DECENTRALISED) and read_model_info(policy).per_robot is None:
        kwargs = model_env_kwargs(policy, env_id, kwargs, transfer=True)  # a centralised model's own observation
    # ``steps`` physics steps for every policy, also one that decides every ``action_repeat`` of them
    env = gym.make(env_id, max_episode_steps=episode_steps(kwargs, steps), **kwargs)
    try:
        if policy == CENTRALISED:
            actor = WavePolicy.from_env(env)
        elif policy == DECENTRALISED:
            actor = DecentralisedWavePolicy.for_env(env, n_phases=n_phases, **({"start_side": side} if side else {}))
        else:
            actor = make_policy(policy, env, transfer=True)
        started = time.perf_counter()
        result = roll_out(env, actor, seed)
        seconds = time.perf_counter() - started
    finally:
        env.close()
    return {"displacement": float(result.metrics.projected_displacement), "seconds": seconds}


def policy_identity(policy: str) -> str:
    """What names a policy in the cache: a model file by its path and its content, so that a file replaced under
    the same path runs again instead of taking the other file's episodes."""
    if policy in (CENTRALISED, DECENTRALISED):
        return policy
    return f"{policy}@{hashlib.sha256(Path(policy).read_bytes()).hexdigest()[:12]}"


def episode_key(env_id: str, model: str, n: int, policy: str, n_phases: int, side: str | None, steps: int, seed: int):
    """The cache key of one episode (``policy`` as :func:`policy_identity` gives it)."""
    return f"{env_id}/{model}/{n}/{policy}/{n_phases}/{side}/{steps}/{seed}"


def label(policy: str, n_phases: int, side: str | None) -> str:
    if policy == CENTRALISED:
        return "centralised wave"
    if policy == DECENTRALISED:
        return f"decentralised wave ({n_phases} phases{', ' + side if side else ''})"
    return Path(policy).name


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="dpr/Navigation-v0")
    parser.add_argument("--models", nargs="+", choices=tuple(DEFAULT_SIZES), default=list(DEFAULT_SIZES))
    parser.add_argument("--sizes", type=int, nargs="+", help="swarm sizes (default: 9 25 49 paddle, 9 100 400 disk)")
    parser.add_argument("--seeds", type=parse_seeds, default=parse_seeds("0-4"))
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument(
        "--policies",
        nargs="+",
        default=[CENTRALISED, DECENTRALISED],
        help="centralised, decentralised, and model files (.zip) that act at any N: per-robot models, and "
        "centralised ones with the swarm actor",
    )
    parser.add_argument("--n-phases", type=int, nargs="+", default=[DEFAULT_N_PHASES], help="of the decentralised wave")
    parser.add_argument("--sides", nargs="+", choices=START_SIDES, help="wave directions (default: the model's)")
    parser.add_argument("--workers", type=int, default=2, help="processes (1: run in this one)")
    parser.add_argument("--cache", type=Path, help="JSON-lines file of finished episodes: a rerun resumes")
    parser.add_argument("--json", type=Path, help="write the table's rows here")
    parser.add_argument("--plot", type=Path, help="draw median projected displacement against N into this PNG")
    args = parser.parse_args(argv)
    if any(n < 1 for n in args.sizes or []):
        parser.error("--sizes: every swarm needs at least 1 robot")
    files = {}
    for policy in args.policies:
        if policy not in (CENTRALISED, DECENTRALISED):
            if not policy.endswith(".zip") or not Path(policy).is_file():
                parser.error(f"--policies: {policy!r} is neither centralised, decentralised nor a model file")
            try:
                files[policy] = model_file_robot_models(policy, args.env)
            except ValueError as error:
                parser.error(str(error))

    variants = []
    for policy in args.policies:
        if policy == DECENTRALISED:
            variants += [(policy, p, side) for p in args.n_phases for side in (args.sides or [None])]
        else:
            variants.append((policy, 0, None))
    grid = [(model, n) for model in args.models for n in (args.sizes or DEFAULT_SIZES[model])]
    identity = {policy: policy_identity(policy) for policy in args.policies}
    jobs = {
        episode_key(args.env, model, n, identity[policy], n_phases, side, args.steps, seed): (
            args.env,
            model,
            n,
            args.steps,
            policy,
            n_phases,
            side,
            seed,
        )
        for model, n in grid
        for policy, n_phases, side in variants
        if model in files.get(policy, (model,))  # a per-robot model file runs on its own robot model only
        for seed in args.seeds
    }
    records = load_episodes(args.cache)
    todo = {key: job for key, job in jobs.items() if key not in records}
    print(f"{len(jobs) - len(todo)} episodes cached, {len(todo)} to run", file=sys.stderr, flush=True)
    started = time.perf_counter()

    def finished(key: str, record: dict) -> None:
        records[key] = {"key": key, **record}
        append_episode(args.cache, records[key])

    if args.workers <= 1:
        for key, job in todo.items():
            finished(key, run_episode(*job))
    else:
        with ProcessPoolExecutor(args.workers) as pool:
            # the largest swarms first, so that the workers end together
            order = sorted(todo, key=lambda key: -todo[key][2] * (30 if todo[key][1] == "paddle" else 1))
            futures = {pool.submit(run_episode, *todo[key]): key for key in order}
            for done, future in enumerate(as_completed(futures), 1):
                finished(futures[future], future.result())
                print(f"[{done}/{len(todo)}] {futures[future]}", file=sys.stderr, flush=True)
    elapsed = time.perf_counter() - started

    rows = []
    for model, n in grid:
        centralised = None
        for policy, n_phases, side in variants:
            keys = [
                episode_key(args.env, model, n, identity[policy], n_phases, side, args.steps, seed)
                for seed in args.seeds
            ]
            if keys[0] not in jobs:
                continue
            values = np.array([records[key]["displacement"] for key in keys])
            seconds = sum(records[key]["seconds"] for key in keys)
            row = {
                "robot_model": model,
                "n_robots": n,
                "policy": label(policy, n_phases, side),
                "median": float(np.median(values)),
                "min": float(values.min()),
                "max": float(values.max()),
                "us_per_robot_step": seconds / (len(keys) * args.steps * n) * 1e6,
            }
            if policy == CENTRALISED:
                centralised = row["median"]
            row["of_centralised"] = row["median"] / centralised if centralised else None
            rows.append(row)
    print(
        f"{args.env}, {args.steps} steps, seeds {args.seeds[0]}-{args.seeds[-1]} ({len(args.seeds)}); {elapsed:.0f} s"
    )
    print("| model | N | policy | median (min to max) | % of centralised | µs per robot-step |")
    print("|---|---:|---|---|---:|---:|")
    for row in rows:
        share = f"{row['of_centralised']:.0%}" if row["of_centralised"] is not None else ""
        print(
            f"| {row['robot_model']} | {row['n_robots']} | {row['policy']} | {row['median']:.1f} "
            f"({row['min']:.1f} to {row['max']:.1f}) | {share} | {row['us_per_robot_step']:.0f} |"
        )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    if args.plot:
        plot(rows, args.plot, f"{args.env}, {args.steps} steps, {len(args.seeds)} seeds")
    return 0


def plot(rows: list[dict], path: Path, title: str) -> None:
    """Median projected displacement against N, one panel per robot model, one line per policy."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    models = sorted({row["robot_model"] for row in rows}, key=list(DEFAULT_SIZES).index)
    figure, axes = plt.subplots(1, len(models), figsize=(6 * len(models), 4), squeeze=False)
    for axis, model in zip(axes[0], models):
        for policy in dict.fromkeys(row["policy"] for row in rows if row["robot_model"] == model):
            points = [
                (r["n_robots"], r["median"], r["min"], r["max"])
                for r in rows
                if r["policy"] == policy and r["robot_model"] == model
            ]
            n, median, low, high = map(np.array, zip(*points))
            axis.errorbar(n, median, yerr=[median - low, high - median], marker="o", capsize=3, label=policy)
        axis.set_xscale("log")
        axis.set_xlabel("robots (N)")
        axis.set_ylabel("projected displacement (median, min-max)")
        axis.set_title(f"{model} model")
        axis.axhline(0.0, color="grey", linewidth=0.5)
        axis.legend(fontsize=8)
    figure.suptitle(title)
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)


if __name__ == "__main__":
    sys.exit(main())
