"""Episode metrics of the paper: total distance, net displacement, projected displacement, success.

All take the agent's trajectory (the swarm's centre, or the object in Manipulation) as a (T+1, 2) array of
positions from the start of the episode, and the goal position.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

SUCCESS_RADIUS = 10.0


def total_distance(trajectory: np.ndarray) -> float:
    """Path length: sum of the step lengths."""
    trajectory = np.asarray(trajectory, dtype=float)
    if len(trajectory) < 2:
        return 0.0
    return float(np.linalg.norm(np.diff(trajectory, axis=0), axis=1).sum())


def net_displacement(trajectory: np.ndarray) -> float:
    """|end - start|."""
    trajectory = np.asarray(trajectory, dtype=float)
    return float(np.linalg.norm(trajectory[-1] - trajectory[0]))


def projected_displacement(trajectory: np.ndarray, goal) -> float:
    """(end - start) projected on the unit vector from start to goal; positive means toward the goal."""
    trajectory = np.asarray(trajectory, dtype=float)
    to_goal = np.asarray(goal, dtype=float) - trajectory[0]
    norm = np.linalg.norm(to_goal)
    if norm == 0:
        return 0.0
    return float((trajectory[-1] - trajectory[0]) @ to_goal / norm)


def success(trajectory: np.ndarray, goal, radius: float = SUCCESS_RADIUS) -> bool:
    """Whether the agent came within ``radius`` of the goal at any step."""
    trajectory = np.asarray(trajectory, dtype=float)
    return bool((np.linalg.norm(trajectory - np.asarray(goal, dtype=float), axis=1) < radius).any())


@dataclass
class EpisodeMetrics:
    projected_displacement: float
    net_displacement: float
    total_distance: float
    success: bool
    steps: int

    def as_dict(self) -> dict:
        return asdict(self)


def episode_metrics(trajectory: np.ndarray, goal) -> EpisodeMetrics:
    trajectory = np.asarray(trajectory, dtype=float)
    return EpisodeMetrics(
        projected_displacement=projected_displacement(trajectory, goal),
        net_displacement=net_displacement(trajectory),
        total_distance=total_distance(trajectory),
        success=success(trajectory, goal),
        steps=len(trajectory) - 1,
    )


class MetricTracker:
    """The same metrics, updated one step at a time in O(1) (what the env reports in ``info``)."""

    def __init__(self, start, goal):
        self.start = np.asarray(start, dtype=float).copy()
        self.last = self.start.copy()
        self.goal = np.asarray(goal, dtype=float)
        to_goal = self.goal - self.start
        norm = np.linalg.norm(to_goal)
        self._unit = to_goal / norm if norm > 0 else np.zeros(2)
        self.total_distance = 0.0
        self.success = bool(np.linalg.norm(self.start - self.goal) < SUCCESS_RADIUS)
        self.steps = 0

    def update(self, position) -> None:
        position = np.array(position, dtype=float)
        self.total_distance += math.hypot(*(position - self.last))
        self.last = position
        self.success |= math.hypot(*(position - self.goal)) < SUCCESS_RADIUS
        self.steps += 1

    @property
    def net_displacement(self) -> float:
        return math.hypot(*(self.last - self.start))

    @property
    def projected_displacement(self) -> float:
        return float((self.last - self.start) @ self._unit)

    def as_metrics(self) -> EpisodeMetrics:
        return EpisodeMetrics(
            self.projected_displacement, self.net_displacement, self.total_distance, self.success, self.steps
        )


def summarize(values) -> dict:
    """Median, min, max (the paper's bars), mean and std, and the count."""
    v = np.asarray(list(values), dtype=float)
    if len(v) == 0:
        return {"n": 0}
    return {
        "n": int(len(v)),
        "median": float(np.median(v)),
        "min": float(v.min()),
        "max": float(v.max()),
        "mean": float(v.mean()),
        "std": float(v.std()),
    }
