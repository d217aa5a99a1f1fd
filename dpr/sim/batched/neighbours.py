"""Neighbour tables for K swarms at once: for every robot, the robots of its swarm closer than a range.

A table is ``(index, valid)``, both ``[K, N, M]``: ``index[k, i, m]`` is a robot of swarm ``k`` and ``valid`` says
whether slot ``m`` holds a neighbour. Pairs appear in both directions (``j`` in ``i``'s row and ``i`` in ``j``'s),
so the solver gathers what acts on a robot from its own row and never scatters.

Two searches fill the same format:

* :func:`all_pairs` compares every robot with every other (``M = N``): cheapest for small swarms;
* :func:`cell_list` bins the robots into square cells of the range's size, sorts them by cell key (swarm
  included in the key, so all K swarms are searched by one sort), and gathers each robot's candidates from the
  3 x 3 cells around its own with ``searchsorted``, ``cell_cap`` per cell; the candidates within range are packed
  into ``max_neighbours`` slots. Cost per robot is flat in N. Overflow (a cell or a row fuller than its cap) is
  reported, never dropped silently: the caller searches again with larger caps.
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


def cell_list(
    position: torch.Tensor, radius: float, cell_cap: int, max_neighbours: int
) -> tuple[torch.Tensor, torch.Tensor, bool]:
    """Neighbours within ``radius`` found through a cell grid of cell size ``radius``; returns the table and
    whether any cell held more than ``cell_cap`` robots or any robot more than ``max_neighbours`` neighbours (then
    the table misses some: search again with larger caps)."""
    k, n, _ = position.shape
    device = position.device
    corner = position.amin(dim=1, keepdim=True)  # each swarm's own grid origin
    cell = torch.floor((position - corner) / radius).long()  # [K, N, 2], >= 0
    # one key space for all swarms: 1 empty column/row on each side keeps the stencil's neighbours in range
    columns = int(cell[..., 1].max()) + 3
    rows = int(cell[..., 0].max()) + 3
    swarm = torch.arange(k, device=device)[:, None]
    key = (swarm * rows + cell[..., 0] + 1) * columns + cell[..., 1] + 1  # [K, N]
    flat_key = key.reshape(-1)
    sorted_key, order = torch.sort(flat_key, stable=True)  # stable: the same table on every run

    stencil = torch.tensor(_STENCIL, device=device)
    wanted = flat_key[:, None] + stencil[:, 0] * columns + stencil[:, 1]  # [R, 9] keys of the 3 x 3 cells
    first = torch.searchsorted(sorted_key, wanted)
    last = torch.searchsorted(sorted_key, wanted, right=True)
    overflow = bool((last - first > cell_cap).any())
    slot = first[..., None] + torch.arange(cell_cap, device=device)  # [R, 9, cap] positions in the sorted order
    in_cell = slot < last[..., None]
    candidate = order[slot.clamp(max=len(order) - 1)]  # flat robot index (swarm * N + robot)
    candidate = candidate.reshape(k * n, -1)
    in_cell = in_cell.reshape(k * n, -1)

    flat_position = position.reshape(-1, 2)
    delta = flat_position[candidate] - flat_position[:, None, :]
    close = in_cell & ((delta * delta).sum(-1) < radius * radius)
    close &= candidate != torch.arange(k * n, device=device)[:, None]

    # pack the close candidates into max_neighbours slots, in candidate order; the rest go to a spare column
    packed_slot = torch.cumsum(close.int(), dim=1) - 1
    overflow |= bool((packed_slot[:, -1] >= max_neighbours).any())
    packed_slot = torch.where(close & (packed_slot < max_neighbours), packed_slot, max_neighbours)
    index = torch.zeros(k * n, max_neighbours + 1, dtype=torch.long, device=device)
    valid = torch.zeros(k * n, max_neighbours + 1, dtype=torch.bool, device=device)
    index.scatter_(1, packed_slot, candidate % n)
    valid.scatter_(1, packed_slot, close)
    index, valid = index[:, :max_neighbours], valid[:, :max_neighbours]
    index = torch.where(valid, index, 0)
    return index.reshape(k, n, max_neighbours), valid.reshape(k, n, max_neighbours), overflow


def carry_over(
    old_index: torch.Tensor, old_valid: torch.Tensor, new_index: torch.Tensor, new_valid: torch.Tensor, *values
) -> list[torch.Tensor]:
    """Move per-slot ``values`` (each ``[K, N, M_old]``) of the old table to the slots of the same pairs in the new
    table (0 where a pair is new): what keeps a constraint's accumulated impulse across a new search."""
    same = (new_index[..., :, None] == old_index[..., None, :]) & old_valid[..., None, :] & new_valid[..., :, None]
    same = same.to(values[0].dtype)
    return [(same * value[..., None, :]).sum(-1) for value in values]
