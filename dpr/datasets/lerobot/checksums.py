"""Content checksums of each episode's frames, kept in its episodes-meta row and checked when frames are read.

A checksum covers one column of one episode's rows, whatever file holds them: compaction moves the rows into
packed files and the checksums still hold. A flipped byte that parquet still decodes, or a data file swapped for
another episode's, then fails with an error naming the file and the column instead of serving wrong numbers.
Datasets written before checksums existed have none (their meta rows read None) and are read unchecked.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from dpr.datasets.lerobot.format import DatasetError

CHECKSUMS_COLUMN = "dpr_checksums"  # JSON text: {column: blake2b-64 hex digest of the episode's values}
DIGEST_BYTES = 8


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
