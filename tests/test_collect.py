"""Dataset collection (dpr.datasets.collect), replay (dpr.datasets.replay) and the `dpr collect` / `dpr replay`
commands: recorded frames equal an independent rollout, resuming, refusing another spec, MCAP logs, pixels, discrete
actions and bad command-line input (killed or interrupted: test_collect_interrupts.py)."""

import json
import shutil
from pathlib import Path

import gymnasium as gym
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from helpers import change_a_reward, parquet_files, run_cli, tree_hash, write_stats

import dpr.datasets.collect as collect_module
from dpr.datasets.collect import CollectSpec, collect
from dpr.datasets.lerobot import DatasetError, LeRobotReader
from dpr.datasets.mcap import read_mcap
from dpr.datasets.replay import replay_dataset
from dpr.envs.particle_env import LENGTH_SCALE
from dpr.policies import registry

REPO = Path(__file__).resolve().parents[1]
NAV = "dpr/Navigation-v0"
SMALL = {"env_id": NAV, "n_robots": 4, "robot_model": "disk", "steps": 40}
COLUMNS = ("observation.state", "action", "next.reward", "next.done", "next.success")


# ------------------------------------------------------------------------------------------------- helpers


def small_spec(**overrides) -> CollectSpec:
    return CollectSpec(**{**SMALL, **overrides})


def reference_rollout(env_id: str, env_kwargs: dict, policy_name: str, seed: int, render: bool = False) -> dict:
    """Roll ``policy_name`` out independently of collect(): gym.make, reset(seed), the registry's policy."""
    env = gym.make(env_id, **env_kwargs)
    try:
        observation, _ = env.reset(seed=seed)
        policy = registry.make_policy(policy_name, env)
        policy.reset(seed)
        frames: dict[str, list] = {name: [] for name in (*COLUMNS, "observation.image")}
        done, info = False, {}
        while not done:
            if render:
                frames["observation.image"].append(env.render())
            action = policy(observation)
            frames["observation.state"].append(observation)
            frames["action"].append(action)
            observation, reward, terminated, truncated, info = env.step(action)
            done = terminated or truncated
            frames["next.reward"].append([reward])
            frames["next.done"].append([done])
            frames["next.success"].append([info["is_success"]])
        return {
            "observation.state": np.array(frames["observation.state"], dtype=np.float32),
            "action": np.array(frames["action"]),
            "next.reward": np.array(frames["next.reward"], dtype=np.float32),
            "next.done": np.array(frames["next.done"], dtype=bool),
            "next.success": np.array(frames["next.success"], dtype=bool),
            "observation.image": np.array(frames["observation.image"], dtype=np.uint8),
            "final_info": info,
            "task": env.unwrapped.task_description,
        }
    finally:
        env.close()


def snapshot(root: Path) -> dict[str, tuple[bytes, int] | None]:
    """Every folder and file under ``root`` with each file's bytes and mtime."""
    return {
        str(p.relative_to(root)): (p.read_bytes(), p.stat().st_mtime_ns) if p.is_file() else None
        for p in sorted(root.rglob("*"))
    }


@pytest.fixture(scope="module")
def small_dataset(tmp_path_factory) -> Path:
    """Two wave-policy episodes (seeds 0, 1) of the small spec; tests must leave it unchanged."""
    root = tmp_path_factory.mktemp("small") / "ds"
    summary = collect(root, small_spec(), episodes=2)
    assert summary.episodes_added == 2 and not summary.interrupted
    return root


# ----------------------------------------------------------------------------------------------- round trip


def test_recorded_frames_equal_an_independent_rollout(small_dataset):
    reader = LeRobotReader(small_dataset)
    assert reader.num_episodes == 2
    spec = small_spec()
    for index, meta in enumerate(reader.episodes):
        assert meta["seed"] == index
        assert meta["env_id"] == NAV
        assert meta["env_kwargs"] == {"n_robots": 4, "robot_model": "disk", "max_episode_steps": 40}
        assert meta["env_kwargs"] == spec.make_kwargs()
        assert (meta["policy"], meta["n_robots"], meta["robot_model"]) == ("wave", 4, "disk")
        assert meta["mcap_file"] == "" and meta["physics_error"] == ""

        expected = reference_rollout(meta["env_id"], meta["env_kwargs"], meta["policy"], meta["seed"])
        recorded = reader.episode(index)
        frames = len(expected["action"])
        assert meta["length"] == frames == 40  # no success within 40 steps: the time limit ends it
        shapes = {
            "observation.state": ((frames, 24), np.float32),
            "action": ((frames, 4), np.float32),
            "next.reward": ((frames, 1), np.float32),
            "next.done": ((frames, 1), np.bool_),
            "next.success": ((frames, 1), np.bool_),
        }
        for name, (shape, dtype) in shapes.items():
            assert recorded[name].shape == shape, name
            assert recorded[name].dtype == dtype, name
            np.testing.assert_array_equal(recorded[name], expected[name].astype(dtype), err_msg=name)

        final = expected["final_info"]
        for metric in ("projected_displacement", "net_displacement", "total_distance"):
            assert meta[metric] == pytest.approx(final[metric], rel=1e-9, abs=1e-9), metric
        assert meta["success"] == bool(final["is_success"])
        assert meta["tasks"] == [expected["task"]]
        assert (recorded["task_index"] == 0).all()

    env = gym.make(NAV, **spec.make_kwargs())
    assert reader.tasks == [env.unwrapped.task_description]
    env.close()
    assert reader.tasks[0]  # a real sentence, not an empty placeholder
    features = reader.features
    assert features["observation.state"]["dtype"] == "float32" and features["observation.state"]["shape"] == [24]
    parts = ("x", "y", "vx", "vy", "omega", "expansion")
    assert features["observation.state"]["names"][:6] == [f"robot0.{part}" for part in parts]
    assert features["action"] == {"dtype": "float32", "shape": [4], "names": [f"robot{i}.expand" for i in range(4)]}
    for flag in ("next.done", "next.success"):
        assert features[flag]["dtype"] == "bool" and features[flag]["shape"] == [1]
    assert reader.info["dpr"] == {
        "env_id": NAV,
        "policy": "wave",
        "env_kwargs": spec.make_kwargs(),
        "mcap": False,
        "robot_model_revision": 2,  # the disk model's physics since force-limited growth
    }
    assert reader.info["robot_type"] == "disk" and reader.fps == 10


def test_replay_reports_every_episode_equal(small_dataset):
    checks = replay_dataset(small_dataset)
    assert [(c.episode_index, c.seed, c.frames, c.equal, c.first_mismatch) for c in checks] == [
        (0, 0, 40, True, None),
        (1, 1, 40, True, None),
    ]
    assert all(v == 0.0 for c in checks for v in c.max_abs_difference.values())


def test_replay_finds_the_first_tampered_frame(small_dataset, monkeypatch):
    original = LeRobotReader.episode

    def tampered(self, index, columns=None):
        data = {name: array.copy() for name, array in original(self, index, columns).items()}
        if index == 1:
            data["observation.state"][23, 7] += np.float32(1e-6)  # robot 1's y, by a few float32 steps
            data["next.reward"][31, 0] += np.float32(0.5)
        return data

    monkeypatch.setattr(LeRobotReader, "episode", tampered)
    checks = replay_dataset(small_dataset)
    assert checks[0].equal and checks[0].first_mismatch is None
    assert not checks[1].equal
    assert checks[1].first_mismatch == 23
    assert checks[1].max_abs_difference["observation.state"] > 0
    assert checks[1].max_abs_difference["next.reward"] == pytest.approx(0.5, rel=1e-3)
    assert checks[1].max_abs_difference["next.done"] == checks[1].max_abs_difference["next.success"] == 0.0


def test_a_data_file_from_another_episode_is_refused(small_dataset, tmp_path):
    """An episode whose data file was replaced by another episode's is refused when read, not replayed."""
    other = tmp_path / "other"
    collect(other, small_spec(), episodes=1, seed=5)
    tampered = tmp_path / "tampered"
    shutil.copytree(small_dataset, tampered)
    data_file = "data/chunk-000/file-001.parquet"
    shutil.copyfile(other / "data/chunk-000/file-000.parquet", tampered / data_file)
    reader = LeRobotReader(tampered)
    reader.episode(0)
    with pytest.raises(DatasetError, match=r"file-001.parquet: holds rows of episode\(s\) \[0\] where episode 1"):
        reader.episode(1)


def test_a_changed_value_fails_its_checksum(small_dataset, tmp_path):
    """A value changed in place fails the episode's checksum when read, naming the column."""
    tampered = tmp_path / "tampered"
    shutil.copytree(small_dataset, tampered)
    change_a_reward(tampered / "data/chunk-000/file-001.parquet")
    reader = LeRobotReader(tampered)
    original = LeRobotReader(small_dataset).episode(1)["action"]
    np.testing.assert_array_equal(reader.episode(1, ["action"])["action"], original)  # other columns still read
    with pytest.raises(DatasetError, match="episode 1: column 'next.reward' does not match its checksum"):
        reader.episode(1)


def test_cli_replay_good_dataset(small_dataset, capsys):
    assert run_cli(["replay", str(small_dataset)]) == 0
    out = capsys.readouterr().out
    assert "2/2 episodes replay bit-identically (80 frames)" in out
    assert run_cli(["replay", str(small_dataset), "--episodes", "1"]) == 0
    assert "1/1 episodes replay bit-identically (40 frames)" in capsys.readouterr().out


def test_cli_replay_reports_a_mismatch(small_dataset, monkeypatch, capsys):
    original = LeRobotReader.episode

    def tampered(self, index, columns=None):
        data = {name: array.copy() for name, array in original(self, index, columns).items()}
        if index == 0:
            data["next.done"][12, 0] = True
        return data

    monkeypatch.setattr(LeRobotReader, "episode", tampered)
    assert run_cli(["replay", str(small_dataset)]) == 1
    out = capsys.readouterr().out
    assert "episode 0 (seed 0): differs from frame 12 on" in out
    assert "1/2 episodes replay bit-identically" in out


# ---------------------------------------------------------------------------------------------------- resume


def test_resume_adds_only_missing_seeds_and_keeps_saved_files(tmp_path):
    root = tmp_path / "ds"
    spec = small_spec(steps=30)
    first = collect(root, spec, episodes=2)
    assert (first.episodes_before, first.episodes_added, first.episodes_total) == (0, 2, 2)
    names = [*parquet_files(root, "data"), *parquet_files(root, "meta/episodes")]
    saved = {name: (root / name).read_bytes() for name in names}
    assert len(saved) == 4

    second = collect(root, spec, episodes=4)
    assert (second.episodes_before, second.episodes_added, second.episodes_total) == (2, 2, 4)
    assert second.frames_total == 120
    reader = LeRobotReader(root)
    assert [int(e["seed"]) for e in reader.episodes] == [0, 1, 2, 3]
    for name, content in saved.items():
        assert (root / name).read_bytes() == content, name
    assert all(c.equal for c in replay_dataset(root))

    before = snapshot(root)
    third = collect(root, spec, episodes=4)  # nothing left to do
    assert third.episodes_added == 0 and third.episodes_total == 4
    assert snapshot(root) == before


def test_resume_with_another_first_seed_skips_recorded_seeds(tmp_path):
    root = tmp_path / "ds"
    spec = small_spec(steps=30)
    collect(root, spec, episodes=2, seed=0)
    summary = collect(root, spec, episodes=3, seed=1)  # seeds 1, 2, 3: 1 is already there
    assert summary.episodes_added == 2
    assert [int(e["seed"]) for e in LeRobotReader(root).episodes] == [0, 1, 2, 3]


@pytest.mark.parametrize(
    "change",
    [
        {"env_id": "dpr/Unresponsive-v0"},
        {"n_robots": 9},
        {"policy": "random"},
        {"pixels": True, "image_size": 16},
        {"robot_model": "paddle"},
        {"steps": 41},
        {"env_kwargs": {"reward": "projected"}},
        {"mcap": True},
    ],
    ids=lambda change: ",".join(change),
)
def test_another_spec_is_refused_before_any_work(small_dataset, change, monkeypatch):
    def no_rollouts(job):
        raise AssertionError("a refused dataset must not start rollouts")

    monkeypatch.setattr(collect_module, "_rollout_job", no_rollouts)
    before = snapshot(small_dataset)
    with pytest.raises(DatasetError, match="does not match"):
        collect(small_dataset, small_spec(**change), episodes=3)
    assert snapshot(small_dataset) == before


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"n_robots": 5}, "feature 'observation.state' has shape [24] in the dataset, [30] requested"),
        ({"robot_model": "paddle"}, "robot_type is 'disk' in the dataset, 'paddle' requested"),
        ({"env_id": "dpr/Gate-v0"}, "dpr/Gate-v0"),
        ({"pixels": True, "image_size": 16}, "features are"),
    ],
    ids=["n_robots", "robot_model", "env", "features"],
)
def test_a_refused_resume_deletes_nothing(small_dataset, tmp_path, change, message):
    """A killed run's leftovers (an uncommitted episode's files, temp files) are what a resume cleans up; a
    resume with other settings is refused before that, and every byte stays as it was."""
    root = tmp_path / "ds"
    shutil.copytree(small_dataset, root)
    shutil.copy(root / "data/chunk-000/file-001.parquet", root / "data/chunk-000/file-002.parquet")
    meta = pq.read_table(root / "meta/episodes/chunk-000/file-001.parquet")
    meta = meta.set_column(0, "episode_index", pa.array([2], pa.int64()))  # as if saved, then killed before info.json
    pq.write_table(meta, root / "meta/episodes/chunk-000/file-002.parquet")
    (root / "data/chunk-000/.file-003.parquet.1.dpr-tmp").write_bytes(b"half")
    (root / "meta/.info.json.1.dpr-tmp").write_bytes(b"{")
    before = tree_hash(root)
    with pytest.raises(DatasetError, match="does not match") as refused:
        collect(root, small_spec(**change), episodes=3)
    assert message in str(refused.value) and "meta/info.json" in str(refused.value)
    assert tree_hash(root) == before
    summary = collect(root, small_spec(), episodes=3)  # the same settings resume and clean up
    assert (summary.episodes_before, summary.episodes_total) == (2, 3)
    assert not list(root.rglob("*.dpr-tmp"))


def test_collect_compact_packs_the_dataset_and_resumes(small_dataset, tmp_path):
    root = tmp_path / "ds"
    summary = collect(root, small_spec(), episodes=3, compact=True)
    assert summary.episodes_total == 3
    assert parquet_files(root, "data") == ["data/chunk-000/file-000.parquet"]
    assert parquet_files(root, "meta/episodes") == ["meta/episodes/chunk-000/file-000.parquet"]
    assert not (root / "meta/.dpr-writer.lock").exists()
    summary = collect(root, small_spec(), episodes=4, compact=True)  # resumes: seed 3 only
    assert (summary.episodes_added, summary.episodes_total) == (1, 4)
    assert parquet_files(root, "data") == ["data/chunk-000/file-000.parquet"]
    reader, recorded = LeRobotReader(root), LeRobotReader(small_dataset)
    for index in range(2):  # seeds 0 and 1, as in the uncompacted dataset
        for name in COLUMNS:
            np.testing.assert_array_equal(reader.episode(index)[name], recorded.episode(index)[name])
    assert all(check.equal for check in replay_dataset(root))


def test_cli_collect_compact(tmp_path):
    root = tmp_path / "ds"
    argv = ["collect", "--env", "dpr/Navigation-v0", "--robot-model", "disk", "--n-robots", "4", "--steps", "8"]
    assert run_cli([*argv, "--episodes", "3", "--workers", "1", "--out", str(root), "--compact"]) == 0
    assert parquet_files(root, "data") == ["data/chunk-000/file-000.parquet"]
    assert LeRobotReader(root).num_episodes == 3


# -------------------------------------------------------------------------------------------- MCAP, pixels


def test_mcap_log_per_episode_matches_the_dataset(tmp_path):
    root = tmp_path / "ds"
    collect(root, small_spec(mcap=True), episodes=1)
    stale = root / "mcap" / ".seed-000001.mcap.123.abcd1234.dpr-tmp"  # a log a killed run had in flight
    stale.write_bytes(b"partial")
    collect(root, small_spec(mcap=True), episodes=2)
    assert not stale.exists()
    assert sorted(p.name for p in (root / "mcap").iterdir()) == ["seed-000000.mcap", "seed-000001.mcap"]

    reader = LeRobotReader(root)
    for index, meta in enumerate(reader.episodes):
        assert meta["mcap_file"] == f"mcap/seed-{index:06d}.mcap"
        log = read_mcap(root / meta["mcap_file"])
        data = reader.episode(index)
        frames = len(data["action"])
        assert log.n_steps == frames
        assert log.metadata["seed"] == index and log.metadata["policy"] == "wave"
        np.testing.assert_array_equal(log.actions, data["action"])
        np.testing.assert_array_equal(log.rewards.astype(np.float32), data["next.reward"][:, 0])
        # frame t's observation is the state before action t: x, y = (position - goal) * LENGTH_SCALE
        state = data["observation.state"].reshape(frames, 4, 6)
        np.testing.assert_array_equal(log.goal, [0.0, 0.0])
        expected_xy = ((log.positions[:-1] - log.goal) * LENGTH_SCALE).astype(np.float32)
        np.testing.assert_array_equal(state[:, :, 0:2], expected_xy)
        np.testing.assert_array_equal(state[:, :, 5], log.expansions[:-1].astype(np.float32))


def test_pixels_record_the_rendered_frames(tmp_path):
    root = tmp_path / "ds"
    collect(root, small_spec(steps=30, pixels=True, image_size=32), episodes=1, seed=3)
    reader = LeRobotReader(root)
    assert reader.features["observation.image"]["dtype"] == "image"
    assert reader.features["observation.image"]["shape"] == [32, 32, 3]
    data = reader.episode(0)
    assert data["observation.image"].dtype == np.uint8 and data["observation.image"].shape == (30, 32, 32, 3)

    kwargs = {
        "n_robots": 4,
        "robot_model": "disk",
        "max_episode_steps": 30,
        "render_mode": "rgb_array",
        "render_size": 32,
    }
    assert reader.episodes[0]["env_kwargs"] == kwargs
    expected = reference_rollout(NAV, kwargs, "wave", 3, render=True)
    np.testing.assert_array_equal(data["observation.image"], expected["observation.image"])
    assert len(np.unique(data["observation.image"].reshape(-1, 3), axis=0)) > 2  # a scene, not a blank frame
    np.testing.assert_array_equal(data["observation.state"], expected["observation.state"])
    assert replay_dataset(root)[0].equal


def test_discrete_actions_are_recorded_as_int64(tmp_path, capsys):
    root = tmp_path / "ds"
    argv = [
        "collect",
        "--env",
        NAV,
        "--robot-model",
        "disk",
        "--n-robots",
        "4",
        "--steps",
        "40",
        "--episodes",
        "2",
        "--workers",
        "1",
        "--env-kwarg",
        "action_type=discrete",
        "--out",
        str(root),
    ]
    assert run_cli(argv) == 0
    reader = LeRobotReader(root)
    assert reader.features["action"] == {"dtype": "int64", "shape": [1], "names": ["action"]}
    assert reader.episodes[0]["env_kwargs"]["action_type"] == "discrete"
    for index in range(2):
        action = reader.episode(index, ["action"])["action"]
        assert action.dtype == np.int64 and action.shape == (40, 1)
        assert ((0 <= action) & (action < 16)).all() and len(np.unique(action)) > 1
        expected = reference_rollout(NAV, reader.episodes[index]["env_kwargs"], "wave", index)
        np.testing.assert_array_equal(action[:, 0], expected["action"])
    assert all(c.equal for c in replay_dataset(root))
    capsys.readouterr()
    assert run_cli(["replay", str(root)]) == 0
    assert "2/2 episodes replay bit-identically" in capsys.readouterr().out


# --------------------------------------------------------------------------------------------- bad input


def collect_argv(out: Path, *extra: str) -> list[str]:
    return [
        "collect",
        "--env",
        NAV,
        "--robot-model",
        "disk",
        "--n-robots",
        "4",
        "--steps",
        "20",
        "--episodes",
        "1",
        "--workers",
        "1",
        "--out",
        str(out),
        *extra,
    ]


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--env", "dpr/Nope-v0"], "dpr/Nope-v0"),
        (["--policy", "nope"], "policy"),
        (["--episodes", "0"], "--episodes"),
        (["--seed", "-1"], "--seed"),
        (["--n-robots", "0"], "--n-robots"),
        (["--env-kwarg", "badformat"], "--env-kwarg"),
        (["--env-kwarg", "n_robots=3"], "n_robots"),
        (["--env-kwarg", "action_type=bogus"], "action_type"),
        (["--env-kwarg", "no_such_kwarg=1"], "no_such_kwarg"),
    ],
    ids=lambda value: value if isinstance(value, str) else " ".join(value),
)
def test_cli_collect_refuses_bad_arguments(tmp_path, capsys, extra, message):
    out = tmp_path / "ds"
    assert run_cli(collect_argv(out, *extra)) == 2
    error = capsys.readouterr().err
    assert message in error and "Traceback" not in error
    assert not out.exists()


def test_cli_collect_records_the_markov_wave_with_the_last_action_it_reads(tmp_path, capsys):
    """`--policy wave-markov` (or a Markov-wave labeller) sets obs_last_action=True where no flag does, and says so;
    obs_last_action=false is refused with the flag that fixes it and the command's own usage."""
    for name, extra in (
        ("drive", ["--policy", "wave-markov"]),
        ("label", ["--label-policy", "wave-markov:hold_steps=5"]),
    ):
        assert run_cli(collect_argv(tmp_path / name, *extra)) == 0, name
        assert "recording with obs_last_action=True" in capsys.readouterr().err
        assert LeRobotReader(tmp_path / name).episodes[0]["env_kwargs"]["obs_last_action"] is True
    out = tmp_path / "plain"
    assert run_cli(collect_argv(out, "--policy", "wave-markov", "--env-kwarg", "obs_last_action=false")) == 2
    error = capsys.readouterr().err
    assert "usage: dpr collect " in error and "dpr collect: error: --policy wave-markov reads the previous" in error
    assert "needs --env-kwarg obs_last_action=true (got obs_last_action=False)" in error
    assert not out.exists()


def test_cli_collect_refuses_a_file_as_out(tmp_path, capsys):
    out = tmp_path / "file"
    out.write_text("keep me")
    assert run_cli(collect_argv(out)) == 2
    assert "--out" in capsys.readouterr().err
    assert out.read_text() == "keep me"


def test_cli_collect_refuses_a_folder_without_a_dataset(tmp_path, capsys):
    out = tmp_path / "ds"
    out.mkdir()
    (out / "notes.txt").write_text("not a dataset")
    before = snapshot(out)
    assert run_cli(collect_argv(out)) == 2
    error = capsys.readouterr().err
    assert str(out / "meta" / "info.json") in error and "holds no dataset" in error
    assert snapshot(out) == before


def test_cli_collect_refuses_another_spec(small_dataset, capsys):
    before = snapshot(small_dataset)
    assert run_cli(collect_argv(small_dataset)) == 2  # 20 steps where the dataset has 40
    assert "does not match" in capsys.readouterr().err
    assert snapshot(small_dataset) == before


def test_cli_replay_refuses_a_corrupt_info_json(small_dataset, tmp_path, capsys):
    root = tmp_path / "ds"
    shutil.copytree(small_dataset, root)
    info = root / "meta" / "info.json"
    info.write_text(info.read_text()[:50])
    before = snapshot(root)
    assert run_cli(["replay", str(root)]) == 2
    error = capsys.readouterr().err
    assert str(info) in error and "not valid JSON" in error
    assert snapshot(root) == before


def test_cli_replay_refuses_missing_folder_and_episodes(small_dataset, tmp_path, capsys):
    assert run_cli(["replay", str(tmp_path / "absent")]) == 2
    assert str(tmp_path / "absent") in capsys.readouterr().err
    assert run_cli(["replay", str(small_dataset), "--episodes", "0-2"]) == 2
    assert "--episodes: [2] are not in the dataset" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ("not a dict", "entry 'action' must be an object of stats"),
        ({"mean": "big"}, "action/mean must be numbers"),
        ({"mean": [1.0, float("inf")]}, "action/mean holds non-finite values"),
        ({"mean": [[1.0], [2.0]]}, r"action/mean has shape \(2, 1\), the feature's is"),
    ],
)
def test_a_malformed_stats_entry_is_one_clear_error(small_dataset, tmp_path, entry, message):
    tampered = tmp_path / "tampered"
    shutil.copytree(small_dataset, tampered)
    stats = json.loads((tampered / "meta/stats.json").read_text())
    stats["action"] = entry
    write_stats(tampered, stats)
    with pytest.raises(DatasetError, match=message):
        LeRobotReader(tampered)


def test_verify_catches_wrong_stats(small_dataset, tmp_path):
    """stats.json with wrong numbers (valid JSON, right shapes) fails the verification against the meta rows."""
    tampered = tmp_path / "tampered"
    shutil.copytree(small_dataset, tampered)
    stats = json.loads((tampered / "meta/stats.json").read_text())
    stats["next.reward"]["mean"] = [123.0]
    write_stats(tampered, stats)
    with pytest.raises(DatasetError, match="next.reward/mean is not the aggregate of the episodes' stats"):
        LeRobotReader(tampered).verify()
    assert LeRobotReader(small_dataset).verify() == 80


def test_collect_verify_names_a_corrupt_file(small_dataset, tmp_path, capsys):
    tampered = tmp_path / "tampered"
    shutil.copytree(small_dataset, tampered)
    change_a_reward(tampered / "data/chunk-000/file-000.parquet")
    argv = ["collect", "--env", NAV, "--robot-model", "disk", "--n-robots", "4", "--steps", "40", "--episodes", "2"]
    assert run_cli([*argv, "--workers", "1", "--out", str(tampered), "--verify"]) == 2
    err = capsys.readouterr().err  # (refused before resuming onto it: test_resume_checks.py)
    assert "error:" in err and "file-000.parquet: episode 0: column 'next.reward' does not match its checksum" in err
    from dpr.cli.data import verify_dataset

    assert verify_dataset(tampered) == 2
    err = capsys.readouterr().err
    assert "verify:" in err and "file-000.parquet: episode 0: column 'next.reward' does not match its checksum" in err


def test_a_compaction_that_freed_space_says_so():
    from dpr.datasets.collect_summary import CollectSummary, format_summary

    summary = CollectSummary("ds", "dpr/Navigation-v0", "wave", 3, 0, 3, 0, 30, 1.5, -1_607_636, False, {})
    text = format_summary(summary)
    assert "freed       1.5 MiB" in text or "freed       1.6 MB" in text, text
    assert "-" not in text.split("freed")[1].split("\n")[0]


def test_evaluate_runs_the_markov_wave_with_the_observation_it_needs(tmp_path, capsys):
    """As `dpr collect` does: obs_last_action is turned on, said, and recorded in the evaluation file."""
    out = tmp_path / "markov.json"
    argv = ["evaluate", "--policy", "wave-markov", "--env", "dpr/Navigation-v0", "--seeds", "1", "--steps", "20"]
    assert run_cli([*argv, "--json", str(out)]) == 0
    assert "dpr evaluate: --policy wave-markov reads" in capsys.readouterr().err
    assert json.loads(out.read_text())["env_kwargs"]["obs_last_action"] is True
    assert run_cli([*argv, "--env-kwarg", "obs_last_action=false"]) == 2
    assert "it needs --env-kwarg obs_last_action=true" in capsys.readouterr().err
