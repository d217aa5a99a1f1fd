"""Compaction of LeRobot datasets (dpr.datasets.lerobot.compaction): packed files read back bit-exact, resume and
compact again, and a compaction stopped at any step (an exception or a real SIGKILL) loses no episode."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import dpr.datasets.lerobot.compaction as compact_module
import dpr.datasets.lerobot.files as files_module
from dpr.checks import ParameterError
from dpr.datasets.lerobot import LeRobotReader, LeRobotWriter, compact, repair

H, W = 6, 5
FEATURES = {
    "observation.state": {"dtype": "float32", "shape": [7], "names": None},
    "action": {"dtype": "float32", "shape": [3], "names": None},
    "next.reward": {"dtype": "float32", "shape": [1], "names": None},
    "next.done": {"dtype": "bool", "shape": [1], "names": None},
    "observation.image": {"dtype": "image", "shape": [H, W, 3], "names": ["height", "width", "channels"]},
}
SETTINGS = {"fps": 10, "features": FEATURES, "robot_type": "disk", "info_extra": {"dpr": {"env_id": "test"}}}
POINTERS = ("data/chunk_index", "data/file_index", "meta/episodes/chunk_index", "meta/episodes/file_index")
TARGET = 12_000  # bytes: a few episodes per packed file
LOCK = "meta/.dpr-writer.lock"


def record(writer: LeRobotWriter, episodes: int) -> None:
    """Append ``episodes`` random episodes; episode i's frames depend on i alone."""
    for _ in range(episodes):
        index = writer.num_episodes
        rng = np.random.default_rng(index)
        length = int(rng.integers(2, 25))
        frames = {
            name: (
                rng.integers(0, 256, (length, *spec["shape"]), dtype=np.uint8)
                if spec["dtype"] == "image"
                else (rng.random((length, *spec["shape"])) < 0.5)
                if spec["dtype"] == "bool"
                else rng.standard_normal((length, *spec["shape"])).astype(spec["dtype"])
            )
            for name, spec in FEATURES.items()
        }
        writer.add_frames(frames, task="navigate" if index % 3 else f"task {index % 2}")
        writer.save_episode({"seed": index, "env_kwargs": {"n": index}, "note": None})


def build(root: Path, episodes: int = 30) -> None:
    with LeRobotWriter.create(root, **SETTINGS) as writer:
        record(writer, episodes)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> tuple[Path, dict]:
    """30 recorded episodes (one file each) and their view; tests compact copies."""
    root = tmp_path_factory.mktemp("recorded") / "ds"
    build(root)
    return root, view(root)


@pytest.fixture(scope="module")
def compacted_files(recorded, tmp_path_factory) -> list[str]:
    """The files of the recorded dataset compacted without interruption."""
    root = tmp_path_factory.mktemp("compacted") / "ds"
    shutil.copytree(recorded[0], root)
    compact(root, target_bytes=TARGET)
    return parquet_files(root)


def copy_of(recorded: tuple[Path, dict], tmp_path: Path) -> tuple[Path, dict]:
    root = tmp_path / "ds"
    shutil.copytree(recorded[0], root)
    return root, recorded[1]


def view(root: Path) -> dict:
    """Everything a dataset says, read through LeRobotReader, less where its files are."""
    reader = LeRobotReader(root)
    order = list(range(reader.num_episodes))
    order = order[::2] + order[1::2][::-1]  # out of order: the packed-file row-group cache must not matter
    info = {k: v for k, v in reader.info.items() if k != "dpr_live_files"}
    info["dpr_meta_checksums"] = {k: v for k, v in info["dpr_meta_checksums"].items() if k != "info"}  # of info
    return {
        "info": info,
        "episodes": {i: reader.episode(i) for i in order},
        "meta": [{k: v for k, v in e.items() if k not in POINTERS} for e in reader.episodes],
        "episode_stats": [reader.episode_stats(i) for i in range(reader.num_episodes)],
        "stats": reader.stats,
        "tasks": reader.tasks,
        "stats.json": (root / "meta/stats.json").read_bytes(),
        "tasks.parquet": (root / "meta/tasks.parquet").read_bytes(),
    }


def assert_same(got: dict, expected: dict) -> None:
    assert got["info"] == expected["info"]
    assert got["meta"] == expected["meta"]
    assert got["tasks"] == expected["tasks"]
    assert got["stats.json"] == expected["stats.json"] and got["tasks.parquet"] == expected["tasks.parquet"]
    assert got["episodes"].keys() == expected["episodes"].keys()
    for index, columns in expected["episodes"].items():
        assert got["episodes"][index].keys() == columns.keys()
        for name, values in columns.items():
            assert got["episodes"][index][name].dtype == values.dtype
            np.testing.assert_array_equal(got["episodes"][index][name], values, err_msg=f"episode {index} {name}")
    for mine, theirs in ((got["stats"], expected["stats"]), *zip(got["episode_stats"], expected["episode_stats"])):
        assert mine.keys() == theirs.keys()
        for feature in theirs:
            assert mine[feature].keys() == theirs[feature].keys()
            for key in theirs[feature]:
                np.testing.assert_array_equal(mine[feature][key], theirs[feature][key])


def parquet_files(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*.parquet") if p.name != "tasks.parquet")


def live(root: Path) -> list[int]:
    return json.loads((root / "meta/info.json").read_text())["dpr_live_files"]


def assert_lerobot_layout(root: Path, target: int | None) -> None:
    """What LeRobot's loader assumes: all data files, concatenated in path order, are the frames in global index
    order, and all meta files the episodes in order, each row pointing at the files that hold it."""
    data_paths = sorted((root / "data").glob("*/*.parquet"))
    meta_paths = sorted((root / "meta/episodes").glob("*/*.parquet"))
    assert [p.name for p in data_paths] == [f"file-{i:03d}.parquet" for i in range(len(data_paths))]
    frames = pa.concat_tables([pq.read_table(p, columns=["index", "episode_index"]) for p in data_paths])
    np.testing.assert_array_equal(frames.column("index").to_numpy(), np.arange(frames.num_rows))
    rows = pa.concat_tables([pq.read_table(p) for p in meta_paths]).to_pylist()
    assert [r["episode_index"] for r in rows] == list(range(len(rows)))
    for row in rows:
        data = root / f"data/chunk-{row['data/chunk_index']:03d}/file-{row['data/file_index']:03d}.parquet"
        meta = root / f"meta/episodes/chunk-{row['meta/episodes/chunk_index']:03d}"
        meta = meta / f"file-{row['meta/episodes/file_index']:03d}.parquet"
        assert row["episode_index"] in pq.read_table(meta, columns=["episode_index"]).column(0).to_pylist()
        episodes = pq.read_table(data, columns=["episode_index"]).column(0).to_numpy()
        assert (episodes == row["episode_index"]).sum() == row["length"]
    for path in data_paths if target else ():
        if len(set(pq.read_table(path, columns=["episode_index"]).column(0).to_pylist())) > 1:
            assert path.stat().st_size <= target * 1.1, path  # only a single large episode may pass the target


# ------------------------------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("row_group_bytes", [compact_module.ROW_GROUP_BYTES, 1500])
def test_a_compacted_dataset_reads_back_bit_exact(recorded, tmp_path, monkeypatch, row_group_bytes):
    monkeypatch.setattr(compact_module, "ROW_GROUP_BYTES", row_group_bytes)  # small: episodes span row groups
    root, before = copy_of(recorded, tmp_path)
    assert len(parquet_files(root)) == 60
    compact(root, target_bytes=TARGET)
    files_after = parquet_files(root)
    assert 2 < len(files_after) <= 30, files_after  # from 60: a few episodes a file at this tiny target
    assert live(root) == [0, len([f for f in files_after if f.startswith("data/")])]
    assert_same(view(root), before)
    small_row_groups = row_group_bytes < 2000  # (each row group's own overhead makes files pass the estimate)
    assert_lerobot_layout(root, None if small_row_groups else TARGET)
    assert not (root / LOCK).exists() and not list(root.rglob("*.dpr-tmp"))
    if small_row_groups:
        assert max(pq.read_metadata(root / f).num_row_groups for f in files_after if f.startswith("data/")) > 1


def test_finalize_compacts_only_when_asked(tmp_path):
    root = tmp_path / "ds"
    build(root, episodes=8)
    assert len(parquet_files(root)) == 16  # finalize (by the with block) keeps one file per episode
    before = view(root)
    writer = LeRobotWriter.open(root, **SETTINGS)
    record(writer, 2)
    expected_episodes = writer.num_episodes
    writer.finalize(compact=True)
    assert parquet_files(root) == ["data/chunk-000/file-000.parquet", "meta/episodes/chunk-000/file-000.parquet"]
    after = view(root)
    assert len(after["episodes"]) == expected_episodes
    for index, columns in before["episodes"].items():
        for name, values in columns.items():
            np.testing.assert_array_equal(after["episodes"][index][name], values)
    assert not (root / LOCK).exists()


def test_compacting_again_changes_nothing(recorded, tmp_path):
    root, _ = copy_of(recorded, tmp_path)
    compact(root, target_bytes=TARGET)
    state = {f: (os.stat(root / f).st_ino, (root / f).read_bytes()) for f in parquet_files(root)}
    info = (root / "meta/info.json").read_bytes()
    compact(root, target_bytes=TARGET)
    repair(root)
    assert {f: (os.stat(root / f).st_ino, (root / f).read_bytes()) for f in parquet_files(root)} == state
    assert (root / "meta/info.json").read_bytes() == info


def test_resume_after_compaction_appends_and_compacts_again(recorded, tmp_path):
    root, _ = copy_of(recorded, tmp_path)
    reference = tmp_path / "reference"  # the same 45 episodes, never compacted
    shutil.copytree(recorded[0], reference)
    with LeRobotWriter.open(reference, **SETTINGS) as writer:
        record(writer, 15)
    compact(root, target_bytes=TARGET)
    packed = {f: os.stat(root / f).st_ino for f in parquet_files(root)}
    with LeRobotWriter.open(root, **SETTINGS) as writer:
        assert writer.num_episodes == 30
        record(writer, 15)
    appended = [f for f in parquet_files(root) if f not in packed]
    assert len(appended) == 30  # one data and one meta file per new episode, numbered after the packed ones
    expected = view(reference)
    assert_same(view(root), expected)
    first_packed_inode = packed["data/chunk-000/file-000.parquet"]
    compact(root, target_bytes=TARGET)
    assert_same(view(root), expected)
    assert_lerobot_layout(root, TARGET)
    assert len(parquet_files(root)) < 30  # 45 episodes
    # a full packed file is kept (hard-linked under its new name), not rewritten
    assert os.stat(root / "data/chunk-000/file-000.parquet").st_ino == first_packed_inode


def test_bad_target_is_refused_before_anything_changes(tmp_path):
    root = tmp_path / "ds"
    build(root, episodes=3)
    before = parquet_files(root)
    with pytest.raises(ParameterError, match="target_bytes"):
        compact(root, target_bytes=0)
    assert parquet_files(root) == before and not (root / LOCK).exists()


def test_an_empty_dataset_compacts_to_itself(tmp_path):
    root = tmp_path / "ds"
    LeRobotWriter.create(root, **SETTINGS).finalize(compact=True)
    compact(root)
    assert LeRobotReader(root).num_episodes == 0 and parquet_files(root) == []


# ------------------------------------------------------------------------------------------ stopped half way


class Killed(BaseException):
    """Stands for a kill: not an Exception, so nothing on the way up handles it."""


def stop_at_commit(number: int, *, after: bool):
    """Raise at the ``number``-th info.json swap of a compaction (1: packing, 2: the move to file 0)."""
    original = compact_module._commit
    calls = []

    def commit(root, info):
        calls.append(1)
        if len(calls) == number and not after:
            raise Killed("before the swap")
        original(root, info)
        if len(calls) == number and after:
            raise Killed("after the swap")

    return "_commit", commit, compact_module


def stop_mid_packing():
    original = compact_module._pack_data
    calls = []

    def pack(*args):
        original(*args)
        calls.append(1)
        if len(calls) == 2:
            raise Killed("two packed files written")

    return "_pack_data", pack, compact_module


def stop_mid_deletion(number: int):
    original = files_module.remove_file
    calls = []

    def remove(path):
        calls.append(1)
        if len(calls) == number:
            raise Killed("half the old files deleted")
        original(path)

    return "remove_file", remove, files_module


STOPS = {
    "mid_packing": stop_mid_packing,
    "packed_not_swapped": lambda: stop_at_commit(1, after=False),
    "swapped": lambda: stop_at_commit(1, after=True),
    "mid_deletion": lambda: stop_mid_deletion(7),
    "moved_not_swapped": lambda: stop_at_commit(2, after=False),
    "moved_and_swapped": lambda: stop_at_commit(2, after=True),
    "mid_second_deletion": lambda: stop_mid_deletion(70),
}


@pytest.mark.parametrize("stop", list(STOPS))
def test_a_compaction_stopped_at_any_step_loses_no_episode(recorded, compacted_files, tmp_path, monkeypatch, stop):
    root, expected = copy_of(recorded, tmp_path)
    old_files = parquet_files(root)
    name, replacement, module = STOPS[stop]()
    with monkeypatch.context() as patch:
        patch.setattr(module, name, replacement)
        with pytest.raises(Killed):
            compact(root, target_bytes=TARGET)
    assert_same(view(root), expected)  # before any clean-up: the live layout is whole, the other one ignored
    first, end = live(root)
    live_files = [f for f in parquet_files(root) if first <= int(f[-11:-8]) < end]
    assert live_files == old_files or len(live_files) < len(old_files)  # the old layout or a packed one
    repair(root)  # what open() does too: the side that is not live goes
    assert not (root / LOCK).exists() and not list(root.rglob("*.dpr-tmp"))
    first, end = live(root)
    assert all(first <= int(f[-11:-8]) < end for f in parquet_files(root))
    assert_same(view(root), expected)
    compact(root, target_bytes=TARGET)
    assert parquet_files(root) == compacted_files
    assert_same(view(root), expected)
    assert_lerobot_layout(root, TARGET)
    with LeRobotWriter.open(root, **SETTINGS) as writer:  # and recording goes on
        record(writer, 2)
    assert LeRobotReader(root).num_episodes == 32


CHILD = textwrap.dedent(
    """
    import sys, time
    import dpr.datasets.lerobot.compaction as c
    import dpr.datasets.lerobot.files as f
    from dpr.datasets.lerobot import compact

    root, stage, target = sys.argv[1], sys.argv[2], int(sys.argv[3])
    calls = []

    def pause_at(n):
        calls.append(1)
        if len(calls) == n:
            print("stopped", flush=True)
            time.sleep(60)

    def wrap(module, name, n, before=False):
        original = getattr(module, name)

        def wrapped(*args):
            if before:
                pause_at(n)
            original(*args)
            if not before:
                pause_at(n)

        setattr(module, name, wrapped)

    if stage == "packing":
        wrap(c, "_pack_data", 2)
    elif stage == "swapped":
        wrap(c, "_commit", 1)
    elif stage == "deleting":
        wrap(f, "remove_file", 7, before=True)
    compact(root, target_bytes=target)
    print("finished", flush=True)
    """
)


@pytest.mark.parametrize("stage", ["packing", "swapped", "deleting"])
def test_sigkill_during_compaction_loses_no_episode(recorded, compacted_files, tmp_path, stage):
    """A real SIGKILL (no finally, no clean-up, the lock file left behind) at a known step: the child pauses there
    and says so, then is killed."""
    root, expected = copy_of(recorded, tmp_path)
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(root), stage, str(TARGET)], stdout=subprocess.PIPE, text=True, env=env
    )
    try:
        line = child.stdout.readline()  # the child sleeps 60 s after "stopped": a hang fails below, not here
        assert line.strip() == "stopped", line
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait()
        child.stdout.close()
    assert (root / LOCK).exists()  # nothing cleaned up after a kill
    assert_same(view(root), expected)
    started = time.monotonic()
    with LeRobotWriter.open(root, **SETTINGS) as writer:  # the killed writer's lock is free; leftovers go
        assert writer.num_episodes == 30
    assert time.monotonic() - started < 10
    first, end = live(root)
    assert all(first <= int(f[-11:-8]) < end for f in parquet_files(root))
    assert_same(view(root), expected)
    compact(root, target_bytes=TARGET)
    assert parquet_files(root) == compacted_files
    assert_same(view(root), expected)
