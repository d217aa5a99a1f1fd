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
    """The same metrics, updated one step at a time in O(1) (what the env reports in ``info``).

    Works on plain floats: a step's bookkeeping is a handful of scalar operations, cheaper than numpy calls
    on 2-vectors. ``distance_to_goal`` is kept so the env's reward and termination need not recompute it.
    """

    def __init__(self, start, goal):
        self._sx, self._sy = float(start[0]), float(start[1])
        self._gx, self._gy = float(goal[0]), float(goal[1])
        self._lx, self._ly = self._sx, self._sy
        self.goal_position = (self._gx, self._gy)
        norm = math.hypot(self._gx - self._sx, self._gy - self._sy)
        self._ux, self._uy = ((self._gx - self._sx) / norm, (self._gy - self._sy) / norm) if norm > 0 else (0.0, 0.0)
        self.distance_to_goal = norm
        self.total_distance = 0.0
        self.success = norm < SUCCESS_RADIUS
        self.steps = 0

    @property
    def start(self) -> np.ndarray:
        return np.array((self._sx, self._sy))

    @property
    def last(self) -> np.ndarray:
        return np.array((self._lx, self._ly))

    @property
    def last_position(self) -> tuple[float, float]:
        return self._lx, self._ly

    def update(self, position) -> None:
        x, y = float(position[0]), float(position[1])
        self.total_distance += math.hypot(x - self._lx, y - self._ly)
        self._lx, self._ly = x, y
        self.distance_to_goal = math.hypot(x - self._gx, y - self._gy)
        self.success = self.success or self.distance_to_goal < SUCCESS_RADIUS
        self.steps += 1

    @property
    def net_displacement(self) -> float:
        return math.hypot(self._lx - self._sx, self._ly - self._sy)

    @property
    def projected_displacement(self) -> float:
        return (self._lx - self._sx) * self._ux + (self._ly - self._sy) * self._uy

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
