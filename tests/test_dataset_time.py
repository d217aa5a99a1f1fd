"""Simulated time in every record of an episode whose policy decides every k physics steps (action_repeat=k):
dataset fps and timestamps (k x 0.1 s a frame), the refusal of datasets recorded with the old fps, MCAP log
times, and `dpr view`'s `step`/`sim_time` timelines of rollouts side by side."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers import run_cli, tree_hash, write_info

from dpr.datasets.collect import CollectSpec, collect
from dpr.datasets.lerobot import DatasetError, LeRobotReader
from dpr.datasets.timing import DATASET_REVISION

NAV = "dpr/Navigation-v0"
SMALL = {"env_id": NAV, "n_robots": 4, "robot_model": "disk"}
CLI_SMALL = ["--env", NAV, "--robot-model", "disk", "--n-robots", "4", "--workers", "1"]


# one robot's state, for MCAP files written by hand
STATE = {
    "positions": [[1.0, 2.0]],
    "angles": [0.0],
    "velocities": [[0.0, 0.0]],
    "angular_velocities": [0.0],
    "expansions": [0.0],
    "alive": [True],
}
METRICS = {"projected_displacement": 0.0, "net_displacement": 0.0, "total_distance": 0.0, "is_success": False}


def record(root: Path, repeat: int, steps: int = 6, episodes: int = 1, **kwargs) -> Path:
    spec = CollectSpec(**SMALL, steps=steps, env_kwargs={"action_repeat": repeat}, **kwargs)
    collect(root, spec, episodes=episodes)
    return root


# ------------------------------------------------------------------------------------------------- datasets
@pytest.mark.parametrize(("repeat", "fps", "seconds"), [(1, 10, 0.1), (10, 1, 1.0), (6, 10 / 6, 0.6)])
def test_a_dataset_records_one_frame_per_decision_in_seconds(tmp_path, repeat, fps, seconds):
    root = record(tmp_path / "ds", repeat)
    reader = LeRobotReader(root)
    assert reader.fps == fps and type(reader.fps) is type(fps)  # an int where 10 / k is one
    timestamps = reader.episode(0, columns=["timestamp"])["timestamp"].reshape(-1)
    np.testing.assert_allclose(timestamps, np.arange(6) * seconds, rtol=1e-6)
    assert timestamps.dtype == np.float32
    # the revision marks datasets whose fps differs from revision 1's; one decision per step is the same in both
    assert reader.info["dpr"].get("dataset_revision") == (DATASET_REVISION if repeat > 1 else None)
    # LeRobot's delta_timestamps in seconds pick the frames one and two decisions back
    offsets = reader.delta_indices({"observation.state": [-2 * seconds, -seconds, 0.0], "action": [0.0, seconds]})
    assert offsets == {"observation.state": [-2, -1, 0], "action": [0, 1]}
    if repeat > 1:  # a time between two decisions is no frame
        with pytest.raises(DatasetError, match="not multiples of the frame period"):
            reader.delta_indices({"action": [0.1]})
    summary = collect(root, CollectSpec(**SMALL, steps=6, env_kwargs={"action_repeat": repeat}), episodes=2)
    assert summary.episodes_total == 2  # the same settings resume, a float fps included


def test_the_reader_refuses_an_unknown_feature_in_delta_timestamps(tmp_path):
    reader = LeRobotReader(record(tmp_path / "ds", 2, steps=2))
    with pytest.raises(DatasetError, match="'observation.velocity', not a feature"):
        reader.delta_indices({"observation.velocity": [0.0]})


def old_layout(root: Path) -> Path:
    """``root`` as dpr wrote it before simulated time: fps 10 and no revision, whatever action_repeat was."""
    info_path = root / "meta" / "info.json"
    info = json.loads(info_path.read_text())
    info["fps"] = 10
    del info["dpr"]["dataset_revision"]
    write_info(root, info, indent=4)
    return root


def test_a_dataset_of_the_old_fps_is_named_by_verify_and_refused_on_resume(tmp_path, capsys):
    root = old_layout(record(tmp_path / "old", 2, steps=3))
    before = tree_hash(root)
    with pytest.raises(DatasetError) as refused:
        collect(root, CollectSpec(**SMALL, steps=3, env_kwargs={"action_repeat": 2}), episodes=2)
    message = str(refused.value)
    assert str(root) in message and "action_repeat=2" in message and "fps 10" in message
    assert "dataset revision 1" in message and "into a new folder" in message and "cannot be resumed" in message
    assert tree_hash(root) == before
    argv = ["collect", *CLI_SMALL, "--steps", "3", "--env-kwarg", "action_repeat=2", "--episodes", "1"]
    assert run_cli([*argv, "--out", str(root), "--verify"]) == 2
    err = capsys.readouterr().err
    assert str(root) in err and "the right fps is 5" in err and "into a new folder" in err
    assert tree_hash(root) == before

    from dpr.cli.data import verify_dataset

    assert verify_dataset(root) == 2
    assert "verify:" in capsys.readouterr().err
    fresh = record(tmp_path / "new", 2, steps=3)  # what the message tells to do
    assert verify_dataset(fresh) == 0
    assert "at 5 fps" in capsys.readouterr().out


def test_a_dataset_of_one_decision_per_step_stays_valid_as_recorded_before(tmp_path):
    """A dataset of action_repeat=1 (or none) is the same in both revisions: no marker, fps 10; it resumes."""
    root = tmp_path / "ds"
    shutil.copytree(record(tmp_path / "src", 1, steps=3), root)
    info = json.loads((root / "meta" / "info.json").read_text())
    assert info["fps"] == 10 and "dataset_revision" not in info["dpr"]
    summary = collect(root, CollectSpec(**SMALL, steps=3, env_kwargs={"action_repeat": 1}), episodes=2)
    assert summary.episodes_total == 2


# ----------------------------------------------------------------------------------------------------- MCAP
def test_mcap_logs_are_stamped_with_simulated_time(tmp_path):
    from mcap.reader import make_reader

    from dpr.datasets.mcap import TOPIC_STATE, read_mcap

    spec = CollectSpec(**SMALL, steps=3, env_kwargs={"action_repeat": 6}, mcap=True)
    collect(tmp_path / "ds", spec, episodes=1)
    path = tmp_path / "ds" / "mcap" / "seed-000000.mcap"
    episode = read_mcap(path)
    assert episode.action_repeat == 6 and episode.metadata["env_kwargs"]["action_repeat"] == 6
    np.testing.assert_array_equal(episode.physics_steps, [0, 6, 12, 18])
    np.testing.assert_allclose(episode.times, [0.0, 0.6, 1.2, 1.8])
    with path.open("rb") as stream:
        messages = [(c.topic, m) for _, c, m in make_reader(stream).iter_messages()]
    states = [(m.log_time, json.loads(m.data)["time"]) for topic, m in messages if topic == TOPIC_STATE]
    assert [log_time for log_time, _ in states] == [0, 600_000_000, 1_200_000_000, 1_800_000_000]
    assert [time for _, time in states] == [0.0, 0.6, 1.2, 1.8]


def test_an_mcap_writer_of_another_repeat_than_the_env_is_refused(tmp_path):
    import gymnasium as gym

    from dpr.datasets.mcap import McapEpisodeWriter, McapError, log_env_step

    env = gym.make(NAV, n_robots=4, robot_model="disk", action_repeat=6)
    env.reset(seed=0)
    with pytest.raises(McapError, match="make the writer with action_repeat=6"):
        with McapEpisodeWriter(tmp_path / "x.mcap", metadata={}) as writer:
            log_env_step(writer, env, 0)
    assert not (tmp_path / "x.mcap").exists()


def test_an_mcap_log_written_before_it_recorded_its_repeat_reads_with_the_env_kwargs_one(tmp_path, monkeypatch):
    """Such a file logged 0.1 s per env step; its episode's env_kwargs say how long each was."""
    import dpr.datasets.mcap.writer as writer_module
    from dpr.datasets.mcap import McapEpisodeWriter, StepOutcome, SwarmState, read_mcap

    encode = writer_module._encode_metadata

    def encode_as_before(path, metadata, repeat=1):
        return {k: v for k, v in encode(path, metadata, repeat).items() if k != "action_repeat"}

    monkeypatch.setattr(writer_module, "_encode_metadata", encode_as_before)
    path = tmp_path / "old.mcap"
    with McapEpisodeWriter(path, metadata={"env_kwargs": {"action_repeat": 5}}) as writer:
        writer.write_scene(goal=[0.0, 0.0])
        writer.write_step(0, SwarmState(**STATE))
        outcome = StepOutcome(action=[1.0], reward=0.0, terminated=False, truncated=False, metrics=METRICS)
        writer.write_step(1, SwarmState(**STATE), outcome)
    episode = read_mcap(path)
    assert episode.action_repeat == 5 and "action_repeat" not in episode.metadata
    np.testing.assert_allclose(episode.times, [0.0, 0.5])
