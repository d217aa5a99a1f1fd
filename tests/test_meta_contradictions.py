"""Dataset meta that contradicts the data is refused by every reader: an ``fps`` the timestamps disagree with, or
``splits`` beyond the episodes, in an info.json sealed anew (its checksum holds, so only the contradiction tells)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from helpers import run_cli, write_info

from dpr.datasets.collect import CollectSpec, collect
from dpr.datasets.lerobot import DatasetError, LeRobotReader

NAV = "dpr/Navigation-v0"


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("meta") / "ds"
    collect(root, CollectSpec(NAV, n_robots=4, robot_model="disk", steps=8), episodes=4)
    return root


def edited(recorded: Path, tmp_path: Path, **changes) -> Path:
    """A copy of ``recorded`` whose info.json holds ``changes``, sealed anew."""
    import shutil

    root = tmp_path / "edited"
    shutil.copytree(recorded, root)
    info = json.loads((root / "meta" / "info.json").read_text())
    write_info(root, {**info, **changes}, indent=4)
    return root


def test_the_recorded_dataset_reads(recorded):
    reader = LeRobotReader(recorded)
    assert reader.fps == 10 and reader.info["splits"] == {"train": "0:4"}


@pytest.mark.parametrize(
    "changes, message",
    [
        ({"fps": 30}, r"fps is 30, but the timestamps of episode 0 in .* are 0.1 s apart \(10 frames per second\)"),
        ({"fps": 10 / 6}, r"fps is 1.66667, but the timestamps of episode 0"),
        ({"splits": {"train": "0:99"}}, r"split 'train' is episodes 0:99, but the dataset holds 4"),
        ({"splits": {"train": "3:1"}}, r"split 'train' must be 'start:stop' episodes, got '3:1'"),
        ({"splits": ["0:4"]}, r"splits must be an object"),
    ],
)
def test_meta_that_contradicts_the_data_is_refused_by_every_reader(recorded, tmp_path, capsys, changes, message):
    root = edited(recorded, tmp_path, **changes)
    with pytest.raises(DatasetError, match=message):
        LeRobotReader(root)
    for argv in (
        ["replay", str(root)],
        ["view", str(root), "--save", str(tmp_path / "v.rrd")],
        ["bc", "--dataset", str(root), "--env", NAV, "--epochs", "1", "--out", str(tmp_path / "bc")],
    ):
        assert run_cli(argv) == 2, argv
        err = capsys.readouterr().err
        assert "meta/info.json" in err and "Traceback" not in err, argv
    assert not (tmp_path / "v.rrd").exists() and not (tmp_path / "bc").exists()
