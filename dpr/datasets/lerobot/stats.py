"""Per-episode statistics (vectors and images) and their exact running aggregate, as LeRobot stores them.

Each episode's meta row holds ``stats/<feature>/<stat>`` for min, max, mean, std (population), count, q01, q10,
q50, q90, q99, computed exactly on that episode (quantiles by linear interpolation, like ``numpy.quantile``).
``stats.json`` aggregates the committed episodes: min/max exact, mean/std combined exactly from the per-episode
counts, means and variances; quantiles are the count-weighted mean of the per-episode quantiles (an
approximation, as in LeRobot's ``aggregate_stats``). Image stats are per channel, shape ``(3, 1, 1)``, in
``[0, 1]``, computed on at most ``IMAGE_STATS_MAX_FRAMES`` evenly spaced frames of each episode (their ``count``
is the number of frames used, as in LeRobot). Stats cover the five default columns too, as LeRobot's do.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from dpr.datasets.lerobot.format import IMAGE_STATS_MAX_FRAMES, QUANTILES, STAT_KEYS

# ----------------------------------------------------------------------------------------------------- statistics


def vector_stats(values: np.ndarray) -> dict[str, np.ndarray]:
    """Stats of a [T, n] array over its frames; min/max keep integer/bool dtypes (as LeRobot's do)."""
    as_float = values.astype(np.float64)
    if values.dtype.kind == "f":
        lo, hi = as_float.min(axis=0), as_float.max(axis=0)
    else:
        lo, hi = values.min(axis=0), values.max(axis=0)
    stats = {
        "min": lo,
        "max": hi,
        "mean": as_float.mean(axis=0),
        "std": as_float.std(axis=0),
        "count": np.array([values.shape[0]], dtype=np.int64),
    }
    qs = np.quantile(as_float, list(QUANTILES.values()), axis=0)
    for i, key in enumerate(QUANTILES):
        stats[key] = qs[i]
    return stats


def _sorted_value_at(cumulative: np.ndarray, k: np.ndarray) -> np.ndarray:
    """The k-th smallest value (0-based) of uint8 data given its cumulative 256-bin histogram."""
    return np.searchsorted(cumulative, k, side="right").astype(np.float64)


def image_stats(frames: list[np.ndarray]) -> dict[str, np.ndarray]:
    """Per-channel stats of uint8 [H, W, 3] frames, scaled to [0, 1], shaped (3, 1, 1).

    Exact for the frames given: computed from per-channel 256-bin histograms (quantiles with numpy's linear
    interpolation between order statistics)."""
    pixels = np.stack(frames).reshape(-1, 3)
    n = pixels.shape[0]
    levels = np.arange(256, dtype=np.float64)
    out: dict[str, list[float]] = {key: [] for key in STAT_KEYS if key != "count"}
    for c in range(3):
        hist = np.bincount(pixels[:, c], minlength=256).astype(np.float64)
        mean = float(hist @ levels) / n
        var = max(float(hist @ (levels - mean) ** 2) / n, 0.0)
        present = np.flatnonzero(hist)
        cumulative = np.cumsum(hist)
        out["min"].append(float(present[0]))
        out["max"].append(float(present[-1]))
        out["mean"].append(mean)
        out["std"].append(var**0.5)
        for key, q in QUANTILES.items():
            h = (n - 1) * q
            lo = np.floor(h)
            v_lo, v_hi = _sorted_value_at(cumulative, np.array([lo, min(lo + 1, n - 1)]))
            out[key].append(float(v_lo + (h - lo) * (v_hi - v_lo)))
    stats = {key: (np.array(vals) / 255.0).reshape(3, 1, 1) for key, vals in out.items()}
    stats["count"] = np.array([len(frames)], dtype=np.int64)
    return stats


def image_sample_indices(n_frames: int) -> np.ndarray:
    """At most IMAGE_STATS_MAX_FRAMES evenly spaced frame indices (first and last included)."""
    k = min(n_frames, IMAGE_STATS_MAX_FRAMES)
    return np.unique(np.round(np.linspace(0, n_frames - 1, k)).astype(np.int64))


@dataclass
class Aggregate:
    """Running aggregate of one feature's per-episode stats (Chan et al.'s exact pairwise mean/variance merge)."""

    count: int
    mean: np.ndarray
    m2: np.ndarray  # sum of squared deviations from ``mean``
    lo: np.ndarray
    hi: np.ndarray
    quantile_sums: dict[str, np.ndarray]  # sum over episodes of count * quantile

    @classmethod
    def of(cls, stats: Mapping[str, np.ndarray]) -> Aggregate:
        n = int(np.asarray(stats["count"]).reshape(-1)[0])
        mean = np.asarray(stats["mean"], dtype=np.float64)
        std = np.asarray(stats["std"], dtype=np.float64)
        return cls(
            count=n,
            mean=mean,
            m2=std**2 * n,
            lo=np.asarray(stats["min"]),
            hi=np.asarray(stats["max"]),
            quantile_sums={k: np.asarray(stats[k], dtype=np.float64) * n for k in QUANTILES},
        )

    def merged(self, other: Aggregate) -> Aggregate:
        total = self.count + other.count
        delta = other.mean - self.mean
        return Aggregate(
            count=total,
            mean=self.mean + delta * (other.count / total),
            m2=self.m2 + other.m2 + delta**2 * (self.count * other.count / total),
            lo=np.minimum(self.lo, other.lo),
            hi=np.maximum(self.hi, other.hi),
            quantile_sums={k: self.quantile_sums[k] + other.quantile_sums[k] for k in QUANTILES},
        )

    def to_json(self) -> dict[str, Any]:
        out = {
            "min": self.lo.tolist(),
            "max": self.hi.tolist(),
            "mean": self.mean.tolist(),
            "std": np.sqrt(np.maximum(self.m2 / self.count, 0.0)).tolist(),
            "count": [self.count],
        }
        for key in QUANTILES:
            out[key] = (self.quantile_sums[key] / self.count).tolist()
        return out


def merge_aggregates(
    aggregates: Mapping[str, Aggregate], episode_stats: Mapping[str, Mapping[str, np.ndarray]]
) -> dict[str, Aggregate]:
    """New aggregates with one more episode folded in (the inputs are left untouched)."""
    out = dict(aggregates)
    for name, stats in episode_stats.items():
        ep = Aggregate.of(stats)
        out[name] = out[name].merged(ep) if name in out else ep
    return out


def stats_json(aggregates: Mapping[str, Aggregate]) -> dict[str, Any]:
    return {name: agg.to_json() for name, agg in aggregates.items()}
