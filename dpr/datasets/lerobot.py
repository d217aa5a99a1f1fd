"""LeRobot dataset format v3.0: a crash-safe writer and a lazy reader (pyarrow + numpy + json, no ``lerobot``).

A dataset written here loads unchanged in ``lerobot.datasets.lerobot_dataset.LeRobotDataset(repo_id, root=ROOT)``
(see ``/work/shared/lerobot_v3_format.md``). Layout::

    ROOT/meta/info.json                                  the commit point (totals, features, fps, ...)
    ROOT/meta/stats.json                                 stats aggregated over the committed episodes
    ROOT/meta/tasks.parquet                              pandas frame indexed by task string, column task_index
    ROOT/meta/episodes/chunk-{c:03d}/file-{f:03d}.parquet  one row per episode (this writer: one file per episode)
    ROOT/data/chunk-{c:03d}/file-{f:03d}.parquet           one row per frame (this writer: one file per episode)

with ``c, f = divmod(episode_index, 1000)``. Column types: a shape ``[1]`` feature is a scalar column, ``[n]`` a
``fixed_size_list<dtype>[n]``, an image a ``struct<bytes: binary, path: string>`` holding a PNG. The five LeRobot
default columns (``timestamp = frame_index / fps`` as float32, ``frame_index``, ``episode_index``, ``index``,
``task_index``) are derived here, never supplied.

Crash safety. LeRobot's own writer keeps one parquet file open until ``finalize()``, so a crash loses everything.
Here every :meth:`LeRobotWriter.save_episode` writes the episode's data file and its episodes-meta file, then
``tasks.parquet`` (when a task is new), ``stats.json`` and last ``info.json``; each through a temporary file in the
same folder (a name that does not end in ``.parquet``, because LeRobot loads every ``data/*/*.parquet``), fsynced
and ``os.replace``'d, folder fsynced. ``info.json``'s ``total_episodes`` is the commit point: episodes with an
index at or above it are uncommitted, ignored by :class:`LeRobotReader` and deleted by :meth:`LeRobotWriter.open`,
which then resumes after the last committed episode (:func:`repair` does the clean-up alone). Committed data/meta
files are never rewritten. LeRobot itself globs every ``data/*/*.parquet``: it would see an uncommitted episode's
rows until the dataset is opened or repaired.

Statistics. Each episode's meta row holds ``stats/<feature>/<stat>`` for min, max, mean, std (population),
count, q01, q10, q50, q90, q99, computed exactly on that episode (quantiles by linear interpolation, like
``numpy.quantile``). ``stats.json`` aggregates the committed episodes: min/max exact, mean/std combined exactly from
the per-episode counts, means and variances; quantiles are the count-weighted mean of the per-episode quantiles
(an approximation, as in LeRobot's ``aggregate_stats``). Image stats are per channel, shape ``(3, 1, 1)``, in
``[0, 1]``, computed on at most ``IMAGE_STATS_MAX_FRAMES`` evenly spaced frames of each episode (their ``count``
is the number of frames used, as in LeRobot). Stats cover the five default columns too, as LeRobot's do.
"""

from __future__ import annotations

import fcntl
import io
import json
import os
import re
import warnings
from bisect import bisect_right
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from PIL import Image

__all__ = [
    "CODEBASE_VERSION",
    "DatasetError",
    "LeRobotReader",
    "LeRobotWriter",
    "default_features",
    "repair",
]

CODEBASE_VERSION = "v3.0"
CHUNKS_SIZE = 1000  # files per chunk folder, LeRobot's default
DATA_FILES_SIZE_IN_MB = 100  # written to info.json for LeRobot's own appender; one file per episode here
VIDEO_FILES_SIZE_IN_MB = 200
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
INFO_PATH = "meta/info.json"
STATS_PATH = "meta/stats.json"
TASKS_PATH = "meta/tasks.parquet"
LOCK_PATH = "meta/.dpr-writer.lock"
TMP_SUFFIX = ".dpr-tmp"  # never ".parquet": LeRobot globs data/*/*.parquet
CHUNK_FILE_RE = re.compile(r"^chunk-(\d{3,})/file-(\d{3,})\.parquet$")

QUANTILES = {"q01": 0.01, "q10": 0.10, "q50": 0.50, "q90": 0.90, "q99": 0.99}
STAT_KEYS = ("min", "max", "mean", "std", "count", *QUANTILES)
IMAGE_STATS_MAX_FRAMES = 100

NUMERIC_DTYPES = frozenset(
    {"bool", "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "uint64", "float32", "float64"}
)
DEFAULT_FEATURE_DTYPES = {
    "timestamp": "float32",
    "frame_index": "int64",
    "episode_index": "int64",
    "index": "int64",
    "task_index": "int64",
}
IMAGE_NAMES = ["height", "width", "channels"]
STANDARD_EPISODE_COLUMNS = (
    "episode_index",
    "tasks",
    "length",
    "data/chunk_index",
    "data/file_index",
    "dataset_from_index",
    "dataset_to_index",
    "meta/episodes/chunk_index",
    "meta/episodes/file_index",
)
RESERVED_PREFIXES = ("stats/", "videos/", "data/", "meta/")
STANDARD_INFO_KEYS = frozenset(
    {
        "codebase_version",
        "robot_type",
        "total_episodes",
        "total_frames",
        "total_tasks",
        "chunks_size",
        "data_files_size_in_mb",
        "video_files_size_in_mb",
        "fps",
        "splits",
        "data_path",
        "video_path",
        "features",
    }
)
REQUIRED_INFO_KEYS = ("codebase_version", "fps", "features", "total_episodes", "total_frames", "data_path")
JSON_FIELD_METADATA = {b"dpr.encoding": b"json"}  # marks an episodes column holding JSON text


class DatasetError(ValueError):
    """A dataset file or a writer argument is not what the format needs; the message names the path."""


def default_features() -> dict[str, dict]:
    """The feature specs of LeRobot's five default columns, in LeRobot's order."""
    return {name: {"dtype": dtype, "shape": [1], "names": None} for name, dtype in DEFAULT_FEATURE_DTYPES.items()}


# --------------------------------------------------------------------------------------------------- file helpers


def _fsync_dir(folder: Path) -> None:
    """Make a rename inside ``folder`` durable (the file's own fsync does not cover its directory entry)."""
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _atomic_write(path: Path, write: Any, *, sync_folder: bool = True) -> None:
    """Write through a temp file in the same folder, fsync it, rename it over ``path``, fsync the folder
    (``sync_folder=False`` when a later write in the same folder will fsync it before anything depends on it)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}{TMP_SUFFIX}")
    try:
        with open(tmp, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    if sync_folder:
        _fsync_dir(path.parent)


def _atomic_write_json(path: Path, obj: Any, *, sync_folder: bool = True, indent: int | None = 4) -> None:
    text = json.dumps(obj, indent=indent, ensure_ascii=False) + "\n"
    _atomic_write(path, lambda f: f.write(text.encode("utf-8")), sync_folder=sync_folder)


def _atomic_write_parquet(path: Path, table: pa.Table, *, sync_folder: bool = True, **options: Any) -> None:
    # No dictionary encoding: float columns rarely repeat, and it cost ~8x the write time of a 2500-frame episode.
    _atomic_write(
        path,
        lambda f: pq.write_table(table, f, compression="snappy", use_dictionary=False, **options),
        sync_folder=sync_folder,
    )


def _chunk_file(episode_index: int) -> tuple[int, int]:
    return divmod(episode_index, CHUNKS_SIZE)


def _read_json(path: Path) -> Any:
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise DatasetError(f"{path}: file not found") from None
    except OSError as exc:
        raise DatasetError(f"{path}: cannot read: {exc}") from exc
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise DatasetError(f"{path}: not valid JSON: {exc}") from exc


def _read_parquet(
    path: Path, columns: list[str] | None = None, filters: list[tuple] | None = None, *, skip_stats: bool = False
) -> pa.Table:
    """Read a parquet file (optionally some columns, some rows, or all but the ``stats/`` columns); every failure
    (missing, truncated, corrupt) becomes a DatasetError naming ``path``."""
    if not path.is_file():
        raise DatasetError(f"{path}: file not found")
    try:
        if filters is not None:
            return pq.read_table(path, columns=columns, filters=filters)
        with pq.ParquetFile(path) as parquet:  # cheaper than read_table's dataset layer for small files
            if skip_stats:
                columns = [n for n in parquet.schema_arrow.names if not n.startswith("stats/")]
            return parquet.read(columns=columns)
    except (pa.ArrowException, OSError, ValueError) as exc:
        raise DatasetError(f"{path}: corrupt or truncated parquet file: {exc}") from exc


def _parquet_num_rows(path: Path) -> int:
    """Rows of a parquet file from its footer only (a truncated file has no valid footer)."""
    if not path.is_file():
        raise DatasetError(f"{path}: file not found")
    try:
        return pq.read_metadata(path).num_rows
    except (pa.ArrowException, OSError, ValueError) as exc:
        raise DatasetError(f"{path}: corrupt or truncated parquet file: {exc}") from exc


# ------------------------------------------------------------------------------------------------ feature specs


def _normalize_spec(name: Any, spec: Any, where: str) -> dict:
    """Check one user feature spec and return it as stored in info.json (shape a list of ints)."""
    if not isinstance(name, str) or not name:
        raise DatasetError(f"{where}: feature names must be non-empty strings, got {name!r}")
    if "/" in name:
        raise DatasetError(f"{where}: feature {name!r}: names must not contain '/' (LeRobot flattens stats with it)")
    if not isinstance(spec, Mapping):
        raise DatasetError(f"{where}: feature {name!r}: expected a dict with dtype/shape/names, got {spec!r}")
    unknown = set(spec) - {"dtype", "shape", "names"}
    if unknown or "dtype" not in spec or "shape" not in spec:
        raise DatasetError(f"{where}: feature {name!r}: expected keys dtype, shape (and names), got {sorted(spec)}")
    dtype, names = spec["dtype"], spec.get("names")
    try:
        shape = [int(s) for s in spec["shape"]]
    except (TypeError, ValueError):
        raise DatasetError(f"{where}: feature {name!r}: shape must be a list of ints, got {spec['shape']!r}") from None
    if any(s < 1 for s in shape):
        raise DatasetError(f"{where}: feature {name!r}: shape entries must be >= 1, got {shape}")
    if dtype == "image":
        if len(shape) != 3 or shape[2] != 3:
            raise DatasetError(f"{where}: feature {name!r}: an image's shape must be [H, W, 3], got {shape}")
        if names is None:
            names = list(IMAGE_NAMES)  # LeRobot's policies read names[2] to find the channel axis
        if list(names) != IMAGE_NAMES:
            raise DatasetError(f"{where}: feature {name!r}: an image's names must be {IMAGE_NAMES}, got {names!r}")
        names = list(names)
    elif dtype in NUMERIC_DTYPES:
        if len(shape) != 1:
            raise DatasetError(f"{where}: feature {name!r}: numeric features must have a 1-D shape [n], got {shape}")
    else:
        raise DatasetError(
            f"{where}: feature {name!r}: dtype must be 'image' or one of {sorted(NUMERIC_DTYPES)}, got {dtype!r}"
        )
    if isinstance(names, tuple):
        names = list(names)
    return {"dtype": dtype, "shape": shape, "names": names}


def _normalize_features(features: Any, where: str) -> dict[str, dict]:
    """User features (without the defaults) checked and normalised; the defaults appended, as LeRobot does."""
    if not isinstance(features, Mapping) or not features:
        raise DatasetError(f"{where}: features must be a non-empty dict of name -> spec, got {features!r}")
    out: dict[str, dict] = {}
    for name, spec in features.items():
        if name in DEFAULT_FEATURE_DTYPES:
            raise DatasetError(f"{where}: feature {name!r} is one of LeRobot's defaults; it is derived, not supplied")
        out[name] = _normalize_spec(name, spec, where)
    out.update(default_features())
    return out


def _spec_shape(spec: Mapping) -> tuple[int, ...]:
    return tuple(int(s) for s in spec["shape"])


# ----------------------------------------------------------------------------------------------------- statistics


def _vector_stats(values: np.ndarray) -> dict[str, np.ndarray]:
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


def _image_stats(frames: list[np.ndarray]) -> dict[str, np.ndarray]:
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


def _image_sample_indices(n_frames: int) -> np.ndarray:
    """At most IMAGE_STATS_MAX_FRAMES evenly spaced frame indices (first and last included)."""
    k = min(n_frames, IMAGE_STATS_MAX_FRAMES)
    return np.unique(np.round(np.linspace(0, n_frames - 1, k)).astype(np.int64))


@dataclass
class _Aggregate:
    """Running aggregate of one feature's per-episode stats (Chan et al.'s exact pairwise mean/variance merge)."""

    count: int
    mean: np.ndarray
    m2: np.ndarray  # sum of squared deviations from ``mean``
    lo: np.ndarray
    hi: np.ndarray
    quantile_sums: dict[str, np.ndarray]  # sum over episodes of count * quantile

    @classmethod
    def of(cls, stats: Mapping[str, np.ndarray]) -> _Aggregate:
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

    def merged(self, other: _Aggregate) -> _Aggregate:
        total = self.count + other.count
        delta = other.mean - self.mean
        return _Aggregate(
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


def _merge_aggregates(
    aggregates: Mapping[str, _Aggregate], episode_stats: Mapping[str, Mapping[str, np.ndarray]]
) -> dict[str, _Aggregate]:
    """New aggregates with one more episode folded in (the inputs are left untouched)."""
    out = dict(aggregates)
    for name, stats in episode_stats.items():
        ep = _Aggregate.of(stats)
        out[name] = out[name].merged(ep) if name in out else ep
    return out


def _stats_json(aggregates: Mapping[str, _Aggregate]) -> dict[str, Any]:
    return {name: agg.to_json() for name, agg in aggregates.items()}


# ------------------------------------------------------------------------------------------ episode meta extras


def _is_json_field(field: pa.Field) -> bool:
    return bool(field.metadata) and field.metadata.get(b"dpr.encoding") == b"json"


def _plain_extra(value: Any) -> Any:
    """A scalar extra as a plain Python value (numpy scalars unwrapped)."""
    if isinstance(value, np.generic):
        return value.item()
    return value


def _json_text(key: str, value: Any, where: str) -> str | None:
    if value is None:
        return None
    if isinstance(value, np.ndarray):
        value = value.tolist()
    try:
        return json.dumps(value, sort_keys=True, default=_plain_extra_json)
    except (TypeError, ValueError) as exc:
        raise DatasetError(f"{where}: episode_meta[{key!r}] is not JSON-serialisable: {exc}") from exc


def _plain_extra_json(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON-serialisable")


def _new_extra_field(key: str, value: Any, where: str) -> tuple[pa.Field, Any]:
    """The column type an extra gets from the first episode that sets it, and its stored value."""
    value = _plain_extra(value)
    if isinstance(value, (dict, list, tuple, np.ndarray)):
        return pa.field(key, pa.string(), metadata=JSON_FIELD_METADATA), _json_text(key, value, where)
    if value is None:
        return pa.field(key, pa.null()), None
    if isinstance(value, bool):
        return pa.field(key, pa.bool_()), value
    if isinstance(value, int):
        return pa.field(key, pa.int64()), value
    if isinstance(value, float):
        return pa.field(key, pa.float64()), value
    if isinstance(value, str):
        return pa.field(key, pa.string()), value
    raise DatasetError(
        f"{where}: episode_meta[{key!r}] must be None, bool, int, float, str, or a JSON-able dict/list, "
        f"got {type(value).__name__}"
    )


def _extra_array(field: pa.Field, value: Any, where: str) -> pa.Array:
    """One episode's extra as a 1-row array of the column's established type."""
    if _is_json_field(field):
        return pa.array([_json_text(field.name, value, where)], type=pa.string())
    value = _plain_extra(value)
    if isinstance(value, (dict, list, tuple, np.ndarray)):
        raise DatasetError(
            f"{where}: episode_meta[{field.name!r}] was a {field.type} in earlier episodes, got a "
            f"{type(value).__name__}"
        )
    try:
        return pa.array([value], type=field.type)
    except (pa.ArrowInvalid, pa.ArrowTypeError, OverflowError) as exc:
        raise DatasetError(
            f"{where}: episode_meta[{field.name!r}] must have the type it had in earlier episodes ({field.type}), "
            f"got {value!r}"
        ) from exc


def _check_extra_key(key: Any, where: str) -> None:
    if not isinstance(key, str) or not key:
        raise DatasetError(f"{where}: episode_meta keys must be non-empty strings, got {key!r}")
    if key in STANDARD_EPISODE_COLUMNS or "/" in key or key.startswith(RESERVED_PREFIXES):
        raise DatasetError(f"{where}: episode_meta key {key!r} clashes with LeRobot's episode columns (no '/' allowed)")


# ------------------------------------------------------------------------------------------- shared meta loading


def _check_info(info: Any, path: Path) -> dict:
    """Validate a parsed info.json (version first, so an old dataset gets the version message)."""
    if not isinstance(info, dict):
        raise DatasetError(f"{path}: expected a JSON object, got {type(info).__name__}")
    if "codebase_version" not in info:
        raise DatasetError(f"{path}: missing required key 'codebase_version'")
    version = info["codebase_version"]
    if version != CODEBASE_VERSION:
        raise DatasetError(
            f"{path}: codebase_version is {version!r}; this reader handles {CODEBASE_VERSION!r} only "
            "(convert older datasets with LeRobot's converter)"
        )
    missing = [k for k in REQUIRED_INFO_KEYS if k not in info]
    if missing:
        raise DatasetError(f"{path}: missing required keys {missing}")
    for key in ("fps", "total_episodes", "total_frames"):
        if not isinstance(info[key], int) or isinstance(info[key], bool) or info[key] < 0:
            raise DatasetError(f"{path}: {key} must be a non-negative int, got {info[key]!r}")
    if info["fps"] < 1:
        raise DatasetError(f"{path}: fps must be >= 1, got {info['fps']}")
    features = info["features"]
    if not isinstance(features, dict):
        raise DatasetError(f"{path}: features must be an object, got {type(features).__name__}")
    for name, dtype in DEFAULT_FEATURE_DTYPES.items():
        spec = features.get(name)
        if not isinstance(spec, dict) or spec.get("dtype") != dtype:
            raise DatasetError(f"{path}: features must include the default {name!r} ({dtype}), got {spec!r}")
    for name, spec in features.items():
        if not isinstance(spec, dict) or "dtype" not in spec or "shape" not in spec:
            raise DatasetError(f"{path}: feature {name!r} needs dtype and shape, got {spec!r}")
    return info


def _load_info(root: Path) -> dict:
    path = root / INFO_PATH
    return _check_info(_read_json(path), path)


def _episode_meta_paths(root: Path) -> list[Path]:
    """Every episodes-meta parquet file, in LeRobot's (lexicographic) order."""
    return sorted((root / "meta" / "episodes").glob("*/*.parquet"))


@dataclass
class _EpisodeRow:
    """One committed episode's meta row, split into standard columns, extras and per-episode stats."""

    meta: dict[str, Any]
    stats: dict[str, dict[str, np.ndarray]]
    extra_fields: list[pa.Field]
    meta_path: Path


def _split_row(row: dict[str, Any], schema: pa.Schema, path: Path) -> _EpisodeRow:
    meta: dict[str, Any] = {}
    stats: dict[str, dict[str, np.ndarray]] = {}
    extra_fields: list[pa.Field] = []
    for field in schema:
        name, value = field.name, row[field.name]
        if name.startswith("stats/"):
            feature, _, stat = name[len("stats/") :].rpartition("/")
            stats.setdefault(feature, {})[stat] = np.asarray(value)
            continue
        if name not in STANDARD_EPISODE_COLUMNS and not name.startswith(RESERVED_PREFIXES):
            extra_fields.append(field)
            if _is_json_field(field) and value is not None:
                value = json.loads(value)
        meta[name] = value
    return _EpisodeRow(meta=meta, stats=stats, extra_fields=extra_fields, meta_path=path)


def _load_committed_episodes(root: Path, total_episodes: int, *, with_stats: bool) -> list[_EpisodeRow]:
    """Rows 0..total_episodes-1 of the episodes meta, checked to be complete, ordered and contiguous
    (``with_stats=False`` leaves each row's ``stats`` empty and reads about half as much)."""
    rows: dict[int, _EpisodeRow] = {}
    for path in _episode_meta_paths(root):
        table = _read_parquet(path, skip_stats=not with_stats)
        if "episode_index" not in table.column_names:
            raise DatasetError(f"{path}: missing column 'episode_index'")
        indices = table.column("episode_index").to_pylist()
        if all(i is None or i >= total_episodes for i in indices):
            continue  # an uncommitted leftover of a crash
        for required in ("dataset_from_index", "dataset_to_index"):
            if required not in table.column_names:
                raise DatasetError(f"{path}: missing column {required!r}")
        for row in table.to_pylist():
            index = row["episode_index"]
            if index is None or index >= total_episodes:
                continue
            if index in rows:
                raise DatasetError(f"{path}: episode {index} is listed twice in meta/episodes")
            rows[index] = _split_row(row, table.schema, path)
    missing = [i for i in range(total_episodes) if i not in rows]
    if missing:
        raise DatasetError(
            f"{root / 'meta' / 'episodes'}: committed episodes {missing[:5]} (of {total_episodes}) have no meta row"
        )
    ordered = [rows[i] for i in range(total_episodes)]
    expected_from = 0
    for i, ep in enumerate(ordered):
        start, stop = ep.meta["dataset_from_index"], ep.meta["dataset_to_index"]
        length = ep.meta.get("length", stop - start)
        if start != expected_from or stop - start != length or length < 1:
            raise DatasetError(
                f"{ep.meta_path}: episode {i} covers frames [{start}, {stop}) with length {length}; "
                f"expected to start at {expected_from} with a positive length"
            )
        expected_from = stop
    return ordered


def _data_file(root: Path, info: Mapping, meta: Mapping) -> Path:
    chunk, file = meta.get("data/chunk_index"), meta.get("data/file_index")
    if chunk is None or file is None:
        chunk, file = _chunk_file(int(meta["episode_index"]))
    return root / info["data_path"].format(chunk_index=int(chunk), file_index=int(file))


def _load_tasks(root: Path, needed: int | None) -> list[str]:
    """The first ``needed`` task strings (all when None) by task_index, from the pandas-layout tasks.parquet
    (read without pandas). Tasks beyond ``needed`` belong to an uncommitted episode."""
    path = root / TASKS_PATH
    if needed == 0:
        return []
    table = _read_parquet(path)
    pandas_meta = (table.schema.metadata or {}).get(b"pandas")
    index_column = None
    if pandas_meta is not None:
        index_columns = json.loads(pandas_meta).get("index_columns", [])
        if len(index_columns) == 1 and isinstance(index_columns[0], str):
            index_column = index_columns[0]
    if index_column is None or index_column not in table.column_names or "task_index" not in table.column_names:
        raise DatasetError(
            f"{path}: expected a pandas frame indexed by the task string with an int64 column task_index"
        )
    tasks = table.column(index_column).to_pylist()
    order = table.column("task_index").to_pylist()
    by_index = dict(zip(order, tasks, strict=True))
    if sorted(by_index) != list(range(len(by_index))):
        raise DatasetError(f"{path}: task_index values must be 0..{len(by_index) - 1}, got {sorted(by_index)}")
    if needed is None:
        needed = len(by_index)
    if len(by_index) < needed:
        raise DatasetError(f"{path}: holds {len(by_index)} tasks; info.json says total_tasks={needed}")
    return [by_index[i] for i in range(needed)]


def _tasks_table(tasks: list[str]) -> pa.Table:
    """LeRobot's layout: pandas DataFrame indexed by task with an int64 task_index column, via from_pandas."""
    import pandas as pd  # lazy: only needed when a new task appears

    frame = pd.DataFrame({"task_index": np.arange(len(tasks), dtype=np.int64)}, index=pd.Index(tasks, dtype=object))
    return pa.Table.from_pandas(frame)


def _aggregates_from_rows(rows: list[_EpisodeRow], feature_names: Iterable[str], where: Path) -> dict[str, _Aggregate]:
    aggregates: dict[str, _Aggregate] = {}
    for i, row in enumerate(rows):
        for name in feature_names:
            stats = row.stats.get(name)
            if stats is None or any(k not in stats for k in STAT_KEYS):
                raise DatasetError(f"{where}: episode {i} lacks the stats/{name}/* columns needed to aggregate stats")
        aggregates = _merge_aggregates(aggregates, {name: row.stats[name] for name in feature_names})
    return aggregates


# ---------------------------------------------------------------------------------------------------------- writer


class LeRobotWriter:
    """Records a LeRobot v3.0 dataset episode by episode; crash-safe (see the module docstring).

    Recording contract: ``create``/``open`` -> ``add_frame`` per step -> ``save_episode`` -> ... -> ``finalize``
    (like LeRobot's). The dataset is valid after every ``save_episode``. One writer per dataset at a time (an
    advisory lock file ``meta/.dpr-writer.lock`` enforces it). As a context manager, an exception discards the
    unsaved episode and keeps every saved one.
    """

    def __init__(
        self,
        root: Path,
        *,
        fps: int,
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
        self._shapes = {k: _spec_shape(v) for k, v in self._user_features.items()}
        self._dtypes = {k: np.dtype(v["dtype"]) for k, v in self._user_features.items() if v["dtype"] != "image"}
        self._tasks: list[str] = []
        self._task_index: dict[str, int] = {}
        self._aggregates: dict[str, _Aggregate] = {}
        self._extra_fields: list[pa.Field] | None = None  # fixed by the first saved episode
        self._num_episodes = 0
        self._num_frames = 0
        self._lock_fd: int | None = None
        self._closed = False
        self._reset_buffer()

    # ----------------------------------------------------------------------------------------- construction

    @staticmethod
    def _check_args(root: Any, fps: Any, robot_type: Any, info_extra: Any) -> tuple[Path, dict[str, Any]]:
        root = Path(root)
        if not isinstance(fps, int) or isinstance(fps, bool) or fps < 1:
            raise DatasetError(f"{root}: fps must be a positive int, got {fps!r}")
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
        fps: int,
        features: dict[str, dict],
        robot_type: str,
        info_extra: dict | None = None,
    ) -> LeRobotWriter:
        """Start a new dataset at ``root``, which must not exist or be an empty folder."""
        root, extra = cls._check_args(root, fps, robot_type, info_extra)
        normalized = _normalize_features(features, str(root))
        if root.exists():
            if not root.is_dir():
                raise DatasetError(f"{root}: exists and is not a folder")
            if any(root.iterdir()):
                raise DatasetError(f"{root}: folder is not empty; create() needs a new or empty folder (use open())")
        (root / "meta").mkdir(parents=True, exist_ok=True)
        writer = cls(root, fps=fps, features=normalized, robot_type=robot_type, info_extra=extra)
        writer._acquire_lock()
        _atomic_write_json(root / INFO_PATH, writer._info(0, 0, 0))
        return writer

    @classmethod
    def open(
        cls,
        root: str | os.PathLike,
        *,
        fps: int,
        features: dict[str, dict],
        robot_type: str,
        info_extra: dict | None = None,
    ) -> LeRobotWriter:
        """Create the dataset if ``root`` is absent or empty, else check it matches and resume appending.

        Every argument must equal what ``meta/info.json`` holds (else DatasetError naming the first difference,
        and nothing on disk is touched); then crash leftovers (data/meta files of uncommitted episodes, temp files)
        are deleted, the aggregates are rebuilt from the committed episodes, and recording resumes after them."""
        root_path = Path(root)
        if not root_path.exists() or (root_path.is_dir() and not any(root_path.iterdir())):
            return cls.create(root_path, fps=fps, features=features, robot_type=robot_type, info_extra=info_extra)
        root_path, extra = cls._check_args(root_path, fps, robot_type, info_extra)
        normalized = _normalize_features(features, str(root_path))
        info_path = root_path / INFO_PATH
        if not info_path.is_file():
            raise DatasetError(f"{info_path}: not found; {root_path} is not empty and holds no dataset")
        info = _check_info(_read_json(info_path), info_path)
        difference = _first_difference(info, fps=fps, features=normalized, robot_type=robot_type, info_extra=extra)
        if difference:
            raise DatasetError(f"{info_path}: does not match the requested dataset: {difference}")
        writer = cls(root_path, fps=fps, features=normalized, robot_type=robot_type, info_extra=extra)
        writer._acquire_lock()
        try:
            writer._resume(info)
        except BaseException:
            writer._release_lock()
            raise
        return writer

    def _acquire_lock(self) -> None:
        path = self.root / LOCK_PATH
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise DatasetError(f"{path}: another writer holds this dataset open") from None
        self._lock_fd = fd

    def _release_lock(self) -> None:
        if self._lock_fd is not None:
            os.close(self._lock_fd)  # closing drops the flock
            self._lock_fd = None

    def _resume(self, info: dict) -> None:
        """Delete uncommitted leftovers, then rebuild tasks, aggregates and extras from the committed episodes."""
        total = info["total_episodes"]
        rows = _load_committed_episodes(self.root, total, with_stats=True)
        referenced = {_data_file(self.root, info, r.meta).resolve() for r in rows}
        referenced |= {r.meta_path.resolve() for r in rows}
        self._delete_leftovers(total, referenced)

        frames = sum(int(r.meta["length"]) for r in rows)
        if frames != info["total_frames"]:
            raise DatasetError(
                f"{self.root / INFO_PATH}: total_frames is {info['total_frames']} but the committed episodes hold "
                f"{frames} frames"
            )
        self._tasks = _load_tasks(self.root, info.get("total_tasks"))
        self._task_index = {t: i for i, t in enumerate(self._tasks)}
        self._aggregates = _aggregates_from_rows(rows, self.features, self.root / "meta" / "episodes")
        self._extra_fields = rows[0].extra_fields if rows else None
        self._num_episodes, self._num_frames = total, frames

        # The aggregate files may hold an uncommitted episode's contribution (crash between them and info.json).
        tasks_path = self.root / TASKS_PATH
        if not self._tasks:
            tasks_path.unlink(missing_ok=True)  # only an uncommitted episode's task can be in it
        elif _parquet_num_rows(tasks_path) != len(self._tasks):
            _atomic_write_parquet(tasks_path, _tasks_table(self._tasks))
        stats = _stats_json(self._aggregates)
        stats_path = self.root / STATS_PATH
        try:
            current = _read_json(stats_path) if stats_path.exists() else None
        except DatasetError:
            current = None  # unreadable: it is derived data, so rewrite it
        if current != json.loads(json.dumps(stats)):
            _atomic_write_json(stats_path, stats)

    def _delete_leftovers(self, total_episodes: int, referenced: set[Path]) -> None:
        """Remove temp files and the data/meta files of episodes >= total_episodes (never a referenced file)."""
        for folder in (self.root / "data", self.root / "meta"):
            if not folder.is_dir():
                continue
            for path in folder.rglob(f"*{TMP_SUFFIX}"):
                path.unlink(missing_ok=True)
        for base in (self.root / "data", self.root / "meta" / "episodes"):
            if not base.is_dir():
                continue
            for path in base.glob("*/*.parquet"):
                match = CHUNK_FILE_RE.match(f"{path.parent.name}/{path.name}")
                if match is None or path.resolve() in referenced:
                    continue
                if int(match.group(1)) * CHUNKS_SIZE + int(match.group(2)) >= total_episodes:
                    path.unlink()

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
            return [_encode_png(image) for image in arr] if leading else _encode_png(arr)
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
        chunk, file = _chunk_file(episode)
        data_path = self.root / DATA_PATH.format(chunk_index=chunk, file_index=file)
        meta_path = self.root / EPISODES_PATH.format(chunk_index=chunk, file_index=file)

        tasks = list(self._tasks)
        task_index = dict(self._task_index)
        episode_tasks: list[str] = []
        for task in dict.fromkeys(self._frame_tasks):  # unique, in order of first appearance
            if task not in task_index:
                task_index[task] = len(tasks)
                tasks.append(task)
            episode_tasks.append(task)
        new_tasks = len(tasks) > len(self._tasks)

        columns = self._episode_columns(episode, n, task_index)
        episode_stats = self._episode_stats(columns)
        extra_fields, extra_arrays = self._extra_columns(episode_meta, meta_path)

        data_table = self._data_table(columns, n)
        meta_table = self._meta_table(
            episode, n, episode_tasks, (chunk, file), episode_stats, extra_fields, extra_arrays
        )
        aggregates = _merge_aggregates(self._aggregates, episode_stats)

        # Commit order: data, episode meta, tasks, stats, and info.json last (the commit point). tasks/stats live
        # in meta/ beside info.json, whose folder fsync makes their renames durable too.
        _atomic_write_parquet(data_path, data_table)
        _atomic_write_parquet(meta_path, meta_table, write_statistics=False)  # 1-row file: stats are noise
        if new_tasks:
            _atomic_write_parquet(self.root / TASKS_PATH, _tasks_table(tasks), sync_folder=False)
        # compact: indenting sends json through its pure-Python encoder, several ms per episode for ~600 numbers
        _atomic_write_json(self.root / STATS_PATH, _stats_json(aggregates), sync_folder=False, indent=None)
        _atomic_write_json(self.root / INFO_PATH, self._info(episode + 1, self._num_frames + n, len(tasks)))

        self._tasks, self._task_index, self._aggregates = tasks, task_index, aggregates
        self._extra_fields = extra_fields
        self._num_episodes += 1
        self._num_frames += n
        self._reset_buffer()
        return episode

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

    def _episode_stats(self, columns: Mapping[str, Any]) -> dict[str, dict[str, np.ndarray]]:
        stats: dict[str, dict[str, np.ndarray]] = {}
        for name, spec in self.features.items():
            values = columns[name]
            if spec["dtype"] == "image":
                sample = [_decode_png(values[i]) for i in _image_sample_indices(len(values))]
                stats[name] = _image_stats(sample)
            else:
                stats[name] = _vector_stats(np.asarray(values).reshape(len(values), -1))
        return stats

    def _data_table(self, columns: Mapping[str, Any], n: int) -> pa.Table:
        arrays, names = [], []
        for name, spec in self.features.items():
            values = columns[name]
            if spec["dtype"] == "image":
                paths = [f"frame-{i:06d}.png" for i in range(n)]
                array: pa.Array = pa.StructArray.from_arrays(
                    [pa.array(values, type=pa.binary()), pa.array(paths, type=pa.string())], names=["bytes", "path"]
                )
            elif _spec_shape(spec) == (1,):
                array = pa.array(values.reshape(n))
            else:
                width = _spec_shape(spec)[0]
                array = pa.FixedSizeListArray.from_arrays(pa.array(values.reshape(-1)), width)
            arrays.append(array)
            names.append(name)
        return pa.Table.from_arrays(arrays, names=names)

    def _extra_columns(self, episode_meta: dict | None, meta_path: Path) -> tuple[list[pa.Field], list[pa.Array]]:
        where = str(meta_path)
        given = dict(episode_meta or {})
        for key in given:
            _check_extra_key(key, where)
        if self._extra_fields is None:  # the first episode fixes keys and types
            fields, arrays = [], []
            for key, value in given.items():
                field, stored = _new_extra_field(key, value, where)
                fields.append(field)
                arrays.append(pa.array([stored], type=field.type))
            return fields, arrays
        expected = [f.name for f in self._extra_fields]
        if set(given) != set(expected):
            raise DatasetError(
                f"{where}: episode_meta keys must be the same every episode: expected {sorted(expected)}, "
                f"got {sorted(given)}"
            )
        return self._extra_fields, [_extra_array(f, given[f.name], where) for f in self._extra_fields]

    def _meta_table(
        self,
        episode: int,
        n: int,
        episode_tasks: list[str],
        chunk_file: tuple[int, int],
        episode_stats: Mapping[str, Mapping[str, np.ndarray]],
        extra_fields: list[pa.Field],
        extra_arrays: list[pa.Array],
    ) -> pa.Table:
        chunk, file = chunk_file
        fields: list[pa.Field] = []
        arrays: list[pa.Array] = []

        def add(name: str, value: Any, type_: pa.DataType | None = None) -> None:
            array = pa.array([value], type=type_)
            fields.append(pa.field(name, array.type))
            arrays.append(array)

        add("episode_index", episode, pa.int64())
        add("tasks", episode_tasks, pa.list_(pa.string()))
        add("length", n, pa.int64())
        add("data/chunk_index", chunk, pa.int64())
        add("data/file_index", file, pa.int64())
        add("dataset_from_index", self._num_frames, pa.int64())
        add("dataset_to_index", self._num_frames + n, pa.int64())
        for name, stats in episode_stats.items():
            for key in STAT_KEYS:
                add(f"stats/{name}/{key}", stats[key].tolist())
        add("meta/episodes/chunk_index", chunk, pa.int64())
        add("meta/episodes/file_index", file, pa.int64())
        fields.extend(extra_fields)
        arrays.extend(extra_arrays)
        return pa.Table.from_arrays(arrays, schema=pa.schema(fields))

    def _info(self, total_episodes: int, total_frames: int, total_tasks: int) -> dict[str, Any]:
        """info.json as LeRobot writes it, plus the caller's info_extra keys."""
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
        }
        info.update(self.info_extra)
        return info

    # ------------------------------------------------------------------------------------------------ closing

    def finalize(self) -> None:
        """Stop recording (idempotent). Saved episodes are already durable; unsaved frames are discarded with a
        RuntimeWarning."""
        if self._closed:
            return
        if self._frame_tasks:
            warnings.warn(
                f"{self.root}: finalize() discards {len(self._frame_tasks)} frames never passed to save_episode()",
                RuntimeWarning,
                stacklevel=2,
            )
        self._reset_buffer()
        self._closed = True
        self._release_lock()

    def __enter__(self) -> LeRobotWriter:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if exc_type is not None:
            self.clear_episode()  # an interrupted episode is never half-saved
        self.finalize()

    def __del__(self) -> None:
        if getattr(self, "_lock_fd", None) is not None:
            self._release_lock()


def repair(root: str | os.PathLike) -> None:
    """Bring a dataset left by a crash back to its committed state without appending: delete the files of
    uncommitted episodes and temp files, and rewrite tasks.parquet/stats.json from the committed episodes.

    LeRobot loads every ``data/*/*.parquet``, so run this (or :meth:`LeRobotWriter.open`) before handing a crashed
    dataset to it; :class:`LeRobotReader` already ignores uncommitted episodes."""
    root = Path(root)
    info = _load_info(root)
    features = {k: v for k, v in info["features"].items() if k not in DEFAULT_FEATURE_DTYPES}
    extra = {k: v for k, v in info.items() if k not in STANDARD_INFO_KEYS}
    LeRobotWriter.open(
        root, fps=info["fps"], features=features, robot_type=info.get("robot_type"), info_extra=extra
    ).finalize()


def _first_difference(
    info: Mapping[str, Any], *, fps: int, features: dict[str, dict], robot_type: str, info_extra: dict[str, Any]
) -> str | None:
    """The first way an existing info.json differs from what a writer was asked for, or None."""
    if info["fps"] != fps:
        return f"fps is {info['fps']} in the dataset, {fps} requested"
    if info.get("robot_type") != robot_type:
        return f"robot_type is {info.get('robot_type')!r} in the dataset, {robot_type!r} requested"
    stored = info["features"]
    if list(stored) != list(features):
        return f"features are {list(stored)} in the dataset, {list(features)} requested"
    for name, spec in features.items():
        have = stored[name]
        for key in ("dtype", "shape", "names"):
            if _json_equal(have.get(key), spec.get(key)) is False:
                return f"feature {name!r} has {key} {have.get(key)!r} in the dataset, {spec.get(key)!r} requested"
    stored_extra = {k: v for k, v in info.items() if k not in STANDARD_INFO_KEYS}
    for key in sorted(set(stored_extra) | set(info_extra)):
        if key not in info_extra:
            return f"info key {key!r} is {stored_extra[key]!r} in the dataset but not in the requested info_extra"
        if key not in stored_extra:
            return f"info_extra key {key!r} is requested but absent from the dataset"
        if not _json_equal(stored_extra[key], info_extra[key]):
            return f"info key {key!r} is {stored_extra[key]!r} in the dataset, {info_extra[key]!r} requested"
    if info.get("video_path") is not None:
        return "the dataset has videos; this writer appends parquet-only episodes"
    return None


def _json_equal(a: Any, b: Any) -> bool:
    """Equality as JSON sees it (tuples equal lists)."""
    return json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


# ------------------------------------------------------------------------------------------------------ images


def _encode_png(image: np.ndarray) -> bytes:
    """Lossless PNG of a uint8 [H, W, 3] array (compress_level 1: recording speed over file size)."""
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image)).save(buf, format="PNG", compress_level=1)
    return buf.getvalue()


def _decode_png(data: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(data)) as img:
        return np.asarray(img.convert("RGB"))


# ------------------------------------------------------------------------------------------------------ reader


class LeRobotReader:
    """Reads a LeRobot v3.0 dataset (ours or LeRobot's own layout) lazily: frame data only on request.

    The constructor validates ``meta/info.json`` (codebase_version, required keys), the committed episodes' meta
    rows, ``meta/tasks.parquet``, ``meta/stats.json`` and every committed data file's parquet footer. Episodes at or
    above ``info.total_episodes`` (crash leftovers) are ignored. Arrays come back as ``[T, *shape]`` in the
    feature's dtype (shape-[1] features as ``[T, 1]``); images as uint8 ``[T, H, W, 3]``.
    """

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        if not self.root.is_dir():
            raise DatasetError(f"{self.root}: dataset folder not found")
        self.info: dict[str, Any] = _load_info(self.root)
        self.fps: int = self.info["fps"]
        self.features: dict[str, dict] = self.info["features"]
        self.num_episodes: int = self.info["total_episodes"]
        self.num_frames: int = self.info["total_frames"]
        rows = _load_committed_episodes(self.root, self.num_episodes, with_stats=False)
        self._meta_paths = [r.meta_path for r in rows]
        self._episode_stats: dict[int, dict[str, dict[str, np.ndarray]]] = {}  # read on demand
        self.episodes: list[dict[str, Any]] = [r.meta for r in rows]
        frames = rows[-1].meta["dataset_to_index"] if rows else 0
        if frames != self.num_frames:
            raise DatasetError(
                f"{self.root / INFO_PATH}: total_frames is {self.num_frames}, the episodes cover {frames} frames"
            )
        self._starts = [int(e["dataset_from_index"]) for e in self.episodes]
        self.tasks: list[str] = _load_tasks(self.root, self.info.get("total_tasks"))
        self._check_data_files()
        self.stats: dict[str, dict[str, np.ndarray]] = self._load_stats()

    def _check_data_files(self) -> None:
        """Each data file's footer parses and holds at least the rows of the committed episodes it stores."""
        needed: dict[Path, int] = {}
        self._episodes_per_file: dict[Path, int] = {}
        for ep in self.episodes:
            path = _data_file(self.root, self.info, ep)
            needed[path] = needed.get(path, 0) + int(ep["length"])
            self._episodes_per_file[path] = self._episodes_per_file.get(path, 0) + 1
        for path, rows in needed.items():
            have = _parquet_num_rows(path)
            if have < rows:
                raise DatasetError(f"{path}: holds {have} rows; the committed episodes stored there need {rows}")

    def _load_stats(self) -> dict[str, dict[str, np.ndarray]]:
        """stats.json, or the aggregate of the per-episode stats when stats.json is absent or stale (a crash
        between writing it and info.json leaves it counting an uncommitted episode)."""
        path = self.root / STATS_PATH
        stats = _read_json(path) if path.exists() else None
        if stats is not None and not isinstance(stats, dict):
            raise DatasetError(f"{path}: expected a JSON object of feature -> stats")
        index_count = None
        if stats is not None:
            try:
                index_count = int(np.asarray(stats["index"]["count"]).reshape(-1)[0])
            except (KeyError, TypeError, ValueError, IndexError):
                index_count = None
        if stats is None or (self.num_frames and index_count is not None and index_count != self.num_frames):
            if not self.episodes:
                return {}
            all_stats = [self.episode_stats(i) for i in range(self.num_episodes)]
            names = [n for n in self.features if all(n in s for s in all_stats)]
            aggregates: dict[str, _Aggregate] = {}
            for ep_stats in all_stats:
                aggregates = _merge_aggregates(aggregates, {n: ep_stats[n] for n in names})
            stats = _stats_json(aggregates)
        return {
            feature: {key: np.asarray(value) for key, value in feature_stats.items()}
            for feature, feature_stats in stats.items()
        }

    # ------------------------------------------------------------------------------------------------ access

    def episode_stats(self, index: int) -> dict[str, dict[str, np.ndarray]]:
        """The per-episode stats stored in episode ``index``'s meta row."""
        self._check_episode(index)
        if index not in self._episode_stats:
            path = self._meta_paths[index]
            table = _read_parquet(path)
            for row in table.to_pylist():  # keep every row's stats: LeRobot's files hold many episodes
                other = row.get("episode_index")
                if other is not None and other < self.num_episodes:
                    self._episode_stats[other] = _split_row(row, table.schema, path).stats
            if index not in self._episode_stats:
                raise DatasetError(f"{path}: no meta row for episode {index}")
        return self._episode_stats[index]

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

    def episode(self, index: int, columns: list[str] | None = None) -> dict[str, np.ndarray]:
        """Episode ``index``'s frames as ``{column: [T, *shape] array}``; reads only its data file's rows."""
        self._check_episode(index)
        ep = self.episodes[index]
        names = self._columns(columns)
        path = _data_file(self.root, self.info, ep)
        shared = self._episodes_per_file.get(path, 1) > 1
        if shared:  # LeRobot's own layout: many episodes per file, pick this one's rows
            table = _read_parquet(path, columns=names, filters=[("episode_index", "=", int(index))])
        else:
            table = _read_parquet(path, columns=names)
        length = int(ep["length"])
        if table.num_rows != length:
            raise DatasetError(f"{path}: episode {index} has {table.num_rows} rows, its meta row says {length}")
        try:
            return {name: self._to_numpy(table.column(name), self.features[name], length) for name in names}
        except (pa.ArrowException, OSError, ValueError) as exc:
            raise DatasetError(f"{path}: cannot decode episode {index}: {exc}") from exc

    @staticmethod
    def _to_numpy(column: pa.ChunkedArray, spec: Mapping, length: int) -> np.ndarray:
        shape = _spec_shape(spec)
        array = column.combine_chunks()
        if spec["dtype"] == "image":
            # flatten() applies the array's slice offset, which field() would not
            data = array.flatten()[array.type.get_field_index("bytes")] if pa.types.is_struct(array.type) else array
            frames = [_decode_png(b) for b in data.to_pylist()]
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
        return np.zeros((0, *_spec_shape(spec)), dtype=dtype)

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
