"""Scoring on the batched disk engine: every seed of a task is one env of one vector env, stepped together.

The results are :class:`dpr.evaluation.scoring.EpisodeResult` objects, so ``dpr evaluate --engine batched --json``
writes the file ``dpr evaluate`` writes, and ``dpr report`` reads both alike.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch

from dpr.envs import MAX_EPISODE_STEPS, episode_steps
from dpr.evaluation.scoring import EpisodeResult, check_env_id, policy_env_kwargs
from dpr.metrics import episode_metrics
from dpr.policies.batched import make_batched_policy
from dpr.policies.registry import check_policy_name

ENGINES = ("pymunk", "batched")  # pymunk: the reference engine, one env per process; batched: dpr.sim.batched


def evaluate_batched(
    env_ids: list[str],
    policy: str,
    seeds: list[int],
    steps: int = MAX_EPISODE_STEPS,
    env_kwargs: dict | None = None,
    device: str = "cpu",
    compile: bool = False,
) -> list[EpisodeResult]:
    """:func:`dpr.evaluation.scoring.evaluate` on the batched engine: per env id, one vector env of ``len(seeds)``
    envs, env ``i`` started from ``seeds[i]`` as ``gymnasium.make(env_id).reset(seed=seeds[i])`` starts;
    ``compile``: torch.compile the physics (:class:`dpr.sim.batched.SolverSettings`)."""
    check_policy_name(policy)
    results = []
    for env_id in env_ids:
        check_env_id(env_id, "env_ids")
        kwargs = policy_env_kwargs(policy, env_id, env_kwargs)
        kwargs = {**kwargs, "device": device, "compile": compile}
        results += _evaluate_task(env_id, policy, list(seeds), episode_steps(kwargs, steps), kwargs)
    return results


def _evaluate_task(env_id: str, policy_name: str, seeds: list[int], steps: int, kwargs: dict):
    venv = gym.make_vec(
        env_id, num_envs=len(seeds), vectorization_mode="vector_entry_point", max_episode_steps=steps, **kwargs
    )
    env = venv.unwrapped
    policy = make_batched_policy(policy_name, env, seed=seeds[0])
    observation = env.reset_tensors(seed=list(seeds))
    trajectory = [env.agent_position().cpu()]
    running = torch.ones(env.num_envs, dtype=torch.bool, device=env.device)
    lengths = torch.full((env.num_envs,), steps, dtype=torch.long)
    measures_at_end: dict[str, np.ndarray] = {}
    for step in range(steps):
        actions = policy(observation)
        observation, _, terminated, truncated, _ = env.advance(env.targets(actions))
        trajectory.append(env.agent_position().cpu())
        ended = running & (terminated | truncated)
        if ended.any():
            lengths[ended.cpu()] = step + 1
            measures_at_end = _measures(env, ended, measures_at_end)
            running &= ~ended
        if not running.any():
            break
    venv.close()
    path = torch.stack(trajectory, dim=1).double().numpy()  # [K, T + 1, 2]
    goal = np.asarray(env.template.goal, dtype=float)
    return [
        EpisodeResult(
            env_id,
            policy_name,
            seed,
            episode_metrics(path[i, : int(lengths[i]) + 1], goal),
            path[i, : int(lengths[i]) + 1],
            goal,
            measures={key: _plain(values[i]) for key, values in measures_at_end.items()},
            action_repeat=env.action_repeat,
        )
        for i, seed in enumerate(seeds)
    ]


def _measures(env, ended: torch.Tensor, kept: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The task's own measures (Gate's passage) of the envs that ``ended`` now, over those kept before."""
    info = env._info(torch.zeros_like(ended))
    mask = ended.cpu().numpy()
    for key in env.template.episode_measures:
        kept[key] = np.where(mask, info[key], kept.get(key, info[key]))
    return kept


def _plain(value):
    return value.item() if isinstance(value, np.generic) else value
