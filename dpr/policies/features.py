"""A features extractor for SB3 policies on the swarm state: the observation plus where each robot stands
along the goal direction, the coordinate the wave's phases are made of.

The tasks are symmetric under rotation about the goal, and the wave bins robots by their distance to the line
through the goal perpendicular to the goal direction. From raw goal-frame positions an MLP has to learn a
projection on a direction that is itself a normalised mean of its inputs, then thresholds 60 units apart on
values scaled by 1/1000: it learns it poorly, and errs exactly where the wave moves to its next bin. This
extractor computes, for every robot, that distance relative to the nearest robot's and the offset across the
goal direction relative to the swarm's centre, both in bin widths (60 units), and appends them to the
observation. It has no parameters; the networks after it are SB3's as usual.
"""

from __future__ import annotations

import gymnasium as gym
import torch
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

from dpr.envs.particle_env import LENGTH_SCALE, ROBOT_FEATURES
from dpr.policies.wave import BIN_WIDTH

__all__ = ["GoalFrame", "SwarmFeatures"]


class SwarmFeatures(BaseFeaturesExtractor):
    """``[observation, along_0..along_{N-1}, across_0..across_{N-1}]`` for a ``state`` observation of ``n_robots``
    robots: ``along`` the distance to the line through the goal perpendicular to the goal direction (from the
    goal to the swarm's centre) minus the smallest one, ``across`` the offset along that line from the centre,
    both in units of 60 (the wave's bin width)."""

    def __init__(self, observation_space: gym.spaces.Box, n_robots: int):
        if (
            not isinstance(observation_space, gym.spaces.Box)
            or len(observation_space.shape) != 1
            or observation_space.shape[0] < ROBOT_FEATURES * n_robots
        ):
            raise ValueError(
                f"SwarmFeatures needs the 1-D state observation of {n_robots} robots, got {observation_space}"
            )
        super().__init__(observation_space, features_dim=int(observation_space.shape[0]) + 2 * n_robots)
        self.n_robots = int(n_robots)

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        n = self.n_robots
        positions = observations[:, : ROBOT_FEATURES * n].reshape(-1, n, ROBOT_FEATURES)[..., 0:2] / LENGTH_SCALE
        frame = GoalFrame(positions)
        along = frame.along(positions).abs()
        along = along - along.min(dim=1, keepdim=True).values
        return torch.cat([observations, along / BIN_WIDTH, frame.across(positions) / BIN_WIDTH], dim=1)


class GoalFrame:
    """The frame of a swarm's goal direction: ``along`` the unit vector from the goal to the swarm's centre,
    ``across`` the one perpendicular to it, for positions ``(B, N, 2)`` relative to the goal."""

    def __init__(self, positions: torch.Tensor):
        self.centre = positions.mean(dim=1, keepdim=True)
        self.distance = self.centre.norm(dim=2, keepdim=True)
        self.along_unit = self.centre / self.distance.clamp_min(1e-6)
        self.across_unit = torch.stack([-self.along_unit[..., 1], self.along_unit[..., 0]], dim=2)

    def along(self, vectors: torch.Tensor) -> torch.Tensor:
        """Signed components along the goal direction (for positions: the distance past the line through the
        goal perpendicular to it)."""
        return (vectors * self.along_unit).sum(dim=2)

    def across(self, positions: torch.Tensor) -> torch.Tensor:
        """Offsets across the goal direction from the swarm's centre."""
        return ((positions - self.centre) * self.across_unit).sum(dim=2)

    def rotate(self, vectors: torch.Tensor) -> torch.Tensor:
        """Vectors (velocities) in the frame: ``(..., 2)`` as (along, across) components."""
        return torch.stack([self.along(vectors), (vectors * self.across_unit).sum(dim=2)], dim=2)
