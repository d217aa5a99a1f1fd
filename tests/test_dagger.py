"""DAgger and what it is built from: labelled collection (`dpr collect --label-policy`), behaviour cloning of
several datasets (`dpr bc --dataset A B`, hyperparameter overrides, change_weight), the DAgger loop (`dpr bc
--dagger-rounds`), and the SwarmFeatures extractor (`policy_kwargs: {features_extractor: swarm}`)."""

import dataclasses
import json
import math

import gymnasium as gym
import numpy as np
import pytest
import torch
import yaml
from helpers import rotate_scene, visited_observations
from helpers import run_cli as run

import dpr.imitation.bc as bc_module
from dpr.datasets.collect import CollectSpec, collect
from dpr.datasets.frames import ConcatFrames, FrameDataset
from dpr.datasets.lerobot import DatasetError, LeRobotReader
from dpr.envs.particle_env import ROBOT_FEATURES
from dpr.imitation import CloneConfig, DaggerConfig, behaviour_clone
from dpr.imitation.bc import measure
from dpr.imitation.dagger import dagger
from dpr.policies.features import SwarmFeatures
from dpr.policies.hyperparams import load_hyperparams
from dpr.policies.model_file import ModelInfo, write_model_info
from dpr.policies.registry import make_policy
from dpr.policies.sb3 import build_model, load_model, load_model_policy, make_vec_env
from dpr.policies.wave import MarkovWavePolicy, WavePolicy

ENV = "dpr/Navigation-v0"
N = 4
SMALL_ENV = {"n_robots": N, "robot_model": "disk"}
MEMORY = {"obs_last_action": True}
ENV_KWARGS = {**SMALL_ENV, **MEMORY}
STEPS = 30
FAST = {"batch_size": 128, "lr": 3e-3}
QUIET = {"log": lambda line: None}
SMALL_NET = {"policy_kwargs": {"net_arch": [16]}}
SWARM_NET = {"policy_kwargs": {"net_arch": [16], "features_extractor": "swarm"}}
OBS_DIM = ROBOT_FEATURES * N + N + 1  # 4 robots, then the last action and its held steps


def spec(**overrides) -> CollectSpec:
    settings = {"policy": "wave-markov", "steps": STEPS, "env_kwargs": MEMORY, **SMALL_ENV, **overrides}
    return CollectSpec(ENV, **settings)


@pytest.fixture(scope="module")
def demos(tmp_path_factory):
    """Three Markov-wave episodes (seeds 0-2) of 4 disk robots with the last action in the observation."""
    root = tmp_path_factory.mktemp("dagger") / "demos"
    collect(root, spec(), episodes=3)
    return root


@pytest.fixture(scope="module")
def labelled(tmp_path_factory):
    """Two episodes (seeds 10, 11) driven by the random policy, labelled by the Markov wave."""
    root = tmp_path_factory.mktemp("dagger") / "labelled"
    collect(root, spec(policy="random", label_policy="wave-markov"), episodes=2, seed=10)
    return root


@pytest.fixture(scope="module")
def others(tmp_path_factory):
    """Two-episode datasets that differ from ``demos`` in one way each."""
    base = tmp_path_factory.mktemp("dagger_others")
    variants = {
        "n5": spec(n_robots=5),
        "no_memory": spec(policy="wave", env_kwargs={}),
        "steps20": spec(steps=20),
    }
    for name, variant in variants.items():
        collect(base / name, variant, episodes=2)
    return {name: base / name for name in variants}


def memory_slice(env) -> slice:
    base = env.unwrapped
    return slice(base.memory_offset, base.memory_offset + base.n_robots)


def random_rollout(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Observations and actions of the seeded random policy, rolled out independently of collect()."""
    env = gym.make(ENV, max_episode_steps=STEPS, **ENV_KWARGS)
    observation, _ = env.reset(seed=seed)
    policy = make_policy("random", env)
    policy.reset(seed)
    observations, actions, done = [], [], False
    while not done:
        action = policy(observation)
        observations.append(observation)
        actions.append(action)
        observation, _, terminated, truncated, _ = env.step(action)
        done = terminated or truncated
    env.close()
    return np.array(observations), np.array(actions)


def linear_layers(network: torch.nn.Module) -> list[tuple[int, int]]:
    return [(m.in_features, m.out_features) for m in network.modules() if isinstance(m, torch.nn.Linear)]


# -- collect --label-policy ----------------------------------------------------------------------------------------
def test_recorded_actions_are_the_labels_on_the_states_the_driver_visits(labelled):
    reader = LeRobotReader(labelled)
    env = gym.make(ENV, **ENV_KWARGS)
    memory = memory_slice(env)
    expert = MarkovWavePolicy.from_env(env)
    disagreements = 0
    for index, meta in enumerate(reader.episodes):
        data = reader.episode(index)
        observations, actions = data["observation.state"], data["action"]
        assert len(observations) == STEPS
        labels = np.array([expert(o) for o in observations])
        np.testing.assert_array_equal(actions, labels.astype(np.float32))
        # the env was driven by random: an independent random rollout of the seed visits the same states
        reference, executed = random_rollout(int(meta["seed"]))
        np.testing.assert_array_equal(observations, reference)
        # the observation's memory holds the executed (random) action, not the recorded label
        np.testing.assert_array_equal(observations[1:, memory], executed[:-1].astype(np.float32))
        disagreements += int((executed != labels).any(axis=1).sum())
    env.close()
    assert disagreements > STEPS  # of 60 frames: random matches a 4-robot label 1 time in 16


def test_label_policy_is_in_the_metadata_only_when_set(labelled, demos):
    info = json.loads((labelled / "meta/info.json").read_text())
    assert (info["dpr"]["policy"], info["dpr"]["label_policy"]) == ("random", "wave-markov")
    episodes = LeRobotReader(labelled).episodes
    assert [(e["seed"], e["policy"], e["label_policy"]) for e in episodes] == [
        (10, "random", "wave-markov"),
        (11, "random", "wave-markov"),
    ]
    plain = json.loads((demos / "meta/info.json").read_text())
    assert "label_policy" not in plain["dpr"]
    assert [e["label_policy"] for e in LeRobotReader(demos).episodes] == ["", "", ""]


def test_resuming_with_another_label_policy_is_refused(tmp_path):
    labelled_spec = spec(policy="random", label_policy="wave-markov", steps=10)
    root = tmp_path / "labelled"
    collect(root, labelled_spec, episodes=1)
    for other in ("wave", None):
        with pytest.raises(DatasetError, match="does not match.*label_policy"):
            collect(root, dataclasses.replace(labelled_spec, label_policy=other), episodes=2)
    assert LeRobotReader(root).num_episodes == 1
    assert collect(root, labelled_spec, episodes=2).episodes_added == 1  # the same spec resumes
    plain = tmp_path / "plain"
    collect(plain, dataclasses.replace(labelled_spec, label_policy=None), episodes=1)
    with pytest.raises(DatasetError, match="does not match.*label_policy"):
        collect(plain, labelled_spec, episodes=2)
    with pytest.raises(ValueError, match="policy must be one of"):
        spec(label_policy="expert")


def test_cli_collect_label_policy(tmp_path):
    out = tmp_path / "ds"
    assert (
        run(
            [
                "collect",
                "--env",
                ENV,
                "--policy",
                "random",
                "--label-policy",
                "wave-markov",
                "--robot-model",
                "disk",
                "--n-robots",
                "4",
                "--steps",
                "10",
                "--episodes",
                "1",
                "--workers",
                "1",
                "--env-kwarg",
                "obs_last_action=true",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    (episode,) = LeRobotReader(out).episodes
    assert (episode["policy"], episode["label_policy"]) == ("random", "wave-markov")


# -- behaviour cloning of several datasets ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def cloned_two(demos, labelled, tmp_path_factory):
    """A clone of demos + labelled, with the datasets its loaders served (a spy on bc._loader)."""
    out = tmp_path_factory.mktemp("bc_two") / "run"
    served = []

    def spy(dataset, batch_size, sampler):
        served.append(dataset)
        return loader(dataset, batch_size, sampler)

    loader = bc_module._loader
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(bc_module, "_loader", spy)
        result = behaviour_clone(
            [demos, labelled], ENV, CloneConfig(epochs=2, patience=2, hyperparams=SMALL_NET, **FAST), out=out, **QUIET
        )
    return result, served


def test_two_datasets_train_together_and_validate_on_the_first(cloned_two, demos, labelled):
    result, served = cloned_two
    config = yaml.safe_load(result.config_path.read_text())
    assert config["dataset"] == str(demos.resolve())
    assert config["more_datasets"] == [{"dataset": str(labelled.resolve()), "episodes": 2, "frames": 2 * STEPS}]
    assert config["env_kwargs"] == ENV_KWARGS and config["steps_per_episode"] == STEPS
    assert sorted(result.train_episodes + result.val_episodes) == [0, 1, 2]
    assert result.val_episodes and set(result.val_episodes).isdisjoint(result.train_episodes)
    # training: the first's training episodes, then every episode of the second; validation: the first's rest
    train_sets = [d for d in served if isinstance(d, ConcatFrames)]
    val_sets = [d for d in served if not isinstance(d, ConcatFrames)]
    assert train_sets and val_sets and len(train_sets) + len(val_sets) == len(served)
    for train_set in train_sets:
        assert [(p.root, p.episode_indices) for p in train_set.datasets] == [
            (demos.resolve(), result.train_episodes),
            (labelled.resolve(), [0, 1]),
        ]
        assert len(train_set) == STEPS * (len(result.train_episodes) + 2)
    for val_set in val_sets:
        assert (val_set.root, val_set.episode_indices) == (demos.resolve(), result.val_episodes)
    model, _ = load_model(result.model_path)
    val_set = FrameDataset(demos, episodes=result.val_episodes)
    assert measure(model.policy, val_set, 256, "val")["val_nll"] == pytest.approx(result.best_val_nll, rel=1e-5)
    # the epoch-0 row measures the untrained network (rebuilt as behaviour_clone built it) on that training set
    env = make_vec_env(ENV, ENV_KWARGS, STEPS, 1)
    torch.manual_seed(0)
    fresh = build_model(load_hyperparams("ppo", ENV, overrides=SMALL_NET), env, 0, None)
    env.close()
    both = ConcatFrames([FrameDataset(demos, episodes=result.train_episodes), FrameDataset(labelled)])
    for key, value in measure(fresh.policy, both, 256, "train").items():
        assert result.history[0][key] == pytest.approx(value, rel=1e-5), key


def test_hyperparams_override_shapes_the_saved_model(cloned_two):
    result, _ = cloned_two
    config = yaml.safe_load(result.config_path.read_text())
    assert config["hyperparameters"]["policy_kwargs"] == {"net_arch": [16]}
    model, _ = load_model(result.model_path)
    assert linear_layers(model.policy.mlp_extractor.policy_net) == [(OBS_DIM, 16)]
    assert linear_layers(model.policy.action_net) == [(16, N)]


def test_clone_with_swarm_features_runs_as_a_policy(demos, tmp_path):
    result = behaviour_clone(
        demos, ENV, CloneConfig(epochs=1, hyperparams=SWARM_NET, **FAST), out=tmp_path / "run", **QUIET
    )
    model, _ = load_model(result.model_path)
    extractor = model.policy.features_extractor
    assert isinstance(extractor, SwarmFeatures) and extractor.n_robots == N
    assert linear_layers(model.policy.mlp_extractor.policy_net) == [(OBS_DIM + 2 * N, 16)]
    env = gym.make(ENV, **ENV_KWARGS)
    policy = load_model_policy(result.model_path, env)
    observation, _ = env.reset(seed=3)
    for _ in range(5):
        action = policy(observation)
        assert action.shape == (N,) and set(np.unique(action)) <= {0, 1}
        observation, *_ = env.step(action)
    env.close()


def test_change_weight_reweights_the_loss(demos, tmp_path):
    def val_nll(name, **kwargs):
        result = behaviour_clone(
            demos, ENV, CloneConfig(epochs=1, hyperparams=SMALL_NET, **FAST, **kwargs), out=tmp_path / name, **QUIET
        )
        return result.history[1]["val_nll"]  # after one update from the same initial network

    plain = val_nll("default")
    assert val_nll("one", change_weight=1.0) == plain  # a weight of 1 is the plain mean
    assert val_nll("five", change_weight=5.0) != pytest.approx(plain, rel=1e-6)
    assert yaml.safe_load((tmp_path / "five" / "config.yaml").read_text())["bc"]["change_weight"] == 5.0


def test_datasets_that_differ_are_refused_before_the_run_folder_exists(demos, others, tmp_path, capsys):
    out = tmp_path / "run"
    for name, words in (
        ("n5", ["'n_robots': 5", "'n_robots': 4"]),
        ("no_memory", ["obs_last_action"]),
        ("steps20", [", 20)", ", 30)"]),
    ):
        with pytest.raises(ValueError, match="must match") as info:
            behaviour_clone([demos, others[name]], ENV, CloneConfig(**FAST), out=out, **QUIET)
        for word in [str(others[name]), str(demos), *words]:
            assert word in str(info.value), (name, word)
        assert not out.exists()
    assert run(["bc", "--dataset", str(demos), str(others["n5"]), "--env", ENV, "--out", str(out)]) == 2
    assert "must match" in capsys.readouterr().err and not out.exists()


def test_bad_change_weight_is_refused_before_the_run_folder_exists(demos, others, tmp_path):
    out = tmp_path / "run"
    for bad in (0.5, 0, -2.0, True, "2", math.nan):
        with pytest.raises(ValueError, match="change_weight must be a number >= 1"):
            behaviour_clone(demos, ENV, CloneConfig(change_weight=bad, **FAST), out=out, **QUIET)
    with pytest.raises(ValueError, match="change_weight needs.*obs_last_action=True"):
        behaviour_clone(others["no_memory"], ENV, CloneConfig(change_weight=2.0, **FAST), out=out, **QUIET)
    assert not out.exists()


# -- DAgger ------------------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def dagger_run(demos, tmp_path_factory):
    out = tmp_path_factory.mktemp("dagger_run") / "run"
    dagger_config = DaggerConfig(rounds=1, episodes_per_round=2, workers=1)
    return dagger(demos, ENV, out, dagger_config, CloneConfig(epochs=1, hyperparams=SMALL_NET, **FAST), **QUIET)


def test_dagger_run_folder(dagger_run, demos):
    out = dagger_run.run_dir
    assert sorted(p.name for p in out.iterdir()) == ["data-1", "model.zip", "round-0", "round-1"]
    assert dagger_run.model_path == out / "model.zip"
    assert dagger_run.model_path.read_bytes() == (out / "round-1" / "model.zip").read_bytes()
    assert [r.run_dir for r in dagger_run.rounds] == [out / "round-0", out / "round-1"]
    assert dagger_run.datasets == [demos, out / "data-1"]
    configs = [yaml.safe_load((out / f"round-{k}" / "config.yaml").read_text()) for k in (0, 1)]
    assert all(c["dataset"] == str(demos.resolve()) for c in configs)
    assert configs[0]["more_datasets"] == []
    assert [d["dataset"] for d in configs[1]["more_datasets"]] == [str((out / "data-1").resolve())]
    assert configs[1]["bc"]["epochs"] == 1 and configs[1]["hyperparameters"]["policy_kwargs"] == {"net_arch": [16]}


def test_dagger_data_is_driven_by_the_clone_and_labelled_by_the_expert(dagger_run, demos):
    out = dagger_run.run_dir
    reader = LeRobotReader(out / "data-1")
    learner = out / "round-0" / "model.zip"
    demo_meta = LeRobotReader(demos).episodes[0]
    assert [int(e["seed"]) for e in reader.episodes] == [50_000, 50_001]
    for meta in reader.episodes:
        assert (meta["policy"], meta["label_policy"]) == (str(learner), "wave-markov")
        assert meta["env_kwargs"] == demo_meta["env_kwargs"]  # the demonstrations' env, steps included
    env = gym.make(ENV, **ENV_KWARGS)
    memory = memory_slice(env)
    expert = MarkovWavePolicy.from_env(env)
    model, _ = load_model(learner)
    for index in range(reader.num_episodes):
        data = reader.episode(index)
        observations, actions = data["observation.state"], data["action"]
        assert len(observations) == STEPS
        np.testing.assert_array_equal(actions, np.array([expert(o) for o in observations], dtype=np.float32))
        driven = np.array([model.predict(o, deterministic=True)[0] for o in observations[:-1]], dtype=np.float32)
        np.testing.assert_array_equal(observations[1:, memory], driven)
    env.close()


def test_dagger_refuses_demo_seeds_and_a_used_folder(demos, tmp_path):
    out = tmp_path / "run"
    with pytest.raises(ValueError, match="overlap"):  # seeds 2, 3: the demonstrations hold seed 2
        dagger_config = DaggerConfig(rounds=1, episodes_per_round=2, first_seed=2, workers=1)
        dagger(demos, ENV, out, dagger_config, CloneConfig(epochs=1, **FAST), **QUIET)
    assert not out.exists()
    out.mkdir()
    (out / "file").write_text("x")
    with pytest.raises(ValueError, match="already exists"):
        dagger(
            demos,
            ENV,
            out,
            DaggerConfig(rounds=1, episodes_per_round=2, workers=1),
            CloneConfig(epochs=1, **FAST),
            **QUIET,
        )
    for bad, words in (
        ({"rounds": -1}, "rounds"),
        ({"episodes_per_round": 0}, "episodes_per_round"),
        ({"first_seed": -5}, "first_seed"),
        ({"expert": "oracle"}, "policy must be one of"),
    ):
        with pytest.raises(ValueError, match=words):
            dagger(demos, ENV, tmp_path / "bad", DaggerConfig(**{"workers": 1, **bad}))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_cli_bc_dagger(demos, tmp_path, capsys):
    out = tmp_path / "cli"
    assert (
        run(
            [
                "bc",
                "--dataset",
                str(demos),
                "--env",
                ENV,
                "--epochs",
                "1",
                "--batch-size",
                "128",
                "--dagger-rounds",
                "1",
                "--dagger-episodes",
                "2",
                "--dagger-seed",
                "700",
                "--workers",
                "1",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    stdout = capsys.readouterr().out
    assert "DAgger: 1 round(s)" in stdout and f"model: {out / 'model.zip'}" in stdout
    assert sorted(p.name for p in out.iterdir()) == ["data-1", "model.zip", "round-0", "round-1"]
    assert [int(e["seed"]) for e in LeRobotReader(out / "data-1").episodes] == [700, 701]
    assert (
        run(
            [
                "bc",
                "--dataset",
                str(demos),
                "--env",
                ENV,
                "--dagger-rounds",
                "1",
                "--dagger-seed",
                "1",
                "--out",
                str(tmp_path / "overlap"),
            ]
        )
        == 2
    )
    assert "overlap" in capsys.readouterr().err and not (tmp_path / "overlap").exists()


# -- SwarmFeatures -----------------------------------------------------------------------------------------------------
SWARM_ENVS = [
    ("dpr/Navigation-v0", {}),
    ("dpr/Navigation-v0", {"obs_last_action": True}),
    ("dpr/Manipulation-v0", {}),
]


def swarm_features(extractor: SwarmFeatures, observations: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(observation part, along, across) of the extractor's output."""
    with torch.no_grad():
        out = extractor(torch.as_tensor(observations)).numpy()
    d, n = observations.shape[1], extractor.n_robots
    return out[:, :d], out[:, d : d + n], out[:, d + n :]


@pytest.mark.parametrize(("env_id", "kwargs"), SWARM_ENVS, ids=["navigation", "navigation-memory", "manipulation"])
def test_swarm_features_along_is_the_waves_bins(env_id, kwargs):
    env = gym.make(env_id, n_robots=9, **kwargs)
    extractor = SwarmFeatures(env.observation_space, 9)
    d = env.observation_space.shape[0]
    assert extractor.features_dim == d + 18 and len(list(extractor.parameters())) == 0
    observations = visited_observations(env)
    env.close()
    head, along, across = swarm_features(extractor, observations)
    np.testing.assert_array_equal(head, observations)
    wave = WavePolicy(9, start_side="near")
    bins_seen = set()
    for observation, row in zip(observations, along, strict=True):
        positions = observation[: 6 * 9].reshape(9, 6)[:, 0:2].astype(np.float64) * 1000.0
        bins = wave.plan(positions)  # exact floor equality: no position of these seeds lies on a bin edge
        np.testing.assert_array_equal(np.floor(row).astype(np.int64), bins)
        bins_seen |= set(bins.tolist())
    assert {0, 1, 2} <= bins_seen  # the comparison covered several bins, not just bin 0
    assert np.all(along.min(axis=1) == 0)
    # across: the offset from the centre perpendicular to the goal direction, so it sums to zero
    np.testing.assert_allclose(across.sum(axis=1), 0.0, atol=1e-4)
    assert np.abs(across).max() > 0.5


@pytest.mark.parametrize(("env_id", "kwargs"), SWARM_ENVS, ids=["navigation", "navigation-memory", "manipulation"])
def test_swarm_features_are_invariant_to_rotating_the_scene_about_the_goal(env_id, kwargs):
    env = gym.make(env_id, n_robots=9, **kwargs)
    extractor = SwarmFeatures(env.observation_space, 9)
    observations = visited_observations(env, seeds=(4,), steps=15)
    env.close()
    _, along, across = swarm_features(extractor, observations)
    for angle in (0.7, math.pi / 2, 2.5, -1.9):
        rotated = rotate_scene(observations, 9, angle)
        head, along_r, across_r = swarm_features(extractor, rotated)
        np.testing.assert_array_equal(head, rotated)
        np.testing.assert_allclose(along_r, along, atol=2e-4)
        np.testing.assert_allclose(across_r, across, atol=2e-4)


def test_swarm_features_match_the_wave_on_a_swarm_around_the_goal():
    """Robots on both sides of the line through the goal (the swarm over the goal): distances are absolute."""
    rng = np.random.default_rng(0)
    n = 7
    extractor = SwarmFeatures(gym.spaces.Box(-np.inf, np.inf, (6 * n,), dtype=np.float32), n)
    observations = np.zeros((50, 6 * n), dtype=np.float32)
    robots = observations.reshape(50, n, 6)
    robots[..., 0:2] = rng.uniform(-0.25, 0.25, (50, n, 2)) + rng.uniform(-0.03, 0.03, (50, 1, 2))
    _, along, across = swarm_features(extractor, observations)
    wave = WavePolicy(n, start_side="near")
    for observation, row in zip(observations, along, strict=True):
        positions = observation.reshape(n, 6)[:, 0:2].astype(np.float64) * 1000.0
        np.testing.assert_array_equal(np.floor(row).astype(np.int64), wave.plan(positions))
    np.testing.assert_allclose(across.sum(axis=1), 0.0, atol=1e-4)


def test_swarm_features_refuse_other_observation_spaces():
    state = gym.spaces.Box(-np.inf, np.inf, (6 * 9,), dtype=np.float32)
    SwarmFeatures(state, 9)
    for space in (
        gym.spaces.Box(-1, 1, (6 * 9 - 1,), dtype=np.float32),  # fewer values than 9 robots have
        gym.spaces.Box(0, 255, (96, 96, 3), dtype=np.uint8),
        gym.spaces.Dict({"state": state}),
    ):
        with pytest.raises(ValueError, match="SwarmFeatures needs the 1-D state observation of 9 robots"):
            SwarmFeatures(space, 9)
    hyper = load_hyperparams("ppo", ENV, overrides=SWARM_NET)
    with pytest.raises(ValueError, match="needs n_robots"):
        hyper.model_kwargs()
    assert hyper.model_kwargs(n_robots=9)["policy_kwargs"]["features_extractor_kwargs"] == {"n_robots": 9}


def test_ppo_with_swarm_features_saves_loads_and_predicts_the_same(tmp_path):
    kwargs = {"n_robots": 9}
    env = make_vec_env(ENV, kwargs, 50, 1)
    model = build_model(load_hyperparams("ppo", ENV, overrides=SWARM_NET), env, 0, None)
    env.close()
    extractor = model.policy.features_extractor
    assert isinstance(extractor, SwarmFeatures) and extractor.n_robots == 9 and extractor.features_dim == 54 + 18
    assert linear_layers(model.policy.mlp_extractor.policy_net) == [(72, 16)]
    path = tmp_path / "model.zip"
    model.save(path)
    write_model_info(path, ModelInfo("ppo", ENV, kwargs, 50))
    loaded, info = load_model(path)
    assert isinstance(loaded.policy.features_extractor, SwarmFeatures)
    assert loaded.policy.features_extractor.n_robots == 9 and info.env_kwargs == kwargs
    probe = gym.make(ENV, **kwargs)
    observations = visited_observations(probe, seeds=(5,), steps=10)
    probe.close()
    before = model.predict(observations, deterministic=True)[0]
    np.testing.assert_array_equal(loaded.predict(observations, deterministic=True)[0], before)
    with torch.no_grad():
        obs = torch.as_tensor(observations)
        probs = [m.policy.get_distribution(obs).distribution.probs for m in (model, loaded)]
    assert torch.equal(probs[0], probs[1])
