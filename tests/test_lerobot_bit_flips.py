"""Any one flipped bit in any file of a compacted dataset is caught, naming the file, or changes nothing a reader
gets back (a property, hypothesis): the data files by their columns' checksums, the meta tables by theirs
(dpr.datasets.lerobot.checksums), on read, on ``dpr collect --verify`` and on resume."""

from __future__ import annotations

import json
import re
import shutil
import warnings
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from helpers import run_cli, tree_hash
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dpr.cli.data import verify_dataset
from dpr.datasets.collect import CollectSpec, collect
from dpr.datasets.lerobot import DatasetError, LeRobotReader, compact, repair
from dpr.datasets.lerobot.checksums import ROW_CHECKSUMS_COLUMN
from dpr.datasets.lerobot.format import META_CHECKSUMS_KEY
from dpr.datasets.timing import check_dataset_time

SPEC = CollectSpec("dpr/Navigation-v0", n_robots=4, robot_model="disk", steps=5, pixels=True, image_size=16)
FLIP_SETTINGS = settings(
    max_examples=50,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)


class Pristine:
    """The dataset as collected: its folder, its files and everything it reads as."""

    def __init__(self, root: Path, files: list[str], read: dict):
        self.root, self.files, self.read = root, files, read

    def __repr__(self) -> str:
        return f"Pristine({self.root})"


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Pristine:
    """Two 5-frame episodes with 16-pixel images, compacted."""
    root = tmp_path_factory.mktemp("flips") / "ds"
    collect(root, SPEC, episodes=2, compact=True)
    files = sorted(str(path.relative_to(root)) for path in root.rglob("*") if path.is_file())
    assert files == [
        "data/chunk-000/file-000.parquet",
        "meta/episodes/chunk-000/file-000.parquet",
        "meta/info.json",
        "meta/stats.json",
        "meta/tasks.parquet",
    ]
    return Pristine(root, files, everything(root))


def everything(root: Path) -> dict:
    """All a reader gives back of the dataset at ``root``, after ``dpr collect --verify``'s checks."""
    reader = LeRobotReader(root)
    check_dataset_time(root, reader.info)
    return {
        "verified": reader.verify(),
        "info": reader.info,
        "episodes": reader.episodes,
        "tasks": reader.tasks,
        "stats": reader.stats,
        "episode_stats": [reader.episode_stats(i) for i in range(reader.num_episodes)],
        "frames": [reader.episode(i) for i in range(reader.num_episodes)],
    }


def assert_identical(got, expected, where: str = "") -> None:
    """Equal values of equal types, arrays of equal dtypes, all the way down."""
    if isinstance(expected, np.ndarray):
        assert isinstance(got, np.ndarray) and got.dtype == expected.dtype, where
        np.testing.assert_array_equal(got, expected, err_msg=where)
    elif isinstance(expected, dict):
        assert isinstance(got, dict) and got.keys() == expected.keys(), where
        for key in expected:
            assert_identical(got[key], expected[key], f"{where}/{key}")
    elif isinstance(expected, list):
        assert isinstance(got, list) and len(got) == len(expected), where
        for index, (mine, theirs) in enumerate(zip(got, expected, strict=True)):
            assert_identical(mine, theirs, f"{where}[{index}]")
    else:
        assert type(got) is type(expected) and got == expected, f"{where}: {got!r} != {expected!r}"


@FLIP_SETTINGS
@given(which=st.integers(min_value=0, max_value=4), where=st.floats(min_value=0.0, max_value=1.0, exclude_max=True))
def test_a_flipped_bit_is_caught_naming_its_file_or_changes_nothing(dataset, tmp_path_factory, which, where):
    original, files, expected = dataset.root, dataset.files, dataset.read
    root = tmp_path_factory.mktemp("flipped") / "ds"
    shutil.copytree(original, root)
    path = root / files[which]
    data = bytearray(path.read_bytes())
    bit = int(where * len(data) * 8)
    data[bit // 8] ^= 1 << (bit % 8)
    path.write_bytes(bytes(data))

    try:
        got = everything(root)
    except DatasetError as error:  # read and --verify
        assert str(path) in str(error), f"bit {bit} of {files[which]}: {error}"
        caught = True
    else:
        assert_identical(got, expected, f"bit {bit} of {files[which]}")
        caught = False

    # A resume (what dpr collect does to a dataset it appends to) refuses damaged meta tables naming the file, or,
    # for stats.json (derived from the meta rows), rewrites it saying so; it never goes on over them unsaid. Of
    # the data files it reads the footers (their content is read, and checked, by the reader and --verify).
    if path.parent.parent.name == "data":
        return
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        try:
            repair(root)
        except DatasetError as error:
            assert caught and str(path) in str(error), f"bit {bit} of {files[which]}: {error}"
            return
    rewritten = [str(warning.message) for warning in said if str(path) in str(warning.message)]
    assert not caught or (rewritten and path.name == "stats.json"), f"bit {bit} of {files[which]}: resumed"
    assert_identical(everything(root), expected, f"bit {bit} of {files[which]}, resumed")


def test_the_env_id_a_flip_renamed_is_refused_by_read_verify_and_resume(dataset, tmp_path, capsys):
    """The probe's flip: 'N' -> 'O' in the meta table's env_id, so that every row read dpr/Oavigation-v0. The
    reader, `dpr collect --verify` and a resume (which appended to it) now refuse it, naming the file."""
    root = tmp_path / "ds"
    shutil.copytree(dataset.root, root)
    path = root / "meta/episodes/chunk-000/file-000.parquet"
    pristine = path.read_bytes()
    for found in re.finditer(re.escape(b"dpr/Navigation-v0"), pristine):  # the copy in env_id's page
        data = bytearray(pristine)
        data[found.start() + 4] ^= 0x01
        path.write_bytes(bytes(data))
        if pq.read_table(path, columns=["env_id"]).column(0).to_pylist() == ["dpr/Oavigation-v0"] * 2:
            break
    else:
        pytest.fail("no flip of the env_id column's page renames it")
    before = tree_hash(root)
    with pytest.raises(DatasetError, match=re.escape(f"{path}: row 0 (episode 0) does not match its checksums")):
        LeRobotReader(root)
    argv = ["collect", "--env", SPEC.env_id, "--n-robots", "4", "--robot-model", "disk", "--steps", "5"]
    argv += ["--pixels", "--image-size", "16", "--episodes", "2", "--workers", "1", "--out", str(root), "--verify"]
    assert run_cli(argv) == 2  # refused by the resume that `dpr collect` is before it verifies
    assert f"{path}: row 0 (episode 0) does not match its checksums" in capsys.readouterr().err
    assert verify_dataset(root) == 2  # and by --verify
    assert f"dpr collect: verify: {path}: row 0" in capsys.readouterr().err
    with pytest.raises(DatasetError, match=re.escape(str(path))):
        collect(root, SPEC, episodes=3)
    assert tree_hash(root) == before


def test_a_dataset_without_meta_checksums_reads_as_before_and_gains_them(dataset, tmp_path):
    """A dataset written before meta checksums (none in info.json or in its meta rows) reads and verifies as
    before; a resume checks the rows of the episodes it adds, and compaction gives every row its checksums."""
    root = tmp_path / "ds"
    shutil.copytree(dataset.root, root)
    path = root / "meta/episodes/chunk-000/file-000.parquet"
    pq.write_table(pq.read_table(path).drop_columns([ROW_CHECKSUMS_COLUMN]), path)
    info = json.loads((root / "meta/info.json").read_text())
    del info[META_CHECKSUMS_KEY]
    (root / "meta/info.json").write_text(json.dumps(info, indent=4))
    assert_identical({**everything(root), "info": {}}, {**dataset.read, "info": {}})

    collect(root, SPEC, episodes=3)  # a resume: the third episode's row carries its checksums
    assert json.loads((root / "meta/info.json").read_text())[META_CHECKSUMS_KEY]["rows_from"] == 2
    assert LeRobotReader(root).verify() == 15
    third = root / "meta/episodes/chunk-000/file-001.parquet"
    rows = pq.read_table(third)
    assert rows.column(ROW_CHECKSUMS_COLUMN).null_count == 0
    index = rows.schema.get_field_index("seed")
    pq.write_table(rows.set_column(index, "seed", pa.array([7], pa.int64())), third)
    with pytest.raises(DatasetError, match=re.escape(f"{third}: row 0 (episode 2) does not match its checksums")):
        LeRobotReader(root)
    pq.write_table(rows, third)

    compact(root)
    assert json.loads((root / "meta/info.json").read_text())[META_CHECKSUMS_KEY]["rows_from"] == 0
    (packed,) = (root / "meta/episodes").rglob("*.parquet")
    assert pq.read_table(packed).column(ROW_CHECKSUMS_COLUMN).null_count == 0
    assert LeRobotReader(root).verify() == 15
