"""The env's ``obs_last_action``: the previous action and how long it has been held at the end of the state
vector (space, values, action types, the object's columns, names, pickling, bad input), and datasets and views
recorded with it."""

import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from helpers import ACTION_TYPES, ENV_IDS

from dpr.datasets.collect import CollectSpec, collect
from dpr.datasets.lerobot import LeRobotReader
from dpr.envs import parallel_env
from dpr.envs.particle_env import HELD_STEPS_CAP, LENGTH_SCALE

N = 4
MANIPULATION = "dpr/Manipulation-v0"


def _memory(obs, n=N):
    """(last action, held steps) from the end of a state observation (or a pixels_state dict)."""
    state = np.asarray(obs["state"] if isinstance(obs, dict) else obs)
    return state[-n - 1 : -1], float(state[-1])


def _held(k):
    return np.float32(min(k, HELD_STEPS_CAP) / HELD_STEPS_CAP)


# -- space and conformance -------------------------------------------------------------------------------------
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_check_env_passes(make_env, env_id):
    check_env(make_env(env_id, obs_last_action=True).unwrapped)


@pytest.mark.parametrize("action_type", ["discrete", "continuous"])
def test_check_env_passes_with_pixels_state_and_other_action_types(make_env, action_type):
    env = make_env(MANIPULATION, obs_last_action=True, obs_type="pixels_state", action_type=action_type, image_size=32)
    check_env(env.unwrapped)
    assert env.observation_space["state"].shape == (6 * N + 4 + N + 1,)


@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize("n_robots", [1, 4, 7])
def test_state_space_gains_n_plus_one_values_in_0_1(make_env, env_id, n_robots):
    plain = make_env(env_id, n_robots=n_robots).observation_space
    space = make_env(env_id, n_robots=n_robots, obs_last_action=True).observation_space
    width = plain.shape[0]
    assert space.shape == (width + n_robots + 1,)
    # the first values are the plain observation's, unchanged
    np.testing.assert_array_equal(space.low[:width], plain.low)
    np.testing.assert_array_equal(space.high[:width], plain.high)
    assert np.all(space.low[width:] == 0.0) and np.all(space.high[width:] == 1.0)
    assert space.dtype == np.float32


@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize("flag", [False, True])
def test_state_names_name_every_value(make_env, env_id, flag):
    base = make_env(env_id, obs_last_action=flag).unwrapped
    names = base.state_names
    assert len(names) == len(set(names)) == base.state_size == base.observation_space.shape[0]
    assert names[:6] == ["robot0.x", "robot0.y", "robot0.vx", "robot0.vy", "robot0.omega", "robot0.expansion"]
    if base.has_object:
        assert names[base.object_offset : base.object_offset + 4] == ["object.x", "object.y", "object.vx", "object.vy"]
    assert base.object_offset == 6 * N
    assert base.memory_offset == 6 * N + (4 if base.has_object else 0)
    if flag:
        assert names[base.memory_offset :] == [f"last_action.robot{i}" for i in range(N)] + ["last_action.held_steps"]
    else:
        assert len(names) == base.memory_offset


# -- values ----------------------------------------------------------------------------------------------------
def test_reset_holds_zeros_and_held_steps_count_up_to_the_cap(make_env):
    env = make_env(obs_last_action=True)
    obs, _ = env.reset(seed=0)
    last, held = _memory(obs)
    assert np.all(last == 0) and held == 0.0
    a = np.array([1, 0, 1, 0], dtype=np.int8)
    for k in range(1, HELD_STEPS_CAP + 6):
        obs, *_ = env.step(a)
        last, held = _memory(obs)
        np.testing.assert_array_equal(last, a)
        assert held == _held(k), k
    assert held == 1.0  # capped at 20/20 after 25 steps
    # another action: back to 1/20, then counting again
    b = np.array([0, 1, 0, 0], dtype=np.int8)
    obs, *_ = env.step(b)
    np.testing.assert_array_equal(_memory(obs)[0], b)
    assert _memory(obs)[1] == _held(1)
    obs, *_ = env.step(b)
    assert _memory(obs)[1] == _held(2)
    # back to the first action: a change too
    obs, *_ = env.step(a)
    np.testing.assert_array_equal(_memory(obs)[0], a)
    assert _memory(obs)[1] == _held(1)


def test_first_step_counts_one_even_for_the_all_zero_action(make_env):
    env = make_env(obs_last_action=True)
    env.reset(seed=1)
    zero = np.zeros(N, dtype=np.int8)
    for k in (1, 2, 3):
        obs, *_ = env.step(zero)
        last, held = _memory(obs)
        assert np.all(last == 0) and held == _held(k)


def test_reset_clears_the_memory(make_env):
    env = make_env(obs_last_action=True)
    env.reset(seed=0)
    for _ in range(5):
        env.step(np.ones(N, dtype=np.int8))
    obs, _ = env.reset(seed=0)
    last, held = _memory(obs)
    assert np.all(last == 0) and held == 0.0
    obs, *_ = env.step(np.ones(N, dtype=np.int8))
    assert _memory(obs)[1] == _held(1)  # not 6/20: the count restarted


def test_continuous_actions_are_stored_as_given(make_env):
    env = make_env(obs_last_action=True, action_type="continuous")
    env.reset(seed=0)
    a = np.array([0.25, 0.5, 0.75, 1.0], dtype=np.float32)
    for k in (1, 2, 3):
        obs, *_ = env.step(a)
        last, held = _memory(obs)
        np.testing.assert_array_equal(last, a)
        assert held == _held(k)
    nudged = a.copy()
    nudged[0] = 0.26  # any change of a target is another action
    obs, *_ = env.step(nudged)
    np.testing.assert_allclose(_memory(obs)[0], nudged)
    assert _memory(obs)[1] == _held(1)


@pytest.mark.parametrize("action, bits", [(10, [1, 0, 1, 0]), (1, [0, 0, 0, 1]), (8, [1, 0, 0, 0]), (15, [1, 1, 1, 1])])
def test_discrete_action_is_stored_as_bits_robot_0_most_significant(make_env, action, bits):
    env = make_env(obs_last_action=True, action_type="discrete")
    env.reset(seed=0)
    obs, *_ = env.step(action)
    np.testing.assert_array_equal(_memory(obs)[0], bits)
    obs, *_ = env.step(np.int64(action))  # the same integer as another type: still the same action
    assert _memory(obs)[1] == _held(2)


@pytest.mark.parametrize("action_type", ACTION_TYPES)
def test_the_same_actions_give_the_same_memory_in_every_action_type(make_env, action_type):
    rng = np.random.default_rng(0)
    bits = rng.integers(0, 2, size=(12, N)).astype(np.int8)
    bits[3:7] = bits[2]  # a held stretch
    env = make_env(obs_last_action=True, action_type=action_type)
    env.reset(seed=2)
    seen = []
    for row in bits:
        if action_type == "discrete":
            action = int("".join(map(str, row)), 2)
        elif action_type == "continuous":
            action = row.astype(np.float32)
        else:
            action = row
        seen.append(_memory(env.step(action)[0]))
    np.testing.assert_array_equal(np.array([last for last, _ in seen]), bits)
    expected = [1]
    for t in range(1, len(bits)):
        expected.append(expected[-1] + 1 if np.array_equal(bits[t], bits[t - 1]) else 1)
    assert [round(held * HELD_STEPS_CAP) for _, held in seen] == expected
    assert max(expected) >= 5


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_the_rest_of_the_state_is_the_plain_observation(make_env, env_id):
    plain = make_env(env_id)
    extended = make_env(env_id, obs_last_action=True)
    a, _ = plain.reset(seed=4)
    b, _ = extended.reset(seed=4)
    np.testing.assert_array_equal(b[: len(a)], a)
    actions = np.random.default_rng(4).integers(0, 2, size=(15, N)).astype(np.int8)
    for action in actions:
        a, ra, *_ = plain.step(action)
        b, rb, *_ = extended.step(action)
        np.testing.assert_array_equal(b[: len(a)], a)
        assert ra == rb


def test_manipulation_object_features_stay_at_6n(make_env):
    from dpr.policies.wave import WavePolicy

    env = make_env(MANIPULATION, obs_last_action=True)
    base = env.unwrapped
    at = base.object_offset
    assert at == 6 * N
    obs, _ = env.reset(seed=5)
    policy = WavePolicy.from_env(env)  # pushes the object within a few steps
    moved = False
    for _ in range(20):
        action = policy(obs)
        obs, *_ = env.step(action)
        world = base.world
        np.testing.assert_allclose(obs[at : at + 2], world.object_pose[0:2] * LENGTH_SCALE, rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(obs[at + 2 : at + 4], world.object_velocity * LENGTH_SCALE, rtol=1e-6, atol=1e-7)
        np.testing.assert_array_equal(obs[base.memory_offset : base.memory_offset + N], action)
        moved |= bool(np.abs(obs[at + 2 : at + 4]).max() > 0)
    assert moved  # the velocity columns were not a constant


# -- determinism, pickling -------------------------------------------------------------------------------------
def test_same_seed_and_actions_give_the_same_observations(make_env):
    actions = np.random.default_rng(6).integers(0, 2, size=(10, N)).astype(np.int8)
    runs = []
    for _ in range(2):
        env = make_env(MANIPULATION, obs_last_action=True)
        obs = [env.reset(seed=6)[0]]
        obs += [env.step(a)[0] for a in actions]
        runs.append(np.array(obs))
    np.testing.assert_array_equal(runs[0], runs[1])


def test_pickled_env_keeps_its_memory_and_replays_after_reset(make_env):
    env = make_env(obs_last_action=True)
    env.reset(seed=7)
    held = np.array([0, 1, 1, 0], dtype=np.int8)
    for _ in range(3):
        env.step(held)
    for original in (env, env.unwrapped):
        clone = pickle.loads(pickle.dumps(original))
        assert _memory(clone.unwrapped._last_obs)[1] == _held(3)
        b, *_ = clone.step(held)  # it goes on counting the held action
        np.testing.assert_array_equal(_memory(b)[0], held)
        assert _memory(b)[1] == _held(4)
        # after a reset, it steps exactly like a fresh env
        a, _ = clone.reset(seed=7)
        fresh = make_env(obs_last_action=True)
        np.testing.assert_array_equal(a, fresh.reset(seed=7)[0])
        for action in (held, held, np.ones(N, dtype=np.int8)):
            np.testing.assert_array_equal(clone.step(action)[0], fresh.step(action)[0])


# -- bad input -------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("value", [1, 0, "true", None, 1.0])
def test_non_bool_is_refused(value):
    with pytest.raises(ValueError, match="obs_last_action must be True or False"):
        gym.make("dpr/Navigation-v0", obs_last_action=value)


def test_numpy_bool_is_accepted(make_env):
    env = make_env(obs_last_action=np.bool_(True))
    assert env.unwrapped.obs_last_action is True and env.observation_space.shape == (6 * N + N + 1,)


def test_pixels_only_is_refused():
    with pytest.raises(ValueError, match="obs_last_action.*pixels_state"):
        gym.make("dpr/Navigation-v0", obs_type="pixels", obs_last_action=True)


def test_parallel_env_refuses_it():
    with pytest.raises(ValueError, match="obs_last_action"):
        parallel_env("navigation", n_robots=N, robot_model="disk", obs_last_action=True)


# -- datasets and views recorded with it -----------------------------------------------------------------------
@pytest.fixture(scope="module")
def manipulation_dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("last_action") / "manip"
    spec = CollectSpec(
        MANIPULATION,
        policy="wave-markov",
        n_robots=N,
        robot_model="disk",
        steps=30,
        env_kwargs={"obs_last_action": True},
    )
    collect(root, spec, episodes=2)
    return root


def test_dataset_features_have_the_memory_columns(manipulation_dataset, make_env):
    reader = LeRobotReader(manipulation_dataset)
    base = make_env(MANIPULATION, obs_last_action=True).unwrapped
    feature = reader.features["observation.state"]
    assert feature["shape"] == [6 * N + 4 + N + 1] and feature["names"] == base.state_names
    assert reader.episodes[0]["env_kwargs"]["obs_last_action"] is True
    for index in range(reader.num_episodes):
        data = reader.episode(index)
        state, action = data["observation.state"], data["action"]
        assert state.shape == (30, 6 * N + 4 + N + 1)
        memory = state[:, base.memory_offset : base.memory_offset + N]
        assert np.all(memory[0] == 0) and state[0, -1] == 0
        np.testing.assert_array_equal(memory[1:], action[:-1])  # each frame holds the action before it
        # held steps: +1/20 while the action repeats, 1/20 when it changes
        counts = np.rint(state[1:, -1] * HELD_STEPS_CAP).astype(int)
        changed = np.r_[True, np.any(action[1:-1] != action[:-2], axis=1)]
        for t in range(1, len(counts)):
            assert counts[t] == (1 if changed[t] else counts[t - 1] + 1), t
        assert counts.max() == 4  # the disk model's Markov wave holds each phase 4 steps


def test_view_reads_the_object_from_column_6n(manipulation_dataset):
    from dpr.viz import episode_from_dataset

    reader = LeRobotReader(manipulation_dataset)
    episode = episode_from_dataset(reader, 1)
    state = reader.episode(1)["observation.state"].astype(np.float64)
    np.testing.assert_allclose(episode.object_poses[:, 0:2], state[:, 6 * N : 6 * N + 2] / LENGTH_SCALE)
    np.testing.assert_allclose(episode.agent, episode.object_poses[:, 0:2])
    assert np.linalg.norm(episode.agent[0]) > 100  # a real object position, not the [0, 1] memory columns
