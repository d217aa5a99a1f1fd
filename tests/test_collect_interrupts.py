"""Collection killed or interrupted: `dpr collect` as a user runs it survives SIGKILL mid-run (at most the episodes
being recorded are lost, and the same command resumes) and stops cleanly on Ctrl-C with whole episodes committed;
Ctrl-C while an episode's files are being written commits that episode whole; pool workers hand episodes back as
files, so that no worker blocks on the pool's pipe when Ctrl-C ends the pool."""

import json
import os
import pickle
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from helpers import assert_group_ends, failed_if_left_running, parquet_files, start_dpr_as_typed
from test_collect import small_spec

import dpr.datasets.collect as collect_module
from dpr.datasets.collect import RolloutWorkers, collect
from dpr.datasets.lerobot import LeRobotReader, LeRobotWriter
from dpr.datasets.replay import replay_episode

NAV = "dpr/Navigation-v0"

# The subprocess runs: long enough (about 0.3 s of work per episode on 2 cores) that a kill after the first
# committed episodes lands well before the last of the 12.
CLI_EPISODES = 12  # the signal comes once 1-2 are committed: it lands mid-run, even on a busy machine
CLI_STEPS = 3000
CLI_ARGS = [
    "--env",
    NAV,
    "--robot-model",
    "disk",
    "--n-robots",
    "9",
    "--steps",
    str(CLI_STEPS),
    "--episodes",
    str(CLI_EPISODES),
    "--workers",
    "2",
]


def committed_episodes(root: Path) -> int:
    try:
        return json.loads((root / "meta" / "info.json").read_text())["total_episodes"]
    except (FileNotFoundError, json.JSONDecodeError, KeyError):
        return 0


def start_cli_collect(out: Path, log: Path) -> subprocess.Popen:
    """`dpr collect` as typed at a terminal, its temporary files beside ``out`` (what a killed run leaves stays in
    the test's folder)."""
    env = {**os.environ, "SDL_VIDEODRIVER": "dummy", "TMPDIR": str(out.parent)}
    return start_dpr_as_typed(["collect", *CLI_ARGS, "--out", str(out)], log, env)


def run_cli_collect(out: Path, log: Path) -> int:
    process = start_cli_collect(out, log)
    try:
        return process.wait(timeout=120)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()


def wait_for_episodes(root: Path, count: int, process: subprocess.Popen, log: Path, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while committed_episodes(root) < count:
        if process.poll() is not None:
            pytest.fail(f"dpr collect exited ({process.returncode}) before {count} episodes:\n{log.read_text()}")
        if time.monotonic() > deadline:
            os.killpg(process.pid, signal.SIGKILL)
            pytest.fail(f"no {count} committed episodes within {timeout} s:\n{log.read_text()}")
        time.sleep(0.01)


def check_complete_dataset(root: Path, steps: int) -> LeRobotReader:
    """Seeds 0..CLI_EPISODES-1 once each, whole episodes, contiguous frame indices, no leftover files."""
    reader = LeRobotReader(root)
    assert reader.num_episodes == CLI_EPISODES
    assert sorted(int(e["seed"]) for e in reader.episodes) == list(range(CLI_EPISODES))
    lengths = [int(e["length"]) for e in reader.episodes]
    assert reader.num_frames == sum(lengths)
    indices = []
    for i in range(reader.num_episodes):
        data = reader.episode(i, ["index", "frame_index", "episode_index", "next.done", "next.success"])
        indices.append(data["index"][:, 0])
        np.testing.assert_array_equal(data["frame_index"][:, 0], np.arange(lengths[i]))
        assert (data["episode_index"] == i).all()
        check_whole_episode(data, steps)
    np.testing.assert_array_equal(np.concatenate(indices), np.arange(reader.num_frames))
    assert len(parquet_files(root, "data")) == len(parquet_files(root, "meta/episodes")) == CLI_EPISODES
    assert not list(root.rglob("*.dpr-tmp"))
    return reader


def check_whole_episode(data: dict, steps: int) -> None:
    """Done only on the last frame, which ended the episode by success or by the step limit."""
    done = data["next.done"][:, 0]
    assert done[-1] and not done[:-1].any()
    assert len(done) == steps or data["next.success"][-1, 0]


# ------------------------------------------------------------------------------------- crash and Ctrl-C (CLI)


def test_cli_collect_survives_sigkill_and_resumes(tmp_path):
    out, log = tmp_path / "ds", tmp_path / "collect.log"
    process = start_cli_collect(out, log)
    try:
        wait_for_episodes(out, 2, process, log)
    finally:
        os.killpg(process.pid, signal.SIGKILL)  # the main process and its workers
        process.wait(timeout=30)
    assert process.returncode == -signal.SIGKILL
    committed = committed_episodes(out)
    assert 2 <= committed < CLI_EPISODES, "the kill should land mid-run; make the episodes longer"

    reader = LeRobotReader(out)
    assert reader.num_episodes == committed
    assert [int(e["seed"]) for e in reader.episodes] == list(range(committed))
    for index in range(committed):
        data = reader.episode(index)
        assert len(data["action"]) == reader.episodes[index]["length"]
        check_whole_episode(data, CLI_STEPS)
    check = replay_episode(reader, committed - 1)
    assert check.equal and check.frames == reader.episodes[committed - 1]["length"]
    kept = {name: (out / name).read_bytes() for name in parquet_files(out, "data")[:committed]}

    assert run_cli_collect(out, log) == 0, log.read_text()
    check_complete_dataset(out, CLI_STEPS)
    for name, content in kept.items():
        assert (out / name).read_bytes() == content, name


def test_cli_collect_stops_cleanly_on_ctrl_c(tmp_path):
    out, log = tmp_path / "ds", tmp_path / "collect.log"
    process = start_cli_collect(out, log)
    with failed_if_left_running(process, log, "dpr collect did not exit within 20 s of Ctrl-C"):
        wait_for_episodes(out, 1, process, log)
        os.killpg(process.pid, signal.SIGINT)  # what a terminal's Ctrl-C does: the whole foreground group
        process.wait(timeout=20)
    assert process.returncode == 130, log.read_text()
    assert "interrupted" in log.read_text()
    assert_group_ends(process.pid, "worker processes outlived dpr collect")
    assert list(out.parent.glob("dpr-collect-*")) == [], "the workers' hand-off folder outlived dpr collect"

    committed = committed_episodes(out)
    assert 1 <= committed < CLI_EPISODES
    reader = LeRobotReader(out)
    for index in range(committed):
        check_whole_episode(reader.episode(index, ["next.done", "next.success"]), CLI_STEPS)
    # a clean stop leaves nothing uncommitted behind (LeRobot itself would load any data/*/*.parquet)
    assert len(parquet_files(out, "data")) == len(parquet_files(out, "meta/episodes")) == committed
    assert not list(out.rglob("*.dpr-tmp"))

    assert run_cli_collect(out, log) == 0, log.read_text()  # the writer lock was released
    check_complete_dataset(out, CLI_STEPS)


# ------------------------------------------------------------------------------ episodes leave a pool as files

PIPE_BUFFER = 65536  # Linux's pipe capacity: a larger message blocks its sender until the other end reads


def test_a_pool_worker_hands_its_episode_back_as_a_file(tmp_path):
    """What crosses the pool's pipe is a path, far smaller than the pipe's buffer, however long the episode: a
    worker never blocks mid-send holding the pipe's lock, which would hang Pool.terminate() on Ctrl-C."""
    spec = small_spec(n_robots=9, steps=CLI_STEPS)
    direct = collect_module.rollout(spec, 5)
    assert len(pickle.dumps(direct)) > PIPE_BUFFER  # the episode itself would block the sender

    path = collect_module._rollout_to_file((spec, 5, None), tmp_path)
    assert len(pickle.dumps(path)) < 1024
    handed = collect_module._take_record(path)
    assert not path.exists() and list(tmp_path.iterdir()) == []
    assert handed.seed == 5
    for name in ("observations", "actions", "rewards", "dones", "environment_states"):
        np.testing.assert_array_equal(getattr(handed, name), getattr(direct, name), err_msg=name)


def test_pooled_collect_records_the_serial_episodes_and_leaves_no_files(tmp_path, monkeypatch):
    handoffs = tmp_path / "tmp"
    handoffs.mkdir()
    monkeypatch.setattr("tempfile.tempdir", str(handoffs))  # where the run's hand-off folder is made
    spec = small_spec(steps=60)
    collect(tmp_path / "pooled", spec, episodes=3, workers=RolloutWorkers(2))
    collect(tmp_path / "serial", spec, episodes=3)
    assert list(handoffs.iterdir()) == []
    pooled, serial = LeRobotReader(tmp_path / "pooled"), LeRobotReader(tmp_path / "serial")
    assert [e["seed"] for e in pooled.episodes] == [e["seed"] for e in serial.episodes] == [0, 1, 2]
    for index in range(3):
        a, b = pooled.episode(index), serial.episode(index)
        for name in ("observation.state", "action", "next.reward"):
            np.testing.assert_array_equal(a[name], b[name], err_msg=f"episode {index}: {name}")


# ----------------------------------------------------------------------------------------- Ctrl-C while saving


@pytest.fixture
def sigint_raises():
    """SIGINT raises KeyboardInterrupt, as in an interactive Python, even where the tests run with it ignored
    (a background job of a shell without job control)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def test_ctrl_c_while_saving_commits_that_episode_whole(tmp_path, monkeypatch, sigint_raises):
    """Ctrl-C arriving in the middle of writing an episode's files waits for them, then stops the run."""
    original = LeRobotWriter.save_episode

    def interrupted_save(self, episode_meta=None):
        os.kill(os.getpid(), signal.SIGINT)  # Python runs the handler at the next bytecode, inside the save
        return original(self, episode_meta)

    monkeypatch.setattr(LeRobotWriter, "save_episode", interrupted_save)
    root = tmp_path / "ds"
    try:
        summary = collect(root, small_spec(steps=30), episodes=3)
    except KeyboardInterrupt:
        pytest.fail("collect() let Ctrl-C escape instead of stopping after the saved episodes")
    assert summary.interrupted
    assert (summary.episodes_added, summary.episodes_total, summary.frames_total) == (1, 1, 30)
    reader = LeRobotReader(root)
    assert reader.num_episodes == 1 and reader.episodes[0]["seed"] == 0
    assert parquet_files(root, "data") == ["data/chunk-000/file-000.parquet"]
    assert not list(root.rglob("*.dpr-tmp"))
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
