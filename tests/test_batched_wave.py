"""The batched wave policies act as the single-env ones do, env by env, on the same observations."""

import gymnasium as gym
import numpy as np
import pytest
import torch

import dpr  # noqa: F401
from dpr.policies.batched import BatchedMarkovWavePolicy, BatchedWavePolicy, bin_ranks
from dpr.policies.wave import MODEL_DEFAULTS, MarkovWavePolicy, WavePolicy


def _episodes(env_id: str, seeds, steps: int, markov: bool, **env_kwargs):
    """Observations and the single policy's actions of a pymunk disk env per seed: [K, T, D] and [K, T, N]."""
    observations, actions = [], []
    for seed in seeds:
        env = gym.make(env_id, robot_model="disk", obs_last_action=markov, **env_kwargs)
        policy = (MarkovWavePolicy if markov else WavePolicy).from_env(env)
        observation, _ = env.reset(seed=seed)
        episode_obs, episode_actions = [], []
        for _ in range(steps):
            action = policy(observation)
            episode_obs.append(observation)
            episode_actions.append(action)
            observation, *_ = env.step(action)
        observations.append(episode_obs)
        actions.append(episode_actions)
    return torch.as_tensor(np.array(observations)), np.array(actions)


@pytest.mark.parametrize("env_id", ["dpr/Navigation-v0", "dpr/Gate-v2"])
def test_the_batched_wave_acts_as_the_single_wave(env_id):
    observations, expected = _episodes(env_id, seeds=[3, 4, 5], steps=60, markov=False, n_robots=9)
    policy = BatchedWavePolicy.for_robot_model(3, 9, "disk")
    got = np.stack([policy(observations[:, t]).numpy() for t in range(observations.shape[1])], axis=1)
    np.testing.assert_array_equal(got, expected)


def test_the_batched_markov_wave_acts_as_the_single_one():
    observations, expected = _episodes("dpr/Navigation-v0", seeds=[7, 8], steps=60, markov=True, n_robots=16)
    policy = BatchedMarkovWavePolicy(16, hold_steps=4)
    got = np.stack([policy(observations[:, t]).numpy() for t in range(observations.shape[1])], axis=1)
    np.testing.assert_array_equal(got, expected)


def test_a_reset_restarts_only_the_masked_envs():
    policy = BatchedWavePolicy(2, 4, hold_steps=1)
    observation = torch.zeros(2, 24)
    observation[:, 0:24:6] = torch.tensor([0.1, 0.2, 0.3, 0.4])  # four robots in four bins along x
    first = policy(observation)
    policy(observation)
    policy.reset(torch.tensor([True, False]))
    third = policy(observation)
    assert torch.equal(third[0], first[0]) and not torch.equal(third[1], first[1])


def test_bin_ranks_count_only_non_empty_bins():
    bins = torch.tensor([[0, 5, 5, 9], [2, 2, 2, 2]])
    assert bin_ranks(bins).tolist() == [[0, 1, 1, 2], [0, 0, 0, 0]]


def test_the_batched_decentralised_wave_acts_as_its_adapter():
    """Against DecentralisedWavePolicy.for_env on Unresponsive (dead robots among them), one env restarted midway."""
    from dpr.policies.batched import BatchedDecentralisedWavePolicy
    from dpr.policies.decentralised import DecentralisedWavePolicy

    envs = [gym.make("dpr/Unresponsive-v0", robot_model="disk") for _ in range(2)]
    singles = [DecentralisedWavePolicy.for_env(env) for env in envs]
    batched = BatchedDecentralisedWavePolicy(2, 9, **MODEL_DEFAULTS["disk"])
    observations = [env.reset(seed=seed)[0] for env, seed in zip(envs, (11, 12))]
    for policy in singles:
        policy.reset()
    for step in range(120):
        if step == 50:  # env 1 starts again: its clock restarts, env 0's runs on
            observations[1] = envs[1].reset(seed=13)[0]
            singles[1].reset()
            batched.reset(torch.tensor([False, True]))
        actions = batched(torch.as_tensor(np.stack(observations)))
        for i, (env, policy) in enumerate(zip(envs, singles)):
            expected = policy(observations[i])
            np.testing.assert_array_equal(actions[i].numpy(), expected, err_msg=f"env {i}, step {step}")
            observations[i] = env.step(expected)[0]
