"""A lazy reader of LeRobot v3.0 datasets, ours or LeRobot's own layout."""

from __future__ import annotations

import os
from bisect import bisect_left, bisect_right
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from dpr.datasets.lerobot.checksums import CHECKSUMS_COLUMN, check_checksums
from dpr.datasets.lerobot.format import (
    INFO_PATH,
    META_CHECKSUMS_KEY,
    STATS_PATH,
    DatasetError,
    content_digest,
    decode_png,
    load_info,
    read_json,
    read_parquet,
    spec_shape,
)
from dpr.datasets.lerobot.meta import (
    check_data_files,
    check_rows,
    data_file_path,
    load_committed_episodes,
    load_tasks,
    split_row,
)
from dpr.datasets.lerobot.stats import Aggregate, merge_aggregates, stats_json

# ------------------------------------------------------------------------------------------------------ reader

DELTA_TOLERANCE_S = 1e-4  # LeRobotDataset's tolerance_s: how far a delta time may be from a whole frame


class LeRobotReader:
    """Reads a LeRobot v3.0 dataset lazily, frame data only on request: as recorded (a file per episode), compacted
    or written by LeRobot (many episodes per file, read by row group), or a mix after a resume.

    The constructor validates ``meta/info.json`` (codebase_version, required keys), the committed episodes' meta
    rows, ``meta/tasks.parquet``, ``meta/stats.json`` (the meta tables against their checksums, where the dataset
    keeps them: :mod:`dpr.datasets.lerobot.checksums`), every committed data file's parquet footer, and that the
    meta does not contradict the data (``splits`` within the episodes, ``fps`` as the timestamps say). Episodes at or
    above ``info.total_episodes`` and files outside ``info.dpr_live_files`` (leftovers of a crash or of an
    interrupted compaction) are ignored. A reader is a snapshot: open a new one after a compaction. Arrays come
    back as ``[T, *shape]`` in the feature's dtype (shape-[1] features as ``[T, 1]``); images as uint8
    ``[T, H, W, 3]``.
    """

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        if not self.root.is_dir():
            raise DatasetError(f"{self.root}: dataset folder not found")
        self.info: dict[str, Any] = load_info(self.root)
        self.fps: int | float = self.info["fps"]  # frames per second (a float for 10/6 Hz: check_fps)
        self.features: dict[str, dict] = self.info["features"]
        self.num_episodes: int = self.info["total_episodes"]
        self.num_frames: int = self.info["total_frames"]
        rows = load_committed_episodes(self.root, self.info, with_stats=False)
        self._meta_paths = [r.meta_path for r in rows]
        self._episode_stats: dict[int, dict[str, dict[str, np.ndarray]]] = {}  # read on demand
        self.episodes: list[dict[str, Any]] = [r.meta for r in rows]
        frames = rows[-1].meta["dataset_to_index"] if rows else 0
        if frames != self.num_frames:
            raise DatasetError(
                f"{self.root / INFO_PATH}: total_frames is {self.num_frames}, the episodes cover {frames} frames"
            )
        self._starts = [int(e["dataset_from_index"]) for e in self.episodes]
        self.tasks: list[str] = load_tasks(self.root, self.info)
        self._episodes_per_file = check_data_files(self.root, self.info, self.episodes)
        self._file_starts: dict[Path, int] = {}  # global index of each data file's first row
        for ep in reversed(self.episodes):
            self._file_starts[data_file_path(self.root, self.info, ep)] = int(ep["dataset_from_index"])
        self._row_group_starts: dict[Path, tuple[pq.FileMetaData, list[int]]] = {}
        self._row_groups: tuple[tuple, pa.Table] | None = None  # the row groups read last
        self.stats: dict[str, dict[str, np.ndarray]] = self._load_stats()
        self._check_frame_rate()

    def _check_frame_rate(self) -> None:
        """A DatasetError when info.json's fps contradicts the data: in the first episode of two frames or more, the
        timestamps must span (last frame index - first) / fps, as LeRobot records them (to within
        :data:`DELTA_TOLERANCE_S` and float32's rounding). Read from the episode's stats in its meta row (made of
        its frames, under the row's checksums), or from its two columns where the row keeps no such stats."""
        index = next((i for i, ep in enumerate(self.episodes) if int(ep["length"]) > 1), None)
        if index is None or "timestamp" not in self.features or "frame_index" not in self.features:
            return
        stats = self.episode_stats(index)
        if all(key in stats.get(name, {}) for name in ("timestamp", "frame_index") for key in ("min", "max")):
            times = [float(np.ravel(stats["timestamp"][key])[0]) for key in ("min", "max")]
            steps = [float(np.ravel(stats["frame_index"][key])[0]) for key in ("min", "max")]
        else:
            frames = self.episode(index, ["timestamp", "frame_index"])
            times = [float(frames["timestamp"].min()), float(frames["timestamp"].max())]
            steps = [float(frames["frame_index"].min()), float(frames["frame_index"].max())]
        span, frames_apart = times[1] - times[0], steps[1] - steps[0]
        if frames_apart > 0 and abs(span - frames_apart / self.fps) > DELTA_TOLERANCE_S + 1e-6 * abs(times[1]):
            apart = span / frames_apart
            rate = f"{1 / apart:g} frames per second" if apart > 0 else "no frame rate"
            path = data_file_path(self.root, self.info, self.episodes[index])
            raise DatasetError(
                f"{self.root / INFO_PATH}: fps is {self.fps:g}, but the timestamps of episode {index} in {path} are "
                f"{apart:g} s apart ({rate}); the meta contradicts the data"
            )

    def _load_stats(self) -> dict[str, dict[str, np.ndarray]]:
        """stats.json, or the aggregate of the per-episode stats when stats.json is absent or stale (a crash
        between writing it and info.json leaves it counting an uncommitted episode). A stats.json that is not stale
        and differs from its checksum in info.json is a DatasetError."""
        path = self.root / STATS_PATH
        stats = read_json(path) if path.exists() else None
        if stats is not None and not isinstance(stats, dict):
            raise DatasetError(f"{path}: expected a JSON object of feature -> stats")
        index_count = None
        if stats is not None:
            try:
                index_count = int(np.asarray(stats["index"]["count"]).reshape(-1)[0])
            except (KeyError, TypeError, ValueError, IndexError, OverflowError):
                index_count = None
        stale = self.num_frames and index_count is not None and index_count != self.num_frames
        expected = (self.info.get(META_CHECKSUMS_KEY) or {}).get("stats")
        if stats is not None and not stale and expected is not None and content_digest(stats) != expected:
            raise DatasetError(f"{path}: does not match its checksum in {INFO_PATH} (the file is corrupt)")
        if stats is None or stale:
            if not self.episodes:
                return {}
            stats = self._aggregate_of_episodes()
        return self._checked_stats(stats, path)

    def _aggregate_of_episodes(self, names: Iterable[str] | None = None) -> dict[str, Any]:
        """stats.json as the episodes' own stats (their meta rows) make it, for ``names`` (default: the features
        every episode has stats of)."""
        all_stats = [self.episode_stats(i) for i in range(self.num_episodes)]
        if names is None:
            names = [n for n in self.features if all(n in s for s in all_stats)]
        names = list(names)
        aggregates: dict[str, Aggregate] = {}
        for episode_stats in all_stats:
            aggregates = merge_aggregates(aggregates, {n: episode_stats[n] for n in names if n in episode_stats})
        return stats_json(aggregates)

    def _checked_stats(self, stats: Mapping[str, Any], path: Path) -> dict[str, dict[str, np.ndarray]]:
        """stats.json's entries as arrays, each a finite number array; a feature's mean/std/min/max shaped as
        the feature (an image's per channel); a malformed entry is a DatasetError naming it."""
        checked: dict[str, dict[str, np.ndarray]] = {}
        for feature, feature_stats in stats.items():
            if not isinstance(feature_stats, Mapping):
                raise DatasetError(f"{path}: entry {feature!r} must be an object of stats, got {feature_stats!r}")
            spec = self.features.get(feature)
            checked[feature] = {}
            for key, value in feature_stats.items():
                try:
                    array = np.asarray(value, dtype=np.float64)
                except (TypeError, ValueError):
                    raise DatasetError(f"{path}: {feature}/{key} must be numbers, got {value!r}") from None
                if not np.isfinite(array).all():
                    raise DatasetError(f"{path}: {feature}/{key} holds non-finite values")
                if spec is not None and key in ("mean", "std", "min", "max"):
                    image = spec["dtype"] in ("image", "video")
                    expected = (spec_shape(spec)[-1], 1, 1) if image else spec_shape(spec)
                    if array.shape != tuple(expected):
                        raise DatasetError(
                            f"{path}: {feature}/{key} has shape {array.shape}, the feature's is {tuple(expected)}"
                        )
                checked[feature][key] = np.asarray(value)
        return checked

    def verify(self) -> int:
        """Read every episode's every column (each checked against its checksum and meta row) and check that
        stats.json is the aggregate of the episodes' own stats; returns the frames read. DatasetError at the
        first problem, naming the file."""
        frames = 0
        for index in range(self.num_episodes):
            frames += len(next(iter(self.episode(index).values()), ()))
        if not self.episodes:
            return frames
        for feature, feature_stats in self._aggregate_of_episodes(self.stats).items():
            for key, value in feature_stats.items():
                stored = self.stats.get(feature, {}).get(key)
                if stored is None or not np.allclose(stored, value, rtol=1e-6, atol=1e-9):
                    raise DatasetError(
                        f"{self.root / STATS_PATH}: {feature}/{key} is not the aggregate of the episodes' stats"
                    )
        return frames

    # ------------------------------------------------------------------------------------------------ access

    def episode_stats(self, index: int) -> dict[str, dict[str, np.ndarray]]:
        """The per-episode stats stored in episode ``index``'s meta row."""
        self._check_episode(index)
        if index not in self._episode_stats:
            path = self._meta_paths[index]
            table = read_parquet(path)
            check_rows(table, path, self.info, with_stats=True)
            for row in table.to_pylist():  # keep every row's stats: LeRobot's files hold many episodes
                other = row.get("episode_index")
                if other is not None and other < self.num_episodes:
                    self._episode_stats[other] = split_row(row, table.schema, path).stats
            if index not in self._episode_stats:
                raise DatasetError(f"{path}: no meta row for episode {index}")
        return self._episode_stats[index]

    def delta_indices(
        self, delta_timestamps: Mapping[str, Sequence[float]], tolerance_s: float = DELTA_TOLERANCE_S
    ) -> dict[str, list[int]]:
        """Frame offsets of ``delta_timestamps`` (feature -> seconds before or after a frame) as LeRobot's
        ``LeRobotDataset(delta_timestamps=...)`` computes them from ``fps``: ``round(seconds * fps)``. A time that
        is not a whole number of frames (to within ``tolerance_s``, LeRobot's default) or an unknown feature is a
        DatasetError naming it."""
        indices: dict[str, list[int]] = {}
        for name, seconds in delta_timestamps.items():
            if name not in self.features:
                raise DatasetError(f"{self.root / INFO_PATH}: delta_timestamps names {name!r}, not a feature")
            off = [float(t) for t in seconds if abs(t * self.fps - round(t * self.fps)) / self.fps > tolerance_s]
            if off:
                raise DatasetError(
                    f"{self.root}: delta_timestamps {off} of {name!r} are not multiples of the frame period "
                    f"1/{self.fps:g} s"
                )
            indices[name] = [round(t * self.fps) for t in seconds]
        return indices

    def _check_episode(self, index: int) -> None:
        if not isinstance(index, (int, np.integer)) or not 0 <= index < self.num_episodes:
            raise IndexError(f"{self.root}: episode index {index!r} out of range [0, {self.num_episodes})")

    def _columns(self, columns: list[str] | None) -> list[str]:
        readable = [n for n, s in self.features.items() if s["dtype"] != "video"]
        if columns is None:
            return readable
        unknown = [c for c in columns if c not in readable]
        if unknown:
            raise DatasetError(f"{self.root / INFO_PATH}: unknown columns {unknown}; features are {readable}")
        return list(columns)

    def check_data(self) -> int:
        """Read every committed episode's rows, each column checked against the checksum its meta row keeps (and
        its row count and episode index), without decoding images; returns the frames read. A DatasetError naming
        the file at the first that does not hold: what to run before adding to a dataset."""
        return sum(self._episode_table(index, self._columns(None)).num_rows for index in range(self.num_episodes))

    def episode(self, index: int, columns: list[str] | None = None) -> dict[str, np.ndarray]:
        """Episode ``index``'s frames as ``{column: [T, *shape] array}``; reads only its data file's rows."""
        names = self._columns(columns)
        table = self._episode_table(index, names)
        path, length = data_file_path(self.root, self.info, self.episodes[index]), table.num_rows
        try:
            return {name: self._to_numpy(table.column(name), self.features[name], length) for name in names}
        except (pa.ArrowException, OSError, ValueError) as exc:
            raise DatasetError(f"{path}: cannot decode episode {index}: {exc}") from exc

    def _episode_table(self, index: int, names: list[str]) -> pa.Table:
        """Episode ``index``'s rows of the columns ``names``, checked against its meta row and checksums."""
        self._check_episode(index)
        ep = self.episodes[index]
        path = data_file_path(self.root, self.info, ep)
        length = int(ep["length"])
        if self._episodes_per_file.get(path, 1) > 1:  # a packed file (LeRobot's layout): pick this episode's rows
            offset = int(ep["dataset_from_index"]) - self._file_starts[path]
            table = self._rows_of_packed_file(path, int(index), offset, length, names)
        else:
            table = read_parquet(path, columns=list(dict.fromkeys([*names, "episode_index"])))
        if table.num_rows != length:
            raise DatasetError(f"{path}: episode {index} has {table.num_rows} rows, its meta row says {length}")
        if not pc.all(pc.equal(table.column("episode_index"), index)).as_py():
            found = sorted(set(table.column("episode_index").to_pylist()))[:3]
            raise DatasetError(f"{path}: holds rows of episode(s) {found} where episode {index} belongs")
        check_checksums(table, ep.get(CHECKSUMS_COLUMN), names, f"{path}: episode {index}")
        return table

    def _rows_of_packed_file(self, path: Path, index: int, offset: int, length: int, names: list[str]) -> pa.Table:
        """Episode ``index``'s rows in a file holding episodes back to back from row 0: only the row groups that
        hold them are decoded, and the last row groups read are kept (episodes are mostly read in order)."""
        wanted = list(dict.fromkeys([*names, "episode_index"]))
        try:
            if path not in self._row_group_starts:
                footer = pq.read_metadata(path)
                sizes = [footer.row_group(g).num_rows for g in range(footer.num_row_groups)]
                self._row_group_starts[path] = (footer, [0, *np.cumsum(sizes).tolist()])
            footer, starts = self._row_group_starts[path]
            first = bisect_right(starts, offset) - 1
            stop = min(bisect_left(starts, offset + length), footer.num_row_groups)
            key = (path, first, stop, tuple(wanted))
            if self._row_groups is None or self._row_groups[0] != key:
                with pq.ParquetFile(path, metadata=footer) as parquet:
                    groups = parquet.read_row_groups(range(first, stop), columns=wanted)
                    groups.validate(full=True)  # (strings that are not UTF-8, offsets out of bounds)
                    self._row_groups = (key, groups.select(wanted))  # (a column parquet lacks is left out)
            table = self._row_groups[1].slice(offset - starts[first], length)
        except (pa.ArrowException, OSError, ValueError, KeyError) as exc:
            raise DatasetError(f"{path}: corrupt or truncated parquet file: {exc}") from exc
        if table.num_rows == length and pc.all(pc.equal(table.column("episode_index"), index)).as_py():
            return table
        # the rows are not where the meta rows say: find them by value
        return read_parquet(path, columns=wanted, filters=[("episode_index", "=", index)])

    @staticmethod
    def _to_numpy(column: pa.ChunkedArray, spec: Mapping, length: int) -> np.ndarray:
        shape = spec_shape(spec)
        array = column.combine_chunks()
        if spec["dtype"] == "image":
            # flatten() applies the array's slice offset, which field() would not
            data = array.flatten()[array.type.get_field_index("bytes")] if pa.types.is_struct(array.type) else array
            frames = [decode_png(b) for b in data.to_pylist()]
            out = np.stack(frames) if frames else np.zeros((0, *shape), np.uint8)
            if out.shape[1:] != shape:
                raise ValueError(f"images decode to {out.shape[1:]}, the feature says {shape}")
            return out
        dtype = np.dtype(spec["dtype"])
        if (
            pa.types.is_list(array.type)
            or pa.types.is_fixed_size_list(array.type)
            or pa.types.is_large_list(array.type)
        ):
            values = array.flatten().to_numpy(zero_copy_only=False)
        else:
            values = array.to_numpy(zero_copy_only=False)
        return values.astype(dtype, copy=False).reshape(length, *shape)

    def frame_range(self, start: int, stop: int, columns: list[str] | None = None) -> dict[str, np.ndarray]:
        """Frames with global index in ``[start, stop)``, reading only the episodes that hold them."""
        if not (0 <= start <= stop <= self.num_frames):
            raise IndexError(f"{self.root}: frame range [{start}, {stop}) outside [0, {self.num_frames})")
        names = self._columns(columns)
        parts: dict[str, list[np.ndarray]] = {name: [] for name in names}
        index = bisect_right(self._starts, start) - 1
        while start < stop:
            ep = self.episodes[index]
            ep_start, ep_stop = int(ep["dataset_from_index"]), int(ep["dataset_to_index"])
            data = self.episode(index, names)
            lo, hi = start - ep_start, min(stop, ep_stop) - ep_start
            for name in names:
                parts[name].append(data[name][lo:hi])
            start = min(stop, ep_stop)
            index += 1
        return {name: np.concatenate(chunks) if chunks else self._empty(name) for name, chunks in parts.items()}

    def _empty(self, name: str) -> np.ndarray:
        spec = self.features[name]
        dtype = np.uint8 if spec["dtype"] == "image" else np.dtype(spec["dtype"])
        return np.zeros((0, *spec_shape(spec)), dtype=dtype)

    def iter_episodes(
        self, columns: list[str] | None = None, indices: Iterable[int] | None = None
    ) -> Iterator[dict[str, np.ndarray]]:
        """Yield :meth:`episode` for each index (all episodes in order by default), one at a time."""
        for index in range(self.num_episodes) if indices is None else indices:
            yield self.episode(index, columns)

    def __len__(self) -> int:
        return self.num_frames

    def __repr__(self) -> str:
        return f"LeRobotReader({str(self.root)!r}, episodes={self.num_episodes}, frames={self.num_frames})"
