"""Content checksums of a dataset's files, checked whenever they are read.

Data: each episode's frames. A checksum covers one column of one episode's rows, whatever file holds them:
compaction moves the rows into packed files and the checksums still hold. They are kept in the episode's meta row
(:data:`CHECKSUMS_COLUMN`). A flipped byte that parquet still decodes, or a data file swapped for another
episode's, then fails with an error naming the file and the column instead of serving wrong numbers.

Meta: each episodes-meta row carries the checksums of its own other columns (:data:`ROW_CHECKSUMS_COLUMN`: one of
its stats columns, one of the rest, with their names, types and field metadata), which compaction writes anew
with the rows' new file pointers; ``info.json`` carries those of the committed task strings, of ``stats.json``'s
content and of its own content (:data:`~dpr.datasets.lerobot.format.META_CHECKSUMS_KEY`, made by
:func:`~dpr.datasets.lerobot.format.sealed_info`). Checksums cover content, not bytes: a flipped bit that changes
nothing a reader gets back (parquet padding, a footer statistic) is harmless, and any other fails naming the file.

Datasets written before checksums existed have none (their meta rows read None, their info.json no such key) and
are read unchecked, as before; a dataset resumed from such a state checks the rows of the episodes added since
(``rows_from``), and compaction gives every row its checksums.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from dpr.datasets.lerobot.format import DIGEST_BYTES, INFO_PATH, DatasetError, text_digest

CHECKSUMS_COLUMN = "dpr_checksums"  # JSON text: {column: blake2b-64 hex digest of the episode's values}
ROW_CHECKSUMS_COLUMN = "dpr_row_checksums"  # JSON text: {"columns": digest, "stats": digest} of the row's others
STATS_PREFIX = "stats/"


def _feed(digest, array: pa.Array) -> None:
    """Feed ``array``'s values (not its buffers, which slicing and re-encoding change) into ``digest``."""
    kind = array.type
    if pa.types.is_list(kind) or pa.types.is_large_list(kind) or pa.types.is_fixed_size_list(kind):
        digest.update(np.asarray(pc.list_value_length(array).fill_null(-1), dtype=np.int64).tobytes())
        _feed(digest, array.flatten())
    elif pa.types.is_struct(kind):
        for index in range(kind.num_fields):
            digest.update(kind.field(index).name.encode() + b"\0")
            _feed(digest, array.field(index))
    elif pa.types.is_binary(kind) or pa.types.is_string(kind) or pa.types.is_large_binary(kind):
        for value in array.to_pylist():
            data = b"" if value is None else value.encode() if isinstance(value, str) else value
            digest.update(len(data).to_bytes(8, "little") + data)
    else:
        digest.update(np.ascontiguousarray(array.to_numpy(zero_copy_only=False)).tobytes())


def column_digest(column: pa.Array | pa.ChunkedArray) -> str:
    digest = hashlib.blake2b(digest_size=DIGEST_BYTES)
    if isinstance(column, pa.ChunkedArray):
        column = column.combine_chunks()
    _feed(digest, column)
    return digest.hexdigest()


def checksums_text(table: pa.Table) -> str:
    """The meta row's value for an episode whose data rows are ``table``."""
    return json.dumps({name: column_digest(table.column(name)) for name in sorted(table.column_names)})


def check_checksums(table: pa.Table, stored: str | None, names: Iterable[str], where: str) -> None:
    """DatasetError naming ``where`` and the column when a column of ``names`` in ``table`` (one episode's rows)
    differs from the checksum stored for it (nothing is checked without stored checksums)."""
    if stored is None:
        return
    try:
        expected = json.loads(stored)
    except (TypeError, ValueError) as exc:
        raise DatasetError(f"{where}: unreadable {CHECKSUMS_COLUMN} in its meta row: {exc}") from None
    for name in names:
        if name in expected and column_digest(table.column(name)) != expected[name]:
            raise DatasetError(f"{where}: column {name!r} does not match its checksum (the data file is corrupt)")


# ----------------------------------------------------------------------------------------------- meta rows


def _as_text(value: Any) -> Any:
    if isinstance(value, bytes):
        return value.hex()
    raise TypeError(f"{type(value).__name__} in an episodes-meta row")


def _type_text(kind: pa.DataType) -> str:
    """A type as text, less the names of list items (parquet reads ``item`` back as ``element``)."""
    if pa.types.is_list(kind) or pa.types.is_large_list(kind):
        return f"list<{_type_text(kind.value_type)}>"
    if pa.types.is_fixed_size_list(kind):
        return f"list<{_type_text(kind.value_type)}>[{kind.list_size}]"
    if pa.types.is_struct(kind):
        return f"struct<{', '.join(f'{f.name}: {_type_text(f.type)}' for f in kind)}>"
    return str(kind)


def _group_digest(fields: list[pa.Field], row: Mapping[str, Any]) -> str:
    """The digest of some columns of one row: each one's name, type, field metadata and value."""
    items = [
        [
            field.name,
            _type_text(field.type),
            sorted((k.decode("latin-1"), v.decode("latin-1")) for k, v in (field.metadata or {}).items()),
            row[field.name],
        ]
        for field in fields
    ]
    return text_digest(json.dumps(items, separators=(",", ":"), default=_as_text))


def _groups(schema: pa.Schema) -> dict[str, list[pa.Field]]:
    fields = sorted((field for field in schema if field.name != ROW_CHECKSUMS_COLUMN), key=lambda f: f.name)
    return {
        "columns": [field for field in fields if not field.name.startswith(STATS_PREFIX)],
        "stats": [field for field in fields if field.name.startswith(STATS_PREFIX)],
    }


def with_row_checksums(table: pa.Table) -> pa.Table:
    """``table`` (episodes-meta rows) with its :data:`ROW_CHECKSUMS_COLUMN` made for every row."""
    groups = _groups(table.schema)
    rows = table.to_pylist()
    texts = [json.dumps({name: _group_digest(fields, row) for name, fields in groups.items()}) for row in rows]
    column = pa.array(texts, type=pa.string())
    index = table.schema.get_field_index(ROW_CHECKSUMS_COLUMN)
    if index < 0:
        return table.append_column(ROW_CHECKSUMS_COLUMN, column)
    return table.set_column(index, ROW_CHECKSUMS_COLUMN, column)


def check_row_checksums(table: pa.Table, path: Path, *, with_stats: bool, required_from: int | None) -> None:
    """A DatasetError naming ``path`` when a row of ``table`` (read from it: all its columns, or all but the stats
    columns without ``with_stats``) differs from its checksums, or when a row of an episode at or after
    ``required_from`` has none; ``required_from`` None: the dataset's info.json records no meta checksums, so
    then no row may carry them either (info.json lost them)."""
    if ROW_CHECKSUMS_COLUMN not in table.column_names:
        stored = [None] * table.num_rows
    else:
        stored = table.column(ROW_CHECKSUMS_COLUMN).to_pylist()
    if required_from is None:
        if any(text is not None for text in stored):
            raise DatasetError(
                f"{path.parents[3] / INFO_PATH}: records no meta checksums, but the meta rows carry theirs "
                "(info.json is damaged)"
            )
        return
    groups = {name: fields for name, fields in _groups(table.schema).items() if with_stats or name != "stats"}
    episodes = table.column("episode_index").to_pylist() if "episode_index" in table.column_names else stored
    for number, (row, text, episode) in enumerate(zip(table.to_pylist(), stored, episodes, strict=True)):
        if text is None:
            if episode is None or not isinstance(episode, int) or episode >= required_from:
                raise DatasetError(f"{path}: row {number} has no {ROW_CHECKSUMS_COLUMN} (the file is corrupt)")
            continue
        try:
            expected = json.loads(text)
            differ = [name for name, fields in groups.items() if _group_digest(fields, row) != expected[name]]
        except (TypeError, ValueError, KeyError):
            differ = ["its checksums"]
        if differ:
            raise DatasetError(
                f"{path}: row {number} (episode {episode}) does not match its checksums "
                f"({', '.join(differ)}; the file is corrupt)"
            )
