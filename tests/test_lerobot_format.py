"""LeRobot v3.0 writer/reader (dpr.datasets.lerobot): exact round trips, layout, stats, bad input (resume and crash
safety: test_lerobot_resume.py)."""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from dpr.datasets.lerobot import (
    CODEBASE_VERSION,
    IMAGE_STATS_MAX_FRAMES,
    DatasetError,
    LeRobotReader,
    LeRobotWriter,
    default_features,
)
from dpr.policies.wave import WavePolicy

H, W = 8, 6  # non-square, so a height/width swap cannot pass
FEATURES = {
    "observation.state": {"dtype": "float32", "shape": [5], "names": None},
    "action": {"dtype": "float32", "shape": [3], "names": None},
    "next.reward": {"dtype": "float32", "shape": [1], "names": None},
    "next.done": {"dtype": "bool", "shape": [1], "names": None},
    "next.success": {"dtype": "bool", "shape": [1], "names": None},
    "observation.image": {"dtype": "image", "shape": [H, W, 3], "names": ["height", "width", "channels"]},
}
VECTOR_FEATURES = {k: v for k, v in FEATURES.items() if v["dtype"] != "image"}
INFO_EXTRA = {"dpr": {"env_id": "dpr/Navigation-v0"}}


def make_episode(rng: np.random.Generator, length: int, features: dict = FEATURES) -> dict[str, np.ndarray]:
    """Random frames for every feature, shaped [T, *shape] in the feature's dtype."""
    out = {}
    for name, spec in features.items():
        shape = (length, *spec["shape"])
        if spec["dtype"] == "image":
            out[name] = rng.integers(0, 256, shape, dtype=np.uint8)
        elif spec["dtype"] == "bool":
            out[name] = rng.random(shape) < 0.5
        else:
            out[name] = rng.standard_normal(shape).astype(spec["dtype"])
    return out


def add_episode(writer: LeRobotWriter, episode: dict[str, np.ndarray], tasks) -> None:
    length = len(next(iter(episode.values())))
    for t in range(length):
        task = tasks if isinstance(tasks, str) else tasks[t]
        writer.add_frame({name: values[t] for name, values in episode.items()}, task=task)


def write_dataset(root: Path, episodes: list[dict], features: dict = FEATURES, metas=None, **kwargs) -> None:
    with LeRobotWriter.create(root, fps=10, features=features, robot_type="disk", info_extra=INFO_EXTRA, **kwargs) as w:
        for i, episode in enumerate(episodes):
            add_episode(w, episode, "navigate")
            w.save_episode(None if metas is None else metas[i])


def snapshot(root: Path) -> dict[str, tuple[bytes, int]]:
    return {str(p.relative_to(root)): (p.read_bytes(), p.stat().st_mtime_ns) for p in root.rglob("*") if p.is_file()}


# ------------------------------------------------------------------------------------------------ round trips


def test_exact_round_trip_of_every_dtype_and_shape(tmp_path):
    rng = np.random.default_rng(0)
    episodes = [make_episode(rng, 7), make_episode(rng, 4)]
    write_dataset(tmp_path / "ds", episodes)
    reader = LeRobotReader(tmp_path / "ds")
    assert (reader.num_episodes, reader.num_frames, reader.fps) == (2, 11, 10)
    for index, expected in enumerate(episodes):
        got = reader.episode(index)
        for name, values in expected.items():
            assert got[name].dtype == values.dtype, name
            assert got[name].shape == values.shape, name
            np.testing.assert_array_equal(got[name], values, err_msg=name)
    # only some columns
    part = reader.episode(1, columns=["action"])
    assert list(part) == ["action"]
    with pytest.raises(DatasetError, match="nope"):
        reader.episode(0, columns=["nope"])
    with pytest.raises(IndexError):
        reader.episode(2)


def test_on_disk_layout_matches_lerobot_v3(tmp_path):
    rng = np.random.default_rng(1)
    write_dataset(tmp_path / "ds", [make_episode(rng, 3), make_episode(rng, 2)])
    root = tmp_path / "ds"
    info = json.loads((root / "meta/info.json").read_text())
    assert info["codebase_version"] == CODEBASE_VERSION == "v3.0"
    assert (info["total_episodes"], info["total_frames"], info["total_tasks"]) == (2, 5, 1)
    assert info["splits"] == {"train": "0:2"} and info["fps"] == 10 and info["robot_type"] == "disk"
    assert info["chunks_size"] == 1000 and info["video_path"] is None and info["dpr"] == INFO_EXTRA["dpr"]
    assert list(info["features"]) == [*FEATURES, *default_features()]
    schema = pq.read_schema(root / "data/chunk-000/file-001.parquet")
    assert str(schema.field("observation.state").type) == "fixed_size_list<element: float>[5]"
    assert str(schema.field("next.reward").type) == "float"  # shape [1] is a scalar column
    assert str(schema.field("next.done").type) == "bool"
    assert str(schema.field("observation.image").type) == "struct<bytes: binary, path: string>"
    assert str(schema.field("timestamp").type) == "float" and str(schema.field("index").type) == "int64"
    episodes = pq.read_table(root / "meta/episodes/chunk-000/file-001.parquet").to_pylist()
    assert len(episodes) == 1
    row = episodes[0]
    assert (row["episode_index"], row["length"], row["dataset_from_index"], row["dataset_to_index"]) == (1, 2, 3, 5)
    assert (row["data/chunk_index"], row["data/file_index"]) == (0, 1)
    assert (row["meta/episodes/chunk_index"], row["meta/episodes/file_index"]) == (0, 1)
    assert row["tasks"] == ["navigate"]
    assert np.asarray(row["stats/observation.image/mean"]).shape == (3, 1, 1)
    image = pq.read_table(root / "data/chunk-000/file-000.parquet").column("observation.image")[0].as_py()
    assert image["bytes"][:8] == b"\x89PNG\r\n\x1a\n"


def test_default_columns(tmp_path):
    rng = np.random.default_rng(2)
    lengths = [5, 3, 4]
    write_dataset(tmp_path / "ds", [make_episode(rng, n) for n in lengths])
    reader = LeRobotReader(tmp_path / "ds")
    everything = reader.frame_range(0, reader.num_frames)
    np.testing.assert_array_equal(everything["index"][:, 0], np.arange(sum(lengths)))
    frame_index = np.concatenate([np.arange(n) for n in lengths])
    np.testing.assert_array_equal(everything["frame_index"][:, 0], frame_index)
    np.testing.assert_array_equal(everything["episode_index"][:, 0], np.repeat(np.arange(3), lengths))
    assert everything["timestamp"].dtype == np.float32
    np.testing.assert_array_equal(everything["timestamp"][:, 0], (frame_index / 10).astype(np.float32))
    np.testing.assert_array_equal(everything["task_index"], 0)
    starts = [e["dataset_from_index"] for e in reader.episodes]
    assert starts == [0, 5, 8]


def test_frame_range_and_iter_episodes(tmp_path):
    rng = np.random.default_rng(3)
    episodes = [make_episode(rng, n) for n in (4, 6, 3)]
    write_dataset(tmp_path / "ds", episodes)
    reader = LeRobotReader(tmp_path / "ds")
    all_state = np.concatenate([e["observation.state"] for e in episodes])
    all_image = np.concatenate([e["observation.image"] for e in episodes])
    part = reader.frame_range(2, 11, columns=["observation.state", "observation.image"])
    np.testing.assert_array_equal(part["observation.state"], all_state[2:11])
    np.testing.assert_array_equal(part["observation.image"], all_image[2:11])
    assert reader.frame_range(5, 5)["action"].shape == (0, 3)
    with pytest.raises(IndexError):
        reader.frame_range(0, reader.num_frames + 1)
    seen = [e["episode_index"][0, 0] for e in reader.iter_episodes(columns=["episode_index"])]
    assert seen == [0, 1, 2]


def test_tasks_and_pandas_layout(tmp_path):
    rng = np.random.default_rng(4)
    root = tmp_path / "ds"
    with LeRobotWriter.create(root, fps=10, features=FEATURES, robot_type="disk") as w:
        add_episode(w, make_episode(rng, 4), ["push", "push", "reach", "push"])
        w.save_episode()
        add_episode(w, make_episode(rng, 2), ["carry", "reach"])
        w.save_episode()
    reader = LeRobotReader(root)
    assert reader.tasks == ["push", "reach", "carry"]
    assert [e["tasks"] for e in reader.episodes] == [["push", "reach"], ["carry", "reach"]]
    np.testing.assert_array_equal(reader.frame_range(0, 6)["task_index"][:, 0], [0, 0, 1, 0, 2, 1])
    frame = pd.read_parquet(root / "meta/tasks.parquet")  # what LeRobot does: the task string is the index
    assert list(frame.index) == ["push", "reach", "carry"]
    assert list(frame["task_index"]) == [0, 1, 2] and frame["task_index"].dtype == np.int64
    assert frame.iloc[2].name == "carry"
    assert b"pandas" in pq.read_schema(root / "meta/tasks.parquet").metadata


def test_episode_meta_extras_round_trip_and_are_checked(tmp_path):
    rng = np.random.default_rng(5)
    metas = [
        {
            "seed": 7,
            "env_id": "dpr/Navigation-v0",
            "env_kwargs": {"n_robots": 4, "start_radius": [450, 550]},
            "policy": "wave",
            "n_robots": 4,
            "robot_model": "disk",
            "success": True,
            "score": 1.5,
        },
        {
            "seed": np.int64(8),
            "env_id": "dpr/Gate-v0",
            "env_kwargs": {},
            "policy": "wave",
            "n_robots": 4,
            "robot_model": "disk",
            "success": False,
            "score": 2,
        },
    ]
    root = tmp_path / "ds"
    write_dataset(root, [make_episode(rng, 3), make_episode(rng, 2)], metas=metas)
    reader = LeRobotReader(root)
    first, second = reader.episodes
    assert first["env_kwargs"] == {"n_robots": 4, "start_radius": [450, 550]} and second["env_kwargs"] == {}
    assert (first["seed"], second["seed"], second["env_id"], second["score"]) == (7, 8, "dpr/Gate-v0", 2.0)
    assert first["success"] is True and isinstance(second["seed"], int)
    schema = pq.read_schema(root / "meta/episodes/chunk-000/file-000.parquet")
    assert str(schema.field("env_kwargs").type) == "string" and str(schema.field("seed").type) == "int64"

    with LeRobotWriter.open(root, fps=10, features=FEATURES, robot_type="disk", info_extra=INFO_EXTRA) as w:
        add_episode(w, make_episode(rng, 2), "navigate")
        with pytest.raises(DatasetError, match="same every episode"):
            w.save_episode({"seed": 1})
        with pytest.raises(DatasetError, match="seed"):
            w.save_episode({**metas[0], "seed": "not an int"})
        with pytest.raises(DatasetError, match="clashes"):
            w.save_episode({**metas[0], "length": 3})
        assert w.save_episode(metas[0]) == 2  # the failed attempts kept the buffer
    assert LeRobotReader(root).episodes[2]["env_kwargs"] == metas[0]["env_kwargs"]


# ---------------------------------------------------------------------------------------------------------- stats


def test_stats_match_numpy(tmp_path):
    rng = np.random.default_rng(6)
    episodes = [make_episode(rng, n) for n in (9, 5, 12)]
    root = tmp_path / "ds"
    write_dataset(root, episodes)
    reader = LeRobotReader(root)
    total = sum(len(e["action"]) for e in episodes)
    for name in VECTOR_FEATURES:
        data = np.concatenate([e[name] for e in episodes]).astype(np.float64)
        stats = reader.stats[name]
        assert stats["mean"].shape == (FEATURES[name]["shape"][0],)
        np.testing.assert_allclose(stats["mean"], data.mean(0), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(stats["std"], data.std(0), rtol=1e-10, atol=1e-12)
        np.testing.assert_array_equal(stats["min"], data.min(0))
        np.testing.assert_array_equal(stats["max"], data.max(0))
        assert stats["count"].tolist() == [total]
        weights = np.array([len(e[name]) for e in episodes], dtype=np.float64)
        for key, q in (("q01", 0.01), ("q50", 0.5), ("q99", 0.99)):
            per_episode = np.stack([np.quantile(e[name].astype(np.float64), q, axis=0) for e in episodes])
            np.testing.assert_allclose(reader.episode_stats(0)[name][key], per_episode[0], rtol=1e-12)
            expected = (per_episode * weights[:, None]).sum(0) / weights.sum()  # documented approximation
            np.testing.assert_allclose(stats[key], expected, rtol=1e-12, atol=1e-12)
    assert reader.stats["next.done"]["min"].dtype == bool  # bools keep boolean min/max, as in LeRobot
    np.testing.assert_array_equal(reader.stats["index"]["max"], [total - 1])
    # images: per channel in [0, 1], shape (3, 1, 1); all frames used since episodes are short
    assert all(len(e["action"]) <= IMAGE_STATS_MAX_FRAMES for e in episodes)
    pixels = np.concatenate([e["observation.image"] for e in episodes]).reshape(-1, 3) / 255.0
    image = reader.stats["observation.image"]
    assert image["mean"].shape == (3, 1, 1)
    np.testing.assert_allclose(image["mean"].ravel(), pixels.mean(0), rtol=1e-12)
    np.testing.assert_allclose(image["std"].ravel(), pixels.std(0), rtol=1e-10)
    np.testing.assert_array_equal(image["min"].ravel(), pixels.min(0))
    first = episodes[0]["observation.image"].reshape(-1, 3) / 255.0
    for key, q in (("q01", 0.01), ("q10", 0.1), ("q50", 0.5), ("q90", 0.9)):
        np.testing.assert_allclose(
            reader.episode_stats(0)["observation.image"][key].ravel(),
            np.quantile(first, q, axis=0),
            rtol=1e-12,
            atol=1e-15,
        )
    # stats.json is plain JSON a policy can normalise with
    on_disk = json.loads((root / "meta/stats.json").read_text())
    assert set(on_disk) == set(reader.features)
    assert set(on_disk["action"]) == {"min", "max", "mean", "std", "count", "q01", "q10", "q50", "q90", "q99"}


def test_image_stats_use_a_subsample_of_long_episodes(tmp_path):
    features = {"observation.image": FEATURES["observation.image"]}
    rng = np.random.default_rng(7)
    episode = make_episode(rng, IMAGE_STATS_MAX_FRAMES + 50, features)
    write_dataset(tmp_path / "ds", [episode], features=features)
    stats = LeRobotReader(tmp_path / "ds").episode_stats(0)["observation.image"]
    assert stats["count"].tolist() == [IMAGE_STATS_MAX_FRAMES]
    assert 0.0 <= stats["min"].min() <= stats["max"].max() <= 1.0


# --------------------------------------------------------------------------------------------------- bad input


def test_truncated_or_corrupt_parquet_is_reported_with_its_path(tmp_path):
    rng = np.random.default_rng(14)
    root = tmp_path / "ds"
    write_dataset(root, [make_episode(rng, 3), make_episode(rng, 3)])
    data = root / "data/chunk-000/file-001.parquet"
    data.write_bytes(data.read_bytes()[:-20])
    with pytest.raises(DatasetError, match="file-001.parquet") as excinfo:
        LeRobotReader(root)
    assert str(data) in str(excinfo.value)

    root2 = tmp_path / "ds2"
    write_dataset(root2, [make_episode(rng, 3)])
    meta = root2 / "meta/episodes/chunk-000/file-000.parquet"
    meta.write_bytes(b"PAR1 this is not a parquet file PAR1")
    with pytest.raises(DatasetError) as excinfo:
        LeRobotReader(root2)
    assert str(meta) in str(excinfo.value)

    root3 = tmp_path / "ds3"
    write_dataset(root3, [make_episode(rng, 3)])
    (root3 / "data/chunk-000/file-000.parquet").unlink()
    with pytest.raises(DatasetError, match="file not found"):
        LeRobotReader(root3)


@pytest.mark.parametrize("version", ["v2.1", "v3.1", "v4.0"])
def test_other_codebase_versions_are_refused(tmp_path, version):
    rng = np.random.default_rng(15)
    root = tmp_path / "ds"
    write_dataset(root, [make_episode(rng, 2)])
    info = json.loads((root / "meta/info.json").read_text())
    info["codebase_version"] = version
    (root / "meta/info.json").write_text(json.dumps(info))
    with pytest.raises(DatasetError, match=version.replace(".", r"\.")):
        LeRobotReader(root)
    with pytest.raises(DatasetError, match="info.json"):
        LeRobotWriter.open(root, fps=10, features=FEATURES, robot_type="disk", info_extra=INFO_EXTRA)


def test_bad_info_json_is_reported(tmp_path):
    with pytest.raises(DatasetError, match="not found"):
        LeRobotReader(tmp_path / "missing")
    root = tmp_path / "ds"
    (root / "meta").mkdir(parents=True)
    (root / "meta/info.json").write_text("{not json")
    with pytest.raises(DatasetError, match="info.json: not valid JSON"):
        LeRobotReader(root)
    (root / "meta/info.json").write_text(json.dumps({"codebase_version": "v3.0", "fps": 10}))
    with pytest.raises(DatasetError, match="missing required keys"):
        LeRobotReader(root)


def test_create_needs_a_new_or_empty_folder(tmp_path):
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "notes.txt").write_text("keep me")
    with pytest.raises(DatasetError, match="not empty"):
        LeRobotWriter.create(tmp_path / "full", fps=10, features=FEATURES, robot_type="disk")
    with pytest.raises(DatasetError, match="holds no dataset"):
        LeRobotWriter.open(tmp_path / "full", fps=10, features=FEATURES, robot_type="disk")
    assert sorted(p.name for p in (tmp_path / "full").iterdir()) == ["notes.txt"]
    (tmp_path / "empty").mkdir()
    LeRobotWriter.create(tmp_path / "empty", fps=10, features=FEATURES, robot_type="disk").finalize()
    assert (tmp_path / "empty/meta/info.json").exists()


@pytest.mark.parametrize(
    ("features", "message"),
    [
        ({"a/b": {"dtype": "float32", "shape": [2]}}, "'/'"),
        ({"x": {"dtype": "float32", "shape": [2, 2]}}, "1-D"),
        ({"x": {"dtype": "string", "shape": [1]}}, "dtype"),
        ({"img": {"dtype": "image", "shape": [8, 8]}}, r"\[H, W, 3\]"),
        ({"index": {"dtype": "int64", "shape": [1]}}, "default"),
        ({}, "non-empty"),
    ],
)
def test_bad_feature_specs_are_refused(tmp_path, features, message):
    with pytest.raises(DatasetError, match=message):
        LeRobotWriter.create(tmp_path / "ds", fps=10, features=features, robot_type="disk")
    assert not (tmp_path / "ds").exists()


def test_add_frame_checks_keys_shapes_and_dtypes(tmp_path):
    rng = np.random.default_rng(16)
    good = {name: values[0] for name, values in make_episode(rng, 1).items()}
    with LeRobotWriter.create(tmp_path / "ds", fps=10, features=FEATURES, robot_type="disk") as w:
        cases = [
            ({k: v for k, v in good.items() if k != "action"}, "action"),
            ({**good, "observation.velocity": np.zeros(3)}, "observation.velocity"),
            ({**good, "action": np.zeros(4, np.float32)}, "'action' expects shape"),
            ({**good, "action": np.array([0.1, 0.2, 0.3])}, "'action' expects float32"),
            ({**good, "next.done": np.array([2])}, "'next.done' expects bool"),
            ({**good, "action": np.array(["a", "b", "c"])}, "'action' expects float32"),
            ({**good, "observation.image": good["observation.image"].astype(np.float32)}, "'observation.image'"),
            ({**good, "observation.image": good["observation.image"].transpose(1, 0, 2)}, "'observation.image'"),
        ]
        for frame, message in cases:
            with pytest.raises(DatasetError, match=message):
                w.add_frame(frame, task="navigate")
        with pytest.raises(DatasetError, match="task"):
            w.add_frame(good, task="")
        assert w.buffered_frames == 0  # nothing half-added
        # exact conversions are accepted: 0/1 ints for a float action, a Python float that float32 holds exactly,
        # a 0-d value for a shape-[1] feature
        w.add_frame(
            {**good, "action": np.array([0, 1, 1], np.int8), "next.reward": 0.5, "next.done": True}, task="navigate"
        )
        w.save_episode()
    got = LeRobotReader(tmp_path / "ds").episode(0)
    np.testing.assert_array_equal(got["action"], [[0.0, 1.0, 1.0]])
    np.testing.assert_array_equal(got["next.reward"], [[0.5]])
    np.testing.assert_array_equal(got["next.done"], [[True]])


def test_empty_episode_cannot_be_saved(tmp_path):
    with LeRobotWriter.create(tmp_path / "ds", fps=10, features=FEATURES, robot_type="disk") as w:
        with pytest.raises(DatasetError, match="no frames"):
            w.save_episode()


# ------------------------------------------------------------------------------------------- a real env rollout


def test_real_rollout_round_trip(tmp_path):
    env = gym.make("dpr/Navigation-v0", n_robots=4, robot_model="disk", obs_type="pixels_state", image_size=24)
    n_state = env.observation_space["state"].shape[0]
    features = {
        "observation.state": {"dtype": "float32", "shape": [n_state], "names": None},
        "observation.image": {"dtype": "image", "shape": [24, 24, 3], "names": ["height", "width", "channels"]},
        "action": {"dtype": "float32", "shape": [4], "names": None},
        "next.reward": {"dtype": "float32", "shape": [1], "names": None},
        "next.done": {"dtype": "bool", "shape": [1], "names": None},
        "next.success": {"dtype": "bool", "shape": [1], "names": None},
    }
    recorded: dict[str, list] = {name: [] for name in features}
    try:
        obs, _ = env.reset(seed=3)
        policy = WavePolicy.from_env(env)
        policy.reset()
        with LeRobotWriter.create(
            tmp_path / "ds",
            fps=10,
            features=features,
            robot_type="disk",
            info_extra={"dpr": {"env_id": "dpr/Navigation-v0"}},
        ) as w:
            for _ in range(20):
                action = policy(obs)
                next_obs, reward, terminated, truncated, info = env.step(action)
                frame = {
                    "observation.state": obs["state"],
                    "observation.image": obs["pixels"],
                    "action": action,
                    "next.reward": np.float32(reward),
                    "next.done": np.array([terminated or truncated]),
                    "next.success": np.array([bool(info["is_success"])]),
                }
                w.add_frame(frame, task="navigate the swarm to the goal")
                for name, value in frame.items():
                    recorded[name].append(
                        np.array(
                            value, dtype=np.uint8 if name == "observation.image" else features[name]["dtype"]
                        ).reshape(features[name]["shape"])
                    )
                obs = next_obs
            w.save_episode({"seed": 3, "env_id": "dpr/Navigation-v0", "policy": "wave"})
    finally:
        env.close()
    got = LeRobotReader(tmp_path / "ds").episode(0)
    for name, values in recorded.items():
        np.testing.assert_array_equal(got[name], np.stack(values), err_msg=name)
    assert got["observation.image"].any()  # a real render, not a blank frame
