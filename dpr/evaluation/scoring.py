"""Score a policy on a task with the paper's metrics, over seeds."""

from __future__ import annotations

import json
import re
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym
import numpy as np

from dpr.atomic import atomic_write_text
from dpr.checks import check_choice, check_seeds
from dpr.envs import MAX_EPISODE_STEPS, TASKS, episode_steps
from dpr.envs.particle_env import action_repeat
from dpr.interrupts import first_completed
from dpr.metrics import EpisodeMetrics, summarize
from dpr.policies.model_file import is_model_path, model_env_kwargs
from dpr.policies.registry import check_policy_name, make_policy
from dpr.policies.sb3 import load_model
from dpr.rollout import roll_out

METRICS = ("projected_displacement", "net_displacement", "total_distance", "success")
# The trajectory stored in `dpr evaluate --json`: the position every 10 physics steps (or at every decision of a
# policy deciding less often) to 0.1 units is plenty for a figure (MAX_EPISODE_STEPS = 2500 steps -> 251 points)
# and keeps the file small.
TRAJECTORY_EVERY = 10
TRAJECTORY_DECIMALS = 1


def check_env_id(env_id: str, parameter: str = "env_id") -> str:
    """``env_id`` if it is a registered dpr env id (ParameterError naming ``parameter`` otherwise)."""
    return check_choice(parameter, env_id, TASKS)


@dataclass
class EpisodeResult:
    env_id: str
    policy: str
    seed: int
    metrics: EpisodeMetrics
    trajectory: np.ndarray = field(repr=False)
    goal: np.ndarray = field(repr=False)
    measures: dict = field(default_factory=dict)  # the task's own at the episode's end (Gate's passage measure)
    action_repeat: int = 1  # physics steps per env step: the trajectory holds a position per env step

    def as_dict(self, trajectory: bool = False) -> dict:
        """The metrics and the task's measures, with ``steps`` the physics steps the episode lasted (and, for a
        policy deciding every ``action_repeat`` > 1 steps, that number); with ``trajectory`` also the goal and the
        path, a position every 10 physics steps or every decision where decisions are longer (see
        subsample_trajectory)."""
        row = {
            "env_id": self.env_id,
            "policy": self.policy,
            "seed": self.seed,
            **self.metrics.as_dict(),
            **self.measures,
        }
        row["steps"] = self.metrics.steps * self.action_repeat
        if self.action_repeat > 1:
            row["action_repeat"] = self.action_repeat
        if trajectory:
            row["goal"] = [float(v) for v in self.goal]
            row["trajectory"] = subsample_trajectory(self.trajectory, max(1, TRAJECTORY_EVERY // self.action_repeat))
        return row


def subsample_trajectory(
    trajectory: np.ndarray, every: int = TRAJECTORY_EVERY, decimals: int = TRAJECTORY_DECIMALS
) -> list[list[float]]:
    """Every ``every``-th position of a (T+1, 2) trajectory and always the last one, rounded to ``decimals``,
    as a list of [x, y] (JSON-ready)."""
    trajectory = np.asarray(trajectory, dtype=float)
    indices = np.arange(0, len(trajectory), every)
    if indices[-1] != len(trajectory) - 1:  # the end position is what the metrics are computed from
        indices = np.append(indices, len(trajectory) - 1)
    return np.round(trajectory[indices], decimals).tolist()


# An [x, y] pair that json.dumps(indent=...) spread over four lines. Raw newlines never occur inside a JSON
# string, so matching them cannot touch string contents.
_SPREAD_PAIR = re.compile(r"\[\n\s*([^\s,\[\]{}]+),\n\s*([^\s,\[\]{}]+)\n\s*\]")


def evaluation_payload(
    policy: str, env_ids: list[str], env_kwargs: dict, steps: int, seeds: list[int], results: list[EpisodeResult]
) -> dict:
    """What ``dpr evaluate --json`` writes: the run's arguments, every episode with its path (for ``dpr report``)
    and the summary per env id (unnested for one env id)."""
    per_env = summary(results)
    return {
        "policy": policy,
        "env_ids": list(env_ids),
        "env_kwargs": env_kwargs,
        "steps": steps,
        "seeds": list(seeds),
        "episodes": [r.as_dict(trajectory=True) for r in results],
        "summary": per_env if len(env_ids) > 1 else per_env[env_ids[0]],
    }


def save_evaluation(
    path, policy: str, env_ids: list[str], env_kwargs: dict, steps: int, seeds: list[int], results: list[EpisodeResult]
) -> Path:
    """Write :func:`evaluation_payload` as :func:`evaluation_json` to ``path`` through a temporary file, so that
    ``path`` exists only once it is complete."""
    payload = evaluation_payload(policy, env_ids, env_kwargs, steps, seeds, results)
    return atomic_write_text(path, evaluation_json(payload))


def evaluation_json(payload: dict) -> str:
    """``payload`` as indented JSON with each [x, y] pair on one line (a trajectory is then a line per point,
    not four)."""
    return _SPREAD_PAIR.sub(r"[\1, \2]", json.dumps(payload, indent=2))


def policy_env_kwargs(policy: str, env_id: str, env_kwargs: dict | None, transfer: bool = False) -> dict:
    """The env kwargs ``policy`` runs with on ``env_id``: a model file's own kwargs (trained-with values;
    a conflicting one in ``env_kwargs`` is a ValueError naming both), else ``env_kwargs`` as given."""
    if is_model_path(policy):
        return model_env_kwargs(policy, env_id, env_kwargs, transfer=transfer)
    return dict(env_kwargs or {})


def run_episode(
    env_id: str,
    policy_name: str,
    seed: int,
    steps: int = MAX_EPISODE_STEPS,
    env_kwargs: dict | None = None,
    transfer: bool = False,
) -> EpisodeResult:
    """One episode of at most ``steps`` physics steps from ``reset(seed=seed)`` (a model file's env kwargs apply;
    one that decides every ``action_repeat`` steps gets ``steps / action_repeat`` env steps)."""
    import dpr  # noqa: F401  (registers the ids in worker processes)

    kwargs = policy_env_kwargs(policy_name, env_id, env_kwargs, transfer)
    env = gym.make(env_id, max_episode_steps=episode_steps(kwargs, steps), **kwargs)
    try:
        result = roll_out(env, make_policy(policy_name, env, transfer), seed)
    finally:
        env.close()
    return episode_result(env_id, policy_name, seed, result, kwargs)


def episode_result(env_id: str, policy: str, seed: int, rollout, env_kwargs: dict) -> EpisodeResult:
    """The :class:`EpisodeResult` of ``rollout`` (what :func:`dpr.rollout.roll_out` returned) of ``policy`` on
    ``env_id`` made with ``env_kwargs``."""
    return EpisodeResult(
        env_id,
        policy,
        seed,
        rollout.metrics,
        rollout.trajectory,
        rollout.goal,
        measures=rollout.measures,
        action_repeat=action_repeat(env_kwargs),
    )


def evaluate(
    env_ids: list[str],
    policy: str,
    seeds: list[int],
    steps: int = MAX_EPISODE_STEPS,
    env_kwargs: dict | None = None,
    workers: int = 1,
    progress=None,
    transfer: bool = False,
) -> list[EpisodeResult]:
    """Run ``policy`` (a scripted policy's name or a ``.zip`` model file) on every env id and seed (in
    ``workers`` processes); results in input order. A model runs with the env kwargs it was trained with, and with
    ``transfer`` on tasks other than its own whose spaces it fits (zero-shot transfer).
    ``steps`` counts physics steps, so policies that decide every step or every ``action_repeat`` steps are
    scored over the same time."""
    for env_id in env_ids:
        check_env_id(env_id, "env_ids")
    check_policy_name(policy)
    seeds = check_seeds("seeds", seeds)
    if is_model_path(policy):
        load_model(policy)  # a corrupt model file is refused here, once, before any worker starts
    # Resolved here, once per env id, so that a conflict is reported before any episode runs.
    kwargs_by_env = {env_id: policy_env_kwargs(policy, env_id, env_kwargs, transfer) for env_id in env_ids}
    jobs = [(env_id, policy, seed, steps, kwargs_by_env[env_id], transfer) for env_id in env_ids for seed in seeds]
    results: list[EpisodeResult | None] = [None] * len(jobs)
    if workers <= 1:
        for i, job in enumerate(jobs):
            results[i] = run_episode(*job)
            if progress:
                progress(results[i])
    else:
        with ProcessPoolExecutor(workers) as pool:
            futures = {pool.submit(run_episode, *job): i for i, job in enumerate(jobs)}
            pending = set(futures)
            try:
                while pending:
                    for future in first_completed(pending):
                        pending.remove(future)
                        results[futures[future]] = future.result()
                        if progress:
                            progress(results[futures[future]])
            except BaseException:
                _stop_now(pool)
                raise
    return results  # type: ignore[return-value]


def _stop_now(pool: ProcessPoolExecutor) -> None:
    """Cancel the episodes ``pool`` has not started and end its workers now: an evaluation keeps nothing of a run
    that stopped (Ctrl-C, an episode's error), and leaving the pool would run every queued episode first, minutes
    after a Ctrl-C. (Python 3.14's ``terminate_workers()``; before it, the pool's own list of its processes.)"""
    workers = list(pool._processes.values()) if pool._processes else []
    pool.shutdown(wait=False, cancel_futures=True)
    for worker in workers:
        worker.terminate()


def summary(results: list[EpisodeResult]) -> dict:
    """Per env id: each metric's median, min, max, mean, std and n (success as a rate), and the task's measures'
    (Gate's passage; its contact step over the episodes that touched a wall, with ``touched``, their fraction)."""
    out: dict[str, dict] = {}
    for env_id in dict.fromkeys(r.env_id for r in results):
        episodes = [r for r in results if r.env_id == env_id]
        rows = [r.metrics.as_dict() for r in episodes]
        out[env_id] = {m: summarize(float(row[m]) for row in rows) for m in METRICS}
        out[env_id].update(measure_summary([r.measures for r in episodes]))
    return out


def measure_summary(measures: list[dict]) -> dict:
    """The task's measures over episodes (each a dict of :attr:`EpisodeResult.measures`): each one's
    :func:`summarize`; a contact step only over the episodes that made contact (-1: none), beside ``touched``,
    the fraction that did."""
    out: dict[str, dict] = {}
    for key in dict.fromkeys(key for row in measures for key in row):
        values = [float(row[key]) for row in measures if key in row]
        if key.endswith("_contact_step"):
            out[key.removesuffix("_contact_step") + "_touched"] = summarize(float(v >= 0) for v in values)
            values = [v for v in values if v >= 0]
        if values:
            out[key] = summarize(values)
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
