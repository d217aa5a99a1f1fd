"""The dataset's meta files: episode rows (standard columns, per-episode stats, caller extras) and tasks."""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from dpr.datasets.lerobot.checksums import ROW_CHECKSUMS_COLUMN, check_row_checksums
from dpr.datasets.lerobot.format import (
    JSON_FIELD_METADATA,
    META_CHECKSUMS_KEY,
    RESERVED_PREFIXES,
    STANDARD_EPISODE_COLUMNS,
    STAT_KEYS,
    TASKS_PATH,
    DatasetError,
    chunk_file,
    content_digest,
    file_number,
    in_threads,
    inside,
    live_files,
    parquet_num_rows,
    read_parquet,
)
from dpr.datasets.lerobot.stats import Aggregate, merge_aggregates

# ------------------------------------------------------------------------------------------ episode meta extras


def is_json_field(field: pa.Field) -> bool:
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


def new_extra_field(key: str, value: Any, where: str) -> tuple[pa.Field, Any]:
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


def extra_array(field: pa.Field, value: Any, where: str) -> pa.Array:
    """One episode's extra as a 1-row array of the column's established type."""
    if is_json_field(field):
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


def check_extra_key(key: Any, where: str) -> None:
    if not isinstance(key, str) or not key:
        raise DatasetError(f"{where}: episode_meta keys must be non-empty strings, got {key!r}")
    if key in STANDARD_EPISODE_COLUMNS or "/" in key or key.startswith(RESERVED_PREFIXES):
        raise DatasetError(f"{where}: episode_meta key {key!r} clashes with LeRobot's episode columns (no '/' allowed)")


def episode_meta_paths(root: Path, info: Mapping) -> list[Path]:
    """The live episodes-meta parquet files (see ``live_files``), in LeRobot's (lexicographic) order."""
    first, end = live_files(info)
    paths = (root / "meta" / "episodes").glob("*/*.parquet")
    return sorted(p for p in paths if (n := file_number(p)) is None or first <= n < end)


@dataclass
class EpisodeRow:
    """One committed episode's meta row, split into standard columns, extras and per-episode stats."""

    meta: dict[str, Any]
    stats: dict[str, dict[str, np.ndarray]]
    extra_fields: list[pa.Field]
    meta_path: Path


def split_row(row: dict[str, Any], schema: pa.Schema, path: Path) -> EpisodeRow:
    meta: dict[str, Any] = {}
    stats: dict[str, dict[str, np.ndarray]] = {}
    extra_fields: list[pa.Field] = []
    for field in schema:
        name, value = field.name, row[field.name]
        if name == ROW_CHECKSUMS_COLUMN:
            continue  # checked where the row was read
        if name.startswith("stats/"):
            if value is not None:  # (None: a file without this column, merged with others)
                feature, _, stat = name[len("stats/") :].rpartition("/")
                stats.setdefault(feature, {})[stat] = np.asarray(value)
            continue
        if name not in STANDARD_EPISODE_COLUMNS and not name.startswith(RESERVED_PREFIXES):
            extra_fields.append(field)
            if is_json_field(field) and value is not None:
                value = json.loads(value)
        meta[name] = value
    return EpisodeRow(meta=meta, stats=stats, extra_fields=extra_fields, meta_path=path)


def read_live_meta(root: Path, info: Mapping, *, with_stats: bool) -> tuple[pa.Table | None, list[Path]]:
    """The committed rows (episode_index < total_episodes) of the live episodes-meta files, concatenated in file
    order with their columns as stored, and the file of each row (None and [] when there are none).
    ``with_stats=False`` leaves out the ``stats/`` columns and reads about half as much."""
    total = info["total_episodes"]
    paths = episode_meta_paths(root, info)
    tables = in_threads(lambda path: read_parquet(path, skip_stats=not with_stats), paths)
    kept: list[pa.Table] = []
    row_paths: list[Path] = []
    for path, table in zip(paths, tables, strict=True):
        check_rows(table, path, info, with_stats=with_stats)
        if "episode_index" not in table.column_names:
            raise DatasetError(f"{path}: missing column 'episode_index'")
        committed = [i is not None and i < total for i in table.column("episode_index").to_pylist()]
        if not any(committed):
            continue  # an uncommitted leftover of a crash
        for required in ("dataset_from_index", "dataset_to_index"):
            if required not in table.column_names:
                raise DatasetError(f"{path}: missing column {required!r}")
        kept.append(table if all(committed) else table.filter(pa.array(committed)))
        row_paths.extend([path] * sum(committed))
    if not kept:
        return None, []
    try:
        return pa.concat_tables(kept), row_paths
    except pa.ArrowInvalid:  # files written by different writers: columns merged, types promoted
        try:
            return pa.concat_tables(kept, promote_options="permissive"), row_paths
        except pa.ArrowInvalid as exc:
            raise DatasetError(f"{root / 'meta' / 'episodes'}: the meta files' columns do not match: {exc}") from exc


def check_rows(table: pa.Table, path: Path, info: Mapping, *, with_stats: bool) -> None:
    """The rows of the episodes-meta file ``path`` (``table``, with or without its stats columns) against their
    checksums, when ``info`` records meta checksums (:mod:`dpr.datasets.lerobot.checksums`)."""
    entry = info.get(META_CHECKSUMS_KEY)
    required_from = entry["rows_from"] if isinstance(entry, Mapping) else None
    check_row_checksums(table, path, with_stats=with_stats, required_from=required_from)


def load_committed_episodes(root: Path, info: Mapping, *, with_stats: bool) -> list[EpisodeRow]:
    """Rows 0..total_episodes-1 of the live episodes meta, checked to be complete, ordered and contiguous
    (``with_stats=False`` leaves each row's ``stats`` empty and reads about half as much)."""
    table, row_paths = read_live_meta(root, info, with_stats=with_stats)
    return episode_rows(root, info, table, row_paths)


def episode_rows(root: Path, info: Mapping, table: pa.Table | None, row_paths: list[Path]) -> list[EpisodeRow]:
    """The rows of :func:`read_live_meta` by episode index, checked to be complete, ordered and contiguous."""
    total_episodes = info["total_episodes"]
    rows: dict[int, EpisodeRow] = {}
    for row, path in zip([] if table is None else table.to_pylist(), row_paths, strict=True):
        index = row["episode_index"]
        if index in rows:
            raise DatasetError(f"{path}: episode {index} is listed twice in meta/episodes")
        rows[index] = split_row(row, table.schema, path)
    missing = [i for i in range(total_episodes) if i not in rows][:5] if len(rows) < total_episodes else []
    if missing:
        raise DatasetError(
            f"{root / 'meta' / 'episodes'}: committed episodes {missing} (of {total_episodes}) have no meta row"
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


def data_file_path(root: Path, info: Mapping, meta: Mapping) -> Path:
    chunk, file = meta.get("data/chunk_index"), meta.get("data/file_index")
    if chunk is None or file is None:
        chunk, file = chunk_file(int(meta["episode_index"]))
    return inside(root, info["data_path"].format(chunk_index=int(chunk), file_index=int(file)))


def check_data_files(root: Path, info: Mapping, episodes: list[Mapping]) -> dict[Path, int]:
    """Check that each committed episode's data file has a footer that parses and holds at least the rows of the
    committed episodes stored there; returns the number of committed episodes per data file."""
    needed: dict[Path, int] = {}
    per_file: dict[Path, int] = {}
    for ep in episodes:
        path = data_file_path(root, info, ep)
        needed[path] = needed.get(path, 0) + int(ep["length"])
        per_file[path] = per_file.get(path, 0) + 1
    for (path, rows), have in zip(needed.items(), in_threads(parquet_num_rows, needed), strict=True):
        if have < rows:
            raise DatasetError(f"{path}: holds {have} rows; the committed episodes stored there need {rows}")
    return per_file


def load_tasks(root: Path, info: Mapping) -> list[str]:
    """The committed task strings (``info``'s total_tasks; all when it has none) by task_index, from the
    pandas-layout tasks.parquet (read without pandas), checked against their checksum when ``info`` records one.
    Tasks beyond them belong to an uncommitted episode."""
    tasks = _read_tasks(root, info.get("total_tasks"))
    entry = info.get(META_CHECKSUMS_KEY)
    if isinstance(entry, Mapping) and content_digest(tasks) != entry["tasks"]:
        raise DatasetError(f"{root / TASKS_PATH}: its tasks do not match their checksum (the file is corrupt)")
    return tasks


def _read_tasks(root: Path, needed: int | None) -> list[str]:
    path = root / TASKS_PATH
    if needed == 0:
        return []
    table = read_parquet(path)
    pandas_meta = (table.schema.metadata or {}).get(b"pandas")
    index_column = None
    if pandas_meta is not None:
        try:
            index_columns = json.loads(pandas_meta).get("index_columns", [])
        except (ValueError, AttributeError) as exc:  # (UnicodeDecodeError is a ValueError)
            raise DatasetError(f"{path}: its pandas metadata is not a JSON object: {exc}") from None
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


def tasks_table(tasks: list[str]) -> pa.Table:
    """LeRobot's layout: pandas DataFrame indexed by task with an int64 task_index column, via from_pandas."""
    import pandas as pd  # lazy: only needed when a new task appears

    frame = pd.DataFrame({"task_index": np.arange(len(tasks), dtype=np.int64)}, index=pd.Index(tasks, dtype=object))
    return pa.Table.from_pandas(frame)


def aggregates_from_rows(rows: list[EpisodeRow], feature_names: Iterable[str], where: Path) -> dict[str, Aggregate]:
    aggregates: dict[str, Aggregate] = {}
    for i, row in enumerate(rows):
        for name in feature_names:
            stats = row.stats.get(name)
            if stats is None or any(k not in stats for k in STAT_KEYS):
                raise DatasetError(f"{where}: episode {i} lacks the stats/{name}/* columns needed to aggregate stats")
        aggregates = merge_aggregates(aggregates, {name: row.stats[name] for name in feature_names})
    return aggregates
