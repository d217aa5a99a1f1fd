"""Score a policy on a task with the paper's metrics, over seeds."""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym
import numpy as np

from dpr.envs import ENV_IDS
from dpr.metrics import EpisodeMetrics, episode_metrics, summarize
from dpr.policies.registry import SCRIPTED_POLICIES, make_policy

METRICS = ("projected_displacement", "net_displacement", "total_distance", "success")


def check_env_id(env_id: str) -> str:
    if env_id not in ENV_IDS.values():
        raise ValueError(f"env must be one of {tuple(ENV_IDS.values())}, got {env_id!r}")
    return env_id


@dataclass
class EpisodeResult:
    env_id: str
    policy: str
    seed: int
    metrics: EpisodeMetrics
    trajectory: np.ndarray = field(repr=False)
    goal: np.ndarray = field(repr=False)

    def as_dict(self) -> dict:
        return {"env_id": self.env_id, "policy": self.policy, "seed": self.seed, **self.metrics.as_dict()}


def run_episode(env_id: str, policy_name: str, seed: int, steps: int = 2500, env_kwargs: dict | None = None) -> EpisodeResult:
    """One episode of at most ``steps`` steps from ``reset(seed=seed)``."""
    import dpr  # noqa: F401  (registers the ids in worker processes)

    env = gym.make(env_id, max_episode_steps=steps, **(env_kwargs or {}))
    policy = make_policy(policy_name, env)
    observation, _ = env.reset(seed=seed)
    policy.reset(seed)
    base = env.unwrapped
    trajectory = [base._agent_position()]
    done = False
    while not done:
        observation, _, terminated, truncated, info = env.step(policy(observation))
        if "physics_error" not in info:  # a blown-up step's state is not part of the trajectory
            trajectory.append(base._agent_position())
        done = terminated or truncated
    env.close()
    trajectory = np.array(trajectory)
    return EpisodeResult(env_id, policy_name, seed, episode_metrics(trajectory, base.goal), trajectory, base.goal.copy())


def evaluate(
    env_ids: list[str],
    policy: str,
    seeds: list[int],
    steps: int = 2500,
    env_kwargs: dict | None = None,
    workers: int = 1,
    progress=None,
) -> list[EpisodeResult]:
    """Run ``policy`` on every env id and seed (in ``workers`` processes); results in input order."""
    for env_id in env_ids:
        check_env_id(env_id)
    if policy not in SCRIPTED_POLICIES:
        if policy.endswith(".zip"):
            path = Path(policy)
            if not path.is_file():
                raise ValueError(f"--policy: no model file at {path}")
            raise ValueError(f"--policy: loading SB3 models ({path}) is not available yet; use 'wave' or 'random'")
        raise ValueError(f"policy must be one of {SCRIPTED_POLICIES} or a path to a .zip model, got {policy!r}")
    jobs = [(env_id, policy, seed, steps, env_kwargs) for env_id in env_ids for seed in seeds]
    results: list[EpisodeResult | None] = [None] * len(jobs)
    if workers <= 1:
        for i, job in enumerate(jobs):
            results[i] = run_episode(*job)
            if progress:
                progress(results[i])
    else:
        with ProcessPoolExecutor(workers) as pool:
            futures = {pool.submit(run_episode, *job): i for i, job in enumerate(jobs)}
            for future in as_completed(futures):
                results[futures[future]] = future.result()
                if progress:
                    progress(results[futures[future]])
    return results  # type: ignore[return-value]


def summary(results: list[EpisodeResult]) -> dict:
    """Per env id: each metric's median, min, max, mean, std and n (success as a rate)."""
    out: dict[str, dict] = {}
    for env_id in dict.fromkeys(r.env_id for r in results):
        rows = [r.metrics.as_dict() for r in results if r.env_id == env_id]
        out[env_id] = {m: summarize(float(row[m]) for row in rows) for m in METRICS}
    return out


def format_table(results: list[EpisodeResult]) -> str:
    lines = [
        "| env | policy | metric | median | min | max | mean ± std | n |",
        "|---|---|---|---:|---:|---:|---:|---:|",
    ]
    policy = results[0].policy if results else ""
    for env_id, metrics in summary(results).items():
        for name, s in metrics.items():
            lines.append(
                f"| {env_id} | {policy} | {name} | {s['median']:.1f} | {s['min']:.1f} | {s['max']:.1f} | "
                f"{s['mean']:.1f} ± {s['std']:.1f} | {s['n']} |"
            )
    return "\n".join(lines)
