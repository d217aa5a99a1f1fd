"""Per-robot behaviour cloning (`dpr bc-decentralised`): relabelling recorded frames into per-robot samples, cloning
them into one model of one robot's spaces, and running that model in centralised envs of any swarm size."""

import json
import zipfile

import gymnasium as gym
import numpy as np
import pytest
import yaml
from helpers import assert_per_robot_model_acts_and_trains, drive, tree_hash
from helpers import run_cli as run

from dpr.checks import ParameterError
from dpr.datasets.collect import CollectSpec, collect
from dpr.datasets.lerobot import LeRobotReader
from dpr.envs import parallel_env
from dpr.envs.parallel import AgentsAsVecEnv
from dpr.imitation import CloneConfig, PerRobotCloneConfig, behaviour_clone
from dpr.imitation.per_robot import behaviour_clone_per_robot, relabel_dataset, robot_actions
from dpr.policies.decentralised import DecentralisedWavePolicy, PerRobotPolicyAdapter
from dpr.policies.model_file import METADATA_MEMBER, read_model_info
from dpr.policies.per_robot_model import RobotModelPolicy
from dpr.policies.per_robot_spec import RobotModelSpec
from dpr.policies.registry import make_policy
from dpr.policies.sb3 import load_model
from dpr.rollout import roll_out

ENV = "dpr/Navigation-v0"
DISK = {"robot_model": "disk"}
# Six 64-step episodes of 16 disk robots: enough goal distances for a held-out episode to be mostly in range.
FAST = {"epochs": 25, "patience": 25, "batch_size": 128, "lr": 3e-3}


def record(root, env_id=ENV, n_robots=16, episodes=6, steps=64, policy="decentralised-wave", **env_kwargs):
    spec = CollectSpec(env_id, policy=policy, n_robots=n_robots, steps=steps, env_kwargs=env_kwargs, **DISK)
    collect(root, spec, episodes=episodes)
    return root


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return record(tmp_path_factory.mktemp("per_robot") / "dwave16")


@pytest.fixture(scope="module")
def cloned(dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("per_robot_run") / "run"
    return behaviour_clone_per_robot(dataset, ENV, PerRobotCloneConfig(**FAST), out=out, log=lambda line: None)


class Recording:
    """A per-robot adapter that keeps every robot's local observation it computed (what the policy saw live)."""

    def __init__(self, adapter: PerRobotPolicyAdapter):
        self.adapter = adapter
        self.rows = []

    def reset(self, seed=None):
        self.adapter.reset(seed)

    def __call__(self, observation):
        self.rows.append(self.adapter.local_observations(observation))
        return self.adapter(observation)


# -- relabelling ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("env_id, n_robots, env_kwargs", [(ENV, 4, {}), ("dpr/Unresponsive-v0", 9, {"n_dead": 2})])
def test_relabelled_rows_are_what_the_adapter_computes_live(tmp_path, env_id, n_robots, env_kwargs):
    root = record(tmp_path / "d", env_id, n_robots=n_robots, episodes=2, steps=50, **env_kwargs)
    reader = LeRobotReader(root)
    for index in range(reader.num_episodes):
        env = gym.make(env_id, n_robots=n_robots, max_episode_steps=50, **DISK, **env_kwargs)
        live = Recording(DecentralisedWavePolicy.for_env(env))
        roll_out(env, live, reader.episodes[index]["seed"])
        layout = live.adapter.layout
        assert layout.dead_flag == (env_id != ENV)
        rows, labels = relabel_dataset(reader, env_id, layout, [index])
        np.testing.assert_array_equal(rows, np.concatenate(live.rows))
        # the teacher's actions are a function of the relabelled rows: the clock and goal signal line up
        np.testing.assert_array_equal(labels, live.adapter.policy.act(rows))
        if layout.dead_flag:
            dead = rows[:n_robots, layout.dead.start]
            assert dead.sum() == 2 and (rows[:, layout.dead.start].reshape(-1, n_robots) == dead).all()


def test_robot_actions_of_every_action_type():
    bits = np.array([[1, 0, 1], [0, 0, 0], [1, 1, 1]])
    np.testing.assert_array_equal(robot_actions(bits.astype(np.float32), 3), bits)
    np.testing.assert_array_equal(robot_actions(np.array([[5], [0], [7]], dtype=np.int64), 3), bits)  # robot 0 = MSB
    with pytest.raises(ValueError, match="0/1 actions"):
        robot_actions(np.array([[0.5, 0.0, 1.0]], dtype=np.float32), 3)


# -- cloning -------------------------------------------------------------------------------------------------------
def test_clone_matches_the_decentralised_wave(cloned):
    first, best = cloned.history[0], cloned.history[cloned.best_epoch]
    assert best["train_accuracy"] > 0.9 and cloned.best_val_accuracy > 0.88
    assert best["val_expand_recall"] > 0.6  # not the 75% of never expanding
    assert cloned.best_val_nll < first["val_nll"] / 2


def test_model_file_is_a_per_robot_model_with_its_layout(cloned):
    assert sorted(p.name for p in cloned.run_dir.iterdir()) == ["bc_log.json", "config.yaml", "model.zip"]
    info = read_model_info(cloned.model_path)
    assert (info.algo, info.env_id, info.max_episode_steps, info.env_kwargs) == ("ppo", ENV, 64, DISK)
    spec = RobotModelSpec.from_info(info, cloned.model_path)
    assert spec == RobotModelSpec("disk", 8, 16, False, False, 4, 4, (16,), distance_period=240.0)
    model, _ = load_model(cloned.model_path)
    assert model.observation_space == spec.layout.space() and model.action_space == gym.spaces.Discrete(2)
    config = yaml.safe_load(cloned.config_path.read_text())
    assert config["per_robot"]["clock_period"] == 16 and config["datasets"][0]["n_robots"] == 16
    assert json.loads(cloned.log_path.read_text())["best_epoch"] == cloned.best_epoch
    with zipfile.ZipFile(cloned.model_path) as archive:
        assert json.loads(archive.read(METADATA_MEMBER))["per_robot"]["trained_n_robots"] == [16]


@pytest.mark.parametrize("n_robots", [1, 4, 9, 30])
def test_saved_model_runs_in_centralised_envs_of_any_size(cloned, n_robots):
    env = gym.make(ENV, n_robots=n_robots, max_episode_steps=12, **DISK)
    policy = make_policy(str(cloned.model_path), env)
    assert isinstance(policy, PerRobotPolicyAdapter) and isinstance(policy.policy, RobotModelPolicy)
    actions = []
    observation, _ = env.reset(seed=7)
    policy.reset(7)
    if n_robots == 1:  # no neighbours: every slot is padding
        assert not policy.local_observations(observation)[:, policy.layout.mask].any()
    for _ in range(12):
        action = policy(observation)
        assert env.action_space.contains(action)
        actions.append(action)
        observation, *_ = env.step(action)
    assert np.asarray(actions).shape == (12, n_robots)


def test_model_runs_in_other_action_types_and_in_the_pettingzoo_env(cloned):
    discrete = gym.make(ENV, n_robots=3, action_type="discrete", **DISK)
    policy = make_policy(str(cloned.model_path), discrete)
    observation, _ = discrete.reset(seed=1)
    policy.reset(1)
    assert discrete.action_space.contains(policy(observation))
    # and in the PettingZoo env, also as an SB3 model on the agents' VecEnv, ready for PPO to fine-tune
    assert_per_robot_model_acts_and_trains(cloned.model_path, 5)


def test_datasets_of_two_swarm_sizes_train_one_model(dataset, tmp_path):
    small = record(tmp_path / "dwave4", n_robots=4, episodes=2, steps=32)
    result = behaviour_clone_per_robot(
        [dataset, small],
        ENV,
        PerRobotCloneConfig(epochs=1, batch_size=512),
        out=tmp_path / "run",
        log=lambda line: None,
    )
    info = read_model_info(result.model_path)
    assert info.per_robot["trained_n_robots"] == [4, 16]
    assert set(result.history[-1]["val_accuracy_by_n"]) == {4, 16}


def test_cli_bc_decentralised_then_evaluate_at_another_size(dataset, tmp_path, capsys):
    out = tmp_path / "cli"
    argv = ["bc-decentralised", "--dataset", str(dataset), "--env", ENV, "--epochs", "1", "--out", str(out)]
    assert run(argv) == 0
    assert capsys.readouterr().out.strip().splitlines()[-1].startswith("best validation accuracy ")
    assert read_model_info(out / "model.zip").per_robot is not None
    evaluate = ["evaluate", "--policy", str(out / "model.zip"), "--env", ENV, "--n-robots", "25"]
    assert run([*evaluate, "--seeds", "100", "--steps", "8", "--workers", "1"]) == 0
    capsys.readouterr()
    before = tree_hash(tmp_path)
    assert run(argv) == 2  # never overwrites a run
    assert "--out" in capsys.readouterr().err
    assert run([*argv[:-2], "--out", str(tmp_path / "other"), "--robot-model", "paddle"]) == 2
    err = capsys.readouterr().err
    assert "--dataset" in err and "robot_model='disk'" in err
    assert run([*argv[:-2], "--out", str(tmp_path / "other"), "--max-neighbours", "0"]) == 2
    assert tree_hash(tmp_path) == before


def test_the_raw_distance_layout_and_model_files_that_predate_the_distance_period(dataset, tmp_path, capsys):
    """``--distance-period none`` clones on the raw distance; a file without the field (older) reads as one."""
    out = tmp_path / "raw"
    argv = ["bc-decentralised", "--dataset", str(dataset), "--epochs", "1", "--distance-period", "none"]
    assert run([*argv, "--out", str(out)]) == 0
    capsys.readouterr()
    spec = RobotModelPolicy.load(out / "model.zip").spec
    assert spec.distance_period is None and spec.layout.size == 6 + 7 * 8 + 3 + 2
    older = tmp_path / "older.zip"
    with zipfile.ZipFile(out / "model.zip") as source, zipfile.ZipFile(older, "w") as target:
        for item in source.namelist():
            data = source.read(item)
            if item == METADATA_MEMBER:
                meta = json.loads(data)
                del meta["per_robot"]["distance_period"]
                data = json.dumps(meta)
            target.writestr(item, data)
    assert RobotModelPolicy.load(older).spec == spec
    drive(env := gym.make(ENV, n_robots=25, **DISK), make_policy(str(older), env), steps=5, seed=1)
    for bad in ("0", "-60", "nan", "inf", "wavy"):
        assert run([*argv[:-1], bad, "--out", str(tmp_path / "bad")]) == 2
        assert "--distance-period" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


# -- refused -------------------------------------------------------------------------------------------------------
def test_max_neighbours_below_one_is_refused(dataset, tmp_path):
    with pytest.raises(ParameterError, match="max_neighbours"):
        behaviour_clone_per_robot(dataset, ENV, PerRobotCloneConfig(max_neighbours=0), out=tmp_path / "run")
    with pytest.raises(ParameterError, match="max_neighbours"):
        RobotModelSpec("disk", 0, 16, False, False)
    assert not (tmp_path / "run").exists()


def test_malformed_layout_in_a_model_file_is_named(cloned, tmp_path):
    bad = tmp_path / "bad.zip"
    with zipfile.ZipFile(cloned.model_path) as source, zipfile.ZipFile(bad, "w") as target:
        for item in source.namelist():
            data = source.read(item)
            if item == METADATA_MEMBER:
                meta = json.loads(data)
                meta["per_robot"]["max_neighbours"] = 0
                data = json.dumps(meta)
            target.writestr(item, data)
    with pytest.raises(ParameterError, match="policy: .*bad.zip: malformed per-robot metadata"):
        make_policy(str(bad), gym.make(ENV, n_robots=4, **DISK))


def test_envs_the_model_was_not_trained_for_are_refused(cloned):
    path = str(cloned.model_path)
    with pytest.raises(ValueError, match="paddle"):
        make_policy(path, gym.make(ENV, n_robots=4, robot_model="paddle"))
    with pytest.raises(ValueError, match="dpr/Manipulation-v0"):
        make_policy(path, gym.make("dpr/Manipulation-v0", n_robots=4, **DISK))
    with pytest.raises(ValueError, match="the model reads no object, the env gives an object in the observation"):
        make_policy(path, gym.make("dpr/Manipulation-v0", n_robots=4, **DISK))
    with pytest.raises(ValueError, match="obs_type"):
        make_policy(path, gym.make(ENV, n_robots=4, obs_type="pixels", **DISK))
    with pytest.raises(ValueError, match="it was trained on dpr/Navigation-v0, this env is dpr/Unresponsive-v0"):
        load_model(path, AgentsAsVecEnv(parallel_env("unresponsive", n_robots=4, local_obs=True, **DISK)))
    other_clock = parallel_env("navigation", n_robots=4, local_obs=True, clock_period=20, distance_period=240, **DISK)
    with pytest.raises(ValueError, match="the model reads clock_period=16, the env gives clock_period=20"):
        load_model(path, AgentsAsVecEnv(other_clock))
    raw_distance = parallel_env("navigation", n_robots=4, local_obs=True, clock_period=16, **DISK)
    with pytest.raises(
        ValueError, match="the model reads the distance's phase .distance_period=240., the env gives the raw"
    ):
        load_model(path, AgentsAsVecEnv(raw_distance))
    no_local = parallel_env("navigation", n_robots=4, **DISK)
    with pytest.raises(ValueError, match="local_obs=True"):
        load_model(path, AgentsAsVecEnv(no_local))
    with pytest.raises(ValueError, match="make_policy"):
        load_model(path, gym.make(ENV, n_robots=4, **DISK))  # the raw model cannot act on the swarm's state


def test_centralised_model_is_not_a_per_robot_model(dataset, tmp_path):
    central = record(tmp_path / "wave4", n_robots=4, episodes=2, steps=16, policy="wave")
    result = behaviour_clone(central, ENV, CloneConfig(epochs=1), out=tmp_path / "run", log=lambda line: None)
    with pytest.raises(ParameterError, match="centralised model"):
        RobotModelPolicy.load(result.model_path)
    env = parallel_env("navigation", n_robots=4, local_obs=True, clock_period=16, **DISK)
    with pytest.raises(ValueError, match="observation space"):
        load_model(result.model_path, AgentsAsVecEnv(env))


def test_datasets_that_differ_in_more_than_n_are_refused(dataset, tmp_path):
    other = record(tmp_path / "projected", ENV, n_robots=4, episodes=2, steps=16, reward="projected")
    with pytest.raises(ParameterError, match="dataset_dirs: .*may differ in n_robots and start_radius only"):
        behaviour_clone_per_robot([dataset, other], ENV, out=tmp_path / "run")
    with pytest.raises(ParameterError, match="algo"):
        behaviour_clone_per_robot(dataset, ENV, PerRobotCloneConfig(algo="dqn"), out=tmp_path / "run")
    assert not (tmp_path / "run").exists()


def test_demonstrations_from_wider_starts_clone_together_and_the_model_keeps_no_start_radius(dataset, tmp_path):
    """Wider starts teach the goal distances of larger swarms: such datasets clone with the others, and the model
    runs on the task's own starts (its file carries no start_radius)."""
    wide = record(tmp_path / "wide", ENV, n_robots=4, episodes=2, steps=16, start_radius=[150.0, 900.0])
    result = behaviour_clone_per_robot(
        [dataset, wide], ENV, PerRobotCloneConfig(epochs=1), out=tmp_path / "run", log=lambda line: None
    )
    info = read_model_info(result.model_path)
    assert "start_radius" not in info.env_kwargs
    assert RobotModelPolicy.load(result.model_path).spec.trained_n_robots == (4, 16)


def test_finetune_of_the_centralised_env_refuses_a_per_robot_model(cloned, tmp_path, capsys):
    argv = ["finetune", "--from", str(cloned.model_path), "--env", ENV, "--timesteps", "64", "--n-envs", "1"]
    assert run([*argv, "--out", str(tmp_path / "ft")]) == 2
    assert "--from" in capsys.readouterr().err and not (tmp_path / "ft").exists()


@pytest.mark.parametrize("env_id", ["dpr/Unresponsive-v0", "dpr/Gate-v0"])
def test_a_navigation_model_drives_swarms_of_the_other_tasks_without_an_object(cloned, env_id):
    """Unresponsive robots ignore commands: the model acts for every robot, not told which are dead."""
    env = gym.make(env_id, n_robots=9, **DISK)
    drive(env, make_policy(str(cloned.model_path), env), steps=20, seed=3)
