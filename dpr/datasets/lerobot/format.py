"""LeRobot v3.0 format basics: paths, info.json checks, feature specs, file reading, PNG frames, DatasetError.

The layout is described in the repository's ``docs/lerobot_v3_format.md``; this module holds the constants and
checks that the writer, the reader and compaction share.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import re
from collections.abc import Callable, Iterable, Mapping
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from PIL import Image

from dpr.atomic import atomic_write_parquet
from dpr.bounded_io import read_bounded
from dpr.checks import ParameterError
from dpr.limits import MAX_METADATA_BYTES

CODEBASE_VERSION = "v3.0"
CHUNKS_SIZE = 1000  # files per chunk folder, LeRobot's default
DATA_FILES_SIZE_IN_MB = 100  # LeRobot's file size limit; compaction packs to it, recording writes a file per episode
VIDEO_FILES_SIZE_IN_MB = 200
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
INFO_PATH = "meta/info.json"
STATS_PATH = "meta/stats.json"
TASKS_PATH = "meta/tasks.parquet"
LOCK_PATH = "meta/.dpr-writer.lock"
CHUNK_FILE_RE = re.compile(r"^chunk-(\d{3,})/file-(\d{3,})\.parquet$")
# info.json key of this writer: files numbered n = chunk_index * CHUNKS_SIZE + file_index in [first, end) hold the
# dataset (data and meta/episodes alike); any other numbered file is a leftover of a crash or of a compaction.
LIVE_FILES_KEY = "dpr_live_files"
# info.json key of this writer: checksums of the meta tables (dpr.datasets.lerobot.checksums), checked on every read:
# {"info": info.json's own (of its content without this entry), "tasks": the committed task strings',
#  "stats": stats.json's content's, "rows_from": the first episode whose meta row carries its own checksums}.
META_CHECKSUMS_KEY = "dpr_meta_checksums"
DIGEST_BYTES = 8  # blake2b-64 content digests

FILE_THREADS = 8  # threads for bulk file operations (see in_threads)
T = TypeVar("T")
R = TypeVar("R")

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
    "dpr_checksums",  # dpr.datasets.lerobot.checksums: content checksums of the episode's columns
    "dpr_row_checksums",  # ... and of the meta row's own
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
        LIVE_FILES_KEY,
        META_CHECKSUMS_KEY,
    }
)
# Sane bounds of info.json's counts: far beyond a real dataset (a million 2500-frame episodes; the fps of a 0.1 ms
# physics step), small enough that nothing sized by them exhausts memory.
MAX_COUNTS = {"fps": 10_000, "total_episodes": 1_000_000, "total_frames": 2_500_000_000}
REQUIRED_INFO_KEYS = ("codebase_version", "fps", "features", "total_episodes", "total_frames", "data_path")
JSON_FIELD_METADATA = {b"dpr.encoding": b"json"}  # marks an episodes column holding JSON text


class DatasetError(ValueError):
    """A dataset file or a writer argument is not what the format needs; the message names the path."""


def default_features() -> dict[str, dict]:
    """The feature specs of LeRobot's five default columns, in LeRobot's order."""
    return {name: {"dtype": dtype, "shape": [1], "names": None} for name, dtype in DEFAULT_FEATURE_DTYPES.items()}


def write_parquet(path: Path, table: pa.Table, *, sync_folder: bool = True, **options: Any) -> None:
    """Crash-safe parquet write (:mod:`dpr.atomic`) with this format's options."""
    # No dictionary encoding: float columns rarely repeat, and it cost ~8x the write time of a 2500-frame episode.
    atomic_write_parquet(
        path,
        table,
        write_options={"compression": "snappy", "use_dictionary": False, **options},
        sync_folder=sync_folder,
    )


def chunk_file(number: int) -> tuple[int, int]:
    """(chunk_index, file_index) of file number ``number`` (files are numbered chunk by chunk)."""
    return divmod(number, CHUNKS_SIZE)


def file_number(path: Path) -> int | None:
    """The number of a ``chunk-XXX/file-YYY.parquet`` file (None for any other name)."""
    match = CHUNK_FILE_RE.match(f"{path.parent.name}/{path.name}")
    return None if match is None else int(match.group(1)) * CHUNKS_SIZE + int(match.group(2))


def numbered_path(root: Path, template: str, number: int) -> Path:
    """The path of file number ``number`` under ``template`` (DATA_PATH or EPISODES_PATH)."""
    chunk, file = chunk_file(number)
    return inside(root, template.format(chunk_index=chunk, file_index=file))


def inside(root: Path, relative: str) -> Path:
    """``root / relative``, which must stay inside the dataset: a relative path without ``..``, and no symlink on
    the way leading out of ``root`` (a DatasetError naming the path otherwise)."""
    parts = Path(relative).parts
    if Path(relative).is_absolute() or ".." in parts:
        raise DatasetError(f"{root}: the path {relative!r} leads out of the dataset; paths are relative, without '..'")
    path = root / relative
    if not path.resolve().is_relative_to(root.resolve()):
        raise DatasetError(f"{path}: a symlink leads out of the dataset, to {path.resolve()}")
    return path


def live_files(info: Mapping[str, Any]) -> tuple[int, int]:
    """The numbers [first, end) of the files that hold the dataset; a dataset without the key (LeRobot's own,
    or one written before compaction existed) stores episode i in file i or in files before it."""
    first, end = info.get(LIVE_FILES_KEY, (0, info["total_episodes"]))
    return first, end


def read_json(path: Path) -> Any:
    """The JSON file ``path`` of a dataset's metadata, at most :data:`dpr.limits.MAX_METADATA_BYTES`: a DatasetError
    naming it when it is missing, larger, not a regular file, or not JSON."""
    try:
        text = read_bounded(path, MAX_METADATA_BYTES).decode("utf-8")
    except ParameterError as exc:
        raise DatasetError(exc.problem) from None
    except FileNotFoundError:
        raise DatasetError(f"{path}: file not found") from None
    except OSError as exc:
        raise DatasetError(f"{path}: cannot read: {exc}") from exc
    except UnicodeDecodeError as exc:
        raise DatasetError(f"{path}: not valid JSON (not UTF-8 text: {exc})") from exc
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise DatasetError(f"{path}: not valid JSON: {exc}") from exc


def in_threads(function: Callable[[T], R], items: Iterable[T]) -> list[R]:
    """``[function(item) for item in items]`` on a few threads: for many small file operations (reads, footers,
    unlinks), whose latency the threads overlap (deleting fsynced files one by one costs milliseconds each on
    some filesystems). The first exception is raised once the calls in flight are done."""
    items = list(items)
    if len(items) < 2:
        return [function(item) for item in items]
    with ThreadPoolExecutor(min(FILE_THREADS, len(items))) as pool:
        return list(pool.map(function, items))


def read_parquet(
    path: Path, columns: list[str] | None = None, filters: list[tuple] | None = None, *, skip_stats: bool = False
) -> pa.Table:
    """Read a parquet file (optionally some columns, some rows, or all but the ``stats/`` columns); every failure
    (missing, truncated, corrupt) becomes a DatasetError naming ``path``."""
    if not path.is_file():
        raise DatasetError(f"{path}: file not found")
    try:
        if filters is not None:
            table = pq.read_table(path, columns=columns, filters=filters)
        else:
            with pq.ParquetFile(path) as parquet:  # cheaper than read_table's dataset layer for small files
                if skip_stats:
                    columns = [n for n in parquet.schema_arrow.names if not n.startswith("stats/")]
                # arrow's own threads cost more than they save on a small file (an episode's), about 40% of its read
                table = parquet.read(columns=columns, use_threads=parquet.metadata.num_rows > 10_000)
        table.validate(full=True)  # what parquet decoded but arrow would not read back: strings not UTF-8, say
        return table if columns is None else table.select(list(dict.fromkeys(columns)))  # (a missing one: KeyError)
    except (pa.ArrowException, OSError, ValueError, KeyError) as exc:
        raise DatasetError(f"{path}: corrupt or truncated parquet file: {exc}") from exc


def parquet_num_rows(path: Path) -> int:
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


def normalize_features(features: Any, where: str) -> dict[str, dict]:
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


def spec_shape(spec: Mapping) -> tuple[int, ...]:
    return tuple(int(s) for s in spec["shape"])


# ------------------------------------------------------------------------------------------- shared meta loading


def check_info(info: Any, path: Path) -> dict:
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
    check_info_checksum(info, path)  # before the values: a damaged one is named as damage, not as a bad value
    missing = [k for k in REQUIRED_INFO_KEYS if k not in info]
    if missing:
        raise DatasetError(f"{path}: missing required keys {missing}")
    for key in ("total_episodes", "total_frames"):
        if not isinstance(info[key], int) or isinstance(info[key], bool) or info[key] < 0:
            raise DatasetError(f"{path}: {key} must be a non-negative int, got {info[key]!r}")
        if info[key] > MAX_COUNTS[key]:  # checked before anything is allocated for them
            raise DatasetError(
                f"{path}: {key} is {info[key]}, beyond any dataset this reader takes ({MAX_COUNTS[key]})"
            )
    check_fps(info["fps"], str(path))
    check_splits(info.get("splits", {}), info["total_episodes"], path)
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
    live = info.get(LIVE_FILES_KEY, [0, 0])
    if (
        not isinstance(live, list)
        or len(live) != 2
        or not all(isinstance(n, int) and not isinstance(n, bool) for n in live)
        or not 0 <= live[0] <= live[1]
    ):
        raise DatasetError(f"{path}: {LIVE_FILES_KEY} must be [first, end] with 0 <= first <= end, got {live!r}")
    return info


def text_digest(text: str) -> str:
    """The blake2b-64 digest of ``text`` (hex), the checksum every meta table carries."""
    return hashlib.blake2b(text.encode(), digest_size=DIGEST_BYTES).hexdigest()


def content_digest(value: Any) -> str:
    """The checksum of a JSON value's content (its canonical text): the same whatever its file's layout."""
    return text_digest(json.dumps(value, sort_keys=True, separators=(",", ":")))


def sealed_info(info: Mapping[str, Any], *, tasks: str | None, stats: str | None, rows_from: int) -> dict[str, Any]:
    """``info`` with its :data:`META_CHECKSUMS_KEY`: the digests of the committed tasks and of stats.json
    (:func:`content_digest`), the first episode whose meta row carries checksums, and info.json's own."""
    entry = {"tasks": tasks, "stats": stats, "rows_from": rows_from}
    unsealed = {**info, META_CHECKSUMS_KEY: entry}
    return {**info, META_CHECKSUMS_KEY: {**entry, "info": content_digest(unsealed)}}


def check_info_checksum(info: dict, path: Path) -> None:
    """A DatasetError naming ``path`` when info.json's content is not the one its checksum was made of (nothing
    is checked in a dataset written without meta checksums)."""
    if META_CHECKSUMS_KEY not in info:
        return
    entry = info[META_CHECKSUMS_KEY]
    keys = {"info", "tasks", "stats", "rows_from"}
    if not isinstance(entry, dict) or set(entry) != keys:
        raise DatasetError(f"{path}: {META_CHECKSUMS_KEY} must be an object of {sorted(keys)}, got {entry!r}")
    unsealed = {**info, META_CHECKSUMS_KEY: {k: v for k, v in entry.items() if k != "info"}}
    if content_digest(unsealed) != entry["info"]:
        raise DatasetError(f"{path}: does not match its checksum (the file is corrupt)")
    rows_from = entry["rows_from"]
    if not isinstance(rows_from, int) or isinstance(rows_from, bool) or rows_from < 0:
        raise DatasetError(f"{path}: {META_CHECKSUMS_KEY}.rows_from must be a non-negative int, got {rows_from!r}")


def check_splits(splits: Any, total_episodes: int, path: Path) -> None:
    """A DatasetError naming ``path`` unless ``splits`` (info.json's) maps each split's name to LeRobot's
    ``"start:stop"`` range of episodes within the dataset's ``total_episodes``."""
    if not isinstance(splits, dict):
        raise DatasetError(f"{path}: splits must be an object of name -> 'start:stop', got {splits!r}")
    for name, span in splits.items():
        start, _, stop = span.partition(":") if isinstance(span, str) else ("", "", "")
        if not (start.isdigit() and stop.isdigit() and int(start) <= int(stop)):
            raise DatasetError(f"{path}: split {name!r} must be 'start:stop' episodes, got {span!r}")
        if int(stop) > total_episodes:
            raise DatasetError(
                f"{path}: split {name!r} is episodes {span}, but the dataset holds {total_episodes} "
                f"(total_episodes); the meta contradicts the data"
            )


def check_fps(fps: Any, where: str) -> int | float:
    """``fps`` if it is a frame rate this format takes: a positive int, or a positive finite float (a dataset of
    decisions every k physics steps records 10 / k frames per second, 10/6 for k = 6; LeRobot's loader computes
    frame offsets as ``round(seconds * fps)``, so it takes one: docs/datasets.md). A DatasetError naming ``where``
    otherwise."""
    if not isinstance(fps, (int, float)) or isinstance(fps, bool) or not math.isfinite(fps) or fps <= 0:
        raise DatasetError(f"{where}: fps must be a positive number of frames per second, got {fps!r}")
    if fps > MAX_COUNTS["fps"]:
        raise DatasetError(f"{where}: fps is {fps}, beyond any dataset this reader takes ({MAX_COUNTS['fps']})")
    return fps


def load_info(root: Path) -> dict:
    path = root / INFO_PATH
    return check_info(read_json(path), path)


def first_difference(
    info: Mapping[str, Any], *, fps: float, features: dict[str, dict], robot_type: str, info_extra: dict[str, Any]
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
            if json_equal(have.get(key), spec.get(key)) is False:
                return f"feature {name!r} has {key} {have.get(key)!r} in the dataset, {spec.get(key)!r} requested"
    stored_extra = {k: v for k, v in info.items() if k not in STANDARD_INFO_KEYS}
    for key in sorted(set(stored_extra) | set(info_extra)):
        if key not in info_extra:
            return f"info key {key!r} is {stored_extra[key]!r} in the dataset but not in the requested info_extra"
        if key not in stored_extra:
            return f"info_extra key {key!r} is requested but absent from the dataset"
        if not json_equal(stored_extra[key], info_extra[key]):
            return f"info key {key!r} is {stored_extra[key]!r} in the dataset, {info_extra[key]!r} requested"
    if info.get("video_path") is not None:
        return "the dataset has videos; this writer appends parquet-only episodes"
    return None


def json_equal(a: Any, b: Any) -> bool:
    """Equality as JSON sees it (tuples equal lists)."""
    return json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


# ------------------------------------------------------------------------------------------------------ images


def encode_png(image: np.ndarray) -> bytes:
    """Lossless PNG of a uint8 [H, W, 3] array (compress_level 1: recording speed over file size)."""
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image)).save(buf, format="PNG", compress_level=1)
    return buf.getvalue()


def decode_png(data: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(data)) as img:
        return np.asarray(img.convert("RGB"))
