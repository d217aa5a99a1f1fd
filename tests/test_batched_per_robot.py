"""Per-robot models on the batched engine: every robot's local observation in batch, the model's actor on all of
them in one pass, the same actions as in the pymunk env, and ``dpr evaluate --engine batched`` with one."""

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

import dpr  # noqa: F401
from dpr.cli import main
from dpr.envs.local_obs import LocalObservation
from dpr.envs.particle_env import ROBOT_FEATURES
from dpr.evaluation.batched import evaluate_batched
from dpr.evaluation.scoring import evaluate
from dpr.policies.batched import BatchedPerRobotModelPolicy, make_batched_policy
from dpr.policies.batched_local_obs import batched_local_observations
from dpr.policies.registry import make_policy
from dpr.sim.disk import DiskSwarm

MODEL = str(Path(__file__).resolve().parents[1] / "models" / "decentralised-disk-bc-ppo.zip")
RANGE = float(DiskSwarm.magnet_range)


def _vector_env(env_id: str, n: int, k: int = 3, **kwargs):
    venv = gym.make_vec(env_id, num_envs=k, vectorization_mode="vector_entry_point", robot_model="disk", n_robots=n)
    return venv.unwrapped


def _numpy_rows(layout: LocalObservation, states: torch.Tensor, n: int, steps, dead) -> np.ndarray:
    return np.stack(
        [
            layout.observe(states[i].numpy(), n, RANGE, int(steps[i]), None if dead is None else dead[i].numpy())
            for i in range(len(states))
        ]
    )


@pytest.mark.parametrize(
    ("env_id", "n", "layout"),
    [
        ("dpr/Navigation-v0", 9, LocalObservation(clock_period=20, distance_period=300.0)),
        ("dpr/Navigation-v0", 16, LocalObservation(max_neighbours=4)),
        ("dpr/Unresponsive-v0", 9, LocalObservation(clock_period=7, dead_flag=True)),
        ("dpr/Unresponsive-v0", 16, LocalObservation(dead_flag=True, distance_period=240.0)),
        ("dpr/Manipulation-v0", 9, LocalObservation(has_object=True, clock_period=40)),
        ("dpr/Manipulation-v0", 16, LocalObservation(has_object=True, max_neighbours=12)),
    ],
)
def test_batched_local_observations_are_each_swarms_numpy_rows(env_id, n, layout):
    env = _vector_env(env_id, n)
    generator = torch.Generator().manual_seed(n)
    state = env.reset_tensors(seed=11)
    steps = torch.tensor([0, 5, 33])
    for _ in range(12):  # the swarms move apart from their start grids
        state, *_ = env.advance(torch.randint(0, 2, (3, n), generator=generator).float())
    dead = ~env.world.alive if layout.dead_flag else None
    if layout.dead_flag:
        assert dead.any()  # Unresponsive has dead robots
    got = batched_local_observations(state, n, RANGE, layout, steps, dead)
    expected = _numpy_rows(layout, state, n, steps, dead)
    assert got.shape == expected.shape == (3, n, layout.size) and got.dtype == torch.float32
    np.testing.assert_allclose(got.numpy(), expected, rtol=0, atol=1e-5)
    assert got[..., layout.mask].sum() > 0  # neighbours were found


def test_crowded_swarms_keep_the_nearest_with_ties_by_index():
    """Robots on a fine grid (many equal distances) and random clusters: more neighbours than slots."""
    n, layout = 16, LocalObservation(max_neighbours=5)
    generator = torch.Generator().manual_seed(3)
    grid = torch.stack(torch.meshgrid(torch.arange(4.0), torch.arange(4.0), indexing="ij"), dim=-1).reshape(n, 2)
    positions = torch.stack([grid * 0.01, grid * 0.02, torch.rand(n, 2, generator=generator) * 0.05])
    robots = torch.rand(3, n, ROBOT_FEATURES, generator=generator)
    robots[..., 0:2] = positions
    state = robots.reshape(3, -1)
    steps = torch.zeros(3, dtype=torch.long)
    got = batched_local_observations(state, n, RANGE, layout, steps)
    np.testing.assert_allclose(got.numpy(), _numpy_rows(layout, state, n, steps, None), rtol=0, atol=1e-6)
    assert (got[..., layout.mask].sum(dim=2) == 5).any()  # some robots had more neighbours than slots


def _pymunk_episodes(env_id: str, seeds, n: int, steps: int):
    """The pymunk disk env's observations and the per-robot model's actions there: [K, T, D] and [K, T, N]."""
    observations, actions = [], []
    for seed in seeds:
        env = gym.make(env_id, robot_model="disk", n_robots=n)
        policy = make_policy(MODEL, env)
        observation, _ = env.reset(seed=seed)
        policy.reset(seed)
        episode_obs, episode_actions = [], []
        for _ in range(steps):
            action = policy(observation)
            episode_obs.append(observation)
            episode_actions.append(np.asarray(action))
            observation, *_ = env.step(action)
        observations.append(episode_obs)
        actions.append(episode_actions)
    return torch.as_tensor(np.array(observations)), np.array(actions)


@pytest.mark.parametrize(("env_id", "n"), [("dpr/Navigation-v0", 9), ("dpr/Unresponsive-v0", 16)])
def test_the_batched_per_robot_model_acts_as_the_single_env_model(env_id, n):
    """On the same observations: a start grid's neighbours lie at equal distances, so the engines' states, equal
    to about 1e-7, may order a tie differently; the policy is compared on the pymunk env's observations."""
    seeds, steps = [4, 5, 6], 30
    observations, expected = _pymunk_episodes(env_id, seeds, n, steps)
    env = _vector_env(env_id, n)
    policy = make_batched_policy(MODEL, env)
    assert isinstance(policy, BatchedPerRobotModelPolicy)
    env.reset_tensors(seed=seeds)  # the same dead robots
    got = np.stack([policy(observations[:, t]).numpy() for t in range(steps)], axis=1)
    assert got.shape == expected.shape == (3, steps, n)
    np.testing.assert_array_equal(got, expected)
    assert len(np.unique(got)) == 2  # the model both expands and contracts


def test_the_batched_per_robot_model_moves_swarms_as_on_pymunk():
    seeds, kwargs = [4, 5, 6], {"n_robots": 9}
    batched = evaluate_batched(["dpr/Navigation-v0"], MODEL, seeds, steps=300, env_kwargs=kwargs)
    reference = evaluate(["dpr/Navigation-v0"], MODEL, seeds, steps=300, env_kwargs=kwargs, workers=1)
    moved = [np.array([r.metrics.projected_displacement for r in results]) for results in (batched, reference)]
    assert (moved[0] > 0).all()  # every swarm moved toward its goal
    assert np.median(moved[0]) == pytest.approx(np.median(moved[1]), rel=0.2)


def test_a_reset_restarts_the_clock_of_the_masked_envs_only():
    env = _vector_env("dpr/Navigation-v0", 9, k=2)
    policy = make_batched_policy(MODEL, env)
    observation = env.reset_tensors(seed=0)
    for _ in range(3):
        policy(observation)
    policy.reset(torch.tensor([True, False]))
    assert policy.steps.tolist() == [0, 3]


def test_a_per_robot_model_of_another_robot_model_is_refused_by_name():
    env = _vector_env("dpr/Navigation-v0", 9, k=1)
    paddle = MODEL.replace("decentralised-disk-bc-ppo", "decentralised-bc")
    with pytest.raises(ValueError, match="paddle robot model"):
        make_batched_policy(paddle, env)


def test_dpr_evaluate_engine_batched_runs_a_per_robot_model(tmp_path, capsys):
    out = tmp_path / "eval.json"
    argv = ["evaluate", "--policy", MODEL, "--env", "dpr/Navigation-v0", "--engine", "batched"]
    assert main([*argv, "--n-robots", "16", "--seeds", "1,2", "--steps", "20", "--json", str(out)]) == 0
    payload = json.loads(out.read_text())
    assert [episode["seed"] for episode in payload["episodes"]] == [1, 2]
    assert "projected_displacement" in capsys.readouterr().out
