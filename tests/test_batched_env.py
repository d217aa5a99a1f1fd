"""The batched engine behind Gymnasium's vector API: spaces, seeding, autoreset and bad input."""

import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.vector import AutoresetMode, VectorEnv

import dpr  # noqa: F401
from dpr.checks import ParameterError
from dpr.envs import ENV_IDS


def make(env_id="dpr/Navigation-v0", num_envs=3, **kwargs):
    kwargs.setdefault("robot_model", "disk")
    return gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point", **kwargs)


@pytest.mark.parametrize("env_id", sorted(ENV_IDS.values()))
def test_make_vec_gives_the_single_envs_spaces(env_id):
    venv, single = make(env_id, n_robots=4), gym.make(env_id, robot_model="disk", n_robots=4)
    assert isinstance(venv, VectorEnv) and venv.num_envs == 3
    assert venv.single_observation_space == single.observation_space
    assert venv.single_action_space == single.action_space
    assert venv.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    observation, info = venv.reset(seed=0)
    assert observation.shape == (3, *single.observation_space.shape) and observation.dtype == np.float32
    assert info["_projected_displacement"].all()


@pytest.mark.parametrize("env_id", ["dpr/Navigation-v0", "dpr/Gate-v2", "dpr/Unresponsive-v0", "dpr/Manipulation-v0"])
def test_env_i_starts_where_the_single_env_starts_with_seed_plus_i(env_id):
    observations, _ = make(env_id).reset(seed=40)
    for i in range(3):
        single, _ = gym.make(env_id, robot_model="disk").reset(seed=40 + i)
        np.testing.assert_allclose(observations[i], single, atol=1e-6)


def test_the_same_seed_gives_the_same_trajectories():
    def run():
        venv = make(num_envs=2)
        venv.reset(seed=5)
        actions = np.random.default_rng(0).integers(0, 2, size=(30, 2, 9))
        return np.stack([venv.step(action)[0] for action in actions])

    np.testing.assert_array_equal(run(), run())


def test_autoreset_is_next_step():
    venv = make(num_envs=2, max_episode_steps=3)
    first, _ = venv.reset(seed=1)
    for _ in range(3):
        _, _, terminated, truncated, _ = venv.step(np.ones((2, 9), dtype=np.int8))
    assert truncated.all() and not terminated.any()
    observation, reward, terminated, truncated, _ = venv.step(np.ones((2, 9), dtype=np.int8))
    assert (reward == 0).all() and not (terminated | truncated).any()
    # the next episode's start comes from each env's own generator, not from the first seed again
    assert not np.array_equal(observation, first)
    assert venv.unwrapped.steps.tolist() == [0, 0]


def test_the_tensor_interface_resets_in_the_same_step():
    venv = make(num_envs=2, max_episode_steps=2).unwrapped
    start = venv.reset_tensors(seed=3)
    assert isinstance(start, torch.Tensor) and start.shape == (2, venv.single_observation_space.shape[0])
    venv.step_tensors(torch.ones(2, 9))
    observation, reward, terminated, truncated, final = venv.step_tensors(torch.ones(2, 9))
    assert truncated.all() and not torch.equal(observation, final)
    assert venv.steps.tolist() == [0, 0]


def test_manipulations_approach_shaping_adds_the_swarms_approach_to_the_ball():
    """As ManipulationEnv: reward + weight * (the swarm-ball distance before the step - after it)."""
    plain = make("dpr/Manipulation-v0", num_envs=2).unwrapped
    shaped = make("dpr/Manipulation-v0", num_envs=2, approach_reward=2.0).unwrapped
    plain.reset(seed=8), shaped.reset(seed=8)
    actions = np.random.default_rng(1).integers(0, 2, size=(20, 2, 9))
    approached = 0.0
    for action in actions:
        before = shaped._swarm_object_gap().numpy()
        reward = plain.step(action)[1]
        shaped_reward = shaped.step(action)[1]
        change = before - shaped._swarm_object_gap().numpy()
        np.testing.assert_allclose(shaped_reward, reward + 2.0 * change, atol=1e-4)
        approached += np.abs(change).sum()
    assert approached > 0.1  # the shaping was exercised, not a zero added to a zero


def test_a_compiled_env_follows_the_eager_one(monkeypatch):
    """``compile=True`` compiles the world's steps and the env's work around them (observation, rewards, trackers,
    the sanity check): the same observations and rewards as eager, to the compiled physics' rounding."""
    import dpr.envs.batched
    from dpr.sim.batched import SolverSettings

    few = lambda compile: SolverSettings(iterations=2, substeps=1, compile=compile)  # noqa: E731 (compiles in seconds)
    monkeypatch.setattr(dpr.envs.batched, "SolverSettings", few)
    actions = torch.as_tensor(np.random.default_rng(2).integers(0, 2, size=(12, 3, 4)))
    runs = []
    for compile in (False, True):
        venv = make("dpr/Manipulation-v0", n_robots=4, action_repeat=2, approach_reward=1.0, compile=compile)
        venv = venv.unwrapped
        assert venv.world.compiled is compile
        venv.reset_tensors(seed=6)
        steps = [venv.step_tensors(action)[:2] for action in actions]
        runs.append([torch.stack(values) for values in zip(*steps)] + [venv.total_distance])
    for eager, compiled in zip(*runs):
        torch.testing.assert_close(compiled, eager, atol=1e-3, rtol=1e-4)
    assert runs[0][2].min() > 0  # the swarms moved: the trackers were exercised


def test_the_paddle_model_is_refused_by_name():
    with pytest.raises(ParameterError, match="robot_model.*paddle"):
        make(robot_model="paddle")
    with pytest.raises(ParameterError, match="robot_model.*paddle"):  # the single env's default, not silently disk
        gym.make_vec("dpr/Navigation-v0", num_envs=2)


@pytest.mark.parametrize("num_envs", [0, -1])
def test_num_envs_must_be_positive(num_envs):
    with pytest.raises((ParameterError, ValueError), match="num_envs"):
        make(num_envs=num_envs)


def test_pixels_are_refused_by_name():
    with pytest.raises(ParameterError, match="obs_type"):
        make(obs_type="pixels")


def test_import_dpr_does_not_import_torch():
    code = "import sys, dpr, gymnasium; gymnasium.make('dpr/Navigation-v0'); print('torch' in sys.modules)"
    assert (
        subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
        == "False"
    )
