"""A dataset that `dpr collect` resumes onto is checked before anything is added to it: one whose stored data no
longer matches the checksums it records is refused, naming the file, and not a byte of it changes."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from helpers import change_a_reward, run_cli, tree_hash

from dpr.datasets.collect import CollectSpec, collect
from dpr.datasets.lerobot import DatasetError, LeRobotReader

DAMAGED = "data/chunk-000/file-001.parquet"


def small_spec(steps: int) -> CollectSpec:
    return CollectSpec("dpr/Navigation-v0", n_robots=4, robot_model="disk", steps=steps)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("resume") / "ds"
    collect(root, small_spec(steps=12), episodes=2)
    return root


def test_a_sound_dataset_passes_the_check_and_resumes(recorded, tmp_path):
    root = tmp_path / "ds"
    shutil.copytree(recorded, root)
    assert LeRobotReader(root).check_data() == 2 * 12
    summary = collect(root, small_spec(steps=12), episodes=3)
    assert (summary.episodes_before, summary.episodes_added) == (2, 1)


def test_collect_refuses_to_resume_onto_damaged_data_naming_the_file(recorded, tmp_path, capsys):
    root = tmp_path / "ds"
    shutil.copytree(recorded, root)
    change_a_reward(root / DAMAGED)  # parquet still decodes it: only its checksum tells
    before = tree_hash(root)
    with pytest.raises(DatasetError, match=rf"{DAMAGED}: episode 1: column 'next.reward' does not match its checksum"):
        collect(root, small_spec(steps=12), episodes=4)
    assert tree_hash(root) == before
    argv = ["collect", "--env", "dpr/Navigation-v0", "--robot-model", "disk", "--n-robots", "4", "--steps", "12"]
    assert run_cli([*argv, "--episodes", "4", "--workers", "1", "--out", str(root)]) == 2
    err = capsys.readouterr().err
    assert f"dpr collect: error: {root / DAMAGED}: episode 1: column 'next.reward' does not match" in err
    assert tree_hash(root) == before and LeRobotReader(root).num_episodes == 2
