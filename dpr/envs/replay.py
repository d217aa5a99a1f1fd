"""Rebuilding an env mid-episode exactly: :class:`ReplayLog` records what its episode was made of, and
:func:`replay` makes the same env again from that record.

Pickling a world mid-episode is not enough for this: pymunk does not carry the contact cache (the impulses a
step starts from) through a pickle, so a pickled world's next step differs slightly from the original's. The
physics is deterministic, so the env's random state at the episode's reset, the reset's arguments and the actions
since then determine the episode exactly; replaying them costs at most one episode of steps. A training run that
was stopped resumes this way (:mod:`dpr.rl.resume`).
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np

__all__ = ["ParallelReplayLog", "ReplayLog", "replay", "replay_parallel"]


def _random_state(generator) -> dict[str, Any] | None:
    return None if generator is None else copy.deepcopy(generator.bit_generator.state)


def _set_random_state(env, state: dict[str, Any] | None) -> None:
    if state is not None:
        generator = np.random.Generator(getattr(np.random, state["bit_generator"])())
        generator.bit_generator.state = state
        env.np_random = generator


class ReplayLog(gym.Wrapper):
    """Passes everything through unchanged and records the current episode: the base env's random state before
    its reset (or the reset's seed), the reset's options and every action since. :meth:`episode` returns that
    record; :func:`replay` rebuilds the env from it."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self._episode: dict[str, Any] | None = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        generator = self.env.unwrapped._np_random  # None until first seeded: a seeded reset then makes it
        state = None if seed is not None else _random_state(generator)
        self._episode = {"random_state": state, "seed": seed, "options": copy.deepcopy(options), "actions": []}
        return self.env.reset(seed=seed, options=options)

    def step(self, action):
        if self._episode is not None:
            self._episode["actions"].append(np.array(action, copy=True))
        return self.env.step(action)

    def episode(self) -> dict[str, Any] | None:
        """The current episode's record (None before the first reset)."""
        return copy.deepcopy(self._episode)


def replay(make: Callable[[], gym.Env], episode: dict[str, Any] | None) -> gym.Env:
    """``make()`` (an env stack with a :class:`ReplayLog` in it), brought to where ``episode``'s env stood: reset
    as it was and stepped through the same actions. ``episode`` None: the env as made, never reset."""
    env = make()
    return _replayed(env, episode, env.unwrapped, env.step)


def _replayed(env, episode: dict[str, Any] | None, base, step: Callable[[Any], Any]):
    """``env`` reset as ``episode``'s was (``base`` holds its generator) and stepped by ``step`` through its
    actions; as it is when ``episode`` is None."""
    if episode is None:
        return env
    _set_random_state(base, episode["random_state"])
    env.reset(seed=episode["seed"], options=episode["options"])
    for action in episode["actions"]:
        step(action)
    return env


class ParallelReplayLog:
    """:class:`ReplayLog` for a :class:`dpr.envs.parallel.ParticleParallelEnv`: passes everything through unchanged
    (attributes too) and records the current episode, each step's actions as one array in ``possible_agents``
    order. :func:`replay_parallel` rebuilds the env from the record."""

    def __init__(self, env):
        self.env = env
        self._episode: dict[str, Any] | None = None

    def __getattr__(self, name: str):
        return getattr(self.env, name)

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None):
        state = None if seed is not None else _random_state(self.env.swarm_env._np_random)
        self._episode = {"random_state": state, "seed": seed, "options": copy.deepcopy(options), "actions": []}
        return self.env.reset(seed=seed, options=options)

    def step(self, actions):
        if self._episode is not None:
            self._episode["actions"].append(np.array([actions[agent] for agent in self.env.possible_agents]))
        return self.env.step(actions)

    def episode(self) -> dict[str, Any] | None:
        """The current episode's record (None before the first reset)."""
        return copy.deepcopy(self._episode)


def replay_parallel(make: Callable[[], ParallelReplayLog], episode: dict[str, Any] | None) -> ParallelReplayLog:
    """``make()``, brought to where ``episode``'s env stood (as :func:`replay`, for a parallel env)."""
    env = make()
    return _replayed(
        env, episode, env.swarm_env, lambda actions: env.step(dict(zip(env.possible_agents, actions, strict=True)))
    )
