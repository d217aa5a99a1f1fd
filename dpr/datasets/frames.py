"""Frame-level torch access to LeRobot v3.0 datasets for behaviour cloning (observation -> action).

:class:`FrameDataset` maps a global item index over the selected episodes' frames to one training pair. It never
loads a whole dataset: ``__init__`` reads metadata only (``meta/info.json``, the episodes' meta rows and
``meta/stats.json`` through :class:`~dpr.datasets.lerobot.LeRobotReader`), and items are served from whole
episodes read on demand (only the needed columns) and kept in a small LRU cache. An episode is the unit of reading
because our writer stores one episode per parquet file; reading single rows would decode the same pages many
times over.

Random access over frames from every episode would evict the cache at nearly every item, so training should use
:class:`EpisodeBlockSampler`: episodes in random order, a few at a time, frames shuffled within each block. With
``block_episodes <= cache_episodes`` each episode is read once per epoch (per DataLoader worker).

The dataset pickles to its root path and metadata (a few KB): readers and caches are created lazily in each process,
so it works with ``DataLoader(num_workers > 0)`` under both fork and spawn.
"""

from __future__ import annotations

import os
from bisect import bisect_right
from collections import OrderedDict
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import ConcatDataset, Dataset, Sampler

from dpr.checks import ParameterError, check_int
from dpr.datasets import features as F
from dpr.datasets.lerobot import DatasetError, LeRobotReader

__all__ = ["ConcatFrames", "EpisodeBlockSampler", "FrameDataset", "FrameKeys"]

NUMERIC_KINDS = frozenset("biuf")  # numpy dtype kinds a vector feature may have (bool, int, uint, float)
NORMALISATION_STATS = ("min", "max", "mean", "std", "q01", "q10", "q50", "q90", "q99")


def _int(name: str, value: Any, minimum: int) -> int:
    """``value`` (an int or a numpy integer, not a bool) as an int >= ``minimum`` (:func:`dpr.checks.check_int`)."""
    return check_int(name, int(value) if isinstance(value, np.integer) else value, minimum)


def _vector_feature(features: Mapping[str, dict], key: str, argument: str, where: Path) -> int:
    """The width D of a numeric 1-D feature ``key``, or DatasetError naming it and the available features."""
    if key not in features:
        raise DatasetError(
            f"{where}: {argument}={key!r} is not a feature of the dataset; available features: {sorted(features)}"
        )
    spec = features[key]
    dtype, shape = spec.get("dtype"), list(spec.get("shape", []))
    try:
        kind = np.dtype(dtype).kind
    except TypeError:
        kind = None
    if kind not in NUMERIC_KINDS or len(shape) != 1:
        raise DatasetError(
            f"{where}: {argument}={key!r} must be a numeric 1-D feature, got dtype {dtype!r} shape {shape}"
        )
    return int(shape[0])


def _image_feature(features: Mapping[str, dict], key: str, where: Path) -> tuple[int, int, int]:
    """The [H, W, 3] shape of image feature ``key`` (stored as PNG in parquet; videos are not decoded here)."""
    if key not in features:
        images = sorted(n for n, s in features.items() if s.get("dtype") in ("image", "video"))
        raise DatasetError(
            f"{where}: with_image=True but image_key={key!r} is not a feature of the dataset; image features: "
            f"{images}; all features: {sorted(features)}"
        )
    spec = features[key]
    if spec.get("dtype") != "image":
        raise DatasetError(
            f"{where}: image_key={key!r} must be an 'image' feature (PNG in parquet), got dtype {spec.get('dtype')!r}"
        )
    h, w, c = (int(s) for s in spec["shape"])
    return h, w, c


def _select_episodes(episodes: Sequence[int] | None, num_episodes: int, where: Path) -> list[int]:
    """The dataset episode indices to serve, in the order given; ValueError naming ``episodes`` on bad input."""
    if episodes is None:
        return list(range(num_episodes))
    if isinstance(episodes, (str, bytes)) or not isinstance(episodes, Sequence | np.ndarray):
        raise ParameterError("episodes", f"must be a list of episode indices or None, got {episodes!r}")
    selected: list[int] = []
    for e in episodes:
        if isinstance(e, bool) or not isinstance(e, (int, np.integer)):
            raise ParameterError("episodes", f"must hold ints, got {e!r} in {list(episodes)!r}")
        selected.append(int(e))
    if not selected:
        raise ParameterError("episodes", "must not be empty (pass None for all episodes)")
    unknown = [e for e in selected if not 0 <= e < num_episodes]
    if unknown:
        raise ParameterError(
            "episodes", f"unknown episode indices {unknown}; {where} has episodes 0..{num_episodes - 1}"
        )
    if len(set(selected)) != len(selected):
        repeated = sorted({e for e in selected if selected.count(e) > 1})
        raise ParameterError("episodes", f"episode indices {repeated} are listed more than once")
    return selected


@dataclass(frozen=True)
class FrameKeys:
    """The features a :class:`FrameDataset` reads: each pair's ``observation`` and ``action`` (numeric 1-D
    features), and the ``image`` (an 'image' feature, read only ``with_image``). The dataset names a key that it
    lacks, or of the wrong kind, as ``observation_key``, ``action_key`` or ``image_key``."""

    observation: str = F.OBSERVATION
    action: str = F.ACTION
    image: str = "observation.image"


class FrameDataset(Dataset):
    """Behaviour-cloning pairs from a LeRobot v3.0 dataset: item ``i`` is the ``i``-th frame of the selected
    episodes (in the order given), as a dict of tensors:

    - ``observation``: ``[frame_stack * D]`` in ``dtype``, frames ``t - frame_stack + 1 .. t`` oldest first;
      frames before the episode's start repeat its first frame (never a frame of another episode);
    - ``action``: ``[N]`` in ``dtype`` (a discrete int64 ``[1]`` action comes back as a float ``[1]``);
    - ``frame_index``, ``episode_index``: int64 scalars (``episode_index`` is the dataset's own index);
    - ``image`` (only with ``with_image``): uint8 ``[H, W, 3]``, or ``[frame_stack, H, W, 3]`` when stacking.

    ``keys`` (:class:`FrameKeys`) names the features these come from.

    ``len()`` and the item -> (episode, frame) map come from the episodes' meta rows; frame data is read only by
    ``__getitem__``, a whole episode at a time (only the needed columns), with an LRU cache of at most
    ``cache_episodes`` episodes per process. ``frame_index`` is the frame's position in its episode, which is what
    LeRobot's ``frame_index`` column holds, so that column is not read.
    """

    def __init__(
        self,
        root: str | os.PathLike,
        *,
        keys: FrameKeys = FrameKeys(),
        frame_stack: int = 1,
        episodes: list[int] | None = None,
        cache_episodes: int = 8,
        with_image: bool = False,
        dtype: torch.dtype = torch.float32,
    ):
        self.frame_stack = _int("frame_stack", frame_stack, 1)
        self.cache_episodes = _int("cache_episodes", cache_episodes, 1)
        if not isinstance(dtype, torch.dtype) or not dtype.is_floating_point:
            raise ValueError(f"dtype must be a floating torch.dtype, got {dtype!r}")
        self.dtype = dtype
        self.with_image = bool(with_image)
        self.observation_key = keys.observation
        self.action_key = keys.action
        self.image_key = keys.image

        reader = LeRobotReader(root)  # metadata only: info, episode meta rows, stats, data-file footers
        self.root = reader.root
        features = reader.features
        self._obs_dim = _vector_feature(features, self.observation_key, "observation_key", self.root)
        self._action_dim = _vector_feature(features, self.action_key, "action_key", self.root)
        self.image_shape = _image_feature(features, self.image_key, self.root) if self.with_image else None
        self._columns = [self.observation_key, self.action_key] + ([self.image_key] if self.with_image else [])

        self._episode_ids = _select_episodes(episodes, reader.num_episodes, self.root)
        lengths = [int(reader.episodes[e]["length"]) for e in self._episode_ids]
        self._starts = np.concatenate([[0], np.cumsum(lengths, dtype=np.int64)]).tolist()  # item offsets, n+1
        # Only the two features' stats travel with the dataset (pickled to workers), not the whole stats.json.
        self._feature_stats = {k: reader.stats[k] for k in (self.observation_key, self.action_key) if k in reader.stats}

        self._reader: LeRobotReader | None = reader
        self._reader_pid = os.getpid()
        self._cache: OrderedDict[int, dict[str, np.ndarray]] = OrderedDict()

    # ------------------------------------------------------------------------------------------- metadata

    @property
    def observation_dim(self) -> int:
        """Width of an item's observation: ``frame_stack * D``."""
        return self.frame_stack * self._obs_dim

    @property
    def action_dim(self) -> int:
        """Width N of an item's action."""
        return self._action_dim

    @property
    def episode_indices(self) -> list[int]:
        """The dataset episode indices served, in item order."""
        return list(self._episode_ids)

    @property
    def episode_ranges(self) -> list[tuple[int, int]]:
        """Item ranges ``[start, stop)`` of each served episode, in item order."""
        return [(self._starts[k], self._starts[k + 1]) for k in range(len(self._episode_ids))]

    @property
    def cached_episodes(self) -> list[int]:
        """Dataset episode indices held in this process's cache, least recently used first."""
        return list(self._cache)

    def __len__(self) -> int:
        return self._starts[-1]

    def locate(self, index: int) -> tuple[int, int]:
        """Item ``index`` (negative counts from the end) as ``(dataset episode index, frame index)``."""
        position, frame = self._locate(index)
        return self._episode_ids[position], frame

    def _locate(self, index: int) -> tuple[int, int]:
        """Item ``index`` as ``(position among the served episodes, frame index)``."""
        n = len(self)
        if isinstance(index, bool) or not isinstance(index, (int, np.integer)):
            raise TypeError(f"{self.root}: item index must be an int, got {index!r}")
        i = int(index) + n if index < 0 else int(index)
        if not 0 <= i < n:
            raise IndexError(f"{self.root}: item index {index} out of range for {n} frames")
        position = bisect_right(self._starts, i) - 1
        return position, i - self._starts[position]

    def stats(self) -> dict[str, dict[str, torch.Tensor]]:
        """Normalisation stats from ``meta/stats.json`` as ``{"observation": {...}, "action": {...}}``, each with
        min, max, mean, std (and the quantiles stats.json holds) as ``dtype`` tensors shaped like an item's field:
        the observation's repeated ``frame_stack`` times to match the stacked observation."""
        out: dict[str, dict[str, torch.Tensor]] = {}
        for name, key, repeat, width in (
            ("observation", self.observation_key, self.frame_stack, self._obs_dim),
            ("action", self.action_key, 1, self._action_dim),
        ):
            if key not in self._feature_stats:
                raise DatasetError(f"{self.root / 'meta/stats.json'}: no stats for feature {key!r}")
            feature_stats = self._feature_stats[key]
            out[name] = {}
            for stat in NORMALISATION_STATS:
                if stat not in feature_stats:
                    continue
                values = np.asarray(feature_stats[stat], dtype=np.float64).reshape(-1)
                if values.shape != (width,):
                    raise DatasetError(
                        f"{self.root / 'meta/stats.json'}: {key}/{stat} has {values.size} values, expected {width}"
                    )
                out[name][stat] = torch.as_tensor(np.tile(values, repeat), dtype=self.dtype)
        return out

    # ------------------------------------------------------------------------------------------- data access

    def _get_reader(self) -> LeRobotReader:
        """This process's reader: a DataLoader worker (forked or spawned) opens its own and starts a fresh cache."""
        if self._reader is None or self._reader_pid != os.getpid():
            self._reader = LeRobotReader(self.root)
            self._reader_pid = os.getpid()
            self._cache = OrderedDict()
        return self._reader

    def _episode(self, position: int) -> dict[str, np.ndarray]:
        """The needed columns of served episode ``position``, through the LRU cache."""
        episode = self._episode_ids[position]
        reader = self._get_reader()
        data = self._cache.get(episode)
        if data is not None:
            self._cache.move_to_end(episode)
            return data
        data = reader.episode(episode, self._columns)
        self._cache[episode] = data
        while len(self._cache) > self.cache_episodes:
            self._cache.popitem(last=False)
        return data

    def _history(self, frames: np.ndarray) -> np.ndarray:
        """``[m, frame_stack]`` frame indices of each frame's stack, oldest first, clamped at the episode start."""
        offsets = np.arange(1 - self.frame_stack, 1, dtype=np.int64)
        return np.maximum(frames[:, None] + offsets[None, :], 0)

    def _gather(self, position: int, frames: np.ndarray) -> dict[str, np.ndarray]:
        """Fields of ``frames`` (int64 [m]) of served episode ``position`` as arrays with a leading batch axis."""
        data = self._episode(position)
        history = self._history(frames)
        m = len(frames)
        out = {
            # Fancy indexing copies, so items never alias the cached episode.
            "observation": data[self.observation_key][history].reshape(m, self.observation_dim),
            "action": data[self.action_key][frames],
            "frame_index": frames,
            "episode_index": np.full(m, self._episode_ids[position], dtype=np.int64),
        }
        if self.with_image:
            images = data[self.image_key][history]  # [m, frame_stack, H, W, 3]
            out["image"] = images[:, 0] if self.frame_stack == 1 else images
        return out

    def _to_tensors(self, arrays: Mapping[str, np.ndarray]) -> dict[str, torch.Tensor]:
        out = {
            "observation": torch.from_numpy(arrays["observation"]).to(self.dtype),
            "action": torch.from_numpy(arrays["action"]).to(self.dtype),
            "frame_index": torch.as_tensor(arrays["frame_index"], dtype=torch.int64),
            "episode_index": torch.as_tensor(arrays["episode_index"], dtype=torch.int64),
        }
        if "image" in arrays:
            out["image"] = torch.from_numpy(np.ascontiguousarray(arrays["image"]))
        return out

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        position, frame = self._locate(index)
        arrays = self._gather(position, np.array([frame], dtype=np.int64))
        return self._to_tensors({key: value[0] for key, value in arrays.items()})

    def __getitems__(self, indices: Sequence[int]) -> list[dict[str, torch.Tensor]]:
        """Items for a DataLoader batch: each episode's frames gathered in one vectorised step (identical to
        ``[self[i] for i in indices]``, several times faster)."""
        located = [self._locate(i) for i in indices]
        if not located:
            return []
        positions = np.fromiter((p for p, _ in located), dtype=np.int64, count=len(located))
        frames = np.fromiter((f for _, f in located), dtype=np.int64, count=len(located))
        batch: dict[str, np.ndarray] = {}
        # Visit episodes in order of first use, so the LRU cache sees the same order as item-by-item access.
        _, first = np.unique(positions, return_index=True)
        for position in positions[np.sort(first)]:
            where = np.flatnonzero(positions == position)
            for key, value in self._gather(int(position), frames[where]).items():
                if key not in batch:
                    batch[key] = np.empty((len(located), *value.shape[1:]), dtype=value.dtype)
                batch[key][where] = value
        tensors = self._to_tensors(batch)
        rows = {key: value.unbind(0) for key, value in tensors.items()}
        return [{key: rows[key][i] for key in rows} for i in range(len(located))]

    # ------------------------------------------------------------------------------------------- pickling

    def __getstate__(self) -> dict[str, Any]:
        """Root path and metadata only: a worker opens its own reader and cache on first use."""
        state = self.__dict__.copy()
        state["_reader"] = None
        state["_reader_pid"] = None
        state["_cache"] = OrderedDict()
        return state

    def __repr__(self) -> str:
        return (
            f"FrameDataset({str(self.root)!r}, episodes={len(self._episode_ids)}, frames={len(self)}, "
            f"observation={self.observation_key!r}[{self.observation_dim}], action={self.action_key!r}"
            f"[{self.action_dim}], frame_stack={self.frame_stack})"
        )


class ConcatFrames(ConcatDataset):
    """Several :class:`FrameDataset` (say, demonstrations and the corrective episodes of DAgger rounds) as one
    dataset; items are numbered part after part, and :class:`EpisodeBlockSampler` shuffles across parts."""

    def __init__(self, parts: Sequence[FrameDataset]):
        parts = list(parts)
        if not parts or not all(isinstance(part, FrameDataset) for part in parts):
            raise ValueError("ConcatFrames needs one or more FrameDataset")
        dims = {(part.observation_dim, part.action_dim) for part in parts}
        if len(dims) > 1:
            raise DatasetError(
                f"datasets differ in (observation, action) width: {sorted(dims)}; {[str(part.root) for part in parts]}"
            )
        super().__init__(parts)

    @property
    def observation_dim(self) -> int:
        return self.datasets[0].observation_dim

    @property
    def action_dim(self) -> int:
        return self.datasets[0].action_dim

    @property
    def episode_ranges(self) -> list[tuple[int, int]]:
        """[start, stop) of every episode of every part, in item numbers of the whole."""
        ranges = []
        for part, offset in zip(self.datasets, [0, *self.cumulative_sizes[:-1]]):
            ranges += [(start + offset, stop + offset) for start, stop in part.episode_ranges]
        return ranges

    def __getitems__(self, indices: Sequence[int]) -> list[dict[str, torch.Tensor]]:
        # one batched read per part (FrameDataset groups by episode), results back in the order asked
        out: list[dict[str, torch.Tensor] | None] = [None] * len(indices)
        by_part: dict[int, list[tuple[int, int]]] = {}
        for position, index in enumerate(indices):
            index = int(index) + len(self) if index < 0 else int(index)  # negative: from the end of the whole
            if not 0 <= index < len(self):
                raise IndexError(f"item index {indices[position]} out of range for {len(self)} frames")
            part = bisect_right(self.cumulative_sizes, index)
            start = self.cumulative_sizes[part - 1] if part else 0
            by_part.setdefault(part, []).append((position, index - start))
        for part, items in by_part.items():
            for (position, _), item in zip(items, self.datasets[part].__getitems__([i for _, i in items])):
                out[position] = item
        return out  # type: ignore[return-value]


class EpisodeBlockSampler(Sampler[int]):
    """Shuffles for training without thrashing the episode cache: episodes in random order, taken
    ``block_episodes`` at a time, frames shuffled within each block.

    Every epoch yields a permutation of ``range(len(dataset))``; the order depends only on ``(seed, epoch)``
    (call :meth:`set_epoch` before each epoch for a new one). Any window of consecutive items inside a block
    touches at most ``block_episodes`` episodes, so with ``block_episodes <= cache_episodes`` each episode is read
    once per epoch by each DataLoader worker. ``shuffle=False`` yields ``0 .. len - 1`` in order.
    """

    def __init__(
        self, dataset: FrameDataset | ConcatFrames, block_episodes: int = 8, seed: int = 0, shuffle: bool = True
    ):
        super().__init__()
        if not isinstance(dataset, (FrameDataset, ConcatFrames)):
            raise ValueError(f"dataset must be a FrameDataset or ConcatFrames, got {type(dataset).__name__}")
        self.block_episodes = _int("block_episodes", block_episodes, 1)
        self.seed = _int("seed", seed, 0)
        self.shuffle = bool(shuffle)
        self.epoch = 0
        self._ranges = dataset.episode_ranges
        self._length = len(dataset)

    def set_epoch(self, epoch: int) -> None:
        """Select the order of epoch ``epoch`` (an int >= 0)."""
        self.epoch = _int("epoch", epoch, 0)

    def blocks(self) -> list[np.ndarray]:
        """This epoch's item order as one array per block (their concatenation is what ``__iter__`` yields)."""
        if not self.shuffle:
            return [np.arange(self._length, dtype=np.int64)]
        rng = np.random.default_rng([self.seed, self.epoch])
        order = rng.permutation(len(self._ranges))
        blocks = []
        for first in range(0, len(order), self.block_episodes):
            block = np.concatenate(
                [np.arange(*self._ranges[k], dtype=np.int64) for k in order[first : first + self.block_episodes]]
            )
            rng.shuffle(block)
            blocks.append(block)
        return blocks

    def __iter__(self) -> Iterator[int]:
        for block in self.blocks():
            yield from block.tolist()

    def __len__(self) -> int:
        return self._length
