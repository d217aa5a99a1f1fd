"""The pairs of robots closer than a range, for K swarms at once.

Two searches give the same pairs:

* :func:`all_pairs` compares every robot with every other: a table ``(index, valid)``, both ``[K, N, N]``, for
  small swarms and as the reference the other is checked against;
* :func:`cell_pairs` bins the robots into square cells of the range's size, sorts them by cell key (swarm
  included in the key, so all K swarms are searched by one sort), finds the robots of the 3 x 3 cells around
  each robot's own with ``searchsorted`` and lists every candidate once, however full its cell (no cap, nothing
  dropped): a ragged list of about 9 cells x their robots per robot. Cost per robot is flat in N.
"""

from __future__ import annotations

import torch

# The 3 x 3 cells around a robot's own, as (dx, dy) offsets.
_STENCIL = [(dx, dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1)]


def all_pairs(position: torch.Tensor, radius: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Every other robot of the swarm within ``radius``: slot ``m`` of row ``i`` is robot ``m``."""
    k, n, _ = position.shape
    delta = position[:, None, :, :] - position[:, :, None, :]  # [K, N, N, 2]: from i (row) to j (slot)
    squared = (delta * delta).sum(-1)
    valid = squared < radius * radius
    valid &= ~torch.eye(n, dtype=torch.bool, device=position.device)
    index = torch.arange(n, device=position.device).expand(k, n, n)
    return index, valid


def cell_pairs(position: torch.Tensor, radius: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Every pair of robots of a swarm ``position [K, N, 2]`` closer than ``radius``, each once: ``(env, first,
    second)``, ``[E]`` each, ``first < second``, found through a cell grid of cell size ``radius``."""
    k, n, _ = position.shape
    device = position.device
    corner = position.amin(dim=1, keepdim=True)  # each swarm's own grid origin
    cell = torch.floor((position - corner) / radius).long()  # [K, N, 2], >= 0
    # one key space for all swarms: 1 empty column/row on each side keeps the stencil within the robot's swarm
    columns = int(cell[..., 1].max()) + 3
    rows = int(cell[..., 0].max()) + 3
    swarm = torch.arange(k, device=device)[:, None]
    key = ((swarm * rows + cell[..., 0] + 1) * columns + cell[..., 1] + 1).reshape(-1)  # [R], R = K N
    sorted_key, order = torch.sort(key, stable=True)

    stencil = torch.tensor(_STENCIL, device=device)
    wanted = (key[:, None] + stencil[:, 0] * columns + stencil[:, 1]).reshape(-1)  # [R 9] keys of the 3 x 3 cells
    start = torch.searchsorted(sorted_key, wanted)
    count = torch.searchsorted(sorted_key, wanted, right=True) - start
    # one row per (robot, robot of a cell around it): cell c's robots are sorted positions start[c] + 0 .. count[c] - 1
    of_cell = torch.repeat_interleave(torch.arange(len(wanted), device=device), count)
    rank = torch.arange(len(of_cell), device=device) - (torch.cumsum(count, 0) - count)[of_cell]
    robot, candidate = of_cell // len(_STENCIL), order[start[of_cell] + rank]  # flat: swarm * N + robot
    later = candidate > robot  # each pair once, from its first robot (same swarm: the flat order is the robot order)
    robot, candidate = robot[later], candidate[later]
    flat_position = position.reshape(-1, 2)
    delta = flat_position[candidate] - flat_position[robot]
    close = (delta * delta).sum(-1) < radius * radius
    robot, candidate = robot[close], candidate[close]
    return robot // n, robot % n, candidate % n
