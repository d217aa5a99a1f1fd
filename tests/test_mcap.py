"""MCAP episode logs (dpr.datasets.mcap): bit-exact round trips of real rollouts, the JSON schemas, the
episode metadata, damaged files, and the writer's write-to-temp-then-rename behaviour."""

import json
import math
import os
import signal
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from dpr.checks import ParameterError
from dpr.datasets.mcap import (
    MAGNET_DECIMALS,
    MCAP_FORMAT,
    METADATA_NAME,
    METRIC_KEYS,
    McapEpisodeWriter,
    McapError,
    StepOutcome,
    SwarmState,
    episode_metadata,
    log_env_step,
    read_mcap,
)
from dpr.policies.wave import WavePolicy

STATE_FIELDS = ("step", "time", "x", "y", "angle", "vx", "vy", "omega", "expansion", "alive", "centre_of_mass")
REWARD_FIELDS = ("step", "reward", "terminated", "truncated", *METRIC_KEYS)


def rollout(path: Path, env_id: str, steps: int = 30, seed: int = 7, magnets: bool = True, **kwargs) -> dict:
    """Run the wave policy in ``env_id`` for ``steps`` steps, log it to ``path`` and return what the sim had."""
    env = gym.make(env_id, **kwargs)
    policy = WavePolicy.from_env(env)
    policy.reset()
    obs, info = env.reset(seed=seed)
    world = env.unwrapped.world
    swarm = world.swarm
    seen: dict[str, list] = {
        key: []
        for key in (
            "positions",
            "angles",
            "velocities",
            "angular_velocities",
            "expansions",
            "com",
            "object_poses",
            "object_velocities",
            "magnets",
            "actions",
            "rewards",
            "terminated",
            "truncated",
        )
    }
    seen["metrics"] = {key: [] for key in METRIC_KEYS}

    def snapshot() -> None:
        for key, value in (
            ("positions", swarm.position),
            ("angles", swarm.angle),
            ("velocities", swarm.velocity),
            ("angular_velocities", swarm.angular_velocity),
            ("expansions", swarm.expansion),
            ("com", world.centre_of_mass),
            ("object_poses", world.object_pose),
            ("object_velocities", world.object_velocity),
            ("magnets", swarm.magnet_segments()),
        ):
            seen[key].append(np.array(value, copy=True))

    metadata = episode_metadata(env, seed=seed, policy="wave")
    with McapEpisodeWriter(path, metadata=metadata) as writer:
        log_env_step(writer, env, 0, magnets=magnets)
        snapshot()
        for step in range(1, steps + 1):
            action = policy(obs)
            obs, reward, terminated, truncated, info = env.step(action)
            outcome = StepOutcome(action, reward, terminated, truncated, metrics=info)
            log_env_step(writer, env, step, outcome, magnets=magnets)
            snapshot()
            seen["actions"].append(np.array(action))
            seen["rewards"].append(reward)
            seen["terminated"].append(terminated)
            seen["truncated"].append(truncated)
            for key in METRIC_KEYS:
                seen["metrics"][key].append(info[key])
    seen["alive"] = swarm.alive.copy()
    seen["walls"] = [wall.copy() for wall in world.walls]
    seen["metadata"] = metadata
    env.close()
    return seen


def assert_bit_exact(got: np.ndarray, want) -> None:
    want = np.asarray(want, dtype=np.float64)
    assert got.dtype == np.float64
    assert got.shape == want.shape
    assert got.tobytes() == want.tobytes()  # stricter than ==: tells -0.0 from 0.0


def check_round_trip(episode, seen: dict, steps: int) -> None:
    n = seen["positions"][0].shape[0]
    assert episode.n_steps == steps and episode.n_robots == n
    np.testing.assert_array_equal(episode.steps, np.arange(steps + 1))
    np.testing.assert_allclose(episode.times, np.arange(steps + 1) * 0.1)
    for field, key in (
        ("positions", "positions"),
        ("angles", "angles"),
        ("velocities", "velocities"),
        ("angular_velocities", "angular_velocities"),
        ("expansions", "expansions"),
        ("centres_of_mass", "com"),
    ):
        assert_bit_exact(getattr(episode, field), np.stack(seen[key]))
    assert_bit_exact(episode.rewards, seen["rewards"])
    for key in ("projected_displacement", "net_displacement", "total_distance"):
        assert_bit_exact(episode.metrics[key], seen["metrics"][key])
    np.testing.assert_array_equal(episode.metrics["is_success"], seen["metrics"]["is_success"])
    np.testing.assert_array_equal(episode.actions, np.stack(seen["actions"]))
    np.testing.assert_array_equal(episode.terminated, seen["terminated"])
    np.testing.assert_array_equal(episode.truncated, seen["truncated"])
    np.testing.assert_array_equal(episode.alive, seen["alive"])
    assert_bit_exact(episode.goal, [0.0, 0.0])
    assert len(episode.walls) == len(seen["walls"])
    for got, want in zip(episode.walls, seen["walls"], strict=True):
        assert_bit_exact(got, want)
    assert episode.metadata == seen["metadata"]
    # magnets are a drawing aid, stored rounded
    assert len(episode.magnets) == steps + 1
    for got, want in zip(episode.magnets, seen["magnets"], strict=True):
        assert got.shape == want.shape
        np.testing.assert_allclose(got, want, rtol=0, atol=0.51 * 10.0**-MAGNET_DECIMALS)
    assert sum(len(m) for m in episode.magnets) > 0, "the swarm should hold magnets during a rollout"


def test_navigation_round_trip_is_bit_exact(tmp_path):
    path = tmp_path / "navigation.mcap"
    seen = rollout(path, "dpr/Navigation-v0", steps=30, n_robots=9)
    episode = read_mcap(path)
    check_round_trip(episode, seen, 30)
    assert episode.object_poses is None and episode.object_velocities is None
    assert episode.actions.dtype == np.int64
    assert episode.metadata["env_id"] == "dpr/Navigation-v0" and episode.metadata["seed"] == 7
    # the swarm moved, so the comparison above compared changing numbers
    assert np.abs(episode.positions[-1] - episode.positions[0]).max() > 0.1
    assert set(np.unique(episode.actions)) == {0, 1}


def test_manipulation_round_trip_covers_the_object(tmp_path):
    path = tmp_path / "manipulation.mcap"
    seen = rollout(path, "dpr/Manipulation-v0", steps=30, n_robots=4, robot_model="disk")
    episode = read_mcap(path)
    check_round_trip(episode, seen, 30)
    assert_bit_exact(episode.object_poses, np.stack(seen["object_poses"]))
    assert_bit_exact(episode.object_velocities, np.stack(seen["object_velocities"]))
    assert episode.scene["object"] == {"kind": "ball", "size": 30.0}
    assert episode.scene["robot_radii"][0] < episode.scene["robot_radii"][1]


def test_gate_walls_discrete_actions_and_no_magnets(tmp_path):
    path = tmp_path / "gate.mcap"
    seen = rollout(path, "dpr/Gate-v0", steps=5, n_robots=4, robot_model="disk", action_type="discrete", magnets=False)
    episode = read_mcap(path)
    assert episode.magnets is None
    assert len(episode.walls) == 2 and all(wall.shape[1] == 2 for wall in episode.walls)
    for got, want in zip(episode.walls, seen["walls"], strict=True):
        assert_bit_exact(got, want)
    # a Discrete(2^N) action is logged as its N bits, robot 0 the most significant
    bits = [[(int(a) >> (3 - k)) & 1 for k in range(4)] for a in seen["actions"]]
    np.testing.assert_array_equal(episode.actions, bits)


# -- schemas and metadata ---------------------------------------------------------------------------------
JSON_TYPES = {"object": dict, "array": list, "string": str, "boolean": bool, "null": type(None)}


def conforms(instance, schema: dict) -> bool:
    """The subset of JSON Schema our schemas use: type (or a list of types), properties, required, items,
    minItems, maxItems, minimum."""
    types = schema.get("type")
    if types is not None:
        types = [types] if isinstance(types, str) else types
        ok = False
        for name in types:
            if name == "number":
                ok |= isinstance(instance, (int, float)) and not isinstance(instance, bool)
            elif name == "integer":
                ok |= isinstance(instance, int) and not isinstance(instance, bool)
            else:
                ok |= isinstance(instance, JSON_TYPES[name])
        if not ok:
            return False
    if isinstance(instance, dict):
        if any(key not in instance for key in schema.get("required", [])):
            return False
        for key, sub in schema.get("properties", {}).items():
            if key in instance and not conforms(instance[key], sub):
                return False
    if isinstance(instance, list):
        if not schema.get("minItems", 0) <= len(instance) <= schema.get("maxItems", math.inf):
            return False
        if "items" in schema and not all(conforms(item, schema["items"]) for item in instance):
            return False
    if "minimum" in schema and instance < schema["minimum"]:
        return False
    return True


def test_schemas_are_json_schema_documents_that_the_messages_follow(tmp_path):
    path = tmp_path / "manipulation.mcap"
    rollout(path, "dpr/Manipulation-v0", steps=12, n_robots=4, robot_model="disk")
    expected_fields = {
        "/scene": ("goal", "walls", "object", "robot_radii"),
        "/swarm/state": STATE_FIELDS,
        "/swarm/magnets": ("step", "segments"),
        "/object": ("step", "x", "y", "angle", "vx", "vy"),
        "/action": ("step", "action"),
        "/reward": REWARD_FIELDS,
    }
    counts: dict[str, int] = {}
    with path.open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert {channel.topic for channel in summary.channels.values()} == set(expected_fields)
        for schema, channel, message in reader.iter_messages():
            assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
            document = json.loads(schema.data)
            assert document["$schema"].startswith("https://json-schema.org/")
            assert document["type"] == "object"
            assert set(document["properties"]) == set(expected_fields[channel.topic])
            assert set(document["required"]) <= set(document["properties"])
            # strict JSON: NaN or Infinity would make Foxglove's parser fail
            decoded = json.loads(message.data, parse_constant=lambda name: pytest.fail(f"non-JSON {name}"))
            assert conforms(decoded, document), (channel.topic, decoded)
            assert message.log_time == decoded.get("step", 0) * 100_000_000
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    assert counts == {
        "/scene": 1,
        "/swarm/state": 13,
        "/swarm/magnets": 13,
        "/object": 13,
        "/action": 12,
        "/reward": 12,
    }


def test_a_message_violating_its_schema_is_caught_by_the_checker():
    """The hand-written checker above must be able to fail, or the schema test proves nothing."""
    schema = {"type": "object", "properties": {"x": {"type": "array", "items": {"type": "number"}}}, "required": ["x"]}
    assert conforms({"x": [1.0, 2]}, schema)
    assert not conforms({"x": [1.0, "2"]}, schema)
    assert not conforms({"y": []}, schema)
    assert not conforms({"x": [True]}, schema)


def test_metadata_record(tmp_path):
    path = tmp_path / "episode.mcap"
    metadata = {
        "env_id": "dpr/Navigation-v0",
        "seed": 3,
        "n_robots": 2,
        "robot_model": "disk",
        "policy": "wave",
        "env_kwargs": {"n_robots": 2, "start_radius": [450.0, 550.0]},
        "note": None,
    }
    write_minimal(path, metadata=metadata)
    with path.open("rb") as stream:
        records = {record.name: record.metadata for record in make_reader(stream).iter_metadata()}
    raw = records[METADATA_NAME]
    assert raw["format"] == MCAP_FORMAT == "dpr-mcap/1"
    assert raw["env_id"] == "dpr/Navigation-v0"  # strings stay readable as they are
    assert json.loads(raw["env_kwargs"]) == metadata["env_kwargs"]  # the rest is JSON text
    assert read_mcap(path).metadata == metadata


# -- writing by hand, damaged and foreign files -----------------------------------------------------------
def write_minimal(path: Path, steps: int = 3, n: int = 2, metadata: dict | None = None, **writer_kwargs) -> None:
    with McapEpisodeWriter(path, metadata=metadata or {"env_id": "test"}, **writer_kwargs) as writer:
        write_minimal_steps(writer, steps, n)


def write_minimal_steps(writer: McapEpisodeWriter, steps: int, n: int) -> None:
    writer.write_scene(goal=[1.0, -2.0], walls=[np.array([[0, 0], [1, 0], [1, 1.0]])])
    metrics = {key: 0.5 for key in METRIC_KEYS} | {"is_success": False}
    for step in range(steps + 1):
        outcome = (
            None
            if step == 0
            else StepOutcome(
                action=np.ones(n, dtype=np.int8),
                reward=0.25 * step,
                terminated=False,
                truncated=step == steps,
                metrics=metrics,
            )
        )
        state = SwarmState(
            positions=np.full((n, 2), 0.1 * step),
            angles=np.zeros(n),
            velocities=np.zeros((n, 2)),
            angular_velocities=np.zeros(n),
            expansions=np.full(n, 0.5),
            alive=np.ones(n, bool),
        )
        writer.write_step(step, state, outcome)


def test_hand_written_episode_with_lz4(tmp_path):
    path = tmp_path / "lz4.mcap"
    write_minimal(path, steps=4, n=3, compression="lz4")
    episode = read_mcap(path)
    assert episode.positions.shape == (5, 3, 2) and episode.actions.shape == (4, 3)
    np.testing.assert_array_equal(episode.truncated, [False, False, False, True])
    assert episode.magnets is None and episode.object_poses is None
    assert_bit_exact(episode.goal, [1.0, -2.0])


def test_reset_only_episode(tmp_path):
    path = tmp_path / "reset.mcap"
    write_minimal(path, steps=0, n=2)
    episode = read_mcap(path)
    assert episode.n_steps == 0 and episode.positions.shape == (1, 2, 2) and episode.actions.shape == (0, 2)


def test_non_finite_values_are_written_as_null_and_read_as_nan(tmp_path):
    path = tmp_path / "blowup.mcap"
    with McapEpisodeWriter(path, metadata={}) as writer:
        writer.write_scene(goal=[0.0, 0.0])
        writer.write_step(
            0,
            SwarmState(
                positions=[[0.0, 0.0]],
                angles=[0.0],
                velocities=[[math.nan, math.inf]],
                angular_velocities=[0.0],
                expansions=[0.0],
                alive=[True],
            ),
        )
    with path.open("rb") as stream:
        for _schema, _channel, message in make_reader(stream).iter_messages(topics=["/swarm/state"]):
            state = json.loads(message.data, parse_constant=lambda name: pytest.fail(f"non-JSON {name}"))
            assert state["vx"] == [None] and state["vy"] == [None]
    episode = read_mcap(path)
    assert np.isnan(episode.velocities).all() and episode.positions[0, 0, 0] == 0.0


@pytest.mark.parametrize("cut", [1, 40, 0.5])
def test_truncated_file_raises_mcap_error_naming_it(tmp_path, cut):
    path = tmp_path / "cut.mcap"
    write_minimal(path, steps=20)
    data = path.read_bytes()
    keep = int(len(data) * cut) if isinstance(cut, float) else len(data) - cut
    path.write_bytes(data[:keep])
    with pytest.raises(McapError, match="cut.mcap") as error:
        read_mcap(path)
    assert error.value.path == str(path)


def test_garbage_and_missing_files_raise_mcap_error(tmp_path):
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(np.random.default_rng(0).bytes(5000))
    with pytest.raises(McapError, match="garbage.mcap"):
        read_mcap(garbage)
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    with pytest.raises(McapError, match="empty.mcap"):
        read_mcap(empty)
    with pytest.raises(McapError, match="missing.mcap.*no such file"):
        read_mcap(tmp_path / "missing.mcap")
    assert issubclass(McapError, ValueError)


def foreign_file(path: Path, metadata: dict[str, str] | None, topics: tuple[str, ...]) -> None:
    """An MCAP file written straight with the mcap library, with the given metadata and empty JSON channels."""
    with path.open("wb") as stream:
        writer = Writer(stream)
        writer.start()
        if metadata is not None:
            writer.add_metadata(METADATA_NAME, metadata)
        for topic in topics:
            schema = writer.register_schema(topic, "jsonschema", b"{}")
            writer.register_channel(topic, "json", schema)
        writer.finish()


def test_wrong_format_version_missing_metadata_and_missing_channels(tmp_path):
    topics = ("/scene", "/swarm/state", "/action", "/reward")
    old = tmp_path / "old.mcap"
    foreign_file(old, {"format": "dpr-mcap/0", "json_keys": ""}, topics)
    with pytest.raises(McapError, match=r"old\.mcap.*dpr-mcap/0"):
        read_mcap(old)
    bare = tmp_path / "bare.mcap"
    foreign_file(bare, None, topics)
    with pytest.raises(McapError, match=r"bare\.mcap.*no 'dpr\.episode' metadata"):
        read_mcap(bare)
    partial = tmp_path / "partial.mcap"
    foreign_file(partial, {"format": MCAP_FORMAT, "json_keys": ""}, topics[:2])
    with pytest.raises(McapError, match=r"partial\.mcap.*missing channel\(s\) /action, /reward"):
        read_mcap(partial)


# -- temp file behaviour ----------------------------------------------------------------------------------
def test_nothing_under_the_final_name_until_close(tmp_path):
    path = tmp_path / "episode.mcap"
    writer = McapEpisodeWriter(path, metadata={})
    write_minimal_steps(writer, steps=3, n=2)
    assert list(tmp_path.iterdir()) == []  # an unfinished episode is on disk under no name at all
    writer.close()
    assert path.is_file() and list(tmp_path.iterdir()) == [path]
    umask = os.umask(0)
    os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask  # not a temp file's private 0600
    writer.close()  # a second close is a no-op
    assert read_mcap(path).n_steps == 3


_KILLED_WRITER = """
import sys, time
sys.path.insert(0, {tests!r})
from test_mcap import write_minimal_steps
from dpr.datasets.mcap import McapEpisodeWriter
writer = McapEpisodeWriter({path!r}, metadata={{}})
write_minimal_steps(writer, steps=50, n=9)
print("written", flush=True)
time.sleep(60)
"""


def test_a_killed_writer_leaves_nothing_on_disk(tmp_path):
    """kill -9 in the middle of an episode: no file of it remains, not even a temporary one."""
    folder = tmp_path / "mcap"
    folder.mkdir()
    code = _KILLED_WRITER.format(tests=str(Path(__file__).parent), path=str(folder / "episode.mcap"))
    process = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert process.stdout.readline().strip() == "written"
        assert list(folder.iterdir()) == []
    finally:
        process.kill()
        process.wait(timeout=30)
    assert process.returncode == -signal.SIGKILL
    assert list(folder.iterdir()) == []


def test_exception_inside_with_leaves_no_file_and_keeps_an_old_one(tmp_path):
    path = tmp_path / "episode.mcap"
    with pytest.raises(RuntimeError, match="boom"):
        with McapEpisodeWriter(path, metadata={}) as writer:
            write_minimal_steps(writer, steps=2, n=2)
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []
    write_minimal(path, steps=2)
    before = path.read_bytes()
    with pytest.raises(RuntimeError):
        with McapEpisodeWriter(path, metadata={}) as writer:
            write_minimal_steps(writer, steps=5, n=2)
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == [path] and path.read_bytes() == before


def test_a_failed_rename_keeps_the_old_file_and_removes_the_temporary_one(tmp_path, monkeypatch):
    path = tmp_path / "episode.mcap"
    write_minimal(path, steps=2)
    before = path.read_bytes()
    writer = McapEpisodeWriter(path, metadata={})
    write_minimal_steps(writer, steps=4, n=2)

    def full_disk(source, target):
        raise OSError("no space left on device")

    monkeypatch.setattr(os, "replace", full_disk)
    with pytest.raises(OSError, match="no space left"):
        writer.close()
    monkeypatch.undo()
    assert list(tmp_path.iterdir()) == [path] and path.read_bytes() == before
    writer.close()  # the failed close closed the writer: this is a no-op, not a second attempt
    assert read_mcap(path).n_steps == 2


def test_close_without_scene_or_steps_writes_nothing(tmp_path):
    path = tmp_path / "episode.mcap"
    writer = McapEpisodeWriter(path, metadata={})
    with pytest.raises(McapError, match=r"episode\.mcap.*write_scene\(\) was never called.*no step"):
        writer.close()
    assert list(tmp_path.iterdir()) == []


def test_bad_writer_input_names_file_and_argument(tmp_path):
    path = tmp_path / "episode.mcap"
    with pytest.raises(McapError, match="does not exist"):
        McapEpisodeWriter(tmp_path / "no_dir" / "x.mcap", metadata={})
    with pytest.raises(McapError, match="reserved"):
        McapEpisodeWriter(path, metadata={"format": "mine"})
    with pytest.raises(McapError, match="not JSON-serialisable"):
        McapEpisodeWriter(path, metadata={"env": object()})
    with pytest.raises(ParameterError, match=r"^compression: expected one of \['zstd', 'lz4', 'none'\], got 'gzip'"):
        McapEpisodeWriter(path, metadata={}, compression="gzip")
    for chunk_size in (0, 1.5, True):
        with pytest.raises(ParameterError, match="^chunk_size: ") as error:
            McapEpisodeWriter(path, metadata={}, chunk_size=chunk_size)
        assert error.value.parameter == "chunk_size"
    assert list(tmp_path.iterdir()) == []
    state = dict(
        angles=np.zeros(2),
        velocities=np.zeros((2, 2)),
        angular_velocities=np.zeros(2),
        expansions=np.zeros(2),
        alive=np.ones(2, bool),
    )
    with McapEpisodeWriter(path, metadata={}) as writer:
        writer.write_scene(goal=[0.0, 0.0])
        with pytest.raises(McapError, match="expected 0, got 1"):
            writer.write_step(1, SwarmState(positions=np.zeros((2, 2)), **state))
        with pytest.raises(McapError, match="step 0 is the reset state and takes no action"):
            writer.write_step(0, SwarmState(positions=np.zeros((2, 2)), **state), StepOutcome(action=[0, 1]))
        with pytest.raises(McapError, match=r"episode\.mcap: velocities must have shape \(3, 2\)"):
            writer.write_step(0, SwarmState(positions=np.zeros((3, 2)), **state))
        writer.write_step(0, SwarmState(positions=np.zeros((2, 2)), **state))
        with pytest.raises(McapError, match="action, reward, terminated, truncated, metrics required"):
            writer.write_step(1, SwarmState(positions=np.zeros((2, 2)), **state))
        with pytest.raises(McapError, match="metrics lacks total_distance"):
            writer.write_step(
                1,
                SwarmState(positions=np.zeros((2, 2)), **state),
                StepOutcome(
                    action=[0, 1],
                    reward=0.0,
                    terminated=False,
                    truncated=False,
                    metrics={"projected_displacement": 0, "net_displacement": 0, "is_success": False},
                ),
            )
    assert read_mcap(path).n_steps == 0  # the rejected calls wrote nothing
