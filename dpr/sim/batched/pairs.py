"""Pairs of bodies in K swarms: read both ends of every pair at once, and sum what pairs do back onto bodies.

Body tensors are ``[B, K]`` (body-major: one row per body, the K swarms along the fast axis, so every operation is
one contiguous, vectorised pass). Each pair ``(i, j)`` is kept once, ``i < j``; a pair's value of a body quantity is
the second end's minus the first's (:meth:`difference`) or their sum (:meth:`total`), and an impulse on a pair acts
on ``j`` and, opposite, on ``i`` (:meth:`scatter`).

* :class:`DensePairs`: every pair of the B bodies, the same in every swarm (pair tensors ``[P, K]``). Summing back
  is a matrix product with the fixed incidence matrix (no scatters, the same order of sums on every device), and so
  is reading the ends, or (``mode``) rows picked by index, or slices for both, whichever a compiler makes fastest.
* :class:`SparsePairs`: a list of pairs found by the neighbour search, flat over all swarms (pair tensors
  ``[E]``), for large swarms where all pairs would cost N squared; reads are index gathers and sums are
  ``index_add``.
"""

from __future__ import annotations

import math

import torch

PAIR_MODES = ("matrix", "gather", "slices")


class DensePairs:
    """All ``P = B (B - 1) / 2`` pairs of ``n_bodies`` bodies, ordered by the gap between their indices."""

    def __init__(self, n_bodies: int, num_envs: int, device: torch.device, mode: str = "matrix"):
        """``mode``: ``"matrix"`` reads ends and sums back through products with the incidence matrix; ``"gather"``
        reads ends as rows picked by index (loads a compiler fuses into what uses them) and sums back through the
        products; ``"slices"`` does both through slices of the body tensors. The same values, sums in the same order."""
        if mode not in PAIR_MODES:
            raise ValueError(f"mode: one of {PAIR_MODES}, got {mode!r}")
        self.mode = mode
        first, second = torch.triu_indices(n_bodies, n_bodies, 1, device=device)
        order = torch.argsort((second - first) * n_bodies + first)  # by gap, then first: a stable layout
        self.first, self.second = first[order], second[order]
        self.n_bodies, self.num_envs, self.size = n_bodies, num_envs, len(self.first)
        columns = torch.arange(self.size, device=device)
        incidence = torch.zeros(n_bodies, self.size, device=device)
        incidence[self.first, columns] = -1.0
        incidence[self.second, columns] = 1.0
        self._incidence = incidence  # [B, P]
        self._incidence_t = incidence.t().contiguous()
        self._ends = incidence.abs()
        self._ends_t = self._ends.t().contiguous()

    @staticmethod
    def _apply(matrix: torch.Tensor, channels: tuple) -> tuple:
        stacked = torch.stack(channels, dim=1)  # [rows, C, K]
        rows, c, k = stacked.shape
        return (matrix @ stacked.view(rows, c * k)).view(matrix.shape[0], c, k).unbind(1)

    def _shifted(self, channels: tuple, sign: float) -> tuple:
        """Pairs ``(i, i + s)`` for every gap ``s``: slices of the body tensors, no matrix (what a compiler fuses)."""
        b = self.n_bodies
        return tuple(torch.cat([x[s:] + sign * x[: b - s] for s in range(1, b)]) for x in channels)

    def _onto_bodies(self, values: tuple, first_sign: float) -> tuple:
        b, out = self.n_bodies, []
        for value in values:
            total, start = torch.zeros(b, value.shape[-1], dtype=value.dtype, device=value.device), 0
            for s in range(1, b):
                part = value[start : start + b - s]
                total = total + torch.nn.functional.pad(part, (0, 0, s, 0))
                total = total + first_sign * torch.nn.functional.pad(part, (0, 0, 0, s))
                start += b - s
            out.append(total)
        return tuple(out)

    def difference(self, *channels: torch.Tensor) -> tuple:
        """Each body tensor ``[B, K]`` at every pair's second end minus its first: ``[P, K]`` each."""
        if self.mode == "slices":
            return self._shifted(channels, -1.0)
        if self.mode == "gather":
            return tuple(x[self.second] - x[self.first] for x in channels)
        return self._apply(self._incidence_t, channels)

    def total(self, *channels: torch.Tensor) -> tuple:
        """Each body tensor's sum over every pair's two ends."""
        if self.mode == "slices":
            return self._shifted(channels, 1.0)
        if self.mode == "gather":
            return tuple(x[self.second] + x[self.first] for x in channels)
        return self._apply(self._ends_t, channels)

    def scatter(self, *impulses: torch.Tensor) -> tuple:
        """Each pair tensor (what acts on the second end; the first gets the opposite) summed onto the bodies."""
        if self.mode == "slices":
            return self._onto_bodies(impulses, -1.0)
        return self._apply(self._incidence, impulses)

    def scatter_total(self, *values: torch.Tensor) -> tuple:
        """Each pair tensor summed onto both of its ends (counts, torques that turn both ends alike)."""
        if self.mode == "slices":
            return self._onto_bodies(values, 1.0)
        return self._apply(self._ends, values)

    def nearest(self, values: torch.Tensor) -> torch.Tensor:
        """Each body's least pair value ``[B, K]`` over the pairs it is in (``inf`` where none)."""
        table = torch.full((self.n_bodies, self.n_bodies, self.num_envs), math.inf, device=values.device)
        table[self.first, self.second] = values
        table[self.second, self.first] = values
        return table.amin(dim=1)


class SparsePairs:
    """Pairs listed per swarm, flat over all swarms: ``first``/``second`` are body indices ``[E]`` and ``env`` the
    swarm of each, sorted by (swarm, first, second) so that sums run in one order on every run."""

    def __init__(self, first: torch.Tensor, second: torch.Tensor, env: torch.Tensor, n_bodies: int, num_envs: int):
        self.first, self.second, self.env = first, second, env
        self.n_bodies, self.num_envs, self.size = n_bodies, num_envs, len(first)
        self._first_flat = first * num_envs + env  # into a body tensor [B, K] viewed flat
        self._second_flat = second * num_envs + env
        self._both_flat = torch.cat((self._second_flat, self._first_flat))
        self._sum_index: dict[int, torch.Tensor] = {}  # channels -> index into [C, B, K] flat, per pair end

    def key(self) -> torch.Tensor:
        """One integer per pair, increasing along the list: what finds a pair again in the next list."""
        return (self.env * self.n_bodies + self.first) * self.n_bodies + self.second

    def _ends(self, channels: tuple) -> tuple[torch.Tensor, torch.Tensor]:
        flat = torch.stack(channels).view(len(channels), -1)
        return flat.index_select(1, self._second_flat), flat.index_select(1, self._first_flat)

    def difference(self, *channels: torch.Tensor) -> tuple:
        second, first = self._ends(channels)
        return (second - first).unbind(0)

    def total(self, *channels: torch.Tensor) -> tuple:
        second, first = self._ends(channels)
        return (second + first).unbind(0)

    def _onto_bodies(self, values: tuple, first_sign: float) -> tuple:
        # One index_add_ over a flat tensor: on a CPU about 5 times faster than one along dim 1 per pair end, with
        # the same sums in the same order (every second end, then every first end).
        c, bodies = len(values), self.n_bodies * self.num_envs
        if c not in self._sum_index:
            channel = torch.arange(c, device=self._both_flat.device)[:, None] * bodies
            self._sum_index[c] = (channel + self._both_flat).view(-1)
        stacked = torch.stack(values)
        onto_ends = torch.cat((stacked, stacked if first_sign == 1.0 else first_sign * stacked), 1)
        out = torch.zeros(c * bodies, device=stacked.device)
        out.index_add_(0, self._sum_index[c], onto_ends.view(-1))
        return out.view(c, self.n_bodies, self.num_envs).unbind(0)

    def scatter(self, *impulses: torch.Tensor) -> tuple:
        return self._onto_bodies(impulses, -1.0)

    def scatter_total(self, *values: torch.Tensor) -> tuple:
        return self._onto_bodies(values, 1.0)

    def nearest(self, values: torch.Tensor) -> torch.Tensor:
        out = torch.full((self.n_bodies * self.num_envs,), math.inf, device=values.device)
        index = torch.cat((self._first_flat, self._second_flat))
        out.scatter_reduce_(0, index, torch.cat((values, values)), reduce="amin")
        return out.view(self.n_bodies, self.num_envs)
