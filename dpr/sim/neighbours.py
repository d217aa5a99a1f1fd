"""Pairs of points closer than a radius, in O(N) numpy work (uniform cell grid, no Python loop over pairs)."""

import functools

import numpy as np

# Half of the 3x3 cell neighbourhood: each pair of neighbouring cells is visited once.
_HALF_STENCIL = np.array([(0, 0), (1, -1), (1, 0), (1, 1), (0, 1)], dtype=np.int64)


# Below this many points a dense distance matrix is cheaper than the cell grid's fixed cost.
_DENSE_LIMIT = 64


@functools.lru_cache(maxsize=64)
def _upper_triangle(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every pair i < j of n points: first indices, second indices, and both as a (P, 2) table."""
    first, second = np.triu_indices(n, 1)
    table = np.stack([first, second], axis=1).astype(np.int64)
    return table[:, 0].copy(), table[:, 1].copy(), table


def pairs_within(points: np.ndarray, radius: float) -> np.ndarray:
    """Return the index pairs ``(i, j)``, ``i < j``, of ``points`` (shape (N, 2)) closer than ``radius``.

    Pairs come sorted by ``i`` then ``j`` as an int64 array of shape (P, 2).
    """
    return _pairs_and_squared_distances(points, radius)[0]


def pairs_and_distances(points: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`pairs_within`'s pairs and, row by row, the distance between the two points of each."""
    pairs, squared = _pairs_and_squared_distances(points, radius)
    return pairs, np.sqrt(squared)


def _pairs_and_squared_distances(points: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    n = len(points)
    if n < 2:
        return np.empty((0, 2), dtype=np.int64), np.empty(0)
    if n <= _DENSE_LIMIT:
        first, second, table = _upper_triangle(n)
        x, y = points[:, 0], points[:, 1]
        dx, dy = x[first] - x[second], y[first] - y[second]  # 1-D gathers: cheaper than rows of (N, 2)
        squared = dx * dx + dy * dy
        close = squared < radius * radius
        return table[close], squared[close]
    cells = np.floor((points - points.min(axis=0)) / radius).astype(np.int64)
    width = int(cells[:, 1].max()) + 3  # +3 leaves room for the -1/+1 stencil offsets
    keys = cells[:, 0] * width + cells[:, 1] + 1
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]

    candidates_i, candidates_j = [], []
    for dx, dy in _HALF_STENCIL:
        target = keys + dx * width + dy
        lo = np.searchsorted(sorted_keys, target, side="left")
        hi = np.searchsorted(sorted_keys, target, side="right")
        counts = hi - lo
        total = int(counts.sum())
        if total == 0:
            continue
        owner = np.repeat(np.arange(n), counts)
        # position of each candidate inside its owner's run: a ragged arange
        offsets = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
        candidates_i.append(owner)
        candidates_j.append(order[np.repeat(lo, counts) + offsets])
    i = np.concatenate(candidates_i)
    j = np.concatenate(candidates_j)
    keep = i != j
    i, j = i[keep], j[keep]
    i, j = np.minimum(i, j), np.maximum(i, j)
    d = points[i] - points[j]
    squared = np.einsum("ij,ij->i", d, d)
    close = squared < radius * radius
    # pairs of points in one cell come in both orders: one key per pair, sorted by i then j
    keys, index = np.unique(i[close] * n + j[close], return_index=True)
    return np.stack([keys // n, keys % n], axis=1), squared[close][index]
