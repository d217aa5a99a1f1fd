"""The PettingZoo parallel env (one agent per robot), its SB3 adapter, and vectorised Gymnasium/SB3 envs."""

import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from helpers import load_tool

with warnings.catch_warnings():
    warnings.simplefilter("ignore", DeprecationWarning)  # pettingzoo.test loads its own deprecated env modules
    from pettingzoo.test import parallel_api_test, parallel_seed_test

from dpr.envs import ENV_IDS, MAX_EPISODE_STEPS, TASK_CLASSES, parallel_env
from dpr.envs.parallel import (
    MAX_NEIGHBOURS,
    LocalObservation,
    ParticleParallelEnv,
    local_observation_size,
    local_observations,
)
from dpr.policies.wave import WavePolicy
from dpr.sim import constants as C

TASKS = tuple(TASK_CLASSES)
SMALL = {"n_robots": 4, "robot_model": "disk"}


def random_actions(env: ParticleParallelEnv) -> dict:
    return {agent: env.action_space(agent).sample() for agent in env.agents}


# -- PettingZoo API ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("task", TASKS)
@pytest.mark.parametrize(
    "options",
    [{}, {"local_obs": True}, {"action_type": "continuous", "shared_reward": False}],
    ids=["global", "local", "continuous-split"],
)
def test_pettingzoo_api_and_seed_tests_pass_without_warnings(task, options):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # pettingzoo's checks report most problems as warnings
        # max_episode_steps < num_cycles: the end of an episode (agents -> []) is exercised too
        env = parallel_env(task, max_episode_steps=25, **SMALL, **options)
        parallel_api_test(env, num_cycles=40)
        parallel_seed_test(lambda: parallel_env(task, **SMALL, **options), num_cycles=40)


def test_spaces_agents_and_defaults():
    env = parallel_env("manipulation", n_robots=5, robot_model="disk")
    assert env.possible_agents == [f"robot_{i}" for i in range(5)]
    assert env.agents == []  # until reset
    assert env.max_episode_steps == MAX_EPISODE_STEPS
    assert env.action_space("robot_2") == spaces.Discrete(2)
    assert env.observation_space("robot_2").shape == (6 * 5 + 4,)
    assert env.observation_space("robot_2") is env.observation_space("robot_2")
    assert env.observation_space("robot_1") is not env.observation_space("robot_2")  # seeded separately
    with pytest.raises(ValueError, match="robot_9"):
        env.action_space("robot_9")

    continuous = parallel_env("navigation", action_type="continuous", local_obs=True, max_neighbours=3, **SMALL)
    assert continuous.action_space("robot_0") == spaces.Box(0.0, 1.0, (1,), dtype=np.float32)
    # own 6, 3 neighbour slots of 6 and their mask, goal signal 3
    assert continuous.observation_space("robot_0").shape == (6 + 7 * 3 + 3,) == (local_observation_size(3, False),)


# -- same trajectory as the super-agent env ------------------------------------------------------------------
@pytest.mark.parametrize(
    "task, kwargs",
    [
        ("navigation", {"n_robots": 9, "robot_model": "paddle"}),
        ("unresponsive", {"n_robots": 9, "robot_model": "disk"}),
        ("manipulation", {"n_robots": 9, "robot_model": "disk", "action_type": "continuous"}),
    ],
)
def test_wave_rollout_matches_the_super_agent_env_bit_for_bit(task, kwargs):
    steps, seed = 100, 7
    single = gym.make(ENV_IDS[task], **kwargs)
    parallel = parallel_env(task, **kwargs)
    policy = WavePolicy.from_env(single)
    obs, info = single.reset(seed=seed)
    pobs, pinfos = parallel.reset(seed=seed)
    policy.reset()
    assert all(np.array_equal(pobs[agent], obs) for agent in parallel.agents)
    moved = False
    for _ in range(steps):
        action = policy(obs)
        obs, reward, terminated, truncated, info = single.step(action)
        per_agent = {agent: action[i] for i, agent in enumerate(parallel.possible_agents)}
        pobs, prewards, pterms, ptruncs, pinfos = parallel.step(per_agent)
        for agent in parallel.possible_agents:
            assert pobs[agent].tobytes() == obs.tobytes()
            assert prewards[agent] == reward
            assert (pterms[agent], ptruncs[agent]) == (terminated, truncated)
        assert pinfos["robot_0"]["projected_displacement"] == info["projected_displacement"]
        moved |= reward != 0.0
    assert moved  # the swarm actually moved during the comparison (not two idle, trivially equal runs)
    assert parallel.state().tobytes() == obs.tobytes()


def test_rewards_shared_or_split_equally():
    shared = parallel_env("navigation", n_robots=6, robot_model="disk")
    split = parallel_env("navigation", n_robots=6, robot_model="disk", shared_reward=False)
    shared.reset(seed=3)
    split.reset(seed=3)
    rng = np.random.default_rng(0)
    total = 0.0
    for _ in range(20):
        actions = {agent: int(rng.integers(2)) for agent in shared.agents}
        _, r_shared, *_ = shared.step(actions)
        _, r_split, *_ = split.step(actions)
        assert len(set(r_shared.values())) == 1 and len(set(r_split.values())) == 1
        assert sum(r_split.values()) == pytest.approx(r_shared["robot_0"], rel=1e-12, abs=1e-12)
        total += abs(r_shared["robot_0"])
    assert total > 0  # non-trivial rewards were compared


# -- local observations --------------------------------------------------------------------------------------
def test_local_observation_layout_on_a_hand_made_state():
    # robots 0..3 on a line at x = 0, 60, 150, 1000 (units); robot 4 at (0, 40); neighbour range 100
    xy = np.array([[0, 0], [60, 0], [150, 0], [1000, 0], [0, 40]], dtype=float)
    robots = np.zeros((5, 6), dtype=np.float32)
    robots[:, 0:2] = xy / 1000.0
    robots[:, 2] = np.arange(5) + 10  # a per-robot tag in vx
    robots[:, 5] = [0.0, 1.0, 0.5, 0.0, 0.25]
    state = np.concatenate([robots.ravel(), np.float32([0.1, 0.2, 0.3, 0.4])])  # + object features
    rows = local_observations(state, 5, neighbour_range=100.0, layout=LocalObservation(2, has_object=True))
    assert rows.shape == (5, local_observation_size(2, True)) == (5, 6 + 14 + 3 + 4)
    k = 2
    own, slots = rows[:, :6], rows[:, 6 : 6 + 6 * k].reshape(5, k, 6)
    mask, goal, obj = rows[:, 6 + 6 * k : 6 + 7 * k], rows[:, 6 + 7 * k : 9 + 7 * k], rows[:, -4:]
    np.testing.assert_array_equal(own, robots)
    np.testing.assert_allclose(obj, [[0.1, 0.2, 0.3, 0.4]] * 5)
    np.testing.assert_allclose(goal[3], [-1.0, 0.0, 1.0], atol=1e-7)  # toward the goal at the origin, 1000 away
    np.testing.assert_array_equal(goal[0], [0.0, 0.0, 0.0])  # on the goal: no direction
    # robot 0: neighbours 4 (40 away) then 1 (60 away), nearest first; relative positions
    np.testing.assert_array_equal(mask[0], [1, 1])
    np.testing.assert_array_equal(slots[0, :, 2], [14, 11])
    np.testing.assert_allclose(slots[0, 0, 0:2], [0.0, 0.04], atol=1e-7)
    np.testing.assert_allclose(slots[0, 1, 0:2], [0.06, 0.0], atol=1e-7)
    assert slots[0, 1, 5] == 1.0
    # robot 1: 0 (60), 4 (72.1) and 2 (90) are in range; only the 2 nearest are kept
    np.testing.assert_array_equal(slots[1, :, 2], [10, 14])
    # robot 2: one neighbour (1, at -90 units), the other slot is padding
    np.testing.assert_array_equal(mask[2], [1, 0])
    np.testing.assert_allclose(slots[2, 0, 0:2], [-0.09, 0.0], atol=1e-7)
    assert not slots[2, 1].any()
    # robot 3: alone
    assert not mask[3].any() and not slots[3].any()


def test_local_observations_in_the_env_follow_the_global_state():
    env = parallel_env("unresponsive", n_robots=9, robot_model="disk", local_obs=True)
    obs, _ = env.reset(seed=0)
    policy = WavePolicy(9, hold_steps=4, start_side="far")
    for _ in range(15):
        state = env.state()
        action = policy(state)
        obs, *_ = env.step({agent: action[i] for i, agent in enumerate(env.agents)})
    state = env.state()
    dead = env.swarm_env.world.dead  # Unresponsive: each robot's row ends with its own dead flag
    expected = local_observations(
        state, 9, env.swarm_env.swarm_class.magnet_range, LocalObservation(MAX_NEIGHBOURS), dead=dead
    )
    for i, agent in enumerate(env.possible_agents):
        np.testing.assert_array_equal(obs[agent], expected[i])
        np.testing.assert_array_equal(obs[agent][:6], state[6 * i : 6 * i + 6])
        assert env.observation_space(agent).contains(obs[agent])
    np.testing.assert_array_equal(expected[:, -1], dead)
    mask = expected[:, 6 + 6 * MAX_NEIGHBOURS : 6 + 7 * MAX_NEIGHBOURS]
    assert mask.sum(axis=1).min() >= 1  # a connected swarm: everybody has a magnet neighbour
    with pytest.raises(ValueError):
        obs["robot_0"][0] = 1.0  # read-only: shared buffers must not be edited by a learner


# -- dead robots, episode end, render --------------------------------------------------------------------------
def test_dead_robots_stay_agents_and_their_actions_are_ignored():
    env = parallel_env("unresponsive", n_robots=6, robot_model="disk", n_dead=2)
    _, infos = env.reset(seed=5)
    dead = [agent for agent in env.agents if infos[agent]["dead"]]
    assert len(dead) == 2 and len(env.agents) == 6
    assert [int(a.split("_")[1]) for a in dead] == infos["robot_0"]["dead_robots"].tolist()
    for _ in range(10):
        obs, _, _, _, infos = env.step(dict.fromkeys(env.agents, 1))
    expansion = obs["robot_0"][: 6 * 6].reshape(6, 6)[:, 5]
    for i, agent in enumerate(env.possible_agents):
        assert infos[agent]["dead"] == (agent in dead)
        assert (expansion[i] == 0.0) == (agent in dead)


def test_truncation_after_max_episode_steps_ends_every_agent():
    env = parallel_env("gate", max_episode_steps=3, **SMALL)
    env.reset(seed=0)
    for step in range(3):
        _, _, terms, truncs, _ = env.step(random_actions(env))
        assert set(truncs) == set(env.possible_agents)
        assert all(truncs.values()) == (step == 2) and not any(terms.values())
    assert env.agents == []
    with pytest.raises(RuntimeError, match="reset"):
        env.step({})
    env.reset(seed=1)
    assert env.agents == env.possible_agents


def test_termination_of_the_super_agent_env_terminates_every_agent(monkeypatch):
    env = parallel_env("navigation", **SMALL)
    env.reset(seed=0)
    base_step = env.swarm_env.step

    def reaching_the_goal(action):
        obs, reward, _, truncated, info = base_step(action)
        return obs, reward, True, truncated, info

    monkeypatch.setattr(env.swarm_env, "step", reaching_the_goal)
    _, _, terms, truncs, _ = env.step(random_actions(env))
    assert all(terms.values()) and not any(truncs.values()) and len(terms) == 4
    assert env.agents == []


def test_render_passes_through():
    env = parallel_env("manipulation", render_mode="rgb_array", render_size=64, **SMALL)
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (64, 64, 3) and frame.dtype == np.uint8 and frame.std() > 0
    assert parallel_env("navigation", **SMALL).render() is None  # no render_mode, as the Gymnasium env


# -- bad input ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"task": "swim"}, "task must be one of"),
        ({"task": "navigation", "action_type": "discrete"}, "no per-agent meaning"),
        ({"task": "navigation", "obs_type": "pixels"}, "obs_type='state' only"),
        ({"task": "navigation", "max_episode_steps": 0}, "max_episode_steps"),
        ({"task": "navigation", "local_obs": "yes"}, "local_obs"),
        ({"task": "navigation", "shared_reward": 1}, "shared_reward"),
        ({"task": "navigation", "max_neighbours": 0}, "max_neighbours"),
        ({"task": "navigation", "n_robots": 0}, "n_robots"),
    ],
)
def test_bad_constructor_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        parallel_env(**kwargs)


def test_bad_actions_name_the_agent():
    env = parallel_env("navigation", **SMALL)
    env.reset(seed=0)
    good = dict.fromkeys(env.agents, 0)
    with pytest.raises(ValueError, match="unknown agent.*robot_7"):
        env.step({**good, "robot_7": 1})
    with pytest.raises(ValueError, match="no action for agent.*robot_2"):
        env.step({a: v for a, v in good.items() if a != "robot_2"})
    for value in (2, 0.5, -1, "1", None, np.array([0, 1]), [[1]]):
        with pytest.raises(ValueError, match="action of 'robot_3' must be 0 or 1"):
            env.step({**good, "robot_3": value})
    with pytest.raises(ValueError, match="dict"):
        env.step([0, 0, 0, 0])
    # accepted forms: ints, bools, numpy scalars, one-element arrays, floats equal to 0 or 1
    env.step({"robot_0": 1, "robot_1": True, "robot_2": np.int64(0), "robot_3": np.array([1.0])})

    continuous = parallel_env("navigation", action_type="continuous", **SMALL)
    continuous.reset(seed=0)
    fine = dict.fromkeys(continuous.agents, 0.25)
    for value in (1.5, -0.1, np.nan, np.float32([0.2, 0.3])):
        with pytest.raises(ValueError, match=r"action of 'robot_1' must be a number in \[0, 1\]"):
            continuous.step({**fine, "robot_1": value})
    continuous.step({**fine, "robot_1": np.float32([1.0])})


def test_importing_dpr_envs_does_not_import_torch():
    code = "import sys, dpr.envs, dpr.envs.parallel; assert 'torch' not in sys.modules, 'torch imported'"
    subprocess.run([sys.executable, "-c", code], check=True)


# -- SB3: one shared policy for every robot ------------------------------------------------------------------
def test_agents_as_vec_env_trains_ppo_and_auto_resets():
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import PPO

    from dpr.envs.parallel import AgentsAsVecEnv

    venv = AgentsAsVecEnv(parallel_env("navigation", n_robots=4, robot_model="disk", max_episode_steps=64))
    assert venv.num_envs == 4 and venv.action_space == spaces.Discrete(2)
    model = PPO("MlpPolicy", venv, n_steps=32, batch_size=64, seed=0, device="cpu")
    model.learn(256)
    assert model.num_timesteps == 256

    # auto-reset at the end of an episode, SB3 style
    venv = AgentsAsVecEnv(
        parallel_env("manipulation", robot_model="disk", n_robots=3, max_episode_steps=5, action_type="continuous")
    )
    venv.seed(11)
    first = venv.reset()
    assert first.shape == (3, 6 * 3 + 4)
    for step in range(5):
        obs, rewards, dones, infos = venv.step(np.full((3, 1), 1.0, dtype=np.float32))
        assert rewards.shape == (3,) and len(set(rewards.tolist())) == 1
        assert dones.all() == (step == 4)
    assert all(info["TimeLimit.truncated"] for info in infos)
    assert infos[0]["terminal_observation"].shape == first.shape[1:]
    assert not np.array_equal(obs[0], infos[0]["terminal_observation"])  # obs is the new episode's
    # seed(11) made the first episode reproducible
    venv.seed(11)
    np.testing.assert_array_equal(venv.reset(), first)


# -- vectorised Gymnasium and SB3 envs ---------------------------------------------------------------------
@pytest.mark.parametrize("task", TASKS)
def test_make_vec_sync_and_async_agree(task):
    steps = 5
    results = {}
    for mode in ("sync", "async"):
        envs = gym.make_vec(ENV_IDS[task], num_envs=2, vectorization_mode=mode, **SMALL)
        try:
            obs, _ = envs.reset(seed=[1, 2])
            rng = np.random.default_rng(0)
            trajectory = [obs]
            for _ in range(steps):
                obs, rewards, *_ = envs.step(rng.integers(0, 2, size=(2, 4)))
                trajectory.append(obs)
            results[mode] = np.stack(trajectory)
        finally:
            envs.close()
    expected_size = 6 * 4 + (4 if TASK_CLASSES[task].has_object else 0) + (2 if task == "gate" else 0)  # the opening
    assert results["sync"].shape == (steps + 1, 2, expected_size)
    np.testing.assert_array_equal(results["sync"], results["async"])
    assert not np.array_equal(results["sync"][:, 0], results["sync"][:, 1])  # two different seeds


@pytest.mark.parametrize("task", TASKS)
def test_sb3_subproc_vec_env(task):
    pytest.importorskip("stable_baselines3")
    from stable_baselines3.common.vec_env import SubprocVecEnv

    def make():
        return gym.make(ENV_IDS[task], **SMALL)

    # fork: the workers start in milliseconds (SB3's default, forkserver, re-imports everything)
    venv = SubprocVecEnv([make, make], start_method="fork")
    try:
        venv.seed(4)
        obs = venv.reset()
        direct, _ = make().reset(seed=5)  # SB3 gives env i the seed 4 + i
        np.testing.assert_array_equal(obs[1], direct)
        for _ in range(5):
            obs, rewards, dones, infos = venv.step(np.ones((2, 4), dtype=np.int64))
        assert obs.shape == (2, direct.shape[0]) and np.isfinite(obs).all() and not dones.any()
    finally:
        venv.close()


# -- tools/bench_scale.py ------------------------------------------------------------------------------------
def test_bench_scale_runs_small_and_writes_json(tmp_path, capsys):
    import json

    bench = load_tool("bench_scale")
    out = tmp_path / "scale.json"
    argv = [
        "--parts",
        "sizes",
        "episode",
        "--sizes",
        "9",
        "16",
        "--size-steps",
        "5",
        "--size-repeats",
        "1",
        "--warmup",
        "2",
        "--episode-robots",
        "9",
        "--episode-steps",
        "10",
        "--json",
        str(out),
    ]
    assert bench.main(argv) == 0
    results = json.loads(out.read_text())
    assert [row["n_robots"] for row in results["sizes"]["rows"]] == [9, 16, 9, 16]
    assert all(row["us_per_robot_step"] > 0 for row in results["sizes"]["rows"])
    episode = results["episode"]
    assert episode["steps"] == 10 and episode["checks"]["no_physics_error"]
    assert episode["min_centre_distance"] > 0
    # tunnelling: a centre inside another robot's contracted disk; touching-contact overlap is reported apart
    contracted = C.DISK_CONTRACTED_RADIUS
    assert episode["tunnelling_below"] == round(contracted, 3)
    assert episode["min_allowed_distance"] == round(2 * contracted - 5.0, 3)
    assert episode["checks"]["no_tunnelling"] == (episode["min_centre_distance"] >= contracted)
    assert episode["checks"]["contact_within_tolerance"] == (episode["min_centre_distance"] >= 2 * contracted - 5.0)
    assert "| wave | 16 |" in capsys.readouterr().out
