"""SB3 training from scratch (`dpr train`), the hyperparameter yaml, and evaluating the saved models."""

import json
import zipfile
from dataclasses import replace

import gymnasium as gym
import numpy as np
import pytest
import yaml
from helpers import run_cli as run

from dpr.evaluation.scoring import evaluate, run_episode
from dpr.policies.hyperparams import load_hyperparams
from dpr.policies.model_file import METADATA_MEMBER, read_model_info
from dpr.policies.registry import check_policy_name, make_policy
from dpr.policies.sb3 import load_model, load_model_policy
from dpr.rl.train import TrainConfig, train

ENV = "dpr/Navigation-v0"
SMALL_ENV = {"n_robots": 4, "robot_model": "disk"}
PAPER_NET = [64, 128, 128, 128, 64]
# Small rollouts and replay starts so that a few hundred steps train every algorithm at least once.
TINY = {
    "ppo": {"n_steps": 64, "batch_size": 32, "n_epochs": 2},
    "a2c": {},
    "dqn": {"learning_starts": 32, "buffer_size": 1000, "target_update_interval": 50},
}


def tiny_config(algo: str, **kwargs) -> TrainConfig:
    return TrainConfig(algo, ENV, timesteps=192, steps_per_episode=64, hyperparams=TINY[algo], **SMALL_ENV, **kwargs)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """One tiny run per algorithm, trained through the Python API."""
    root = tmp_path_factory.mktemp("train")
    return {algo: train(tiny_config(algo), root / algo, show_progress=False, log=lambda line: None) for algo in TINY}


# -- hyperparameters --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("algo", sorted(TINY))
def test_presets_hold_the_papers_values_and_laptop_defaults(algo):
    paper = load_hyperparams(algo, "dpr/Gate-v0", "paper")
    assert paper.n_timesteps == 10_000_000
    assert paper.algo_kwargs["policy_kwargs"]["net_arch"] == PAPER_NET
    schedule = paper.model_kwargs()["learning_rate"]
    assert schedule(1.0) == pytest.approx(0.0075) and schedule(0.5) == pytest.approx(0.00375) and schedule(0.0) == 0.0
    for env_id in ("dpr/Navigation-v0", "dpr/Gate-v0", "dpr/Unresponsive-v0", "dpr/Manipulation-v0"):
        default = load_hyperparams(algo, env_id)
        assert default.n_timesteps <= 1_000_000
        assert default.algo_kwargs["policy_kwargs"]["net_arch"] == PAPER_NET
    expected = {"action_type": "discrete"} if algo == "dqn" else {}
    assert paper.env_kwargs == expected and load_hyperparams(algo, ENV).env_kwargs == expected


@pytest.mark.parametrize(
    "args, message",
    [
        (("sac", ENV), "algo must be one of"),
        (("ppo", ENV, "huge"), "preset must be one of"),
        (("ppo", "dpr/Nowhere-v0"), "env must be one of"),
        (("ppo", ENV, "default", {"n_stepz": 64}), "unknown hyperparameter.*n_stepz.*n_steps"),
        (("ppo", ENV, "default", {"learning_rate": "cos_1e-3"}), "learning_rate"),
        (("a2c", ENV, "default", {"policy_kwargs": {"net_arch": [64, "wide"]}}), "net_arch"),
        (
            ("ppo", ENV, "default", {"policy_kwargs": {"features_extractor": "nope"}}),
            r"features_extractor must be one of \('flatten', 'swarm'\), got 'nope'",
        ),
    ],
)
def test_bad_hyperparameters_are_refused(args, message):
    with pytest.raises(ValueError, match=message):
        load_hyperparams(*args)


def test_bad_train_config_is_refused(tmp_path):
    with pytest.raises(ValueError, match="algo must be one of"):
        TrainConfig("sac", ENV)
    with pytest.raises(ValueError, match="preset must be one of"):
        TrainConfig("ppo", ENV, preset="huge")
    with pytest.raises(ValueError, match="must not set"):
        TrainConfig("ppo", ENV, env_kwargs={"n_robots": 4})
    with pytest.raises(ValueError, match="dqn needs action_type='discrete'"):
        train(TrainConfig("dqn", ENV, env_kwargs={"action_type": "multibinary"}), tmp_path / "run")
    assert not (tmp_path / "run").exists()  # refused before the run folder was made


# -- the run folder ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("algo", sorted(TINY))
def test_run_folder_holds_models_and_the_resolved_config(runs, algo):
    result = runs[algo]
    names = {p.name for p in result.run_dir.iterdir()}
    assert {"model.zip", "config.yaml", "best_model.zip", "checkpoints"} <= names
    assert result.best_model_path == result.run_dir / "best_model.zip"
    config = yaml.safe_load(result.config_path.read_text())
    env_kwargs = {**SMALL_ENV, **({"action_type": "discrete"} if algo == "dqn" else {})}
    assert config["algo"] == algo and config["env_id"] == ENV and config["env_kwargs"] == env_kwargs
    assert config["seed"] == 0 and config["n_envs"] == 1 and config["timesteps"] == 192
    assert config["timesteps_done"] >= 192 and config["steps_per_episode"] == 64
    assert config["hyperparameters"]["policy_kwargs"]["net_arch"] == PAPER_NET
    assert config["versions"]["stable-baselines3"].startswith("2.")
    # Every model file written by the run carries its env, so each one can be evaluated as it is.
    for path in [result.model_path, result.best_model_path, *result.run_dir.glob("checkpoints/*.zip")]:
        info = read_model_info(path)
        assert (info.algo, info.env_id, info.env_kwargs, info.max_episode_steps) == (algo, ENV, env_kwargs, 64)


def test_a_task_trains_on_its_earlier_registered_versions(tmp_path):
    """Gate-v0 and Gate-v1 stay registered for the runs made on them (`dpr pipeline --env-id`), and train there."""
    for env_id in ("dpr/Gate-v0", "dpr/Gate-v1"):
        config = TrainConfig("ppo", env_id, timesteps=64, steps_per_episode=32, hyperparams=TINY["ppo"], **SMALL_ENV)
        result = train(config, tmp_path / env_id[-2:], show_progress=False, log=lambda line: None)
        assert read_model_info(result.model_path).env_id == env_id


def test_trained_network_has_the_configured_layers(runs):
    policy = load_model_policy(runs["ppo"].model_path, gym.make(ENV, **SMALL_ENV))
    layers = [m.out_features for m in policy.model.policy.mlp_extractor.policy_net if hasattr(m, "out_features")]
    assert layers == PAPER_NET


# -- evaluating saved models ------------------------------------------------------------------------------------
@pytest.mark.parametrize("algo", sorted(TINY))
def test_evaluate_runs_a_model_with_its_own_env_kwargs(runs, algo):
    path = str(runs[algo].model_path)
    (result,) = evaluate([ENV], path, seeds=[0], steps=64)
    assert result.policy == path and 2 <= len(result.trajectory) <= 65
    # The same episode by hand: the model's kwargs, its deterministic actions.
    env = gym.make(ENV, max_episode_steps=64, **read_model_info(path).env_kwargs)
    policy = make_policy(path, env)
    observation, _ = env.reset(seed=0)
    policy.reset(0)
    positions = [env.unwrapped._agent_position()]
    done = False
    while not done:
        observation, _, terminated, truncated, _ = env.step(policy(observation))
        positions.append(env.unwrapped._agent_position())
        done = terminated or truncated
    np.testing.assert_array_equal(result.trajectory, np.array(positions))


@pytest.mark.parametrize("algo", sorted(TINY))
def test_predict_is_deterministic(runs, algo):
    path = runs[algo].model_path
    env = gym.make(ENV, **read_model_info(path).env_kwargs)
    observation, _ = env.reset(seed=3)
    first, second = load_model_policy(path, env), load_model_policy(path, env)
    actions = [first(observation), first(observation), second(observation)]
    for action in actions[1:]:
        np.testing.assert_array_equal(action, actions[0])
    assert env.action_space.contains(
        np.asarray(actions[0]).reshape(env.action_space.shape).astype(env.action_space.dtype)
    )


def test_cli_trains_in_subprocess_envs_and_evaluates(tmp_path, capsys):
    out = tmp_path / "run"
    argv = [
        "train",
        "--algo",
        "ppo",
        "--env",
        ENV,
        "--robot-model",
        "disk",
        "--n-robots",
        "4",
        "--timesteps",
        "128",
        "--n-envs",
        "2",
        "--steps-per-episode",
        "64",
        "--seed",
        "7",
        "--hyperparam",
        "n_steps=32",
        "--hyperparam",
        "batch_size=32",
        "--out",
        str(out),
    ]
    assert run(argv) == 0
    assert f"model: {out / 'model.zip'}" in capsys.readouterr().out
    config = yaml.safe_load((out / "config.yaml").read_text())
    assert config["n_envs"] == 2 and config["seed"] == 7 and config["hyperparameters"]["n_steps"] == 32
    report = tmp_path / "eval.json"
    argv = [
        "evaluate",
        "--policy",
        str(out / "model.zip"),
        "--env",
        ENV,
        "--seeds",
        "0",
        "--steps",
        "32",
        "--workers",
        "1",
        "--json",
        str(report),
    ]
    assert run(argv) == 0
    payload = json.loads(report.read_text())
    assert payload["env_kwargs"] == SMALL_ENV and payload["episodes"][0]["steps"] <= 32


# -- bad models and mismatches ----------------------------------------------------------------------------------
def test_train_refuses_an_existing_run_folder(tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    (out / "notes.txt").write_text("earlier run")
    with pytest.raises(ValueError, match="already exists"):
        train(tiny_config("ppo"), out)
    assert run(["train", "--algo", "ppo", "--env", ENV, "--out", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err
    assert [p.name for p in out.iterdir()] == ["notes.txt"]
    assert run(["train", "--algo", "sac", "--env", ENV]) == 2
    assert "invalid choice: 'sac'" in capsys.readouterr().err


def test_missing_corrupt_and_foreign_zips_are_refused(tmp_path, runs):
    env = gym.make(ENV, **SMALL_ENV)
    with pytest.raises(ValueError, match="no model file at .*missing.zip"):
        make_policy(str(tmp_path / "missing.zip"), env)
    corrupt = tmp_path / "corrupt.zip"
    corrupt.write_bytes(b"not a zip at all")
    with pytest.raises(ValueError, match="corrupt.zip is not a readable .zip"):
        evaluate([ENV], str(corrupt), seeds=[0], steps=8)
    # A plain SB3 save (no dpr_env.json): the env it needs is unknown.
    plain = tmp_path / "plain.zip"
    with zipfile.ZipFile(runs["a2c"].model_path) as source, zipfile.ZipFile(plain, "w") as target:
        for name in source.namelist():
            if name != METADATA_MEMBER:
                target.writestr(name, source.read(name))
    with pytest.raises(ValueError, match=f"plain.zip is an SB3 model without {METADATA_MEMBER}"):
        check_policy_name(str(plain))
    assert check_policy_name(str(runs["a2c"].model_path)) == str(runs["a2c"].model_path)


def test_model_for_another_swarm_or_task_is_refused(runs, capsys):
    path = str(runs["ppo"].model_path)
    with pytest.raises(ValueError, match=r"trained with n_robots=4; n_robots=9 makes a different observation"):
        evaluate([ENV], path, seeds=[0], steps=8, env_kwargs={"n_robots": 9})
    with pytest.raises(
        ValueError, match=r"observation space .*\(24,\).*\(54,\).*n_robots=4 \(the env has n_robots=9\)"
    ):
        make_policy(path, gym.make(ENV, robot_model="disk", n_robots=9))
    with pytest.raises(ValueError, match="action space Discrete\\(16\\) vs the env's MultiBinary"):
        make_policy(str(runs["dqn"].model_path), gym.make(ENV, **SMALL_ENV))
    with pytest.raises(ValueError, match="trained on dpr/Navigation-v0; it cannot be run on dpr/Gate-v0"):
        run_episode("dpr/Gate-v0", path, seed=0, steps=8)
    assert run(["evaluate", "--policy", path, "--n-robots", "9", "--seeds", "0", "--workers", "1"]) == 2
    assert "trained with n_robots=4; --n-robots 9 makes a different observation" in capsys.readouterr().err


def test_a_model_runs_on_another_task_with_its_spaces_as_a_transfer(runs, tmp_path, capsys):
    """--transfer: a Navigation model scored on Gate-v1 as it is, over the same physics steps as on its own task;
    a task of other spaces is still refused."""
    path = str(runs["ppo"].model_path)
    (own,) = evaluate([ENV], path, seeds=[0], steps=8)
    (moved,) = evaluate(["dpr/Gate-v1"], path, seeds=[0], steps=8, transfer=True)
    assert moved.env_id == "dpr/Gate-v1" and "gate_passage" in moved.measures
    assert moved.metrics.steps == own.metrics.steps
    with pytest.raises(ValueError, match="observation space"):
        evaluate(["dpr/Manipulation-v0"], path, seeds=[0], steps=8, transfer=True)
    argv = ["evaluate", "--policy", path, "--env", "dpr/Gate-v1", "--seeds", "0", "--steps", "8", "--workers", "1"]
    assert run(argv) == 2
    assert "it cannot be run on dpr/Gate-v1 (unless as a transfer" in capsys.readouterr().err
    assert run([*argv, "--transfer"]) == 0
    assert run([*argv, "--transfer", "--rerun", str(tmp_path / "x.rrd")]) == 0
    assert (tmp_path / "x.rrd").stat().st_size > 0


def test_the_viewer_shows_a_model_on_another_task_as_a_transfer(runs, tmp_path, capsys):
    """dpr view --transfer rolls a Navigation model out on Gate-v1 (its walls in the episode); without the flag, or
    on a dataset, it is refused before anything is written."""
    from dpr.viz.episodes import ViewRollout, rollout_episode

    path = str(runs["ppo"].model_path)
    episode = rollout_episode(ViewRollout("dpr/Gate-v1", path, 0, steps=8, transfer=True, **SMALL_ENV))
    assert len(episode.walls) == 2 and episode.n_states == 9
    argv = ["view", "--env", "dpr/Gate-v1", "--policies", f"wave,{path}", "--steps", "8"]
    argv += ["--n-robots", "4", "--robot-model", "disk"]
    assert run([*argv, "--save", str(tmp_path / "refused.rrd")]) == 2
    assert "unless as a transfer" in capsys.readouterr().err and not (tmp_path / "refused.rrd").exists()
    assert run([*argv, "--transfer", "--save", str(tmp_path / "x.rrd")]) == 0
    assert (tmp_path / "x.rrd").stat().st_size > 0
    assert run(["view", str(tmp_path), "--transfer", "--save", str(tmp_path / "y.rrd")]) == 2
    assert "--transfer rolls policies out with --env" in capsys.readouterr().err


def test_saved_model_loads_for_more_training(runs, tmp_path):
    """The fine-tuning path: load with schedules and a VecEnv, learn on, save with the same metadata."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    from dpr.policies.sb3 import load_model, save_model

    info = read_model_info(runs["a2c"].model_path)
    vec_env = DummyVecEnv([lambda: gym.make(ENV, max_episode_steps=64, **info.env_kwargs)])
    model, loaded = load_model(runs["a2c"].model_path, vec_env, for_training=True)
    assert loaded == info and model.lr_schedule(1.0) == pytest.approx(7.0e-4)
    before = model.num_timesteps
    model.learn(total_timesteps=16, reset_num_timesteps=False)
    assert model.num_timesteps > before
    path = save_model(model, tmp_path / "more.zip", info)
    assert read_model_info(path) == info
    with pytest.raises(ValueError, match="action space Discrete\\(16\\) vs the env's MultiBinary\\(4\\)"):
        load_model(runs["dqn"].model_path, vec_env, for_training=True)


# -- saved models in the other commands ---------------------------------------------------------------------------
def test_collect_records_a_model_with_its_env_kwargs(runs, tmp_path):
    from dpr.datasets.collect import CollectSpec, collect
    from dpr.datasets.lerobot import LeRobotReader

    model = str(runs["ppo"].model_path)
    spec = CollectSpec(ENV, policy=model, steps=20, **SMALL_ENV)
    summary = collect(tmp_path / "ds", spec, episodes=2)
    assert summary.episodes_added == 2
    reader = LeRobotReader(tmp_path / "ds")
    assert reader.episodes[0]["policy"] == model
    assert reader.episode(0)["action"].shape == (20, 4)
    with pytest.raises(ValueError, match="n_robots=4"):  # the model's N, named before any work
        CollectSpec(ENV, policy=model, steps=20, n_robots=9, robot_model="disk")
    with pytest.raises(ValueError, match="cannot be run on dpr/Gate-v0"):
        CollectSpec("dpr/Gate-v0", policy=model, steps=20, **SMALL_ENV)


def test_view_rolls_out_a_model_beside_the_wave_policy(runs, tmp_path, capsys):
    model = str(runs["a2c"].model_path)
    out = tmp_path / "view.rrd"
    argv = [
        "view",
        "--env",
        ENV,
        "--policies",
        f"wave,{model}",
        "--seed",
        "0",
        "--n-robots",
        "4",
        "--robot-model",
        "disk",
        "--steps",
        "20",
        "--save",
        str(out),
    ]
    assert run(argv) == 0, capsys.readouterr().err
    assert out.is_file() and out.stat().st_size > 0
    bad = ["view", "--env", ENV, "--policies", model, "--seed", "0", "--steps", "20", "--save", str(tmp_path / "x.rrd")]
    assert run(bad) == 2  # the CLI's default N=9 is not the model's
    assert "n_robots=4" in capsys.readouterr().err
    assert not (tmp_path / "x.rrd").exists()


def test_hyperparameters_sb3_refuses_leave_no_run_folder(tmp_path):
    """SB3's own checks run before the run folder exists, so the same --out works once the value is fixed."""
    from dpr.checks import ParameterError
    from dpr.rl.train import TrainConfig, train

    config = TrainConfig(
        algo="ppo",
        env_id="dpr/Navigation-v0",
        n_robots=4,
        robot_model="disk",
        timesteps=64,
        hyperparams={"n_steps": 1},  # within its bound (dpr.limits), but SB3 needs n_steps * n_envs > 1
    )
    with pytest.raises(ParameterError, match="hyperparams: ppo refuses them"):
        train(config, tmp_path / "run", show_progress=False)
    assert not (tmp_path / "run").exists()
    out_of_bounds = replace(config, hyperparams={"n_steps": -3})  # refused when the entry is read
    with pytest.raises(ValueError, match="n_steps: must be >= 1, got -3"):
        train(out_of_bounds, tmp_path / "run", show_progress=False)
    assert not (tmp_path / "run").exists()


def test_a_run_without_periodic_evaluations_keeps_no_best_model(tmp_path):
    """eval_episodes=0 (`--eval-episodes 0`): no evaluation during training, so no best_model.zip; the run's own
    envs, all in this process when env_processes is False."""
    config = tiny_config("ppo", eval_episodes=0, n_envs=2, env_processes=False)
    result = train(config, tmp_path / "run", show_progress=False, log=lambda line: None)
    assert result.model_path.is_file() and result.best_model_path is None
    assert not (tmp_path / "run" / "eval").exists()
    with pytest.raises(ValueError, match="eval_episodes: must be >= 0"):
        tiny_config("ppo", eval_episodes=-1)


# -- step budgets -----------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "algo, hyperparams, n_envs, timesteps, made, fitted",
    [
        ("ppo", {}, 1, 100, 100, {"n_steps": 100, "batch_size": 50}),  # the yaml's rollouts of 1024: shortened
        ("ppo", {"n_steps": 256, "batch_size": 128}, 2, 201, 200, {"n_steps": 100, "batch_size": 100}),
        ("a2c", {"n_steps": 32}, 2, 41, 40, {"n_steps": 20}),
        ("ppo", {"n_steps": 16, "batch_size": 16}, 2, 40, 64, {"n_steps": 16}),  # whole rollouts: SB3's rounding
        ("dqn", {"learning_starts": 0}, 1, 10, 12, {"train_freq": 4}),  # DQN collects train_freq steps at a time
    ],
    ids=["ppo-under-one-rollout", "ppo-two-envs", "a2c", "ppo-rounded-up", "dqn-rounded-up"],
)
def test_a_run_makes_the_steps_its_log_and_config_say(tmp_path, algo, hyperparams, n_envs, timesteps, made, fitted):
    """A budget under one rollout runs no more steps than asked (shorter rollouts, named in the log); a larger one
    is rounded up to whole rollouts as SB3 does, and the log and config.yaml say how many steps that makes."""
    config = TrainConfig(
        algo,
        ENV,
        timesteps=timesteps,
        n_envs=n_envs,
        env_processes=False,
        steps_per_episode=32,
        eval_episodes=0,
        hyperparams=hyperparams,
        **SMALL_ENV,
    )
    lines = []
    result = train(config, tmp_path / "run", show_progress=False, log=lines.append)
    record = yaml.safe_load(result.config_path.read_text())
    assert record["timesteps"] == timesteps and record["timesteps_done"] == made
    assert record["steps"]["training"] == made and record["steps"]["critic_warmup"] == 0
    assert {name: record["hyperparameters"].get(name) for name in fitted} == fitted
    assert load_model(result.model_path)[0].num_timesteps == made
    note = record["steps"]["note"]
    assert note in lines
    if made <= timesteps:  # shorter rollouts
        assert "fewer than one rollout" in note and f"makes {made} training steps ({timesteps} asked)" in note
        assert f"rollouts of {' '.join(f'{k}={v}' for k, v in fitted.items())} (" in note
    else:
        assert f"so this run makes {made} training steps for the {timesteps} asked" in note


def test_training_env_kwargs_reach_the_training_envs_only(tmp_path, monkeypatch):
    """`--training-env-kwarg`: the envs that gather experience draw Gate's walls over a spread of placements; the
    model records the task as evaluated (no gate_distance), and its evaluation env is the task's."""
    import dpr.rl.train as train_module

    made = []
    real = train_module.make_vec_env

    def recording(env_id, env_kwargs, *args, **kwargs):
        made.append(dict(env_kwargs))
        return real(env_id, env_kwargs, *args, **kwargs)

    monkeypatch.setattr(train_module, "make_vec_env", recording)
    spread = {"gate_distance": [150.0, 200.0]}
    config = TrainConfig(
        "ppo", "dpr/Gate-v2", 4, "disk", 64, steps_per_episode=32, hyperparams=TINY["ppo"], training_env_kwargs=spread
    )
    result = train(config, tmp_path / "run", show_progress=False, log=lambda line: None)
    assert [kwargs.get("gate_distance") for kwargs in made] == [[150.0, 200.0], None]  # training, then evaluation
    assert "gate_distance" not in read_model_info(result.model_path).env_kwargs
    recorded = yaml.safe_load((result.run_dir / "config.yaml").read_text())
    assert recorded["training_env_kwargs"] == spread


def test_training_env_kwargs_must_keep_the_spaces(tmp_path):
    config = TrainConfig(
        "ppo", "dpr/Gate-v2", timesteps=64, steps_per_episode=32, training_env_kwargs={"observe_opening": False}
    )
    with pytest.raises(ValueError, match="training_env_kwargs"):
        train(config, tmp_path / "run", show_progress=False, log=lambda line: None)
    assert not (tmp_path / "run").exists()
    with pytest.raises(ValueError, match="training_env_kwargs must not set"):
        TrainConfig("ppo", "dpr/Gate-v2", training_env_kwargs={"n_robots": 4})
