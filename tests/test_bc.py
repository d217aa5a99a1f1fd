"""Behaviour cloning (`dpr bc`): run folder, episode split, learning, evaluation of the cloned model, bad input."""

import json
import zipfile

import gymnasium as gym
import numpy as np
import pytest
import torch
import yaml
from helpers import run_cli as run
from stable_baselines3.common.policies import ActorCriticPolicy

from dpr.datasets.collect import CollectSpec, collect
from dpr.datasets.frames import FrameDataset
from dpr.datasets.lerobot import LeRobotReader
from dpr.evaluation.scoring import evaluate
from dpr.imitation import CloneConfig, behaviour_clone
from dpr.imitation.bc import measure
from dpr.imitation.loss import check_features
from dpr.policies.model_file import METADATA_MEMBER, read_model_info
from dpr.policies.sb3 import load_model
from dpr.policies.swarm_policy import SwarmActorCriticPolicy

ENV = "dpr/Navigation-v0"
# Full-batch steps (two 64-frame training episodes) learn this tiny set; small noisy batches barely move it.
FAST = {"batch_size": 128, "lr": 3e-3}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """Three 64-step wave episodes of 4 disk robots."""
    root = tmp_path_factory.mktemp("bc") / "wave4"
    collect(root, CollectSpec(ENV, robot_model="disk", n_robots=4, steps=64), episodes=3)
    return root


@pytest.fixture(scope="module")
def cloned(dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("bc_run") / "run"
    return behaviour_clone(dataset, ENV, CloneConfig(epochs=40, patience=40, **FAST), out=out, log=lambda line: None)


def test_run_folder_holds_model_log_and_config(cloned, dataset):
    assert sorted(p.name for p in cloned.run_dir.iterdir()) == ["bc_log.json", "config.yaml", "model.zip"]
    info = read_model_info(cloned.model_path)
    assert (info.algo, info.env_id, info.max_episode_steps) == ("ppo", ENV, 64)
    assert info.env_kwargs == {"n_robots": 4, "robot_model": "disk"}  # max_episode_steps is kept apart
    # the network it was built with (the library keeps the yaml's MLP): what fine-tuning must build again
    assert info.architecture == {"policy": "MlpPolicy", "policy_kwargs": {"net_arch": [64, 128, 128, 128, 64]}}
    with zipfile.ZipFile(cloned.model_path) as archive:
        assert METADATA_MEMBER in archive.namelist()
    log = json.loads(cloned.log_path.read_text())
    assert [row["epoch"] for row in log["epochs"]] == list(range(41))
    for row in log["epochs"]:
        assert {
            "train_nll",
            "val_nll",
            "val_accuracy",
            "train_accuracy",
            "val_exact_match",
            "val_expand_recall",
        } <= set(row)
        assert 0 <= row["val_exact_match"] <= row["val_accuracy"] <= 1
        assert len(row["val_accuracy_per_robot"]) == 4 and 0 <= row["val_accuracy"] <= 1
    config = yaml.safe_load(cloned.config_path.read_text())
    assert config["env_kwargs"] == {"n_robots": 4, "robot_model": "disk"}
    assert config["hyperparameters"]["policy_kwargs"]["net_arch"] == [64, 128, 128, 128, 64]
    assert config["dataset"] == str(dataset.resolve()) and config["best_epoch"] == log["best_epoch"]


def test_validation_holds_out_whole_episodes(cloned):
    assert cloned.val_episodes and cloned.train_episodes
    assert set(cloned.val_episodes).isdisjoint(cloned.train_episodes)
    assert sorted(cloned.val_episodes + cloned.train_episodes) == [0, 1, 2]


def test_cloning_learns_the_training_actions_and_keeps_the_best_validation_weights(cloned, dataset):
    first, last = cloned.history[0], cloned.history[-1]
    assert last["train_nll"] < first["train_nll"] - 0.05
    assert last["train_accuracy"] > first["train_accuracy"] + 0.03
    # The saved model carries the best-validation weights, not the last epoch's.
    model, _ = load_model(cloned.model_path)
    val_set = FrameDataset(dataset, episodes=cloned.val_episodes)
    measured = measure(model.policy, val_set, 256, "val")
    assert measured["val_nll"] == pytest.approx(cloned.best_val_nll, rel=1e-5)
    assert measured["val_nll"] == pytest.approx(min(row["val_nll"] for row in cloned.history), rel=1e-5)


def test_value_head_is_left_alone(dataset, tmp_path):
    from dpr.policies.hyperparams import load_hyperparams
    from dpr.policies.sb3 import build_model, make_vec_env

    result = behaviour_clone(dataset, ENV, CloneConfig(epochs=2, **FAST), out=tmp_path / "run", log=lambda line: None)
    model, _ = load_model(result.model_path)
    env = make_vec_env(ENV, {"n_robots": 4, "robot_model": "disk"}, 64, 1)
    torch.manual_seed(0)
    fresh = build_model(load_hyperparams("ppo", ENV), env, 0, None)  # what behaviour_clone started from
    env.close()
    trained, initial = model.policy.state_dict(), fresh.policy.state_dict()
    for name in trained:
        same = torch.equal(trained[name], initial[name])
        assert same == name.startswith(("value_net.", "mlp_extractor.value_net.")), name


def test_early_stopping_stops_after_patience_epochs(dataset, tmp_path):
    result = behaviour_clone(
        dataset, ENV, CloneConfig(epochs=60, patience=2, **FAST), out=tmp_path / "run", log=lambda line: None
    )
    assert result.stopped_early and result.epochs_run < 60
    assert result.epochs_run == result.best_epoch + 2


def test_saved_model_evaluates_unchanged(cloned):
    (result,) = evaluate([ENV], str(cloned.model_path), seeds=[100], steps=64)
    assert result.metrics.steps == 64 and np.isfinite(result.metrics.projected_displacement)


def test_cli_bc_then_evaluate(dataset, tmp_path, capsys):
    out = tmp_path / "cli"
    assert (
        run(
            [
                "bc",
                "--dataset",
                str(dataset),
                "--env",
                ENV,
                "--algo",
                "a2c",
                "--epochs",
                "2",
                "--batch-size",
                "64",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[-1].startswith("best validation accuracy ")
    assert read_model_info(out / "model.zip").algo == "a2c"
    assert (
        run(
            [
                "evaluate",
                "--policy",
                str(out / "model.zip"),
                "--env",
                ENV,
                "--seeds",
                "100",
                "--steps",
                "32",
                "--workers",
                "1",
            ]
        )
        == 0
    )


def test_cli_bc_clones_an_actor_critic_into_the_swarm_actor_by_default(dataset, tmp_path):
    """`dpr bc`: PPO's and A2C's actor is SwarmPolicy unless --hyperparam policy=... says otherwise; DQN keeps the
    yaml's policy. Each model file records the network it holds."""
    base = ["bc", "--dataset", str(dataset), "--env", ENV, "--epochs", "1", "--batch-size", "128"]
    runs = {
        "ppo": [],
        "a2c": ["--algo", "a2c"],
        "mlp": ["--hyperparam", "policy=MlpPolicy"],
        "dqn": ["--algo", "dqn"],
    }
    for name, extra in runs.items():
        assert run([*base, *extra, "--out", str(tmp_path / name)]) == 0, name
    net = {"net_arch": [64, 128, 128, 128, 64]}
    for name, (policy, kind) in {
        "ppo": ("SwarmPolicy", SwarmActorCriticPolicy),
        "a2c": ("SwarmPolicy", SwarmActorCriticPolicy),
        "mlp": ("MlpPolicy", ActorCriticPolicy),
    }.items():
        model, info = load_model(tmp_path / name / "model.zip")
        assert type(model.policy) is kind and info.architecture == {"policy": policy, "policy_kwargs": net}, name
    dqn = read_model_info(tmp_path / "dqn" / "model.zip").architecture
    assert dqn["policy"] == "MlpPolicy"


def test_cli_bc_takes_the_env_the_dataset_was_recorded_on(dataset, tmp_path, capsys):
    assert run(["bc", "--dataset", str(dataset), "--epochs", "1", "--out", str(tmp_path / "r")]) == 0
    assert f"--env {ENV}" in capsys.readouterr().out  # the line that says how to evaluate it
    assert read_model_info(tmp_path / "r" / "model.zip").env_id == ENV
    assert run(["bc", "--dataset", str(tmp_path / "nothing"), "--out", str(tmp_path / "r2")]) == 2
    assert "--dataset: " in capsys.readouterr().err and not (tmp_path / "r2").exists()


# -- bad input -----------------------------------------------------------------------------------------------------
def test_missing_dataset_is_named(tmp_path):
    with pytest.raises(ValueError, match="no_such_dataset"):
        behaviour_clone(tmp_path / "no_such_dataset", ENV, out=tmp_path / "run")
    assert not (tmp_path / "run").exists()


def test_dataset_of_another_env_names_both(dataset, tmp_path):
    with pytest.raises(ValueError, match=r"^dataset_dirs: .*recorded on dpr/Navigation-v0.*dpr/Gate-v0") as error:
        behaviour_clone(dataset, "dpr/Gate-v0", out=tmp_path / "run")
    assert error.value.parameter == "dataset_dirs"  # a ParameterError, which the CLI says as --dataset
    assert not (tmp_path / "run").exists()


def test_dataset_of_another_n_names_both(dataset, tmp_path, capsys):
    with pytest.raises(ValueError, match=r"n_robots=4.*n_robots=9"):
        behaviour_clone(dataset, ENV, CloneConfig(env_kwargs={"n_robots": 9}), out=tmp_path / "run")
    assert run(["bc", "--dataset", str(dataset), "--env", ENV, "--n-robots", "9", "--out", str(tmp_path / "r")]) == 2
    assert "n_robots=4" in capsys.readouterr().err


def test_features_that_do_not_fit_the_env_name_both(dataset):
    env = gym.make(ENV, n_robots=9, robot_model="disk")
    with pytest.raises(ValueError, match=r"shape \[24\].*Box\(shape=\(54,\)\).*shape \[4\].*MultiBinary\(9\)"):
        check_features(LeRobotReader(dataset), env.observation_space, env.action_space, "N=9")
    env.close()


def test_existing_out_and_bad_arguments_are_refused(dataset, tmp_path, capsys):
    out = tmp_path / "taken"
    out.mkdir()
    (out / "file").write_text("x")
    with pytest.raises(ValueError, match="^out: .*already exists") as error:
        behaviour_clone(dataset, ENV, out=out)
    assert error.value.parameter == "out"
    assert run(["bc", "--dataset", str(dataset), "--env", ENV, "--out", str(out)]) == 2
    assert "--out: " in (err := capsys.readouterr().err) and "already exists" in err
    with pytest.raises(ValueError, match="algo must be one of"):
        behaviour_clone(dataset, ENV, CloneConfig(algo="sac"), out=tmp_path / "sac")
    with pytest.raises(ValueError, match="val_fraction"):
        behaviour_clone(dataset, ENV, CloneConfig(val_fraction=1.0), out=tmp_path / "v")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["taken"]


def test_dqn_clone_classifies_the_recorded_actions_as_integers(dataset, tmp_path):
    """DQN: the Q-network learns the demonstrated MultiBinary actions as Discrete(2^N) classes, its target
    network is the trained Q-network, and the model runs on the discrete-action env."""
    result = behaviour_clone(
        dataset,
        ENV,
        CloneConfig(algo="dqn", epochs=150, patience=150, **FAST),
        out=tmp_path / "dqn",
        log=lambda line: None,
    )
    info = read_model_info(result.model_path)
    assert info.algo == "dqn" and info.env_kwargs["action_type"] == "discrete"
    first, last = result.history[0], result.history[-1]
    assert last["train_nll"] < 0.7 * first["train_nll"]  # the cross-entropy over the 16 joint actions falls
    assert last["train_accuracy"] > first["train_accuracy"]
    model, _ = load_model(result.model_path)
    for name, value in model.policy.q_net.state_dict().items():
        assert torch.equal(value, model.policy.q_net_target.state_dict()[name])
    frames = FrameDataset(dataset)
    sample = frames[0]
    with torch.no_grad():
        chosen = int(model.policy.q_net(sample["observation"][None]).argmax())
    bits = [(chosen >> (3 - i)) & 1 for i in range(4)]  # robot 0 is the most significant bit
    expected = model.predict(sample["observation"].numpy(), deterministic=True)[0]
    assert int(expected) == chosen and len(bits) == 4
    results = evaluate([ENV], str(result.model_path), [0], steps=20)
    assert results[0].metrics.steps == 20
