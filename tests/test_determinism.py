"""Seeding, bit-for-bit reproducibility, pickling and subprocess vector envs."""

import functools
import pickle

import gymnasium as gym
import numpy as np
import pytest
from helpers import ENV_IDS, ROBOT_MODELS


def _rollout(env_id, robot_model, seed, actions, **kwargs):
    env = gym.make(env_id, robot_model=robot_model, n_robots=actions.shape[1], **kwargs)
    obs, info = env.reset(seed=seed)
    observations, rewards, infos = [obs], [], [info]
    for action in actions:
        obs, reward, terminated, truncated, info = env.step(action)
        observations.append(obs)
        rewards.append(reward)
        infos.append(info)
        assert not truncated
    env.close()
    return observations, rewards, infos


@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
def test_same_seed_same_actions_bit_identical(env_id, robot_model):
    actions = np.random.default_rng(0).integers(0, 2, size=(50, 4)).astype(np.int8)
    obs_a, rew_a, info_a = _rollout(env_id, robot_model, 123, actions)
    obs_b, rew_b, info_b = _rollout(env_id, robot_model, 123, actions)
    for a, b in zip(obs_a, obs_b):
        assert np.array_equal(a, b)
    assert rew_a == rew_b
    for a, b in zip(info_a, info_b):
        assert np.array_equal(a["centre_of_mass"], b["centre_of_mass"])
        assert a["total_distance"] == b["total_distance"]
    # and the rollout did something
    assert not np.array_equal(obs_a[0], obs_a[-1])


def test_reset_in_same_env_is_reproducible():
    """Re-seeding the same env instance (new physics world each reset) gives the same trajectory."""
    env = gym.make("dpr/Manipulation-v0", robot_model="paddle", n_robots=4)
    actions = np.random.default_rng(1).integers(0, 2, size=(30, 4)).astype(np.int8)
    runs = []
    for _ in range(2):
        obs, _ = env.reset(seed=7)
        trace = [obs]
        for a in actions:
            trace.append(env.step(a)[0])
        runs.append(np.array(trace))
        # an unseeded reset in between must not disturb the next seeded one
        env.reset()
        env.step(actions[0])
    assert np.array_equal(runs[0], runs[1])
    env.close()


def test_pixel_observations_are_reproducible():
    actions = np.random.default_rng(2).integers(0, 2, size=(10, 3)).astype(np.int8)
    obs_a, *_ = _rollout("dpr/Gate-v0", "paddle", 5, actions, obs_type="pixels_state", image_size=48)
    obs_b, *_ = _rollout("dpr/Gate-v0", "paddle", 5, actions, obs_type="pixels_state", image_size=48)
    for a, b in zip(obs_a, obs_b):
        assert np.array_equal(a["pixels"], b["pixels"]) and np.array_equal(a["state"], b["state"])


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_different_seeds_different_starts(env_id):
    env = gym.make(env_id, robot_model="disk", n_robots=4)
    starts = []
    for seed in range(10):
        obs, info = env.reset(seed=seed)
        starts.append(obs)
    for i in range(len(starts)):
        for j in range(i + 1, len(starts)):
            assert not np.array_equal(starts[i], starts[j])
    # the start centre is spread around the goal, not always on one side
    angles = [np.arctan2(s[1::6][:4].mean(), s[0::6][:4].mean()) for s in starts]
    assert np.ptp(angles) > 1.0
    env.close()


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_pickle_reset_env(env_id, robot_model):
    env = gym.make(env_id, robot_model=robot_model, n_robots=4, obs_type="pixels_state", image_size=32)
    obs, _ = env.reset(seed=3)
    for a in np.eye(4, dtype=np.int8):
        env.step(a)
    for original in (env, env.unwrapped):
        clone = pickle.loads(pickle.dumps(original))
        obs2, info2 = clone.reset(seed=3)
        assert np.array_equal(obs["state"], obs2["state"])
        assert np.array_equal(obs["pixels"], obs2["pixels"])
        # the clone steps like a fresh env
        fresh = gym.make(env_id, robot_model=robot_model, n_robots=4, obs_type="pixels_state", image_size=32)
        fresh.reset(seed=3)
        a = np.array([1, 0, 1, 1], dtype=np.int8)
        for _ in range(5):
            x = clone.step(a)[0]
            y = fresh.step(a)[0]
            assert np.array_equal(x["state"], y["state"])
            assert np.array_equal(x["pixels"], y["pixels"])
        fresh.close()


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
def test_pickle_mid_episode_keeps_joint_state(robot_model):
    """A world pickled (or deep-copied) mid-episode keeps what its joints are set to: magnet rod lengths,
    motor rates, disk radii. (World defines __getstate__ so that worlds pickle; pymunk itself does not
    carry PinJoint.distance through a pickle, it re-measures it from the bodies.)"""
    import pymunk

    env = gym.make("dpr/Navigation-v0", robot_model=robot_model, n_robots=4)
    env.reset(seed=0)
    for action in ([1, 0, 1, 0], [1, 1, 0, 0], [0, 1, 1, 0]):
        env.step(np.array(action, dtype=np.int8))
    world = env.unwrapped.world
    clone = pickle.loads(pickle.dumps(env.unwrapped)).world

    def joint_state(w):
        rows = []
        for c in w.space.constraints:
            if isinstance(c, pymunk.PinJoint):
                rows.append(("pin", c.distance, c.max_force))
            elif isinstance(c, pymunk.SimpleMotor):
                rows.append(("motor", c.rate, c.max_force))
        return rows

    ours, theirs = joint_state(world), joint_state(clone)
    assert [r[0] for r in ours] == [r[0] for r in theirs]
    np.testing.assert_allclose([r[1:] for r in theirs], [r[1:] for r in ours], rtol=0, atol=1e-9)
    radii = sorted(s.radius for s in world.space.shapes if isinstance(s, pymunk.Circle))
    assert sorted(s.radius for s in clone.space.shapes if isinstance(s, pymunk.Circle)) == radii
    np.testing.assert_array_equal(clone.swarm.position, world.swarm.position)
    env.close()


def test_pickle_env_with_renderer():
    env = gym.make("dpr/Gate-v0", robot_model="disk", n_robots=4, render_mode="rgb_array", render_size=64)
    env.reset(seed=1)
    frame = env.render()
    clone = pickle.loads(pickle.dumps(env))
    clone.reset(seed=1)
    assert np.array_equal(clone.render(), frame)
    env.close()
    clone.close()


def test_subproc_vec_env_matches_local_envs():
    from stable_baselines3.common.vec_env import SubprocVecEnv

    fns = [functools.partial(gym.make, "dpr:dpr/Navigation-v0", robot_model="disk", n_robots=4) for _ in range(2)]
    vec = SubprocVecEnv(fns, start_method="spawn")
    try:
        vec.seed(40)
        obs = vec.reset()
        assert obs.shape == (2, 24) and obs.dtype == np.float32
        actions = np.array([[1, 1, 0, 0], [0, 1, 0, 1]], dtype=np.int8)
        local = []
        for i in range(2):
            env = gym.make("dpr/Navigation-v0", robot_model="disk", n_robots=4)
            first, _ = env.reset(seed=40 + i)
            assert np.array_equal(obs[i], first)
            local.append(env)
        assert not np.array_equal(obs[0], obs[1])
        for _ in range(3):
            obs, rewards, dones, infos = vec.step(actions)
            assert obs.shape == (2, 24) and rewards.shape == (2,) and dones.shape == (2,)
            for i, env in enumerate(local):
                o, r, *_ = env.step(actions[i])
                assert np.array_equal(obs[i], o)
                assert rewards[i] == pytest.approx(r, rel=1e-6)
    finally:
        vec.close()
