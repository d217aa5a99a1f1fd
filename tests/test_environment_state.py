"""`observation.environment_state`: the env's `environment_state()` (the swarm's centre and the object in the goal
frame, the gate's opening), recorded at every frame of state-only and pixel datasets with its stats; datasets
recorded before it still read, verify, replay and view, and are not resumed with it."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import gymnasium as gym
import numpy as np
import pyarrow.parquet as pq
import pytest
from helpers import run_cli, tree_hash

import dpr.datasets.collect as collect_module
from dpr.datasets import features as F
from dpr.datasets.collect import CollectSpec, collect, rollout
from dpr.datasets.lerobot import DatasetError, LeRobotReader
from dpr.datasets.lerobot.format import STAT_KEYS
from dpr.datasets.replay import replay_dataset
from dpr.envs.gate import WALL_THICKNESS
from dpr.envs.particle_env import LENGTH_SCALE

NAV, MANIPULATION = "dpr/Navigation-v0", "dpr/Manipulation-v0"
SWARM = ["swarm.x", "swarm.y", "swarm.vx", "swarm.vy", "swarm.distance"]
OBJECT = ["object.x", "object.y", "object.vx", "object.vy", "object.distance"]
N = 4
NAMES = {
    NAV: SWARM,
    "dpr/Unresponsive-v0": [*SWARM, *(f"dead.robot{i}" for i in range(N))],
    "dpr/Gate-v1": [*SWARM, "gate.dx", "gate.dy"],
    "dpr/Gate-v2": [*SWARM, "gate.dx", "gate.dy"],
    MANIPULATION: [*SWARM, *OBJECT],
}
SMALL = {"n_robots": N, "robot_model": "disk"}


def spec(env_id: str = NAV, steps: int = 12, **overrides) -> CollectSpec:
    return CollectSpec(env_id, **SMALL, steps=steps, **overrides)


def expected_from_observation(observation: np.ndarray, has_object: bool) -> np.ndarray:
    """The environment state that the state observation implies (float64): the robots' mean x, y, vx, vy and the
    centre's distance to the goal; the object's block and its distance."""
    robots = observation[: 6 * N].astype(np.float64).reshape(N, 6)
    centre, velocity = robots[:, 0:2].mean(axis=0), robots[:, 2:4].mean(axis=0)
    values = [*centre, *velocity, math.hypot(*centre)]
    if has_object:
        obj = observation[6 * N : 6 * N + 4].astype(np.float64)
        values += [*obj, math.hypot(*obj[0:2])]
    return np.array(values)


# ------------------------------------------------------------------------------------------------------- env
@pytest.mark.parametrize("env_id", sorted(NAMES))
def test_each_task_names_its_environment_state(make_env, env_id):
    env = make_env(env_id)
    base = env.unwrapped
    assert base.environment_state_names == NAMES[env_id]
    with pytest.raises(RuntimeError, match="reset"):
        base.environment_state()
    env.reset(seed=3)
    state = base.environment_state()
    assert state.dtype == np.float32 and state.shape == (len(NAMES[env_id]),)
    assert np.isfinite(state).all()


@pytest.mark.parametrize("env_id", [NAV, MANIPULATION])
def test_the_environment_state_is_the_observations_swarm_and_object_in_the_goal_frame(make_env, env_id):
    env = make_env(env_id)
    base = env.unwrapped
    observation, _ = env.reset(seed=5)
    rng = np.random.default_rng(0)
    for _ in range(15):
        state = base.environment_state()
        expected = expected_from_observation(observation, base.has_object)
        np.testing.assert_allclose(state, expected, rtol=1e-5, atol=1e-7)
        if base.has_object:  # the same values as the observation's object block, to the bit
            np.testing.assert_array_equal(state[5:9], observation[6 * N : 6 * N + 4])
        centre = (base.world.centre_of_mass - base.goal) * LENGTH_SCALE
        np.testing.assert_array_equal(state[0:2], centre.astype(np.float32))
        observation, *_ = env.step(rng.integers(0, 2, N))


def test_the_gate_state_is_the_openings_centre_from_the_swarms(make_env):
    for env_id in ("dpr/Gate-v1", "dpr/Gate-v0"):
        env = make_env(env_id)
        base = env.unwrapped
        env.reset(seed=2)
        along = (base.goal - base.start) / np.linalg.norm(base.goal - base.start)
        centre = base.start + along * (base._gate_near + WALL_THICKNESS / 2)  # on the line from start to goal
        if env_id == "dpr/Gate-v0":
            np.testing.assert_allclose(centre, (base.start + base.goal) / 2, atol=1e-9)  # halfway: the paper's gate
        expected = (centre - base.world.centre_of_mass) * LENGTH_SCALE
        np.testing.assert_allclose(base.environment_state()[5:7], expected, rtol=1e-6, atol=1e-9)


def test_gate_v2_observes_the_openings_centre_and_is_gate_v1_otherwise(make_env):
    """The opening's centre in the goal frame, between the robots' features and the last action; the rest of the
    state is Gate-v1's to the bit, and Gate-v0/v1 keep Navigation's state (their models still load)."""
    v2, v1 = make_env("dpr/Gate-v2", obs_last_action=True), make_env("dpr/Gate-v1", obs_last_action=True)
    base = v2.unwrapped
    assert v2.observation_space.shape == (v1.observation_space.shape[0] + 2,)
    assert base.state_names[6 * N : 6 * N + 3] == ["opening.x", "opening.y", "last_action.robot0"]
    assert make_env("dpr/Gate-v0").observation_space.shape == make_env("dpr/Navigation-v0").observation_space.shape
    (new, _), (old, _) = v2.reset(seed=4), v1.reset(seed=4)
    rng = np.random.default_rng(0)
    for _ in range(3):
        opening = (base._gate_centre - base.goal) * LENGTH_SCALE
        np.testing.assert_allclose(new[6 * N : 6 * N + 2], opening, rtol=1e-6)
        # the same point as the environment state's, there seen from the swarm's centre
        np.testing.assert_allclose(
            new[6 * N : 6 * N + 2] - base.environment_state()[0:2], base.environment_state()[5:7], atol=1e-6
        )
        np.testing.assert_array_equal(np.delete(new, [6 * N, 6 * N + 1]), old)
        action = rng.integers(0, 2, N)
        (new, *_), (old, *_) = v2.step(action), v1.step(action)
    with pytest.raises(ValueError, match="observe_opening: expected True or False"):
        make_env("dpr/Gate-v2", observe_opening="yes")


def test_the_unresponsive_state_flags_the_dead_robots_of_each_episode(make_env):
    """One flag per robot, 1 for the dead ones of this episode (drawn anew at each reset), not scaled as lengths;
    the swarm's five values are Navigation's."""
    env = make_env("dpr/Unresponsive-v0", n_dead=2)
    base = env.unwrapped
    drawn = set()
    for seed in range(6):
        _, info = env.reset(seed=seed)
        state = base.environment_state()
        flags = state[len(SWARM) :]
        assert flags.dtype == np.float32 and set(np.unique(flags)) == {0.0, 1.0}
        np.testing.assert_array_equal(np.flatnonzero(flags), info["dead_robots"])
        centre = (base.world.centre_of_mass - base.goal) * LENGTH_SCALE
        np.testing.assert_array_equal(state[0:2], centre.astype(np.float32))
        env.step(np.ones(N, dtype=np.int64))
        np.testing.assert_array_equal(base.environment_state()[len(SWARM) :], flags)  # fixed for the episode
        drawn.add(tuple(info["dead_robots"]))
    assert len(drawn) > 1


def test_the_environment_state_is_deterministic():
    first, second = (rollout(spec(MANIPULATION), seed=4) for _ in range(2))
    np.testing.assert_array_equal(first.environment_states, second.environment_states)
    assert first.environment_states.shape == (12, 10)


# -------------------------------------------------------------------------------------------------- datasets
@pytest.mark.parametrize(("env_id", "pixels"), [(NAV, False), (MANIPULATION, True)], ids=["state", "pixels"])
def test_datasets_record_the_environment_state_at_every_frame(tmp_path, env_id, pixels):
    root = tmp_path / "ds"
    recorded_spec = spec(env_id, pixels=pixels, image_size=16)
    collect(root, recorded_spec, episodes=2, seed=7)
    reader = LeRobotReader(root)
    names = NAMES[env_id]
    assert reader.features[F.ENVIRONMENT_STATE] == {"dtype": "float32", "shape": [len(names)], "names": names}
    assert (F.IMAGE in reader.features) == pixels
    stats = reader.stats[F.ENVIRONMENT_STATE]
    assert set(stats) == set(STAT_KEYS)
    for key in STAT_KEYS:
        assert np.shape(stats[key]) == ((1,) if key == "count" else (len(names),)), key
    assert list(stats["count"]) == [24]
    meta = pq.read_table(root / "meta/episodes/chunk-000/file-000.parquet")
    assert {f"stats/{F.ENVIRONMENT_STATE}/{key}" for key in STAT_KEYS} <= set(meta.column_names)

    values = []
    for index, episode in enumerate(reader.episodes):
        data = reader.episode(index)
        states = data[F.ENVIRONMENT_STATE]
        assert states.dtype == np.float32 and states.shape == (12, len(names))
        values.append(states)
        # the env's own call, at each frame of an independent replay of the seed and the recorded actions
        env = gym.make(env_id, **recorded_spec.make_kwargs())
        try:
            env.reset(seed=episode[F.SEED])
            for t, action in enumerate(data[F.ACTION]):
                np.testing.assert_array_equal(states[t], env.unwrapped.environment_state(), err_msg=f"frame {t}")
                env.step(action.astype(np.int64))
        finally:
            env.close()
        for t in (0, 5, 11):  # the centre is the robots' mean position in the observation
            expected = expected_from_observation(data[F.OBSERVATION][t], env_id == MANIPULATION)
            np.testing.assert_allclose(states[t], expected, rtol=1e-5, atol=1e-7)
    all_values = np.concatenate(values)
    np.testing.assert_allclose(stats["mean"], all_values.astype(np.float64).mean(axis=0), rtol=1e-6, atol=1e-9)
    np.testing.assert_array_equal(stats["min"], all_values.min(axis=0))
    assert all(check.equal for check in replay_dataset(root))


def tamper_environment_state(monkeypatch, frame: int, column: int) -> None:
    """Every episode read from a dataset has its environment state at ``frame``, ``column`` moved by 1e-3."""
    original = LeRobotReader.episode

    def tampered(self, index, columns=None):
        data = original(self, index, columns)
        data[F.ENVIRONMENT_STATE] = data[F.ENVIRONMENT_STATE].copy()
        data[F.ENVIRONMENT_STATE][frame, column] += 1e-3
        return data

    monkeypatch.setattr(LeRobotReader, "episode", tampered)


def test_replay_compares_the_environment_state(tmp_path, monkeypatch):
    root = tmp_path / "ds"
    collect(root, spec(), episodes=1)
    tamper_environment_state(monkeypatch, 4, 1)
    (check,) = replay_dataset(root)
    assert not check.equal and check.first_mismatch == 4
    assert check.max_abs_difference[F.ENVIRONMENT_STATE] == pytest.approx(1e-3, rel=1e-3)


# ----------------------------------------------------------------------------------------- older datasets
def record_old_layout(root: Path, recorded_spec: CollectSpec, episodes: int, monkeypatch) -> Path:
    """``root`` recorded as dpr collect recorded it before the environment state: without the feature."""
    with monkeypatch.context() as patch:
        features = collect_module.dataset_features
        patch.setattr(
            collect_module,
            "dataset_features",
            lambda *args, **kwargs: {k: v for k, v in features(*args, **kwargs).items() if k != F.ENVIRONMENT_STATE},
        )
        record = collect_module.rollout
        patch.setattr(
            collect_module,
            "rollout",
            lambda *args: dataclasses.replace(record(*args), environment_states=None),
        )
        collect(root, recorded_spec, episodes=episodes)
    assert F.ENVIRONMENT_STATE not in json.loads((root / "meta/info.json").read_text())["features"]
    return root


def test_a_dataset_without_the_environment_state_reads_and_is_not_resumed_with_it(tmp_path, monkeypatch, capsys):
    old_spec = spec(steps=8)
    root = record_old_layout(tmp_path / "old", old_spec, 2, monkeypatch)
    reader = LeRobotReader(root)
    assert reader.verify() == 16 and reader.episode(1)[F.OBSERVATION].shape == (8, 6 * N)
    assert all(check.equal for check in replay_dataset(root))

    from dpr.cli.data import verify_dataset
    from dpr.datasets.frames import FrameDataset
    from dpr.viz import episode_from_dataset

    assert verify_dataset(root) == 0
    frames = FrameDataset(root)  # what dpr bc reads: observation.state -> action
    assert len(frames) == 16 and frames[0]["observation"].shape == (6 * N,)
    assert episode_from_dataset(reader, 0).n_states == 8  # dpr view

    def no_rollouts(job):
        raise AssertionError("a refused dataset must not start rollouts")

    before = tree_hash(root)
    with monkeypatch.context() as patch:
        patch.setattr(collect_module, "_rollout_job", no_rollouts)
        with pytest.raises(DatasetError) as refused:
            collect(root, old_spec, episodes=3)
    message = str(refused.value)
    assert str(root) in message and f"'{F.ENVIRONMENT_STATE}'" in message and "new folder" in message
    assert "--out" in message and "dpr bc still learns from it" in message
    assert tree_hash(root) == before
    argv = ["collect", "--env", NAV, "--robot-model", "disk", "--n-robots", str(N), "--steps", "8", "--workers", "1"]
    assert run_cli([*argv, "--episodes", "3", "--out", str(root)]) == 2
    assert F.ENVIRONMENT_STATE in capsys.readouterr().err
    assert tree_hash(root) == before

    # a rerun that adds no episode (every seed recorded) opens it as it is: dpr collect --verify still passes
    summary = collect(root, old_spec, episodes=2)
    assert (summary.episodes_added, summary.episodes_total) == (0, 2)
    assert run_cli([*argv, "--episodes", "2", "--out", str(root), "--verify"]) == 0
    assert "verified" in capsys.readouterr().out
    assert F.ENVIRONMENT_STATE not in LeRobotReader(root).features
    # what the message tells to do: a new folder records it
    fresh = collect(tmp_path / "new", old_spec, episodes=3)
    assert fresh.episodes_total == 3 and F.ENVIRONMENT_STATE in LeRobotReader(tmp_path / "new").features


def test_an_unresponsive_dataset_recorded_before_the_dead_flags_replays_equal(tmp_path, monkeypatch):
    """Recorded when Unresponsive's state was Navigation's five values: replay compares those five, and a change
    in them is still found."""
    from dpr.envs.particle_env import ParticleSwarmEnv
    from dpr.envs.unresponsive import UnresponsiveEnv

    root = tmp_path / "old"
    with monkeypatch.context() as patch:
        patch.setattr(UnresponsiveEnv, "environment_state_names", ParticleSwarmEnv.environment_state_names)
        patch.setattr(UnresponsiveEnv, "environment_state", ParticleSwarmEnv.environment_state)
        collect(root, spec("dpr/Unresponsive-v0", steps=8), episodes=1)
    assert LeRobotReader(root).features[F.ENVIRONMENT_STATE]["names"] == SWARM
    (check,) = replay_dataset(root)
    assert check.equal and check.max_abs_difference[F.ENVIRONMENT_STATE] == 0.0
    tamper_environment_state(monkeypatch, 3, 0)
    (check,) = replay_dataset(root)
    assert not check.equal and check.first_mismatch == 3
