"""One recorded episode as arrow tables: its data rows, its per-episode stats and its episodes-meta row."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np
import pyarrow as pa

from dpr.datasets.lerobot.checksums import CHECKSUMS_COLUMN, with_row_checksums
from dpr.datasets.lerobot.format import STAT_KEYS, decode_png, spec_shape
from dpr.datasets.lerobot.stats import image_sample_indices, image_stats, vector_stats


def episode_stats(features: Mapping[str, Mapping], columns: Mapping[str, Any]) -> dict[str, dict[str, np.ndarray]]:
    """Per-feature stats of one episode's columns (images from a sample of decoded frames)."""
    stats: dict[str, dict[str, np.ndarray]] = {}
    for name, spec in features.items():
        values = columns[name]
        if spec["dtype"] == "image":
            sample = [decode_png(values[i]) for i in image_sample_indices(len(values))]
            stats[name] = image_stats(sample)
        else:
            stats[name] = vector_stats(np.asarray(values).reshape(len(values), -1))
    return stats


def data_table(features: Mapping[str, Mapping], columns: Mapping[str, Any], n: int) -> pa.Table:
    """The episode's ``n`` frames, one column per feature (images as PNG structs)."""
    arrays, names = [], []
    for name, spec in features.items():
        values = columns[name]
        if spec["dtype"] == "image":
            paths = [f"frame-{i:06d}.png" for i in range(n)]
            array: pa.Array = pa.StructArray.from_arrays(
                [pa.array(values, type=pa.binary()), pa.array(paths, type=pa.string())], names=["bytes", "path"]
            )
        elif spec_shape(spec) == (1,):
            array = pa.array(values.reshape(n))
        else:
            width = spec_shape(spec)[0]
            array = pa.FixedSizeListArray.from_arrays(pa.array(values.reshape(-1)), width)
        arrays.append(array)
        names.append(name)
    return pa.Table.from_arrays(arrays, names=names)


class ExtraColumns(NamedTuple):
    """The caller's own columns of an episodes-meta row (its ``episode_meta``): their fields, and one value each."""

    fields: list[pa.Field]
    arrays: list[pa.Array]


def meta_table(
    *,
    episode: int,
    frames: tuple[int, int],
    tasks: list[str],
    data_file: tuple[int, int],
    meta_file: tuple[int, int],
    stats: Mapping[str, Mapping[str, np.ndarray]],
    extra: ExtraColumns,
    checksums: str | None = None,
) -> pa.Table:
    """The episode's one-row episodes-meta table; ``frames`` its global frame range [from, to), ``data_file`` and
    ``meta_file`` the (chunk_index, file_index) of the files that hold it, ``extra`` the caller's columns (after
    the standard ones), ``checksums`` its data's (:func:`dpr.datasets.lerobot.checksums.checksums_text`); last,
    the row's own checksums."""
    fields: list[pa.Field] = []
    arrays: list[pa.Array] = []

    def add(name: str, value: Any, type_: pa.DataType | None = None) -> None:
        array = pa.array([value], type=type_)
        fields.append(pa.field(name, array.type))
        arrays.append(array)

    add("episode_index", episode, pa.int64())
    add("tasks", tasks, pa.list_(pa.string()))
    add("length", frames[1] - frames[0], pa.int64())
    add("data/chunk_index", data_file[0], pa.int64())
    add("data/file_index", data_file[1], pa.int64())
    add("dataset_from_index", frames[0], pa.int64())
    add("dataset_to_index", frames[1], pa.int64())
    for name, feature_stats in stats.items():
        for key in STAT_KEYS:
            add(f"stats/{name}/{key}", feature_stats[key].tolist())
    add("meta/episodes/chunk_index", meta_file[0], pa.int64())
    add("meta/episodes/file_index", meta_file[1], pa.int64())
    if checksums is not None:
        add(CHECKSUMS_COLUMN, checksums, pa.string())
    fields.extend(extra.fields)
    arrays.extend(extra.arrays)
    return with_row_checksums(pa.Table.from_arrays(arrays, schema=pa.schema(fields)))
