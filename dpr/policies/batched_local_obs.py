"""Every robot's local observation for K swarms at once, in torch: :meth:`LocalObservation.observe` on a batch.

:func:`batched_local_observations` takes the [K, D] state observations of a batched vector env
(:mod:`dpr.envs.batched`) and gives [K, N, size] float32 rows, each swarm's rows the ones
:func:`dpr.envs.local_obs.local_observations` computes from that swarm's state: the same parts in the same order,
neighbours within the same range (strictly closer), nearest first with ties by index, unused slots zeros, the
goal, clock, dead flag and object parts. The arithmetic is the numpy code's (float64 distances from the float32
state, float32 rows), so rows agree to the last bit or so. Neighbours are found by a distance table per swarm,
owners taken in chunks so that memory stays bounded: O(N^2) work per swarm, which suits the swarm sizes the
per-robot models are run at in batch (tens to hundreds of robots).

This module imports torch: ``import dpr`` does not load it.
"""

from __future__ import annotations

import math

import torch

from dpr.envs.local_obs import NEIGHBOUR_FEATURES, LocalObservation
from dpr.envs.particle_env import LENGTH_SCALE, OBJECT_FEATURES, ROBOT_FEATURES

# Entries of one chunk of the [K, owners, N] distance table (float64): about 32 MiB per tensor.
_CHUNK_ENTRIES = 1 << 22


def batched_local_observations(
    state: torch.Tensor,
    n_robots: int,
    neighbour_range: float,
    layout: LocalObservation,
    steps: torch.Tensor | None = None,
    dead: torch.Tensor | None = None,
) -> torch.Tensor:
    """Every robot's row of every swarm, [K, N, ``layout.size``] float32, from the state observations ``state``
    [K, D] (robots first, then the object where the layout has one), ``steps`` [K] since each swarm's reset (for
    the clock; zeros when None) and ``dead`` [K, N] bool (needed with ``layout.dead_flag``)."""
    k_envs, n = state.shape[0], n_robots
    robots = state[:, : ROBOT_FEATURES * n].float().reshape(k_envs, n, ROBOT_FEATURES)
    out = torch.zeros(k_envs, n, layout.size, dtype=torch.float32, device=state.device)
    out[..., layout.own] = robots
    if layout.has_object:
        start = ROBOT_FEATURES * n
        out[..., layout.object] = state[:, None, start : start + OBJECT_FEATURES].float()
    positions = robots[..., 0:2].double()
    out[..., layout.goal] = _goal_part(positions, layout)
    if layout.distance_period is not None:
        out[..., 0:2] = 0.0
    if layout.clock_period is not None:
        step = torch.zeros(k_envs, dtype=torch.long, device=state.device) if steps is None else steps.long()
        angle = (2.0 * math.pi) * (step % layout.clock_period).double() / layout.clock_period
        out[..., layout.clock] = torch.stack((angle.sin(), angle.cos()), dim=1)[:, None, :].float()
    if layout.dead_flag:
        if dead is None:
            raise ValueError("this layout has a dead flag: pass dead ([K, N] bool)")
        out[..., layout.dead.start] = dead.float()
    index, valid = nearest_neighbours(positions / LENGTH_SCALE, neighbour_range, layout.max_neighbours)
    slots = robots.gather(1, index.reshape(k_envs, -1, 1).expand(-1, -1, ROBOT_FEATURES))
    slots = slots.reshape(k_envs, n, -1, NEIGHBOUR_FEATURES).clone()
    slots[..., 0:2] -= robots[:, :, None, 0:2]
    slots = torch.where(valid[..., None], slots, 0.0)
    width = slots.shape[2]  # min(max_neighbours, N): slots past it stay zeros
    neighbours = layout.neighbours.start
    out[..., neighbours : neighbours + NEIGHBOUR_FEATURES * width] = slots.reshape(k_envs, n, -1)
    out[..., layout.mask.start : layout.mask.start + width] = valid.float()
    return out


def _goal_part(positions: torch.Tensor, layout: LocalObservation) -> torch.Tensor:
    """The goal part of every row, [K, N, 3 or 4] float32, from positions in the goal frame (state units)."""
    distance = torch.hypot(positions[..., 0], positions[..., 1])
    toward = torch.where(distance[..., None] > 0, -positions / distance[..., None], 0.0)
    if layout.distance_period is None:
        return torch.cat((toward, distance[..., None]), dim=-1).float()
    angle = (2.0 * math.pi / (layout.distance_period * LENGTH_SCALE)) * distance
    return torch.cat((toward, angle.sin()[..., None], angle.cos()[..., None]), dim=-1).float()


def nearest_neighbours(positions: torch.Tensor, neighbour_range: float, k: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Each robot's ``k`` nearest other robots strictly closer than ``neighbour_range`` (positions [K, N, 2],
    float64, world units), nearest first with ties by index: their indices [K, N, min(k, N)] (int64) and whether
    each slot holds one [K, N, min(k, N)] (bool; indices of empty slots are arbitrary)."""
    k_envs, n = positions.shape[0], positions.shape[1]
    width = min(k, n)
    chunk = max(1, _CHUNK_ENTRIES // max(1, k_envs * n))
    limit = float(neighbour_range) * float(neighbour_range)
    indices, valids = [], []
    for first in range(0, n, chunk):
        owners = positions[:, first : first + chunk]
        dx = positions[:, None, :, 0] - owners[:, :, None, 0]  # [K, owners, N]: other minus owner
        dy = positions[:, None, :, 1] - owners[:, :, None, 1]
        squared = dx * dx + dy * dy
        within = squared < limit
        own = torch.arange(first, first + owners.shape[1], device=positions.device)
        within[:, torch.arange(owners.shape[1], device=positions.device), own] = False
        key = torch.where(within, squared, torch.inf)
        order = _nearest_first(key, within, width)
        indices.append(order)
        valids.append(within.gather(2, order))
    return torch.cat(indices, dim=1), torch.cat(valids, dim=1)


def _nearest_first(key: torch.Tensor, within: torch.Tensor, width: int) -> torch.Tensor:
    """The indices of the ``width`` smallest ``key`` values along the last axis, smallest first and ties by index.
    Only the robots within range are ranked (``topk`` of as many as the most crowded robot has, then a stable sort
    of those few), so the cost per robot grows with N only through the distance table."""
    crowd = int(within.count_nonzero(dim=2).max()) if within.numel() else 0
    candidates = min(key.shape[2], max(crowd, width))
    picked = key.topk(candidates, dim=2, largest=False, sorted=False).indices  # every robot within range
    picked = picked.sort(dim=2).values  # by index, so that the stable sort below breaks ties by index
    order = key.gather(2, picked).sort(dim=2, stable=True).indices
    return picked.gather(2, order)[..., :width]


__all__ = ["batched_local_observations", "nearest_neighbours"]
