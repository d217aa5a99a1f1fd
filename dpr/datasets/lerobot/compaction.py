"""Compaction: a finished dataset's per-episode files packed into LeRobot's ~100 MB files, crash-safely.

Recording writes one data file and one episodes-meta file per episode, so that each episode commits on its own;
10,000 episodes make 20,000 small files. Compaction rewrites them in LeRobot's own layout: episodes back to back
in data files of at most ``target_bytes`` (an episode larger than that gets a file of its own), the meta rows in
as few files, and each row's ``data/chunk_index``, ``data/file_index``, ``meta/episodes/chunk_index`` and
``meta/episodes/file_index`` pointing at the new files, and its checksums (:mod:`.checksums`) made anew with them
(``info.json``'s too). Every column of every episode, the per-episode stats, ``stats.json`` and ``tasks.parquet``
stay as they were. A data file already at least half of ``target_bytes``
(from an earlier compaction) is kept, hard-linked under its new name rather than rewritten, so compacting again
after a resume rewrites only the files recorded since.

Crash safety. ``info.json``'s ``dpr_live_files = [first, end]`` names the files that hold the dataset (see
:func:`~dpr.datasets.lerobot.format.live_files`). One compaction step

1. writes the new files under numbers outside ``[first, end)`` (each through :mod:`dpr.atomic`: temp file,
   fsync, rename; then the folders fsynced),
2. rewrites ``info.json`` with the new range: the commit point, before it the old files are the dataset and
   after it the new ones,
3. deletes the old files.

A kill at any point leaves ``info.json`` naming one complete set of files; the other set lies outside the live
range, where :class:`~dpr.datasets.lerobot.LeRobotReader` does not look and where the next ``open``, ``repair``
or ``compact`` deletes it. The new files go after the live ones; a second step then moves them to the numbers
from 0 (hard links and rewritten meta rows, no data rewritten), so that a compacted dataset starts at
``data/chunk-000/file-000.parquet`` like one LeRobot wrote.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from dpr.atomic import atomic_link, atomic_write, atomic_write_json, fsync_dir
from dpr.datasets.lerobot.checksums import with_row_checksums
from dpr.datasets.lerobot.files import delete_leftovers
from dpr.datasets.lerobot.format import (
    DATA_FILES_SIZE_IN_MB,
    DATA_PATH,
    EPISODES_PATH,
    INFO_PATH,
    LIVE_FILES_KEY,
    META_CHECKSUMS_KEY,
    STATS_PATH,
    DatasetError,
    chunk_file,
    content_digest,
    in_threads,
    live_files,
    numbered_path,
    read_json,
    read_parquet,
    sealed_info,
    write_parquet,
)
from dpr.datasets.lerobot.meta import data_file_path, load_tasks, read_live_meta

DEFAULT_TARGET_BYTES = DATA_FILES_SIZE_IN_MB * 2**20
# Row groups of about this many bytes in memory, cut at episode boundaries: reading one episode of a packed file
# decodes only its row group(s).
ROW_GROUP_BYTES = 2 * 2**20
SOURCE_BATCH = 64  # source files read at once when packing
POINTER_COLUMNS = ("data/chunk_index", "data/file_index", "meta/episodes/chunk_index", "meta/episodes/file_index")


@dataclass
class _DataFile:
    """A live data file and the committed episodes it holds (its rows from 0 on)."""

    path: Path
    episodes: range
    first_frame: int  # global index of its row 0
    rows: int  # rows in the file
    needed: int  # rows of its committed episodes
    data_bytes: int  # bytes of its column data (the file less its footer)

    @property
    def whole(self) -> bool:
        """Whether it holds nothing but its committed episodes."""
        return self.rows == self.needed


@dataclass
class _Output:
    """One data file of the new layout: these episodes, packed, or ``source`` kept as it is."""

    episodes: range
    source: _DataFile | None = None


def compact_files(
    root: Path, info: dict, target_bytes: int = DEFAULT_TARGET_BYTES, meta: pa.Table | None = None
) -> dict:
    """Pack the live files of the dataset at ``root``, whose committed state is ``info`` (info.json as on disk),
    and return the info.json now live. The caller holds the writer lock and has deleted leftovers; ``meta``: the
    committed meta rows with their stats columns, when the caller has read them already."""
    if info["total_episodes"] == 0:
        return info
    meta = _live_meta_table(root, info, meta)
    files = _data_files(root, info, meta)
    data_plan = _plan_data(files, meta, target_bytes)
    meta_plan = _plan_meta(meta, target_bytes)
    if _already_laid_out(info, meta, data_plan, meta_plan):
        return info
    first, end = live_files(info)
    count = max(len(data_plan), len(meta_plan))
    base = 0 if count <= first else end
    info = _write_layout(root, info, meta, files, data_plan, meta_plan, base)
    if base != 0 and count <= base:  # the numbers from 0 are free now: move the new files there
        meta = _live_meta_table(root, info)
        files = _data_files(root, info, meta)
        info = _write_layout(root, info, meta, files, [_Output(f.episodes, f) for f in files], meta_plan, 0)
    return info


# ---------------------------------------------------------------------------------------------- what is there


def _live_meta_table(root: Path, info: dict, meta: pa.Table | None = None) -> pa.Table:
    """Every committed episode's meta row (``meta`` when the caller has read them), in episode order, with its
    columns exactly as stored."""
    total = info["total_episodes"]
    if meta is None:
        meta, _ = read_live_meta(root, info, with_stats=True)
    if meta is None or meta.column("episode_index").to_pylist() != list(range(total)):
        raise DatasetError(f"{root / 'meta' / 'episodes'}: the meta rows are not episodes 0..{total - 1} in order")
    return meta


def _data_files(root: Path, info: dict, meta: pa.Table) -> list[_DataFile]:
    """The live data files in episode order (each holding a run of consecutive episodes)."""
    chunks = meta.column("data/chunk_index").to_pylist()
    numbers = meta.column("data/file_index").to_pylist()
    starts = meta.column("dataset_from_index").to_pylist()
    lengths = meta.column("length").to_pylist()
    runs: list[tuple[Path, range, int]] = []  # (file, its episodes, rows they need)
    for episode, key in enumerate(zip(chunks, numbers, strict=True)):
        if runs and key == (chunks[episode - 1], numbers[episode - 1]):
            path, episodes, needed = runs[-1]
            runs[-1] = (path, range(episodes.start, episode + 1), needed + lengths[episode])
            continue
        runs.append(
            (
                data_file_path(root, info, {"data/chunk_index": key[0], "data/file_index": key[1]}),
                range(episode, episode + 1),
                lengths[episode],
            )
        )
    if len({path for path, _, _ in runs}) != len(runs):
        raise DatasetError(f"{root / 'data'}: a data file holds episodes that are not consecutive")
    footers = in_threads(_footer, [path for path, _, _ in runs])
    return [
        _DataFile(
            path=path,
            episodes=episodes,
            first_frame=starts[episodes.start],
            rows=footer.num_rows,
            needed=needed,
            data_bytes=max(path.stat().st_size - footer.serialized_size, 1),
        )
        for (path, episodes, needed), footer in zip(runs, footers, strict=True)
    ]


def _footer(path: Path) -> pq.FileMetaData:
    try:
        return pq.read_metadata(path)
    except (pa.ArrowException, OSError) as exc:
        raise DatasetError(f"{path}: corrupt or truncated parquet file: {exc}") from exc


# ------------------------------------------------------------------------------------------------------- plans


def _plan_data(files: list[_DataFile], meta: pa.Table, target_bytes: int) -> list[_Output]:
    """Keep the leading files already half of ``target_bytes`` or more (and the last file when it alone remains);
    pack the episodes of the others greedily, each file up to ``target_bytes`` (estimated from the bytes their
    rows take now, which is what the same rows take in a packed file but for its one footer)."""
    plan: list[_Output] = []
    kept = 0
    while kept < len(files) and files[kept].whole and files[kept].data_bytes >= target_bytes / 2:
        plan.append(_Output(files[kept].episodes, files[kept]))
        kept += 1
    rest = files[kept:]
    if len(rest) == 1 and rest[0].whole:
        return [*plan, _Output(rest[0].episodes, rest[0])]
    lengths = meta.column("length").to_pylist()
    start, size = None, 0.0
    for file in rest:
        per_row = file.data_bytes / max(file.rows, 1)
        for episode in file.episodes:
            estimate = lengths[episode] * per_row
            if start is not None and size + estimate > target_bytes:
                plan.append(_Output(range(start, episode)))
                start, size = None, 0.0
            if start is None:
                start = episode
            size += estimate
    if start is not None:
        plan.append(_Output(range(start, files[-1].episodes.stop)))
    return plan


def _plan_meta(meta: pa.Table, target_bytes: int) -> list[range]:
    """Consecutive runs of meta rows of at most ``target_bytes`` each (from their size in memory)."""
    per_row = meta.nbytes / meta.num_rows
    rows_per_file = max(int(target_bytes // max(per_row, 1.0)), 1)
    return [range(i, min(i + rows_per_file, meta.num_rows)) for i in range(0, meta.num_rows, rows_per_file)]


def _pointers(data_plan: list[_Output], meta_plan: list[range], base: int, n: int) -> dict[str, np.ndarray]:
    """Each episode's four file pointer columns when the plan's files are numbered from ``base``."""
    pointers = {name: np.zeros(n, np.int64) for name in POINTER_COLUMNS}
    for runs, prefix in ((data_plan, "data"), ([_Output(rows) for rows in meta_plan], "meta/episodes")):
        for i, output in enumerate(runs):
            chunk, file = chunk_file(base + i)
            pointers[f"{prefix}/chunk_index"][output.episodes.start : output.episodes.stop] = chunk
            pointers[f"{prefix}/file_index"][output.episodes.start : output.episodes.stop] = file
    return pointers


def _already_laid_out(info: dict, meta: pa.Table, data_plan: list[_Output], meta_plan: list[range]) -> bool:
    """Whether the live files are exactly the plan's, numbered from 0: then there is nothing to do."""
    if live_files(info) != (0, max(len(data_plan), len(meta_plan))):
        return False
    if any(output.source is None for output in data_plan):
        return False
    planned = _pointers(data_plan, meta_plan, 0, meta.num_rows)
    return all(
        name in meta.column_names and np.array_equal(meta.column(name).to_numpy(), values)
        for name, values in planned.items()
    )


# ----------------------------------------------------------------------------------------------------- writing


def _write_layout(
    root: Path,
    info: dict,
    meta: pa.Table,
    files: list[_DataFile],
    data_plan: list[_Output],
    meta_plan: list[range],
    base: int,
) -> dict:
    """One crash-safe step: the planned files written as numbers ``base, base + 1, ...`` (outside the live
    range), info.json swapped to them, the old files deleted. Returns the new info.json."""
    count = max(len(data_plan), len(meta_plan))
    first, end = live_files(info)
    if not (base + count <= first or base >= end):
        raise AssertionError(f"new files {base}..{base + count} overlap the live ones {first}..{end}")
    folders: set[Path] = set()
    for i, output in enumerate(data_plan):
        path = numbered_path(root, DATA_PATH, base + i)
        if output.source is not None:
            atomic_link(output.source.path, path, sync_folder=False)
        else:
            _pack_data(path, output.episodes, files, meta)
        folders.add(path.parent)
    for name, values in _pointers(data_plan, meta_plan, base, meta.num_rows).items():
        column = pa.array(values, type=pa.int64())
        index = meta.schema.get_field_index(name)
        meta = meta.append_column(name, column) if index < 0 else meta.set_column(index, name, column)
    meta = with_row_checksums(meta)  # the rows' checksums, of their new pointers (and for rows that had none)
    for j, rows in enumerate(meta_plan):
        path = numbered_path(root, EPISODES_PATH, base + j)
        write_parquet(path, meta.slice(rows.start, len(rows)), sync_folder=False)
        folders.add(path.parent)
    for folder in sorted(folders | {f.parent for f in folders}):
        fsync_dir(folder)
    new_info = _sealed(root, {**info, LIVE_FILES_KEY: [base, base + count]})
    _commit(root, new_info)
    delete_leftovers(root, (base, base + count))
    return new_info


def _sealed(root: Path, info: dict) -> dict:
    """``info`` sealed anew (its content changed; every meta row now carries its checksums): the tasks' and
    stats.json's checksums as it records them, or, in a dataset written before them, of the files as they are."""
    entry = info.get(META_CHECKSUMS_KEY)
    if entry is not None:
        tasks, stats = entry["tasks"], entry["stats"]
    else:
        stats_path = root / STATS_PATH
        tasks = content_digest(load_tasks(root, info))
        stats = content_digest(read_json(stats_path)) if stats_path.exists() else None
    unsealed = {k: v for k, v in info.items() if k != META_CHECKSUMS_KEY}
    return sealed_info(unsealed, tasks=tasks, stats=stats, rows_from=0)


def _commit(root: Path, info: dict) -> None:
    """The commit point of a compaction step: info.json names the new files live."""
    atomic_write_json(root / INFO_PATH, info)


def _pack_data(path: Path, episodes: range, files: list[_DataFile], meta: pa.Table) -> None:
    """Write ``episodes``' rows, read from their current files, back to back into one parquet file at ``path``,
    in row groups of about ROW_GROUP_BYTES cut at episode boundaries."""
    starts = meta.column("dataset_from_index").to_pylist()
    lengths = meta.column("length").to_pylist()
    sources = [f for f in files if f.episodes.start < episodes.stop and f.episodes.stop > episodes.start]

    def episode_rows() -> Iterator[pa.Table]:
        for i in range(0, len(sources), SOURCE_BATCH):  # a batch of source files read on threads
            batch = sources[i : i + SOURCE_BATCH]
            for source, table in zip(batch, in_threads(lambda f: read_parquet(f.path), batch), strict=True):
                for episode in range(
                    max(source.episodes.start, episodes.start), min(source.episodes.stop, episodes.stop)
                ):
                    yield table.slice(starts[episode] - source.first_frame, lengths[episode])

    def write(sink) -> None:
        writer: pq.ParquetWriter | None = None
        group: list[pa.Table] = []
        group_bytes = 0

        def flush() -> None:
            nonlocal writer, group, group_bytes
            table = pa.concat_tables(group)
            if writer is None:
                writer = pq.ParquetWriter(sink, table.schema, compression="snappy", use_dictionary=False)
            writer.write_table(table, row_group_size=table.num_rows)
            group, group_bytes = [], 0

        try:
            for rows in episode_rows():
                if group and group_bytes + rows.nbytes > ROW_GROUP_BYTES:
                    flush()
                group.append(rows)
                group_bytes += rows.nbytes
            flush()
        finally:
            if writer is not None:
                writer.close()

    atomic_write(path, write, sync_folder=False)
