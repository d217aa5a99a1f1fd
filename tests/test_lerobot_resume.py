"""LeRobot v3.0 writer (dpr.datasets.lerobot): resuming a dataset, refusing other settings without changing a byte,
crash leftovers, repair, SIGKILL mid-recording, the writer's lock."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
from helpers import tree_hash, write_info
from test_lerobot_format import (
    FEATURES,
    INFO_EXTRA,
    VECTOR_FEATURES,
    add_episode,
    make_episode,
    snapshot,
    write_dataset,
)

from dpr.datasets.lerobot import (
    DatasetError,
    LeRobotReader,
    LeRobotWriter,
    repair,
)

# ----------------------------------------------------------------------------------------------- resume / crashes


def test_open_resumes_without_duplicating(tmp_path):
    rng = np.random.default_rng(9)
    root = tmp_path / "ds"
    episodes = [make_episode(rng, n) for n in (4, 3)]
    write_dataset(root, episodes)
    before = snapshot(root)
    more = [make_episode(rng, 5)]
    with LeRobotWriter.open(root, fps=10, features=FEATURES, robot_type="disk", info_extra=INFO_EXTRA) as w:
        assert (w.num_episodes, w.num_frames) == (2, 7)
        add_episode(w, more[0], "navigate")
        assert w.save_episode() == 2
    after = snapshot(root)
    for name in (
        "data/chunk-000/file-000.parquet",
        "data/chunk-000/file-001.parquet",
        "meta/episodes/chunk-000/file-000.parquet",
        "meta/episodes/chunk-000/file-001.parquet",
    ):
        assert after[name] == before[name], f"{name} was rewritten"
    reader = LeRobotReader(root)
    assert (reader.num_episodes, reader.num_frames, reader.tasks) == (3, 12, ["navigate"])
    everything = reader.frame_range(0, 12)
    np.testing.assert_array_equal(everything["index"][:, 0], np.arange(12))
    all_episodes = episodes + more
    np.testing.assert_array_equal(everything["action"], np.concatenate([e["action"] for e in all_episodes]))
    data = np.concatenate([e["observation.state"] for e in all_episodes]).astype(np.float64)
    np.testing.assert_allclose(reader.stats["observation.state"]["mean"], data.mean(0), rtol=1e-12, atol=1e-12)
    assert reader.stats["index"]["count"].tolist() == [12]


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"fps": 15}, "fps"),
        ({"robot_type": "paddle"}, "robot_type"),
        ({"features": {**FEATURES, "action": {"dtype": "float32", "shape": [4], "names": None}}}, "action"),
        ({"features": {**FEATURES, "next.done": {"dtype": "float32", "shape": [1], "names": None}}}, "dtype"),
        ({"info_extra": {"dpr": {"env_id": "dpr/Gate-v0"}}}, "dpr"),
        ({"info_extra": None}, "dpr"),
    ],
)
def test_open_with_other_settings_fails_and_changes_nothing(tmp_path, change, message):
    rng = np.random.default_rng(10)
    root = tmp_path / "ds"
    write_dataset(root, [make_episode(rng, 3)])
    (root / "data/chunk-000/.file-001.parquet.99.dpr-tmp").write_bytes(b"leftover")  # must survive a failed open
    before = snapshot(root)
    kwargs = {"fps": 10, "features": FEATURES, "robot_type": "disk", "info_extra": INFO_EXTRA, **change}
    with pytest.raises(DatasetError, match=message) as excinfo:
        LeRobotWriter.open(root, **kwargs)
    assert "meta/info.json" in str(excinfo.value)
    assert snapshot(root) == before


def make_crashed_dataset(root: Path, rng: np.random.Generator) -> list[dict]:
    """Three episodes written, then info.json rolled back to two: a crash just before the third commit."""
    episodes = [make_episode(rng, n) for n in (4, 3, 5)]
    with LeRobotWriter.create(root, fps=10, features=FEATURES, robot_type="disk", info_extra=INFO_EXTRA) as w:
        for i, episode in enumerate(episodes):
            if i == 2:
                committed_info = (root / "meta/info.json").read_bytes()
            add_episode(w, episode, "navigate" if i < 2 else "a task of the lost episode")
            w.save_episode({"seed": i})
    # A crash just before info.json's rename: episode 2's files, tasks and stats are on disk, info says 2.
    (root / "meta/info.json").write_bytes(committed_info)
    temp = root / "meta/episodes/chunk-000/.file-003.parquet.1234.dpr-tmp"
    temp.write_bytes(b"half a parquet file")
    (root / "meta/.info.json.1234.dpr-tmp").write_bytes(b"{")
    return episodes


def test_crash_leftovers_are_ignored_by_the_reader_and_cleaned_by_open(tmp_path):
    root = tmp_path / "ds"
    rng = np.random.default_rng(11)
    episodes = make_crashed_dataset(root, rng)
    temp = root / "meta/episodes/chunk-000/.file-003.parquet.1234.dpr-tmp"
    reader = LeRobotReader(root)
    assert (reader.num_episodes, reader.num_frames, reader.tasks) == (2, 7, ["navigate"])
    assert reader.stats["index"]["count"].tolist() == [7]  # stale stats.json is recomputed, not trusted
    data = np.concatenate([e["observation.state"] for e in episodes[:2]]).astype(np.float64)
    np.testing.assert_allclose(reader.stats["observation.state"]["mean"], data.mean(0), rtol=1e-12, atol=1e-12)

    replacement = make_episode(rng, 2)
    with LeRobotWriter.open(root, fps=10, features=FEATURES, robot_type="disk", info_extra=INFO_EXTRA) as w:
        assert not temp.exists() and not list(root.rglob("*.dpr-tmp"))
        assert not (root / "data/chunk-000/file-002.parquet").exists()
        assert not (root / "meta/episodes/chunk-000/file-002.parquet").exists()
        assert w.tasks == ["navigate"]
        assert list(pd.read_parquet(root / "meta/tasks.parquet").index) == ["navigate"]  # the lost task is gone
        assert json.loads((root / "meta/stats.json").read_text())["index"]["count"] == [7]
        add_episode(w, replacement, "navigate")
        assert w.save_episode({"seed": 2}) == 2
    reader = LeRobotReader(root)
    assert (reader.num_episodes, reader.num_frames, reader.tasks) == (3, 9, ["navigate"])
    np.testing.assert_array_equal(reader.episode(2)["observation.image"], replacement["observation.image"])
    np.testing.assert_array_equal(reader.episode(2)["index"][:, 0], [7, 8])


def test_repair_brings_a_crashed_dataset_back_to_its_committed_state(tmp_path):
    root = tmp_path / "ds"
    episodes = make_crashed_dataset(root, np.random.default_rng(11))
    committed = {k: v for k, v in snapshot(root).items() if "file-002" not in k and "tmp" not in k}
    repair(root)
    after = snapshot(root)
    assert sorted(after) == sorted(committed)  # only the uncommitted episode's files and temp files are gone
    for name in ("data/chunk-000/file-000.parquet", "data/chunk-000/file-001.parquet", "meta/info.json"):
        assert after[name] == committed[name]
    assert json.loads((root / "meta/stats.json").read_text())["index"]["count"] == [7]
    assert list(pd.read_parquet(root / "meta/tasks.parquet").index) == ["navigate"]
    reader = LeRobotReader(root)
    np.testing.assert_array_equal(reader.episode(1)["action"], episodes[1]["action"])
    repair(root)  # idempotent
    assert snapshot(root) == after


CHILD = textwrap.dedent(
    """
    import sys, numpy as np
    from dpr.datasets.lerobot import LeRobotWriter
    features = {"observation.state": {"dtype": "float32", "shape": [4], "names": None},
                "next.done": {"dtype": "bool", "shape": [1], "names": None}}
    w = LeRobotWriter.open(sys.argv[1], fps=10, features=features, robot_type="disk")
    while True:
        e = w.num_episodes
        for t in range(30 + e % 7):
            w.add_frame({"observation.state": np.full(4, e * 1000 + t, np.float32), "next.done": np.array([False])},
                        task="navigate")
        w.save_episode({"seed": e})
    """
)


def test_sigkill_during_recording_keeps_every_committed_episode(tmp_path):
    root = tmp_path / "ds"
    child = subprocess.Popen([sys.executable, "-c", CHILD, str(root)], env={**os.environ, "PYTHONPATH": os.getcwd()})
    try:
        # generous: the wait ends as soon as 4 episodes are committed, and a loaded CI machine is slow to start it
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and child.poll() is None:
            info = root / "meta/info.json"
            if info.exists() and json.loads(info.read_text() or "{}").get("total_episodes", 0) >= 4:
                break
            time.sleep(0.005)
        else:
            pytest.fail(f"the recording child did not commit 4 episodes (exit code {child.poll()})")
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait()
    reader = LeRobotReader(root)
    assert reader.num_episodes >= 4
    for e in range(reader.num_episodes):
        state = reader.episode(e)["observation.state"]
        np.testing.assert_array_equal(state[:, 0], e * 1000 + np.arange(30 + e % 7))
        assert reader.episodes[e]["seed"] == e
    features = {
        "observation.state": {"dtype": "float32", "shape": [4], "names": None},
        "next.done": {"dtype": "bool", "shape": [1], "names": None},
    }
    with LeRobotWriter.open(root, fps=10, features=features, robot_type="disk") as w:
        committed = w.num_episodes
        assert committed == reader.num_episodes
        assert not list(root.rglob("*.dpr-tmp"))
        assert len(list((root / "data").glob("*/*.parquet"))) == committed
        w.add_frame({"observation.state": np.zeros(4, np.float32), "next.done": np.array([True])}, task="navigate")
        assert w.save_episode({"seed": committed}) == committed


def finished_dataset(root: Path, seed: int) -> Path:
    """A finalized dataset of one 3-frame episode at ``root``."""
    writer = LeRobotWriter.create(root, fps=10, features=FEATURES, robot_type="disk")
    add_episode(writer, make_episode(np.random.default_rng(seed), 3), "navigate")
    writer.save_episode()
    writer.finalize()
    return root


@pytest.mark.parametrize("key, value", [("total_episodes", 10**9), ("total_frames", 10**12), ("fps", 10**9)])
def test_an_absurd_count_in_info_json_is_refused_before_any_allocation(tmp_path, key, value):
    root = finished_dataset(tmp_path / "ds", seed=3)
    info = json.loads((root / "meta" / "info.json").read_text())
    write_info(root, {**info, key: value})
    with pytest.raises(DatasetError, match=f"{key} is {value}, beyond any dataset this reader takes"):
        LeRobotReader(root)
    with pytest.raises(DatasetError, match=f"{key} is {value}"):
        LeRobotWriter.open(root, fps=10, features=FEATURES, robot_type="disk")


@pytest.mark.parametrize("how", ["absolute", "parent", "symlink"])
def test_a_data_path_leading_out_of_the_dataset_is_refused(tmp_path, how):
    import shutil

    root = finished_dataset(tmp_path / "ds", seed=4)
    info_path = root / "meta" / "info.json"
    info = json.loads(info_path.read_text())
    (data,) = (root / "data").rglob("*.parquet")
    outside = tmp_path / "outside" / data.relative_to(root)
    outside.parent.mkdir(parents=True)
    shutil.copy(data, outside)
    if how == "symlink":
        data.unlink()
        data.symlink_to(outside)
    else:
        template = (
            str(tmp_path / "outside" / info["data_path"]) if how == "absolute" else f"../outside/{info['data_path']}"
        )
        write_info(root, {**info, "data_path": template})
    with pytest.raises(DatasetError, match="leads out of the dataset"):
        LeRobotReader(root).verify()


def test_a_damaged_stats_json_is_rewritten_on_resume_with_a_warning(tmp_path):
    root = finished_dataset(tmp_path / "ds", seed=5)
    stats = (root / "meta" / "stats.json").read_text()
    (root / "meta" / "stats.json").write_text("{ not json")
    with pytest.warns(RuntimeWarning, match="stats.json.*rewritten from the committed episodes' stats"):
        LeRobotWriter.open(root, fps=10, features=FEATURES, robot_type="disk").finalize()
    assert json.loads((root / "meta" / "stats.json").read_text()) == json.loads(stats)


def test_second_writer_on_the_same_dataset_is_refused(tmp_path):
    root = tmp_path / "ds"
    first = LeRobotWriter.create(root, fps=10, features=VECTOR_FEATURES, robot_type="disk")
    with pytest.raises(DatasetError, match=rf"another writer \(process {os.getpid()}\) holds this dataset open"):
        LeRobotWriter.open(root, fps=10, features=VECTOR_FEATURES, robot_type="disk")
    first.finalize()
    LeRobotWriter.open(root, fps=10, features=VECTOR_FEATURES, robot_type="disk").finalize()


LOCK = "meta/.dpr-writer.lock"


def test_a_finished_dataset_holds_no_lock_file(tmp_path):
    rng = np.random.default_rng(14)
    root = tmp_path / "ds"
    writer = LeRobotWriter.create(root, fps=10, features=FEATURES, robot_type="disk")
    assert (root / LOCK).exists()  # while a writer is open
    add_episode(writer, make_episode(rng, 3), "navigate")
    writer.save_episode()
    writer.finalize()
    assert not (root / LOCK).exists()
    with pytest.raises(RuntimeError, match="boom"):
        with LeRobotWriter.open(root, fps=10, features=FEATURES, robot_type="disk") as w:
            assert (root / LOCK).exists()
            raise RuntimeError("boom")
    assert not (root / LOCK).exists()
    (root / LOCK).write_bytes(b"")  # left by a writer that was killed
    with LeRobotWriter.open(root, fps=10, features=FEATURES, robot_type="disk") as w:
        assert w.num_episodes == 1
    assert not (root / LOCK).exists()
    repair(root)
    assert not (root / LOCK).exists()
    assert LeRobotReader(root).num_episodes == 1


def test_a_released_lock_can_be_taken_again_while_its_file_comes_and_goes(tmp_path):
    root = tmp_path / "ds"
    for _ in range(3):
        first = LeRobotWriter.open(root, fps=10, features=VECTOR_FEATURES, robot_type="disk")
        with pytest.raises(DatasetError, match="another writer"):
            LeRobotWriter.open(root, fps=10, features=VECTOR_FEATURES, robot_type="disk")
        assert (root / LOCK).exists()  # a refused second writer leaves the holder's lock file alone
        first.finalize()
        assert not (root / LOCK).exists()


def break_total_frames(root: Path) -> str:
    info = json.loads((root / "meta/info.json").read_text())
    info["total_frames"] += 1
    write_info(root, info, indent=4)
    return "total_frames"


def remove_a_data_file(root: Path) -> str:
    (root / "data/chunk-000/file-001.parquet").unlink()
    return "file-001.parquet: file not found"


def truncate_a_data_file(root: Path) -> str:
    path = root / "data/chunk-000/file-000.parquet"
    path.write_bytes(path.read_bytes()[:100])
    return "file-000.parquet: corrupt or truncated"


def remove_the_tasks(root: Path) -> str:
    (root / "meta/tasks.parquet").unlink()
    return "tasks.parquet: file not found"


def drop_a_stats_column(root: Path) -> str:
    path = root / "meta/episodes/chunk-000/file-001.parquet"
    table = pq.read_table(path)
    pq.write_table(table.drop_columns(["stats/action/q50"]), path)
    return "file-001.parquet: row 0 (episode 1) does not match its checksums (stats"


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"fps": 15}, "fps is 10 in the dataset, 15 requested"),
        ({"robot_type": "paddle"}, "robot_type is 'disk' in the dataset, 'paddle' requested"),
        ({"features": VECTOR_FEATURES}, "features are"),
        ({"info_extra": {"dpr": {"env_id": "dpr/Gate-v0"}}}, "info key 'dpr'"),
        (break_total_frames, None),
        (remove_a_data_file, None),
        (truncate_a_data_file, None),
        (remove_the_tasks, None),
        (drop_a_stats_column, None),
    ],
    ids=["fps", "robot_type", "features", "info_extra", "total_frames", "no_data", "torn_data", "no_tasks", "no_stats"],
)
def test_a_refused_resume_changes_no_byte(tmp_path, change, message):
    """Refusals come before any clean-up: the uncommitted episode's files and the temp files of the crashed dataset
    are still there, and so is everything else, byte for byte."""
    root = tmp_path / "ds"
    make_crashed_dataset(root, np.random.default_rng(15))
    kwargs = {"fps": 10, "features": FEATURES, "robot_type": "disk", "info_extra": INFO_EXTRA}
    if callable(change):
        message = change(root)
    else:
        kwargs.update(change)
    before = tree_hash(root)
    with pytest.raises(DatasetError, match=re.escape(message)):
        LeRobotWriter.open(root, **kwargs)
    assert tree_hash(root) == before
    assert (root / "data/chunk-000/file-002.parquet").exists()  # the leftover a resume would have deleted
    assert not (root / LOCK).exists()


def test_exception_inside_with_discards_only_the_unsaved_episode(tmp_path):
    rng = np.random.default_rng(12)
    root = tmp_path / "ds"
    saved = make_episode(rng, 3)
    with pytest.raises(RuntimeError, match="boom"):
        with LeRobotWriter.create(root, fps=10, features=FEATURES, robot_type="disk") as w:
            add_episode(w, saved, "navigate")
            w.save_episode()
            add_episode(w, make_episode(rng, 2), "navigate")
            raise RuntimeError("boom")
    reader = LeRobotReader(root)
    assert (reader.num_episodes, reader.num_frames) == (1, 3)
    with LeRobotWriter.open(root, fps=10, features=FEATURES, robot_type="disk") as w:  # the lock was released
        assert w.num_episodes == 1


def test_finalize_is_idempotent_and_warns_about_unsaved_frames(tmp_path):
    rng = np.random.default_rng(13)
    w = LeRobotWriter.create(tmp_path / "ds", fps=10, features=FEATURES, robot_type="disk")
    add_episode(w, make_episode(rng, 2), "navigate")
    with pytest.warns(RuntimeWarning, match="discards 2 frames"):
        w.finalize()
    w.finalize()
    with pytest.raises(DatasetError, match="finalized"):
        add_episode(w, make_episode(rng, 1), "navigate")
    reader = LeRobotReader(tmp_path / "ds")  # an empty dataset is valid
    assert (reader.num_episodes, reader.num_frames, reader.tasks, reader.stats) == (0, 0, [], {})
