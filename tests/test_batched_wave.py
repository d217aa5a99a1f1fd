"""The batched waves (dpr.policies.batched_wave) act as the single-env waves do, row by row, on the same
observations: pymunk disk envs are stepped by the single policies, and every observation is fed to both."""

import gymnasium as gym
import numpy as np
import pytest

torch = pytest.importorskip("torch")

import dpr  # noqa: E402,F401  (registers the ids)
from dpr.policies.batched_wave import (  # noqa: E402
    BatchedDecentralisedWavePolicy,
    BatchedMarkovWavePolicy,
    BatchedWavePolicy,
)
from dpr.policies.decentralised import DecentralisedWavePolicy  # noqa: E402
from dpr.policies.wave import MODEL_DEFAULTS, MarkovWavePolicy, WavePolicy  # noqa: E402

STEPS = 240
RESTART = 100  # the step at which env 1 starts a new episode (its policy memory resets; the others' must not)
SEEDS = (3, 4, 5)


def _compare(env_id, env_kwargs, single_policy, batched_policy, as_tensor=False):
    """Step len(SEEDS) pymunk disk envs with their single policies; the batched policy must give the same
    actions from the stacked observations at every step. Returns how many robot-steps expanded."""
    envs = [gym.make(env_id, robot_model="disk", **env_kwargs) for _ in SEEDS]
    policies = [single_policy(env) for env in envs]
    observations = []
    for env, policy, seed in zip(envs, policies, SEEDS):
        observations.append(env.reset(seed=seed)[0])
        policy.reset()
    episode_start = np.ones(len(SEEDS), dtype=bool)
    expanded = 0
    for step in range(STEPS):
        if step == RESTART:
            observations[1] = envs[1].reset(seed=99)[0]
            policies[1].reset()
            episode_start[1] = True
        stacked = np.stack(observations)
        batched = batched_policy(torch.as_tensor(stacked) if as_tensor else stacked, episode_start)
        batched = batched.cpu().numpy() if as_tensor else batched
        for i, (env, policy) in enumerate(zip(envs, policies)):
            action = policy(observations[i])
            assert np.array_equal(np.asarray(action), batched[i]), f"env {i}, step {step}: {action} vs {batched[i]}"
            expanded += int(np.sum(np.asarray(action) > 0))
            observations[i], _, terminated, truncated, _ = env.step(action)
            assert not (terminated or truncated)
        episode_start[:] = False
    return expanded


def test_batched_wave_gives_the_single_wave_actions():
    hold = MODEL_DEFAULTS["disk"]["hold_steps"]
    batched = BatchedWavePolicy(len(SEEDS), 9, "multibinary", hold_steps=hold)
    assert _compare("dpr/Gate-v2", {}, WavePolicy.from_env, batched) > 0


def test_batched_wave_from_the_far_side_with_discrete_actions():
    hold = MODEL_DEFAULTS["disk"]["hold_steps"]
    batched = BatchedWavePolicy(len(SEEDS), 4, "discrete", hold_steps=hold, start_side="far")
    single = lambda env: WavePolicy.from_env(env, start_side="far")  # noqa: E731
    assert _compare("dpr/Navigation-v0", {"n_robots": 4, "action_type": "discrete"}, single, batched, True) > 0


def test_batched_markov_wave_gives_the_single_markov_wave_actions():
    kwargs = {"n_robots": 16, "obs_last_action": True}
    batched = BatchedMarkovWavePolicy(len(SEEDS), 16, hold_steps=MODEL_DEFAULTS["disk"]["hold_steps"])
    assert _compare("dpr/Navigation-v0", kwargs, MarkovWavePolicy.from_env, batched, as_tensor=True) > 0


def test_batched_decentralised_wave_gives_the_adapter_actions():
    batched = BatchedDecentralisedWavePolicy(
        len(SEEDS), 9, "continuous", hold_steps=MODEL_DEFAULTS["disk"]["hold_steps"]
    )
    kwargs = {"action_type": "continuous"}
    assert _compare("dpr/Unresponsive-v0", kwargs, DecentralisedWavePolicy.for_env, batched) > 0


def test_from_env_takes_the_vector_env_settings():
    envs = gym.make_vec(
        "dpr/Navigation-v0", num_envs=2, vectorization_mode="vector_entry_point", robot_model="disk", n_robots=4
    )
    wave = BatchedWavePolicy.from_env(envs)
    assert (wave.num_envs, wave.n_robots, wave.hold_steps) == (2, 4, MODEL_DEFAULTS["disk"]["hold_steps"])
    assert BatchedDecentralisedWavePolicy.from_env(envs).clock_period == 4 * wave.hold_steps
    with pytest.raises(ValueError, match="obs_last_action"):
        BatchedMarkovWavePolicy.from_env(envs)
    with pytest.raises(ValueError, match="observations"):
        wave(np.zeros((3, 24), dtype=np.float32))
    with pytest.raises(ValueError, match="episode_start"):
        wave(np.zeros((2, 24), dtype=np.float32), np.zeros(2, dtype=np.int64))
