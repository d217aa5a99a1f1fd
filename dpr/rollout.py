"""The one episode loop: a policy acts in an env from ``reset(seed=seed)`` until the episode ends.

Evaluation (:mod:`dpr.evaluation.scoring`), dataset collection (:mod:`dpr.datasets.collect`), replay
(:mod:`dpr.datasets.replay`) and the viewer's live rollouts (:mod:`dpr.viz.episodes`) all run episodes through
:func:`roll_out` and differ only in what they record, through two hooks: ``on_reset(observation, info)`` once
after the reset, and ``on_step(step)`` after every step with the :class:`Step` (what the policy saw, what it
did, what the env returned). The loop itself keeps the agent's trajectory, the rewards and how the episode
ended (:class:`RolloutResult`, whose ``metrics`` are the paper's).

A physics error (the simulator's state blew up: the env truncates the episode and sets
``info["physics_error"]``) follows one rule everywhere: the episode stops *before* the step that blew up. That
step is not passed to ``on_step`` and is not part of the trajectory, the rewards or the step count, since the
world it left is not a state; everything recorded up to it is kept, and ``RolloutResult.physics_error`` holds
the env's message. So a dataset's frames, an MCAP log's states, the viewer's states and the metrics' step
count always describe the same sane steps.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dpr.envs.particle_env import AGENT_POSITION, PHYSICS_ERROR
from dpr.interrupts import raise_if_interrupted
from dpr.metrics import EpisodeMetrics, episode_metrics


@dataclass
class Step:
    """One env step: ``index`` is the state it led to (1 for the first step), ``observation`` what the policy
    saw before it, ``action`` what the env was given, the rest what ``env.step`` returned."""

    index: int
    observation: Any
    action: Any
    next_observation: Any
    reward: float
    terminated: bool
    truncated: bool
    info: dict

    @property
    def done(self) -> bool:
        return self.terminated or self.truncated


@dataclass
class RolloutResult:
    """How an episode went: the agent's positions at the reset and after every step (``[steps + 1, 2]``), the
    steps' rewards, the goal, and how it ended (``physics_error``: the env's message, else None)."""

    seed: int
    trajectory: np.ndarray = field(repr=False)
    rewards: np.ndarray = field(repr=False)
    goal: np.ndarray = field(repr=False)
    terminated: bool = False
    truncated: bool = False
    physics_error: str | None = None
    measures: dict[str, float] = field(default_factory=dict)  # the task's own (env.episode_measures) at the end

    @property
    def steps(self) -> int:
        return len(self.rewards)

    @property
    def metrics(self) -> EpisodeMetrics:
        """The paper's metrics of the trajectory (:func:`dpr.metrics.episode_metrics`)."""
        return episode_metrics(self.trajectory, self.goal)


class ReplayPolicy:
    """A policy that plays back ``actions`` (one per step, in order), for re-running a recorded episode.
    ``reset`` rewinds it; asking for more actions than it holds is an IndexError."""

    def __init__(self, actions):
        self.actions = actions
        self._next = 0

    def __len__(self) -> int:
        return len(self.actions)

    def reset(self, seed: int | None = None) -> None:
        self._next = 0

    def __call__(self, observation):
        if self._next >= len(self.actions):
            raise IndexError(f"ReplayPolicy: all {len(self.actions)} recorded actions are played")
        action = self.actions[self._next]
        self._next += 1
        return action


def roll_out(
    env,
    policy: Callable[[Any], Any],
    seed: int,
    steps: int | None = None,
    *,
    on_reset: Callable[[Any, dict], None] | None = None,
    on_step: Callable[[Step], None] | None = None,
) -> RolloutResult:
    """Run one episode of ``policy`` (a callable with ``reset(seed)``) in ``env`` (a dpr env, wrapped or not):
    ``env.reset(seed=seed)``, ``policy.reset(seed)``, ``on_reset``, then ``policy(observation)`` and
    ``env.step`` until the episode terminates or truncates, or after ``steps`` steps when given (the env's own
    time limit applies either way). A step with a physics error ends the episode before it (module docstring).
    The env is left open: the caller made it and closes it."""
    observation, info = env.reset(seed=seed)
    policy.reset(seed)
    if on_reset is not None:
        on_reset(observation, info)
    goal = np.array(env.unwrapped.goal, dtype=float)
    trajectory = [info[AGENT_POSITION]]
    measure_keys = env.unwrapped.episode_measures
    last_info = info  # the last sane step's, whose measures end the episode
    rewards: list[float] = []
    terminated = truncated = False
    physics_error = None
    while not (terminated or truncated) and (steps is None or len(rewards) < steps):
        raise_if_interrupted()  # a Ctrl-C that a callback from C code swallowed stops the loop here
        action = policy(observation)
        next_observation, reward, terminated, truncated, info = env.step(action)
        if PHYSICS_ERROR in info:
            physics_error = info[PHYSICS_ERROR]
            break
        trajectory.append(info[AGENT_POSITION])
        last_info = info
        rewards.append(float(reward))
        if on_step is not None:
            on_step(Step(len(rewards), observation, action, next_observation, reward, terminated, truncated, info))
        observation = next_observation
    return RolloutResult(
        seed=seed,
        trajectory=np.array(trajectory, dtype=float),
        rewards=np.array(rewards, dtype=float),
        goal=goal,
        terminated=bool(terminated),
        truncated=bool(truncated),
        physics_error=physics_error,
        measures={
            key: last_info[key].item() if hasattr(last_info[key], "item") else last_info[key] for key in measure_keys
        },
    )


__all__ = ["AGENT_POSITION", "PHYSICS_ERROR", "ReplayPolicy", "RolloutResult", "Step", "roll_out"]
