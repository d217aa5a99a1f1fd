"""The crash-safe LeRobot v3.0 writer, :func:`repair` and :func:`compact` (the commit protocol: the package's
docstring; compaction's: :mod:`dpr.datasets.lerobot.compaction`)."""

from __future__ import annotations

import json
import os
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import pyarrow as pa

from dpr.atomic import atomic_write_json
from dpr.checks import check_int
from dpr.datasets.lerobot.checksums import checksums_text
from dpr.datasets.lerobot.compaction import DEFAULT_TARGET_BYTES, compact_files
from dpr.datasets.lerobot.files import WriterLock, delete_leftovers
from dpr.datasets.lerobot.format import (
    CHUNKS_SIZE,
    CODEBASE_VERSION,
    DATA_FILES_SIZE_IN_MB,
    DATA_PATH,
    DEFAULT_FEATURE_DTYPES,
    EPISODES_PATH,
    INFO_PATH,
    LIVE_FILES_KEY,
    META_CHECKSUMS_KEY,
    STANDARD_INFO_KEYS,
    STATS_PATH,
    TASKS_PATH,
    VIDEO_FILES_SIZE_IN_MB,
    DatasetError,
    check_fps,
    check_info,
    chunk_file,
    content_digest,
    encode_png,
    first_difference,
    live_files,
    load_info,
    normalize_features,
    numbered_path,
    parquet_num_rows,
    read_json,
    sealed_info,
    spec_shape,
    write_parquet,
)
from dpr.datasets.lerobot.meta import (
    EpisodeRow,
    aggregates_from_rows,
    check_data_files,
    check_extra_key,
    data_file_path,
    episode_rows,
    extra_array,
    load_tasks,
    new_extra_field,
    read_live_meta,
    tasks_table,
)
from dpr.datasets.lerobot.stats import (
    Aggregate,
    merge_aggregates,
    stats_json,
)
from dpr.datasets.lerobot.tables import ExtraColumns, data_table, episode_stats, meta_table

# ---------------------------------------------------------------------------------------------------------- writer


@dataclass
class _Committed:
    """What a resume reads from a dataset's committed episodes before it changes anything."""

    info: dict
    rows: list[EpisodeRow]
    meta: pa.Table | None  # the rows as stored (what compaction rewrites)
    frames: int
    tasks: list[str]
    aggregates: dict[str, Aggregate]


class LeRobotWriter:
    """Records a LeRobot v3.0 dataset episode by episode; crash-safe (see the module docstring).

    Recording contract: ``create``/``open`` -> ``add_frame`` per step -> ``save_episode`` -> ... -> ``finalize``
    (like LeRobot's). The dataset is valid after every ``save_episode``. One writer per dataset at a time (an
    advisory lock on ``meta/.dpr-writer.lock`` enforces it; the file exists only while a writer is open). As a
    context manager, an exception discards the unsaved episode and keeps every saved one.
    """

    def __init__(
        self,
        root: Path,
        *,
        fps: float,
        features: dict[str, dict],
        robot_type: str,
        info_extra: dict[str, Any],
    ):
        """Internal: use :meth:`create` or :meth:`open`."""
        self.root = root
        self.fps = fps
        self.features = features  # all features, defaults included, as stored in info.json
        self.robot_type = robot_type
        self.info_extra = info_extra
        self._user_features = {k: v for k, v in features.items() if k not in DEFAULT_FEATURE_DTYPES}
        self._shapes = {k: spec_shape(v) for k, v in self._user_features.items()}
        self._dtypes = {k: np.dtype(v["dtype"]) for k, v in self._user_features.items() if v["dtype"] != "image"}
        self._tasks: list[str] = []
        self._task_index: dict[str, int] = {}
        self._aggregates: dict[str, Aggregate] = {}
        self._extra_fields: list[pa.Field] | None = None  # fixed by the first saved episode
        self._num_episodes = 0
        self._num_frames = 0
        self._live = (0, 0)  # the numbers of the files that hold the committed episodes (see live_files)
        self._rows_from = 0  # the first episode whose meta row carries its checksums (0 unless resumed from older)
        self._meta_at_open: pa.Table | None = None
        self._lock = WriterLock(root)
        self._closed = False
        self._reset_buffer()

    # ----------------------------------------------------------------------------------------- construction

    @staticmethod
    def _check_args(root: Any, fps: Any, robot_type: Any, info_extra: Any) -> tuple[Path, dict[str, Any]]:
        root = Path(root)
        check_fps(fps, str(root))
        if robot_type is not None and not isinstance(robot_type, str):
            raise DatasetError(f"{root}: robot_type must be a str (or None), got {robot_type!r}")
        extra = dict(info_extra or {})
        clash = sorted(STANDARD_INFO_KEYS & set(extra))
        if clash:
            raise DatasetError(f"{root}: info_extra keys {clash} clash with info.json's own keys")
        try:
            extra = json.loads(json.dumps(extra))  # as it will read back from info.json
        except (TypeError, ValueError) as exc:
            raise DatasetError(f"{root}: info_extra must be JSON-serialisable: {exc}") from exc
        return root, extra

    @classmethod
    def create(
        cls,
        root: str | os.PathLike,
        *,
        fps: float,
        features: dict[str, dict],
        robot_type: str,
        info_extra: dict | None = None,
    ) -> LeRobotWriter:
        """Start a new dataset at ``root``, which must not exist or be an empty folder."""
        root, extra = cls._check_args(root, fps, robot_type, info_extra)
        normalized = normalize_features(features, str(root))
        if root.exists():
            if not root.is_dir():
                raise DatasetError(f"{root}: exists and is not a folder")
            if any(root.iterdir()):
                raise DatasetError(f"{root}: folder is not empty; create() needs a new or empty folder (use open())")
        (root / "meta").mkdir(parents=True, exist_ok=True)
        writer = cls(root, fps=fps, features=normalized, robot_type=robot_type, info_extra=extra)
        writer._lock.acquire()
        atomic_write_json(root / INFO_PATH, writer._info(0, 0, [], (0, 0), {}))
        return writer

    @classmethod
    def open(
        cls,
        root: str | os.PathLike,
        *,
        fps: float,
        features: dict[str, dict],
        robot_type: str,
        info_extra: dict | None = None,
    ) -> LeRobotWriter:
        """Create the dataset if ``root`` is absent or empty, else check it matches and resume appending.

        A resume is refused with a DatasetError, before anything on disk changes, when an argument differs from
        what ``meta/info.json`` holds (the message names the first difference), when another writer holds the
        dataset, or when the committed episodes are not intact (meta rows, frame totals, tasks, stats columns, data
        file footers). Only then are crash leftovers (files of uncommitted episodes, temp files) deleted, the
        aggregates rebuilt from the committed episodes, and recording resumed after them."""
        root_path = Path(root)
        if not root_path.exists() or (root_path.is_dir() and not any(root_path.iterdir())):
            return cls.create(root_path, fps=fps, features=features, robot_type=robot_type, info_extra=info_extra)
        root_path, extra = cls._check_args(root_path, fps, robot_type, info_extra)
        normalized = normalize_features(features, str(root_path))
        info_path = root_path / INFO_PATH
        if not info_path.is_file():
            raise DatasetError(f"{info_path}: not found; {root_path} is not empty and holds no dataset")

        def check_settings() -> dict:
            info = check_info(read_json(info_path), info_path)
            difference = first_difference(info, fps=fps, features=normalized, robot_type=robot_type, info_extra=extra)
            if difference:
                raise DatasetError(f"{info_path}: does not match the requested dataset: {difference}")
            return info

        check_settings()  # before the lock, whose file would be the first change on disk
        writer = cls(root_path, fps=fps, features=normalized, robot_type=robot_type, info_extra=extra)
        writer._lock.acquire()
        try:
            committed = writer._committed_state(check_settings())  # again: another writer may have appended
        except BaseException:
            writer._lock.release(remove=writer._lock.created)
            raise
        try:
            writer._resume(committed)
        except BaseException:
            writer._lock.release()
            raise
        return writer

    def _committed_state(self, info: dict) -> _Committed:
        """Read and check everything a resume needs, changing nothing on disk (DatasetError when it is not
        intact)."""
        meta_folder = self.root / "meta" / "episodes"
        meta, row_paths = read_live_meta(self.root, info, with_stats=True)
        rows = episode_rows(self.root, info, meta, row_paths)
        frames = sum(int(r.meta["length"]) for r in rows)
        if frames != info["total_frames"]:
            raise DatasetError(
                f"{self.root / INFO_PATH}: total_frames is {info['total_frames']} but the committed episodes hold "
                f"{frames} frames"
            )
        check_data_files(self.root, info, [r.meta for r in rows])
        tasks = load_tasks(self.root, info)
        return _Committed(
            info=info,
            rows=rows,
            meta=meta,
            frames=frames,
            tasks=tasks,
            aggregates=aggregates_from_rows(rows, self.features, meta_folder),
        )

    def _resume(self, committed: _Committed) -> None:
        """Delete uncommitted leftovers, bring tasks.parquet and stats.json back to the committed episodes, and
        take up recording after them."""
        info, rows = committed.info, committed.rows
        referenced = {data_file_path(self.root, info, r.meta).resolve() for r in rows}
        referenced |= {r.meta_path.resolve() for r in rows}
        delete_leftovers(self.root, live_files(info), referenced)
        self._live = live_files(info)
        entry = info.get(META_CHECKSUMS_KEY)  # none: written before meta checksums, whose rows carry none
        self._rows_from = entry["rows_from"] if entry is not None else info["total_episodes"]

        self._tasks = committed.tasks
        self._meta_at_open = committed.meta  # until an episode is added: spares compaction reading it again
        self._task_index = {t: i for i, t in enumerate(self._tasks)}
        self._aggregates = committed.aggregates
        self._extra_fields = rows[0].extra_fields if rows else None
        self._num_episodes, self._num_frames = info["total_episodes"], committed.frames

        # The aggregate files may hold an uncommitted episode's contribution (crash between them and info.json).
        tasks_path = self.root / TASKS_PATH
        if not self._tasks:
            tasks_path.unlink(missing_ok=True)  # only an uncommitted episode's task can be in it
        elif parquet_num_rows(tasks_path) != len(self._tasks):
            write_parquet(tasks_path, tasks_table(self._tasks))
        stats = stats_json(self._aggregates)
        stats_path = self.root / STATS_PATH
        try:
            current = read_json(stats_path) if stats_path.exists() else None
        except DatasetError as error:  # written atomically, so no crash leaves it unreadable: it was damaged
            warnings.warn(f"{error}; rewritten from the committed episodes' stats", RuntimeWarning, stacklevel=3)
            current = None  # it is derived data, so rewrite it
        expected = (info.get(META_CHECKSUMS_KEY) or {}).get("stats")
        if current != json.loads(json.dumps(stats)):
            if expected is not None and current is not None and content_digest(current) != expected:
                count = (current.get("index") or {}).get("count") if isinstance(current, dict) else None
                if count == [self._num_frames]:  # not the file of an episode a crash left uncommitted: damaged
                    message = f"{stats_path}: does not match its checksum; rewritten from the committed episodes"
                    warnings.warn(message, RuntimeWarning, stacklevel=3)
            atomic_write_json(stats_path, stats)

    # ------------------------------------------------------------------------------------------- recording

    @property
    def num_episodes(self) -> int:
        """Committed episodes."""
        return self._num_episodes

    @property
    def num_frames(self) -> int:
        """Committed frames."""
        return self._num_frames

    @property
    def tasks(self) -> list[str]:
        """Committed task strings by task_index."""
        return list(self._tasks)

    @property
    def buffered_frames(self) -> int:
        """Frames added to the episode in progress."""
        return len(self._frame_tasks)

    def _reset_buffer(self) -> None:
        self._buffer: dict[str, list] = {name: [] for name in self._user_features}
        self._frame_tasks: list[str] = []

    def _check_open(self) -> None:
        if self._closed:
            raise DatasetError(f"{self.root}: the writer is finalized; open the dataset again to append")

    def add_frame(self, frame: dict[str, object], task: str) -> None:
        """Buffer one frame: exactly the user features (not the five defaults), each with its shape and a dtype
        that converts to the feature's exactly (images: uint8 [H, W, 3]); ``task`` a non-empty string."""
        self._check_open()
        if not isinstance(frame, Mapping):
            raise DatasetError(f"{self.root}: add_frame: frame must be a dict of feature -> value, got {type(frame)}")
        if frame.keys() != self._user_features.keys():
            missing = sorted(self._user_features.keys() - frame.keys())
            extra = sorted(frame.keys() - self._user_features.keys())
            raise DatasetError(
                f"{self.root}: add_frame: frame keys differ from the features: missing features "
                f"{missing}, unknown features {extra}"
            )
        if not isinstance(task, str) or not task:
            raise DatasetError(f"{self.root}: add_frame: task must be a non-empty string, got {task!r}")
        # Convert everything before appending anything, so a bad frame leaves the buffer as it was.
        converted = {name: self._convert(name, value) for name, value in frame.items()}
        for name, value in converted.items():
            self._buffer[name].append([value] if self._user_features[name]["dtype"] == "image" else value[None])
        self._frame_tasks.append(task)

    def add_frames(self, frames: dict[str, object], task: str) -> None:
        """Buffer ``T`` frames at once: each feature an array of shape ``[T, *shape]`` (images ``[T, H, W, 3]``
        uint8), all with the same ``T``. The same checks as :meth:`add_frame`, once per array instead of once per
        frame (what recording a whole rolled-out episode wants)."""
        self._check_open()
        if not isinstance(frames, Mapping) or frames.keys() != self._user_features.keys():
            given = sorted(frames.keys()) if isinstance(frames, Mapping) else type(frames)
            raise DatasetError(
                f"{self.root}: add_frames: frames must map exactly the features "
                f"{sorted(self._user_features)} to arrays, got {given}"
            )
        if not isinstance(task, str) or not task:
            raise DatasetError(f"{self.root}: add_frames: task must be a non-empty string, got {task!r}")
        lengths = {name: np.shape(value)[0] if np.ndim(value) else None for name, value in frames.items()}
        if None in lengths.values() or len(set(lengths.values())) != 1:
            raise DatasetError(f"{self.root}: add_frames: every feature needs the same number of frames, got {lengths}")
        converted = {name: self._convert(name, value, leading=(lengths[name],)) for name, value in frames.items()}
        for name, value in converted.items():
            self._buffer[name].append(value)
        self._frame_tasks.extend([task] * next(iter(lengths.values())))

    def _convert(self, name: str, value: object, leading: tuple[int, ...] = ()) -> object:
        """``value`` checked and converted to the feature's dtype; ``leading``: the frame axis of a block."""
        spec = self._user_features[name]
        shape = leading + self._shapes[name]
        if spec["dtype"] == "image":
            arr = np.asarray(value)
            if arr.dtype != np.uint8 or arr.shape != shape:
                raise DatasetError(
                    f"{self.root}: add_frame: feature {name!r} expects a uint8 image of shape "
                    f"{shape}, got {arr.dtype} {arr.shape}"
                )
            return [encode_png(image) for image in arr] if leading else encode_png(arr)
        arr = np.asarray(value)
        if arr.shape != shape:
            if self._shapes[name] == (1,) and arr.shape == leading:
                arr = arr.reshape(shape)
            else:
                raise DatasetError(f"{self.root}: add_frame: feature {name!r} expects shape {shape}, got {arr.shape}")
        target = self._dtypes[name]
        if arr.dtype == target:
            return arr.copy()  # the caller may reuse its buffer
        if arr.dtype.kind not in "biuf":
            raise DatasetError(f"{self.root}: add_frame: feature {name!r} expects {target} values, got {arr.dtype}")
        if np.can_cast(arr.dtype, target, casting="safe"):
            return arr.astype(target)
        with np.errstate(invalid="ignore", over="ignore"):
            cast = arr.astype(target)
            exact = np.array_equal(cast.astype(arr.dtype), arr, equal_nan=arr.dtype.kind == "f" and target.kind == "f")
        if not exact:
            raise DatasetError(
                f"{self.root}: add_frame: feature {name!r} expects {target}; the {arr.dtype} values "
                "given do not convert to it exactly"
            )
        return cast

    def clear_episode(self) -> None:
        """Drop the frames buffered for the episode in progress."""
        self._reset_buffer()

    def save_episode(self, episode_meta: dict | None = None) -> int:
        """Durably write the buffered episode and return its index.

        ``episode_meta``: flat JSON-able extras stored as extra columns of the episode's meta row (None, bool,
        int, float, str as such; dict/list as JSON text, decoded again by the reader). The first saved episode
        fixes the keys and their types; every later episode must give the same keys."""
        self._check_open()
        n = len(self._frame_tasks)
        if n == 0:
            raise DatasetError(f"{self.root}: save_episode: no frames buffered (call add_frame first)")
        episode = self._num_episodes
        first, number = self._live  # a new episode gets the next file number, for its data and its meta row
        data_path = numbered_path(self.root, DATA_PATH, number)
        meta_path = numbered_path(self.root, EPISODES_PATH, number)

        tasks, task_index, episode_tasks = self._with_episode_tasks()
        new_tasks = len(tasks) > len(self._tasks)

        columns = self._episode_columns(episode, n, task_index)
        stats = episode_stats(self.features, columns)
        extra = self._extra_columns(episode_meta, meta_path)
        data = data_table(self.features, columns, n)
        meta = meta_table(
            episode=episode,
            frames=(self._num_frames, self._num_frames + n),
            tasks=episode_tasks,
            data_file=chunk_file(number),
            meta_file=chunk_file(number),
            stats=stats,
            extra=extra,
            checksums=checksums_text(data),
        )
        aggregates = merge_aggregates(self._aggregates, stats)
        live = (first, number + 1)

        # Commit order: data, episode meta, tasks, stats, and info.json last (the commit point). tasks/stats live
        # in meta/ beside info.json, whose folder fsync makes their renames durable too.
        write_parquet(data_path, data)
        write_parquet(meta_path, meta, write_statistics=False)  # 1-row file: stats are noise
        if new_tasks:
            write_parquet(self.root / TASKS_PATH, tasks_table(tasks), sync_folder=False)
        # compact: indenting sends json through its pure-Python encoder, several ms per episode for ~600 numbers
        stats_text = stats_json(aggregates)
        atomic_write_json(self.root / STATS_PATH, stats_text, sync_folder=False, indent=None)
        atomic_write_json(self.root / INFO_PATH, self._info(episode + 1, self._num_frames + n, tasks, live, stats_text))

        self._tasks, self._task_index, self._aggregates, self._live = tasks, task_index, aggregates, live
        self._meta_at_open = None
        self._extra_fields = extra.fields
        self._num_episodes += 1
        self._num_frames += n
        self._reset_buffer()
        return episode

    def _with_episode_tasks(self) -> tuple[list[str], dict[str, int], list[str]]:
        """The dataset's tasks and task index with the buffered episode's new tasks added (the writer's own are
        changed only once the episode is committed), and the episode's tasks in order of first appearance."""
        tasks = list(self._tasks)
        task_index = dict(self._task_index)
        episode_tasks: list[str] = []
        for task in dict.fromkeys(self._frame_tasks):  # unique, in order of first appearance
            if task not in task_index:
                task_index[task] = len(tasks)
                tasks.append(task)
            episode_tasks.append(task)
        return tasks, task_index, episode_tasks

    def _episode_columns(self, episode: int, n: int, task_index: Mapping[str, int]) -> dict[str, Any]:
        """The buffered frames stacked per feature, plus the five derived default columns."""
        columns: dict[str, Any] = {}
        for name, spec in self._user_features.items():
            blocks = self._buffer[name]  # per add_frame(s) call: a list of PNGs, or an array [k, *shape]
            columns[name] = (
                [png for block in blocks for png in block] if spec["dtype"] == "image" else np.concatenate(blocks)
            )
        frame_index = np.arange(n, dtype=np.int64)
        columns["timestamp"] = (frame_index / self.fps).astype(np.float32)
        columns["frame_index"] = frame_index
        columns["episode_index"] = np.full(n, episode, dtype=np.int64)
        columns["index"] = np.arange(self._num_frames, self._num_frames + n, dtype=np.int64)
        columns["task_index"] = np.fromiter((task_index[t] for t in self._frame_tasks), dtype=np.int64, count=n)
        return columns

    def _extra_columns(self, episode_meta: dict | None, meta_path: Path) -> ExtraColumns:
        where = str(meta_path)
        given = dict(episode_meta or {})
        for key in given:
            check_extra_key(key, where)
        if self._extra_fields is None:  # the first episode fixes keys and types
            fields, arrays = [], []
            for key, value in given.items():
                field, stored = new_extra_field(key, value, where)
                fields.append(field)
                arrays.append(pa.array([stored], type=field.type))
            return ExtraColumns(fields, arrays)
        expected = [f.name for f in self._extra_fields]
        if set(given) != set(expected):
            raise DatasetError(
                f"{where}: episode_meta keys must be the same every episode: expected {sorted(expected)}, "
                f"got {sorted(given)}"
            )
        return ExtraColumns(self._extra_fields, [extra_array(f, given[f.name], where) for f in self._extra_fields])

    def _info(
        self, total_episodes: int, total_frames: int, tasks: list[str], live: tuple[int, int], stats: dict[str, Any]
    ) -> dict[str, Any]:
        """info.json as LeRobot writes it, plus the caller's info_extra keys, sealed with the checksums of its
        content, of ``tasks`` and of ``stats`` (stats.json's content): :mod:`dpr.datasets.lerobot.checksums`."""
        total_tasks = len(tasks)
        info: dict[str, Any] = {
            "codebase_version": CODEBASE_VERSION,
            "robot_type": self.robot_type,
            "total_episodes": total_episodes,
            "total_frames": total_frames,
            "total_tasks": total_tasks,
            "chunks_size": CHUNKS_SIZE,
            "data_files_size_in_mb": DATA_FILES_SIZE_IN_MB,
            "video_files_size_in_mb": VIDEO_FILES_SIZE_IN_MB,
            "fps": self.fps,
            "splits": {"train": f"0:{total_episodes}"} if total_episodes else {},
            "data_path": DATA_PATH,
            "video_path": None,
            "features": self.features,
            LIVE_FILES_KEY: list(live),
        }
        info.update(self.info_extra)
        return sealed_info(info, tasks=content_digest(tasks), stats=content_digest(stats), rows_from=self._rows_from)

    # ------------------------------------------------------------------------------------------------ closing

    def finalize(self, *, compact: bool = False, target_bytes: int = DEFAULT_TARGET_BYTES) -> None:
        """Stop recording (idempotent) and delete the writer's lock file. Saved episodes are already durable;
        unsaved frames are discarded with a RuntimeWarning.

        ``compact=True`` first packs the per-episode files into LeRobot's files of up to ``target_bytes``
        (:mod:`dpr.datasets.lerobot.compaction`; crash-safe, a kill leaves the old or the new layout). It is off by
        default: recording is already a valid LeRobot dataset, and compaction rewrites the episodes recorded
        since the last one, seconds to minutes for gigabytes."""
        if self._closed:
            return
        check_int("target_bytes", target_bytes, 1)
        if self._frame_tasks:
            warnings.warn(
                f"{self.root}: finalize() discards {len(self._frame_tasks)} frames never passed to save_episode()",
                RuntimeWarning,
                stacklevel=2,
            )
        self._reset_buffer()
        self._closed = True
        try:
            if compact and self._num_episodes:
                compact_files(self.root, load_info(self.root), target_bytes, self._meta_at_open)
        finally:
            self._meta_at_open = None
            self._lock.release()

    def __enter__(self) -> LeRobotWriter:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if exc_type is not None:
            self.clear_episode()  # an interrupted episode is never half-saved
        self.finalize()

    def __del__(self) -> None:
        lock = getattr(self, "_lock", None)
        if lock is not None:
            lock.release()


def repair(root: str | os.PathLike) -> None:
    """Bring a dataset left by a crash back to its committed state without appending: delete the files of
    uncommitted episodes, temp files and the side of an interrupted compaction that is not live, and rewrite
    tasks.parquet/stats.json from the committed episodes.

    LeRobot loads every ``data/*/*.parquet``, so run this (or :meth:`LeRobotWriter.open`) before handing a crashed
    dataset to it; :class:`LeRobotReader` already ignores uncommitted episodes."""
    _open_as_recorded(root).finalize()


def compact(root: str | os.PathLike, *, target_bytes: int = DEFAULT_TARGET_BYTES) -> None:
    """Pack the dataset at ``root`` into LeRobot's files of up to ``target_bytes`` (after the clean-up of
    :func:`repair`); crash-safe, see :mod:`dpr.datasets.lerobot.compaction`. Recording can resume afterwards."""
    check_int("target_bytes", target_bytes, 1)
    _open_as_recorded(root).finalize(compact=True, target_bytes=target_bytes)


def _open_as_recorded(root: str | os.PathLike) -> LeRobotWriter:
    """A writer on an existing dataset with the settings its info.json holds."""
    root = Path(root)
    info = load_info(root)
    features = {k: v for k, v in info["features"].items() if k not in DEFAULT_FEATURE_DTYPES}
    extra = {k: v for k, v in info.items() if k not in STANDARD_INFO_KEYS}
    return LeRobotWriter.open(
        root, fps=info["fps"], features=features, robot_type=info.get("robot_type"), info_extra=extra
    )
