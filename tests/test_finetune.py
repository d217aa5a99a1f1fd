"""Fine-tuning a behaviour-cloned model (`dpr finetune`: the finetune preset, init_from, the critic warm-up); the
whole pipeline is tests/test_pipeline.py."""

import io
import json
import re
import zipfile
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
import yaml
from helpers import QUIET, TINY_PPO, visited_observations
from helpers import run_cli as run

from dpr.datasets.collect import CollectSpec, collect
from dpr.envs import ENV_IDS
from dpr.evaluation.scoring import evaluate
from dpr.imitation import CloneConfig, behaviour_clone
from dpr.policies.exploration import soften_actions
from dpr.policies.hyperparams import load_hyperparams
from dpr.policies.model_file import METADATA_MEMBER, SWARM_POLICY, ModelInfo, read_model_info
from dpr.policies.registry import make_policy
from dpr.policies.sb3 import (
    actor_parameters,
    build_model,
    load_initial_policy,
    load_model,
    loaded_architecture,
    make_vec_env,
)
from dpr.policies.swarm_policy import SwarmActorCriticPolicy
from dpr.rl.recipe import FINETUNE_AT_REPEAT, default_critic_warmup, finetune_defaults, physics_discount
from dpr.rl.train import TrainConfig, train, warm_up_critic

ENV = "dpr/Navigation-v0"
SMALL_ENV = {"n_robots": 4, "robot_model": "disk"}
MEMORY = {"obs_last_action": True}
ENV_KWARGS = {**SMALL_ENV, **MEMORY}
STEPS = 40
PAPER_NET = [64, 128, 128, 128, 64]


@pytest.fixture(scope="module")
def cloned(tmp_path_factory):
    """A PPO actor-critic cloned (one epoch) from three 40-step Markov-wave episodes of 4 disk robots."""
    root = tmp_path_factory.mktemp("finetune")
    spec = CollectSpec(ENV, policy="wave-markov", steps=STEPS, env_kwargs=MEMORY, **SMALL_ENV)
    collect(root / "demos", spec, episodes=3)
    return behaviour_clone(
        root / "demos", ENV, CloneConfig(epochs=1, batch_size=128), out=root / "bc", log=lambda line: None
    )


def finetune_config(init_from, **kwargs) -> TrainConfig:
    settings = dict(
        preset="finetune",
        timesteps=64,
        critic_warmup=64,
        steps_per_episode=STEPS,
        env_kwargs=MEMORY,
        hyperparams=TINY_PPO,
        **SMALL_ENV,
    )
    settings.update(kwargs)
    return TrainConfig("ppo", ENV, init_from=str(init_from), **settings)


@pytest.fixture(scope="module")
def finetuned(cloned, tmp_path_factory):
    # seed 1: the run's own initial network is not the one BC started from (seed 0)
    return train(finetune_config(cloned.model_path, seed=1), tmp_path_factory.mktemp("ft") / "run", **QUIET)


def fresh_model(hyperparams=TINY_PPO, env_kwargs=ENV_KWARGS, seed=1):
    """A new PPO model as `dpr finetune` builds it, before any weights are loaded (seed 1: not the network
    behaviour_clone started from, which one epoch hardly moved)."""
    env = make_vec_env(ENV, env_kwargs, STEPS, 1)
    return build_model(load_hyperparams("ppo", ENV, "finetune", hyperparams), env, seed, None)


def _is_value_head(name: str) -> bool:
    return name.startswith(("value_net.", "mlp_extractor.value_net."))


# -- the finetune preset -----------------------------------------------------------------------------------------
def test_finetune_preset_is_the_env_entry_with_the_finetune_entry_on_top():
    default = load_hyperparams("ppo", ENV)
    ppo = load_hyperparams("ppo", ENV, "finetune")
    assert ppo.preset == "finetune" and ppo.n_timesteps == 100_000
    assert ppo.model_kwargs()["learning_rate"] == pytest.approx(3e-5)  # a constant, not the env entry's lin_3e-4
    assert ppo.algo_kwargs["policy_kwargs"]["net_arch"] == PAPER_NET  # from the env id's entry
    expected = {"n_steps": 1024, "batch_size": 256, "n_epochs": 5, "clip_range": 0.1, "target_kl": 0.02}
    assert {key: ppo.algo_kwargs[key] for key in expected} == expected
    for key in ("gamma", "gae_lambda", "ent_coef"):  # not in the finetune entry: the env entry's
        assert ppo.algo_kwargs[key] == default.algo_kwargs[key]
    a2c = load_hyperparams("a2c", "dpr/Manipulation-v0", "finetune")
    assert a2c.model_kwargs()["learning_rate"] == pytest.approx(1e-5) and a2c.algo_kwargs["n_steps"] == 32
    assert a2c.algo_kwargs["gae_lambda"] == 1.0 and a2c.algo_kwargs["policy_kwargs"]["net_arch"] == PAPER_NET
    # overrides go on top of both
    assert load_hyperparams("ppo", ENV, "finetune", {"n_steps": 64}).algo_kwargs["n_steps"] == 64
    # the yaml itself is not changed by merging
    assert load_hyperparams("ppo", ENV).model_kwargs()["learning_rate"](1.0) == pytest.approx(3e-4)


def test_dqn_has_no_finetune_preset():
    with pytest.raises(ValueError, match="'finetune'"):
        load_hyperparams("dqn", ENV, "finetune")


# -- loading the cloned weights and warming up the critic --------------------------------------------------------
def test_initial_policy_is_the_cloned_one(cloned):
    model = fresh_model()
    source, _ = load_model(cloned.model_path)
    assert any(
        not torch.equal(value, source.policy.state_dict()[name]) for name, value in model.policy.state_dict().items()
    )  # a new model's weights are its own
    load_initial_policy(model, cloned.model_path)
    for name, value in source.policy.state_dict().items():
        assert torch.equal(model.policy.state_dict()[name], value), name


def test_critic_warmup_changes_the_value_head_only(cloned):
    model = fresh_model()
    load_initial_policy(model, cloned.model_path)
    before = {name: value.clone() for name, value in model.policy.state_dict().items()}
    warm_up_critic(model, 64, show_progress=False)
    after = model.policy.state_dict()
    assert model.num_timesteps >= 64
    changed = {name for name in before if not torch.equal(before[name], after[name])}
    assert changed and all(_is_value_head(name) for name in changed), sorted(changed)
    assert "value_net.weight" in changed
    # the actor is trainable again afterwards
    assert all(parameter.requires_grad for parameter in model.policy.parameters())
    assert len(actor_parameters(model.policy)) < len(list(model.policy.parameters()))


def test_initial_policy_for_another_swarm_or_network_is_refused(cloned):
    other_n = fresh_model(env_kwargs={**ENV_KWARGS, "n_robots": 5})
    message = rf"(?s)init_from: {re.escape(str(cloned.model_path))}: its observation_space .*\(29,\).*differs.*\(36,\)"
    with pytest.raises(ValueError, match=message) as error:
        load_initial_policy(other_n, cloned.model_path)
    assert error.value.parameter == "init_from"
    no_memory = fresh_model(env_kwargs=SMALL_ENV)
    with pytest.raises(ValueError, match=r"(?s)observation_space Box\(.*\(29,\).*differs.*\(24,\)"):
        load_initial_policy(no_memory, cloned.model_path)
    narrow = fresh_model(hyperparams={**TINY_PPO, "policy_kwargs": {"net_arch": [32, 32]}})
    with pytest.raises(ValueError, match=r"has another network than this run's"):
        load_initial_policy(narrow, cloned.model_path)


# -- a fine-tuning run ---------------------------------------------------------------------------------------------
def test_run_records_its_start_and_warmup(finetuned, cloned):
    config = yaml.safe_load(finetuned.config_path.read_text())
    assert config["init_from"] == str(cloned.model_path.resolve()) and config["critic_warmup"] == 64
    assert config["env_kwargs"] == ENV_KWARGS and config["timesteps"] == 64
    assert config["hyperparameters"]["preset"] == "finetune" and config["hyperparameters"]["learning_rate"] == 3e-5
    assert config["hyperparameters"]["n_steps"] == 32 and config["hyperparameter_overrides"] == TINY_PPO
    assert config["timesteps_done"] >= 64 + 64  # the warm-up steps count too
    info = read_model_info(finetuned.model_path)
    assert (info.algo, info.env_id, info.env_kwargs, info.max_episode_steps) == ("ppo", ENV, ENV_KWARGS, STEPS)


def test_finetuned_actor_starts_from_the_clone(finetuned, cloned):
    """64 steps at a learning rate of 3e-5 move the cloned actor a little; the run's own initial network (seed 1)
    is far from it."""
    tuned, _ = load_model(finetuned.model_path)
    clone, _ = load_model(cloned.model_path)
    other = fresh_model(seed=1)
    tuned_sd, clone_sd, other_sd = (m.policy.state_dict() for m in (tuned, clone, other))
    for name in clone_sd:
        if _is_value_head(name):
            continue
        assert (tuned_sd[name] - clone_sd[name]).abs().max() < 0.01, name
    assert max((other_sd[name] - clone_sd[name]).abs().max() for name in clone_sd) > 0.1


def test_finetuned_model_evaluates_with_its_env_kwargs(finetuned, tmp_path):
    path = str(finetuned.model_path)
    env = gym.make(ENV, max_episode_steps=20, **read_model_info(path).env_kwargs)
    assert env.unwrapped.obs_last_action
    policy = make_policy(path, env)
    observation, _ = env.reset(seed=100)
    assert env.action_space.contains(np.asarray(policy(observation)).astype(np.int8))
    (result,) = evaluate([ENV], path, seeds=[100], steps=20)
    assert 2 <= len(result.trajectory) <= 21
    with pytest.raises(ValueError, match="obs_last_action=True; obs_last_action=False"):
        evaluate([ENV], path, seeds=[100], steps=20, env_kwargs={"obs_last_action": False})
    report = tmp_path / "eval.json"
    argv = [
        "evaluate",
        "--policy",
        path,
        "--env",
        ENV,
        "--seeds",
        "100",
        "--steps",
        "20",
        "--workers",
        "1",
        "--json",
        str(report),
    ]
    assert run(argv) == 0
    assert json.loads(report.read_text())["env_kwargs"] == ENV_KWARGS


# -- bad configurations ------------------------------------------------------------------------------------------
def test_warmup_needs_init_from_and_dqn_cannot_start_from_a_clone(cloned, tmp_path):
    with pytest.raises(ValueError, match="critic_warmup needs init_from"):
        TrainConfig("ppo", ENV, critic_warmup=64)
    with pytest.raises(ValueError, match="algo 'dqn' cannot start from a cloned policy"):
        TrainConfig("dqn", ENV, init_from=str(cloned.model_path))
    for bad in (-1, True, 1.5):
        with pytest.raises(ValueError, match="critic_warmup: (expected an integer|must be >= 0)"):
            TrainConfig("ppo", ENV, critic_warmup=bad, init_from=str(cloned.model_path))
    with pytest.raises(ValueError, match="^init_from: no model file at .*missing.zip"):
        train(finetune_config(tmp_path / "missing.zip"), tmp_path / "run", **QUIET)
    assert not (tmp_path / "run").exists()  # refused before the run folder was made


def test_cli_refuses_a_model_of_another_task_or_swarm(cloned, tmp_path, capsys):
    model = str(cloned.model_path)
    base = ["finetune", "--from", model, "--timesteps", "32", "--n-envs", "1"]
    assert run([*base, "--env", "dpr/Gate-v0", "--out", str(tmp_path / "gate")]) == 2
    assert f"{model} was trained on dpr/Navigation-v0, not on --env dpr/Gate-v0" in capsys.readouterr().err
    assert run([*base, "--env", "dpr/Gate-v1", "--transfer", "--out", str(tmp_path / "moved")]) == 0
    assert read_model_info(tmp_path / "moved" / "model.zip").env_id == "dpr/Gate-v1"  # now a Gate model
    assert run([*base, "--env", "dpr/Manipulation-v0", "--transfer", "--out", str(tmp_path / "ball")]) == 2
    assert "its observation_space" in capsys.readouterr().err and not (tmp_path / "ball").exists()
    assert run([*base, "--env", ENV, "--env-kwarg", "n_robots=9", "--out", str(tmp_path / "n9")]) == 2
    assert "trained with n_robots=4; n_robots=9 makes a different observation" in capsys.readouterr().err
    assert run([*base, "--env", ENV, "--env-kwarg", "obs_last_action=false", "--out", str(tmp_path / "plain")]) == 2
    assert "trained with obs_last_action=True; obs_last_action=False" in capsys.readouterr().err
    assert run([*base, "--env", ENV, "--algo", "dqn"]) == 2
    assert "invalid choice: 'dqn'" in capsys.readouterr().err
    assert run(["finetune", "--from", str(tmp_path / "none.zip"), "--env", ENV, "--out", str(tmp_path / "x")]) == 2
    assert "no model file" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["moved"]  # nothing written but the transfer's run


def test_cli_finetunes_a_ppo_clone_with_a2c(cloned, tmp_path, capsys):
    out = tmp_path / "run"
    argv = [
        "finetune",
        "--from",
        str(cloned.model_path),
        "--env",
        ENV,
        "--algo",
        "a2c",
        "--timesteps",
        "32",
        "--critic-warmup",
        "16",
        "--n-envs",
        "1",
        "--seed",
        "3",
        "--out",
        str(out),
    ]
    assert run(argv) == 0
    assert f"model: {out / 'model.zip'}" in capsys.readouterr().out
    config = yaml.safe_load((out / "config.yaml").read_text())
    assert config["algo"] == "a2c" and config["seed"] == 3 and config["critic_warmup"] == 16
    assert config["env_kwargs"] == ENV_KWARGS and config["steps_per_episode"] == STEPS  # from the model file
    assert config["hyperparameters"]["learning_rate"] == 1e-5 and config["hyperparameters"]["n_steps"] == 32
    info = read_model_info(out / "model.zip")
    assert (info.algo, info.env_kwargs) == ("a2c", ENV_KWARGS)


def test_cli_average_checkpoints_writes_the_mean_of_the_runs_weights(cloned, tmp_path, capsys):
    """averaged_model.zip holds the mean of the policy's weights at the run's first three checkpoints (a quarter, half
    and three quarters of the way) and at its end, beside model.zip, which keeps the last weights."""
    out = tmp_path / "run"
    argv = ["finetune", "--from", str(cloned.model_path), "--env", ENV, "--timesteps", "64", "--critic-warmup", "16"]
    argv += ["--n-envs", "1", "--hyperparam", "n_steps=16", "--hyperparam", "batch_size=16", "--out", str(out)]
    assert run([*argv, "--average-checkpoints"]) == 0
    assert f"averaged model: {out / 'averaged_model.zip'}" in capsys.readouterr().out
    checkpoints = sorted((out / "checkpoints").glob("*.zip"), key=lambda path: int(path.stem.split("_")[1]))
    assert len(checkpoints) == 4
    states = [load_model(path)[0].policy.state_dict() for path in (out / "model.zip", *checkpoints[:3])]
    averaged = load_model(out / "averaged_model.zip")[0].policy.state_dict()
    for name, value in averaged.items():
        torch.testing.assert_close(value, sum(state[name] for state in states) / 4)
    assert any(not torch.equal(averaged[name], states[0][name]) for name in averaged)
    assert read_model_info(out / "averaged_model.zip") == read_model_info(out / "model.zip")
    short = tmp_path / "short"
    assert run([*argv[:5], "--timesteps", "3", "--n-envs", "1", "--out", str(short), "--average-checkpoints"]) == 2
    assert "--average-checkpoints: the run must last at least 4 steps per env" in capsys.readouterr().err
    assert not short.exists()


def test_a_disk_model_runs_and_fine_tunes_on_the_paddle_model(cloned, tmp_path, capsys):
    """The two robot models make the same spaces: a policy learned on the fast disk model is evaluated on, and
    fine-tuned on, the paddle model when asked (and the swarm then moves by the paddle physics)."""
    model = str(cloned.model_path)
    on_disk, on_paddle = (
        evaluate([ENV], model, [5], steps=STEPS, env_kwargs=kwargs)[0] for kwargs in ({}, {"robot_model": "paddle"})
    )
    assert not np.array_equal(on_disk.trajectory, on_paddle.trajectory)  # the same actor, another physics
    report = tmp_path / "paddle.json"
    argv = ["evaluate", "--policy", model, "--env", ENV, "--robot-model", "paddle", "--seeds", "5"]
    assert run([*argv, "--steps", str(STEPS), "--json", str(report)]) == 0
    assert json.loads(report.read_text())["env_kwargs"] == {**ENV_KWARGS, "robot_model": "paddle"}

    out = tmp_path / "run"
    argv = ["finetune", "--from", model, "--env", ENV, "--robot-model", "paddle", "--timesteps", "32"]
    argv += ["--critic-warmup", "16", "--n-envs", "1", "--out", str(out)]
    argv += [arg for name, value in TINY_PPO.items() for arg in ("--hyperparam", f"{name}={value}")]
    assert run(argv) == 0
    assert read_model_info(out / "model.zip").env_kwargs == {**ENV_KWARGS, "robot_model": "paddle"}
    assert yaml.safe_load((out / "config.yaml").read_text())["env_kwargs"]["robot_model"] == "paddle"


# -- the demonstration anchor ---------------------------------------------------------------------------------------
def _demos(cloned):
    return yaml.safe_load(cloned.config_path.read_text())["dataset"]


def _demonstration_nll(model_path, demos) -> float:
    from dpr.imitation.loss import batch_stats
    from dpr.rl.anchor import load_demonstrations

    model, _ = load_model(model_path)
    frames = load_demonstrations([demos], model.observation_space, model.action_space, "test")
    with torch.no_grad():
        return float(batch_stats(model.policy, frames.observation, frames.action)[0].mean())


def test_anchor_holds_the_actor_at_the_demonstrations(cloned, tmp_path):
    """At a learning rate 30x the preset's, the unanchored updates follow the returns only; the anchored run ends
    closer to the demonstrated actions than both that run and the clone it started from."""
    fast = {**TINY_PPO, "learning_rate": 1e-3}
    demos = _demos(cloned)
    free = train(
        finetune_config(cloned.model_path, critic_warmup=0, hyperparams=fast, seed=1), tmp_path / "free", **QUIET
    )
    anchored = train(
        finetune_config(
            cloned.model_path,
            critic_warmup=0,
            hyperparams=fast,
            seed=1,
            anchor_datasets=[demos],
            anchor_weight=1.0,
            anchor_decay=1.0,
        ),
        tmp_path / "anchored",
        **QUIET,
    )
    nll = {
        name: _demonstration_nll(path, demos)
        for name, path in (("clone", cloned.model_path), ("free", free.model_path), ("anchored", anchored.model_path))
    }
    assert nll["anchored"] < nll["clone"] and nll["anchored"] < nll["free"], nll
    record = yaml.safe_load(anchored.config_path.read_text())["anchor"]
    assert record["datasets"] == [str(Path(demos).resolve())] and record["frames"] == 3 * STEPS
    assert (record["weight"], record["decay"]) == (1.0, 1.0)
    assert yaml.safe_load(free.config_path.read_text())["anchor"] is None


def test_anchor_refuses_bad_settings_before_writing(cloned, tmp_path):
    for name, bad in (("anchor_weight", 0), ("anchor_weight", -1.0), ("anchor_decay", 1.5), ("anchor_decay", True)):
        with pytest.raises(ValueError, match=rf"^{name}: (expected a number|must be)"):
            TrainConfig("ppo", ENV, init_from=str(cloned.model_path), anchor_datasets=["x"], **{name: bad})
    with pytest.raises(ValueError, match="algo 'dqn' cannot be anchored"):
        TrainConfig("dqn", ENV, anchor_datasets=[_demos(cloned)])
    other = tmp_path / "n5"  # demonstrations of 5 robots cannot anchor a 4-robot policy
    collect(
        other,
        CollectSpec(ENV, policy="wave-markov", steps=10, env_kwargs=MEMORY, n_robots=5, robot_model="disk"),
        episodes=1,
    )
    with pytest.raises(ValueError, match=rf"(?s)^anchor_datasets: {re.escape(str(other))} does not fit.*shape \[5\]"):
        train(finetune_config(cloned.model_path, anchor_datasets=[str(other)]), tmp_path / "run", **QUIET)
    assert not (tmp_path / "run").exists()


def test_cli_finetune_with_an_anchor(cloned, tmp_path, capsys):
    out = tmp_path / "run"
    argv = [
        "finetune",
        "--from",
        str(cloned.model_path),
        "--env",
        ENV,
        "--timesteps",
        "32",
        "--critic-warmup",
        "0",
        "--n-envs",
        "1",
        "--anchor",
        _demos(cloned),
        "--anchor-weight",
        "0.5",
        "--anchor-decay",
        "0.9",
        "--hyperparam",
        "n_steps=32",
        "--hyperparam",
        "batch_size=32",
        "--out",
        str(out),
    ]
    assert run(argv) == 0
    record = yaml.safe_load((out / "config.yaml").read_text())["anchor"]
    assert (record["weight"], record["decay"], record["frames"]) == (0.5, 0.9, 3 * STEPS)
    assert run([*argv[:-1], str(tmp_path / "bad"), "--anchor-decay", "0"]) == 2
    assert "--anchor-decay: must be > 0.0, got 0.0" in capsys.readouterr().err


# -- the pipeline --------------------------------------------------------------------------------------------------
def test_task_names_are_the_env_ids_keys():
    from dpr.cli import TASK_NAMES

    assert TASK_NAMES == tuple(ENV_IDS)


# -- the recipe: what `dpr finetune` takes from the model unless told ----------------------------------------------
REPEAT = 10  # the clone below decides every 10 physics steps, as the pipeline's learners do
AT_REPEAT = {**MEMORY, "action_repeat": REPEAT}


def _probabilities(policy, observations) -> torch.Tensor:
    with torch.no_grad():
        return policy.get_distribution(observations).distribution.probs


def test_soften_actions_widens_the_actions_and_keeps_the_likeliest(cloned):
    model, _ = load_model(cloned.model_path)
    env = gym.make(ENV, max_episode_steps=STEPS, **ENV_KWARGS)
    observations = torch.as_tensor(visited_observations(env, seeds=(0,), steps=31), dtype=torch.float32)
    before = _probabilities(model.policy, observations)
    soften_actions(model.policy, 1.0)
    assert torch.equal(_probabilities(model.policy, observations), before)
    soften_actions(model.policy, 3.0)
    after = _probabilities(model.policy, observations)
    logit = torch.logit(before, eps=1e-7)
    torch.testing.assert_close(torch.logit(after, eps=1e-7), logit / 3.0, atol=1e-4, rtol=1e-4)
    assert torch.equal(after > 0.5, before > 0.5)  # what a deterministic run of the model does
    bernoulli_entropy = lambda p: -(p * p.log() + (1 - p) * (1 - p).log())  # noqa: E731
    assert bernoulli_entropy(after).mean() > bernoulli_entropy(before).mean()


def test_soften_actions_on_the_swarm_actor_and_a_gaussian_one(swarm_clone):
    model, _ = load_model(swarm_clone)
    unit = model.policy.action_net.unit  # the swarm actor's logits come from one unit shared by every robot
    weight, bias = unit.weight.detach().clone(), unit.bias.detach().clone()
    soften_actions(model.policy, 4.0)
    torch.testing.assert_close(unit.weight, weight / 4.0)
    torch.testing.assert_close(unit.bias, bias / 4.0)
    from stable_baselines3 import PPO as SB3PPO

    gaussian = SB3PPO("MlpPolicy", "Pendulum-v1", n_steps=16, batch_size=16, device="cpu")
    log_std = gaussian.policy.log_std.detach().clone()
    soften_actions(gaussian.policy, 2.0)
    torch.testing.assert_close(gaussian.policy.log_std, log_std + np.log(2.0))


def test_exploration_temperature_needs_init_from_and_a_bounded_number(cloned, tmp_path):
    with pytest.raises(ValueError, match="^exploration_temperature: needs init_from"):
        TrainConfig("ppo", ENV, exploration_temperature=2.0)
    for bad in (0.0, -1.0, 101.0, float("nan"), "2", True):
        with pytest.raises(ValueError, match="^exploration_temperature: "):
            finetune_config(cloned.model_path, exploration_temperature=bad)
    assert finetune_config(cloned.model_path, exploration_temperature=100.0).exploration_temperature == 100.0


def test_cli_finetune_starts_from_the_softened_actor_and_records_it(swarm_clone, tmp_path, capsys, monkeypatch):
    import dpr.rl.train as training

    softened = []
    monkeypatch.setattr(training, "soften_actions", lambda policy, t: softened.append(t) or soften_actions(policy, t))
    out = tmp_path / "run"
    assert run(_finetune_argv(swarm_clone, out, "--timesteps", "16", "--exploration-temperature", "3")) == 0
    assert softened == [3.0]
    assert yaml.safe_load((out / "config.yaml").read_text())["exploration_temperature"] == 3.0
    assert run(_finetune_argv(swarm_clone, tmp_path / "bad", "--exploration-temperature", "0")) == 2
    assert "--exploration-temperature: must be > 0.0, got 0.0" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


@pytest.fixture(scope="module")
def swarm_clone(tmp_path_factory):
    """`dpr bc` with its defaults (one epoch) on three 12-decision Markov-wave episodes of 4 disk robots deciding
    every 10 physics steps."""
    root = tmp_path_factory.mktemp("recipe")
    spec = CollectSpec(ENV, policy="wave-markov", steps=12, env_kwargs=AT_REPEAT, **SMALL_ENV)
    collect(root / "demos", spec, episodes=3)
    argv = ["bc", "--dataset", str(root / "demos"), "--env", ENV, "--epochs", "1", "--out", str(root / "bc")]
    assert run(argv) == 0
    return root / "bc" / "model.zip"


def _finetune_argv(source, out, *extra: str) -> list[str]:
    return ["finetune", "--from", str(source), "--env", ENV, "--n-envs", "1", "--eval-episodes", "0"] + [
        *extra,
        "--out",
        str(out),
    ]


def _rewrite_metadata(source, target, change) -> None:
    """A copy of the model file ``source`` whose metadata is ``change(metadata)``."""
    with zipfile.ZipFile(source) as old, zipfile.ZipFile(target, "w") as new:
        for item in old.infolist():
            data = old.read(item)
            if item.filename == METADATA_MEMBER:
                data = json.dumps(change(json.loads(data)), indent=2, sort_keys=True)
            new.writestr(item, data)


def _strip_architecture(source, target) -> None:
    """A copy of the model file ``source`` as written before models recorded their network."""
    _rewrite_metadata(source, target, lambda metadata: {k: v for k, v in metadata.items() if k != "architecture"})


def test_dpr_bc_records_the_swarm_actor_it_built(swarm_clone):
    info = read_model_info(swarm_clone)
    assert info.architecture == {"policy": SWARM_POLICY, "policy_kwargs": {"net_arch": PAPER_NET}}
    assert info.env_kwargs["action_repeat"] == REPEAT
    model, _ = load_model(swarm_clone)
    assert isinstance(model.policy, SwarmActorCriticPolicy)


def test_dpr_finetune_takes_the_network_and_the_recipe_from_the_model(swarm_clone, tmp_path, capsys):
    """No --hyperparam: the clone's SwarmPolicy, gamma 0.99^10 and the pipeline's rollouts of 512 decisions, which
    a 16-decision run after a one-decision warm-up shortens to PPO's least, 2 (dpr.rl.budget)."""
    out = tmp_path / "run"
    assert run(_finetune_argv(swarm_clone, out, "--timesteps", "16")) == 0
    err = capsys.readouterr().err
    assert f"dpr finetune: from {swarm_clone}: policy=SwarmPolicy policy_kwargs={{net_arch: " in err
    assert "gamma=0.904 n_steps=512 batch_size=128 n_epochs=10 (for its decisions every 10 physics steps)" in err
    assert f"dpr finetune: wrote {out / 'model.zip'}" in err
    config = yaml.safe_load((out / "config.yaml").read_text())
    hyper = config["hyperparameters"]
    assert hyper["policy"] == SWARM_POLICY and hyper["policy_kwargs"] == {"net_arch": PAPER_NET}
    assert hyper["gamma"] == physics_discount(REPEAT) == round(0.99**REPEAT, 3)
    assert {key: hyper[key] for key in FINETUNE_AT_REPEAT} == {"n_steps": 2, "batch_size": 2, "n_epochs": 10}
    assert "fewer than one rollout of n_steps 512 x 1 envs" in config["steps"]["note"] in err
    assert hyper["learning_rate"] == 3e-5 and hyper["clip_range"] == 0.1  # the rest is the finetune preset's
    assert config["critic_warmup"] == default_critic_warmup(16) == 1
    assert config["timesteps_done"] == 2 + 16  # a warm-up of one whole rollout, the least PPO collects
    model, info = load_model(out / "model.zip")
    assert isinstance(model.policy, SwarmActorCriticPolicy) and info.architecture["policy"] == SWARM_POLICY


def test_a_hyperparam_of_the_user_wins_over_the_models(swarm_clone, tmp_path, capsys):
    out = tmp_path / "run"
    mine = {"gamma": 0.5, "n_steps": 16, "batch_size": 16, "n_epochs": 1}
    given = [arg for name, value in mine.items() for arg in ("--hyperparam", f"{name}={value}")]
    assert run(_finetune_argv(swarm_clone, out, "--timesteps", "40", *given)) == 0
    err = capsys.readouterr().err
    assert "policy=SwarmPolicy" in err and "gamma=" not in err and "n_steps=" not in err
    config = yaml.safe_load((out / "config.yaml").read_text())
    assert {key: config["hyperparameters"][key] for key in mine} == mine
    assert config["hyperparameters"]["policy"] == SWARM_POLICY  # what the user left alone comes from the model
    assert config["critic_warmup"] == 4  # a tenth of --timesteps
    assert (
        run(_finetune_argv(swarm_clone, tmp_path / "mlp", "--timesteps", "16", "--hyperparam", "policy=MlpPolicy")) == 2
    )
    assert "has another network than this run's" in capsys.readouterr().err  # the user's choice, and its error


def test_a_model_file_without_its_network_has_it_read_off_the_model(cloned, swarm_clone, tmp_path, capsys):
    """A model written before files recorded their network (the shipped ones): the network is read off the loaded
    model, the swarm actor included, so it fine-tunes with no --hyperparam policy=..."""
    old = tmp_path / "old.zip"
    _strip_architecture(cloned.model_path, old)
    assert read_model_info(old).architecture is None
    assert read_model_info(cloned.model_path).architecture == {
        "policy": "MlpPolicy",
        "policy_kwargs": {"net_arch": PAPER_NET},
    }
    assert loaded_architecture(old) == read_model_info(cloned.model_path).architecture
    given = [arg for name, value in TINY_PPO.items() for arg in ("--hyperparam", f"{name}={value}")]
    out = tmp_path / "run"
    assert run(_finetune_argv(old, out, "--timesteps", "32", "--critic-warmup", "16", *given)) == 0
    assert "policy=MlpPolicy policy_kwargs={net_arch: [" in capsys.readouterr().err
    config = yaml.safe_load((out / "config.yaml").read_text())
    assert config["critic_warmup"] == 16 and config["hyperparameters"]["gamma"] == 0.99  # no action_repeat: no recipe

    old_swarm = tmp_path / "old-swarm.zip"
    _strip_architecture(swarm_clone, old_swarm)
    assert loaded_architecture(old_swarm) == read_model_info(swarm_clone).architecture
    assert read_model_info(swarm_clone).architecture["policy"] == SWARM_POLICY
    assert run(_finetune_argv(old_swarm, tmp_path / "swarm", "--timesteps", "16")) == 0
    assert "policy=SwarmPolicy" in capsys.readouterr().err


def test_finetune_defaults_and_the_default_critic_warmup():
    at_repeat = ModelInfo("ppo", ENV, {"action_repeat": 10})
    assert finetune_defaults(at_repeat) == {"gamma": 0.904, **FINETUNE_AT_REPEAT}
    assert finetune_defaults(at_repeat, "a2c") == {"gamma": 0.904}  # A2C has no batches or epochs
    assert finetune_defaults(ModelInfo("ppo", ENV, {"action_repeat": 6})) == {"gamma": 0.941, **FINETUNE_AT_REPEAT}
    assert finetune_defaults(ModelInfo("ppo", ENV, {"action_repeat": 1})) == {}
    network = {"policy": SWARM_POLICY, "policy_kwargs": {"robot_net": [8]}}
    assert finetune_defaults(ModelInfo("ppo", ENV, {}, architecture=network)) == network
    assert [default_critic_warmup(n) for n in (5, 16, 3000, 30_000, 100_000, 1_000_000)] == [
        *(0, 1, 300, 3000, 10_000, 10_000)
    ]


def test_the_recorded_network_is_optional_and_checked(cloned, tmp_path):
    info = ModelInfo("ppo", ENV, {"n_robots": 4})
    assert "architecture" not in json.loads(info.as_json())  # files without it keep their old form
    bad = tmp_path / "bad.zip"
    for architecture in ({"policy": 3, "policy_kwargs": {}}, {"policy": "MlpPolicy"}, ["MlpPolicy"]):
        _rewrite_metadata(
            cloned.model_path, bad, lambda metadata, wrong=architecture: {**metadata, "architecture": wrong}
        )
        with pytest.raises(
            ValueError, match=rf"^policy: {re.escape(str(bad))}: {METADATA_MEMBER} is malformed.*architecture"
        ):
            read_model_info(bad)


def test_a_finetune_run_says_finetune_and_its_bars_stop_at_their_totals(cloned, tmp_path, monkeypatch):
    """SB3 rounds both the warm-up and the run up to whole 32-step rollouts (20 -> 32, 40 -> 64): the bars stop at
    the steps asked for, not past them."""
    import tqdm

    bars = []

    class Recorded(tqdm.tqdm):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **{**kwargs, "disable": False, "file": io.StringIO()})
            bars.append(self)

    monkeypatch.setattr(tqdm, "tqdm", Recorded)
    lines = []
    config = finetune_config(cloned.model_path, timesteps=40, critic_warmup=20, eval_episodes=0)
    result = train(config, tmp_path / "run", show_progress=True, log=lines.append)
    assert yaml.safe_load(result.config_path.read_text())["timesteps_done"] == 32 + 64
    assert [(bar.desc.split()[0], bar.total, bar.n) for bar in bars] == [("critic", 20, 20), ("finetune", 40, 40)]
    assert lines[-1].startswith(f"dpr finetune: wrote {result.model_path}")


def test_finetune_under_one_rollout_runs_no_more_than_asked(cloned, tmp_path, capsys):
    """`dpr finetune --timesteps 200` on the finetune preset's rollouts of 1024 x 2 envs (which ran a whole rollout
    for the warm-up and another for the training): rollouts of 10 x 2 make the 20 warm-up and 200 training steps
    asked, and the log and config.yaml say so."""
    out = tmp_path / "run"
    flags = ["--env", ENV, "--timesteps", "200", "--n-envs", "2", "--eval-episodes", "0", "--out", str(out)]
    assert run(["finetune", "--from", str(cloned.model_path), *flags]) == 0
    err = capsys.readouterr().err
    record = yaml.safe_load((out / "config.yaml").read_text())
    assert (record["timesteps"], record["critic_warmup"], record["timesteps_done"]) == (200, 20, 220)
    assert load_model(out / "model.zip")[0].num_timesteps == 220
    assert {k: record["hyperparameters"][k] for k in ("n_steps", "batch_size")} == {"n_steps": 10, "batch_size": 20}
    steps = record["steps"]
    assert (steps["rollout"], steps["critic_warmup"], steps["training"]) == (20, 20, 200)
    assert steps["note"] in err and "fewer than one rollout of n_steps 1024 x 2 envs" in steps["note"]
    assert "rollouts of n_steps=10 batch_size=20 (20 steps)" in steps["note"]
