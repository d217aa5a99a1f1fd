"""Fine-tuning a behaviour-cloned model (`dpr finetune`: the finetune preset, init_from, the critic warm-up), and
the whole pipeline (`dpr pipeline`: demonstrations -> BC -> fine-tuning beside RL from scratch -> evaluation ->
report, resumable)."""

import json
import re
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
import yaml
from helpers import run_cli as run
from helpers import shrink_rollouts

from dpr.datasets.collect import CollectSpec, collect
from dpr.envs import ENV_IDS
from dpr.imitation import behaviour_clone
from dpr.policies.hyperparams import load_hyperparams
from dpr.policies.registry import make_policy
from dpr.policies.sb3 import (
    actor_parameters,
    build_model,
    load_initial_policy,
    load_model,
    make_vec_env,
    read_model_info,
)
from dpr.rl.evaluation import evaluate
from dpr.rl.pipeline import PipelineConfig, run_pipeline
from dpr.rl.train import TrainConfig, train, warm_up_critic

ENV = "dpr/Navigation-v0"
SMALL_ENV = {"n_robots": 4, "robot_model": "disk"}
MEMORY = {"obs_last_action": True}
ENV_KWARGS = {**SMALL_ENV, **MEMORY}
STEPS = 40
# One 32-step rollout per update, so that 64 steps of warm-up and 64 of fine-tuning are a few updates, not a
# rollout of the yaml's 1024 steps.
TINY_PPO = {"n_steps": 32, "batch_size": 32}
PAPER_NET = [64, 128, 128, 128, 64]
QUIET = {"show_progress": False, "log": lambda line: None}


@pytest.fixture(scope="module")
def cloned(tmp_path_factory):
    """A PPO actor-critic cloned (one epoch) from three 40-step Markov-wave episodes of 4 disk robots."""
    root = tmp_path_factory.mktemp("finetune")
    spec = CollectSpec(ENV, policy="wave-markov", steps=STEPS, env_kwargs=MEMORY, **SMALL_ENV)
    collect(root / "demos", spec, episodes=3, workers=1)
    return behaviour_clone(root / "demos", ENV, epochs=1, batch_size=128, out=root / "bc", log=lambda line: None)


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
    assert run([*base, "--env", ENV, "--env-kwarg", "n_robots=9", "--out", str(tmp_path / "n9")]) == 2
    assert "trained with n_robots=4; n_robots=9 makes a different observation" in capsys.readouterr().err
    assert run([*base, "--env", ENV, "--env-kwarg", "obs_last_action=false", "--out", str(tmp_path / "plain")]) == 2
    assert "trained with obs_last_action=True; obs_last_action=False" in capsys.readouterr().err
    assert run([*base, "--env", ENV, "--algo", "dqn"]) == 2
    assert "invalid choice: 'dqn'" in capsys.readouterr().err
    assert run(["finetune", "--from", str(tmp_path / "none.zip"), "--env", ENV, "--out", str(tmp_path / "x")]) == 2
    assert "no model file" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # nothing written


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
        with pytest.raises(ValueError, match=rf"{name} must be a number"):
            TrainConfig("ppo", ENV, init_from=str(cloned.model_path), anchor_datasets=["x"], **{name: bad})
    with pytest.raises(ValueError, match="algo 'dqn' cannot be anchored"):
        TrainConfig("dqn", ENV, anchor_datasets=[_demos(cloned)])
    other = tmp_path / "n5"  # demonstrations of 5 robots cannot anchor a 4-robot policy
    collect(
        other,
        CollectSpec(ENV, policy="wave-markov", steps=10, env_kwargs=MEMORY, n_robots=5, robot_model="disk"),
        episodes=1,
        workers=1,
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
    assert "anchor_decay must be a number in (0.0, 1.0], got 0.0" in capsys.readouterr().err


# -- the pipeline --------------------------------------------------------------------------------------------------
def test_task_names_are_the_env_ids_keys():
    from dpr.cli import TASK_NAMES

    assert TASK_NAMES == tuple(ENV_IDS)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"test_seeds": [1000]}, r"test_seeds: \[1000\] are demonstration seeds"),
        ({"demo_seed": 100, "episodes": 3, "test_seeds": [90, 102]}, r"test_seeds: \[102\]"),
        ({"validation_seeds": [1001]}, r"validation_seeds: \[1001\] are demonstration seeds"),
        ({"test_seeds": []}, "test_seeds: must name at least one seed"),
        ({"test_seeds": [5, 5]}, "test_seeds: each seed must appear once"),
        ({"validation_seeds": [7, 300]}, r"validation_seeds: \[300\] are test seeds too"),
        ({"train_seeds": [0, 1]}, "validation_seeds: several train_seeds need validation seeds"),
        ({"train_seeds": [-1]}, "train_seeds: must be >= 0"),
        ({"tasks": ["swimming"]}, "tasks must be among"),
        ({"tasks": []}, "tasks must be among"),
        ({"finetune_algos": ["dqn"]}, "finetune_algos must be among"),
        ({"scratch_algos": ["sac"]}, "scratch_algos must be among"),
        ({"episodes": 1}, "episodes: must be >= 2"),
        ({"steps": 0}, "steps: must be >= 1"),
        ({"critic_warmup": -1}, "critic_warmup: must be >= 0"),
        ({"approach_reward": -1.0}, "approach_reward must be a number >= 0"),
        ({"approach_reward": "1"}, "approach_reward must be a number >= 0"),
    ],
)
def test_pipeline_config_refuses_bad_settings(kwargs, message):
    with pytest.raises(ValueError, match=message):
        PipelineConfig(**kwargs)


def test_pipeline_shapes_only_manipulation_rewards():
    config = PipelineConfig(tasks=list(ENV_IDS), action_repeat=1)
    assert config.rl_env_kwargs("manipulation") == {"obs_last_action": True, "approach_reward": 1.0}
    for task in ("navigation", "gate", "unresponsive"):
        assert config.rl_env_kwargs(task) == {"obs_last_action": True}
    unshaped = PipelineConfig(approach_reward=0, action_repeat=1)
    assert unshaped.rl_env_kwargs("manipulation") == {"obs_last_action": True}
    for task in ENV_IDS:  # every task's env takes them
        gym.make(ENV_IDS[task], **config.rl_env_kwargs(task)).close()


PIPELINE = dict(
    tasks=["navigation"],
    n_robots=4,
    episodes=2,
    steps=30,
    bc_epochs=1,
    critic_warmup=32,
    finetune_steps=64,
    scratch_algos=["ppo"],
    test_seeds=[100],
    workers=1,
    anchor=True,
    action_repeat=1,  # a decision every physics step, and the yaml's (shrunk) rollouts: RL of a few dozen steps
    finetune_hyperparams={},
)
METHODS = ["wave", "bc", "bc-ppo", "ppo"]


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory):
    """One tiny pipeline run. PipelineConfig has no hyperparameter overrides: the yaml's 1024-step PPO rollouts
    are shrunk to 32 steps here, so that a few dozen steps of RL are a few updates."""
    out = tmp_path_factory.mktemp("pipeline") / "run"
    with pytest.MonkeyPatch.context() as patch:
        shrink_rollouts(patch, TINY_PPO)
        report = run_pipeline(PipelineConfig(**PIPELINE), out, **QUIET)
    return out, report


def test_pipeline_trains_manipulation_with_the_shaping(tmp_path):
    """RL on Manipulation, fine-tuning and from scratch, gets the approach shaping; the clone and the
    evaluations do not need it (the metric follows the ball either way)."""
    settings = {**PIPELINE, "tasks": ["manipulation"], "anchor": False, "approach_reward": 0.5}
    with pytest.MonkeyPatch.context() as patch:
        shrink_rollouts(patch, TINY_PPO)
        run_pipeline(PipelineConfig(**settings), tmp_path / "run", **QUIET)
    for method in ("bc-ppo", "ppo"):
        info = read_model_info(tmp_path / "run" / "models" / f"manipulation-{method}.zip")
        assert info.env_kwargs["approach_reward"] == 0.5, method
    assert "approach_reward" not in read_model_info(tmp_path / "run" / "models" / "manipulation-bc.zip").env_kwargs


def test_pipeline_learners_decide_every_action_repeat_steps(tmp_path):
    """With action_repeat=10 the demonstrations, the clone and RL all decide every 10 physics steps; budgets and
    evaluations count physics steps, so the wave (every step) and the learners are scored over the same time."""
    from dpr.datasets.lerobot import LeRobotReader

    settings = {**PIPELINE, "anchor": False, "action_repeat": 10, "steps": 60, "critic_warmup": 320}
    out = tmp_path / "run"
    with pytest.MonkeyPatch.context() as patch:
        shrink_rollouts(patch, TINY_PPO)
        run_pipeline(PipelineConfig(**settings), out, **QUIET)
    assert LeRobotReader(out / "datasets" / "navigation").info["total_frames"] == 2 * 6
    for method in METHODS[1:]:
        assert read_model_info(out / "models" / f"navigation-{method}.zip").env_kwargs["action_repeat"] == 10
        payload = json.loads((out / "eval" / "test" / f"navigation-{method}-seed0.json").read_text())
        assert payload["steps"] == 60
    assert json.loads((out / "eval" / "test" / "navigation-wave.json").read_text())["steps"] == 60
    config = yaml.safe_load((out / "runs").glob("navigation-ppo-seed0*").__next__().joinpath("config.yaml").read_text())
    assert config["timesteps"] == (2 * 60 + 320 + 64) // 10  # RL from scratch: the same physics steps, in decisions


def test_pipeline_writes_every_stage(pipeline):
    out, report = pipeline
    assert report == out / "report"
    assert (out / "datasets" / "navigation" / "meta" / "info.json").is_file()
    models = [f"navigation-{m}{run}.zip" for m in METHODS[1:] for run in ("", "-seed0")]  # one run: its own median
    assert sorted(p.name for p in (out / "models").iterdir()) == sorted(models)
    evaluations = ["navigation-wave.json", *(f"navigation-{m}-seed0.json" for m in METHODS[1:])]
    assert sorted(p.name for p in (out / "eval" / "test").iterdir()) == sorted(evaluations)
    assert not any((out / "eval" / "validation").iterdir())  # one training seed: nothing to choose
    assert {"results.md", "bars.png", "trajectories.png", "intervals.png"} <= {p.name for p in report.iterdir()}
    for model in (out / "models").iterdir():
        info = read_model_info(model)
        assert info.env_kwargs == {"n_robots": 4, "robot_model": "paddle", "obs_last_action": True}
        assert info.max_episode_steps == 30
    finetune = yaml.safe_load((out / "runs" / "navigation-bc-ppo-seed0" / "config.yaml").read_text())
    assert finetune["init_from"] == str((out / "models" / "navigation-bc-seed0.zip").resolve())
    assert finetune["critic_warmup"] == 32 and finetune["timesteps"] == 64
    dataset = str((out / "datasets" / "navigation").resolve())
    assert finetune["anchor"]["datasets"] == [dataset] and finetune["anchor"]["frames"] == 2 * 30
    scratch = yaml.safe_load((out / "runs" / "navigation-ppo-seed0" / "config.yaml").read_text())
    assert scratch["timesteps"] == PipelineConfig(**PIPELINE).rl_steps == 2 * 30 + 32 + 64
    assert scratch["init_from"] is None and scratch["hyperparameters"]["preset"] == "default"


def test_pipeline_evaluates_every_method_on_the_same_swarm(pipeline):
    out, _ = pipeline
    starts = []
    for method in METHODS:
        name = "navigation-wave" if method == "wave" else f"navigation-{method}-seed0"
        payload = json.loads((out / "eval" / "test" / f"{name}.json").read_text())
        assert payload["seeds"] == [100] and payload["steps"] == 30
        assert payload["env_kwargs"].get("n_robots", 9) == 4, method  # the wave too, not the default N=9
        assert payload["env_kwargs"]["obs_last_action"] is True
        (episode,) = payload["episodes"]
        starts.append(episode["trajectory"][0])
    assert all(start == starts[0] for start in starts)


def test_pipeline_report_has_a_row_per_method(pipeline):
    _, report = pipeline
    rows = [
        line.split("|")
        for line in (report / "results.md").read_text().split("## Interval estimates")[0].splitlines()
        if line.startswith("| Navigation |")
    ]
    assert [row[2].strip() for row in rows] == METHODS


def test_pipeline_resumes_without_changing_anything_and_refuses_other_settings(pipeline):
    out, _ = pipeline
    files = {path: path.stat().st_mtime_ns for path in out.rglob("*") if path.is_file()}
    lines = []
    run_pipeline(PipelineConfig(**PIPELINE), out, show_progress=False, log=lines.append)  # would train for long
    assert {path: path.stat().st_mtime_ns for path in out.rglob("*") if path.is_file()} == files
    skipped = [line for line in lines if line.endswith("skipped")]
    assert (
        len(skipped) == 1 + 4 + 1
    )  # the task's training (its models and test evaluations exist), four evaluations, report
    with pytest.raises(ValueError, match="^out: .* holds a pipeline run with other settings"):
        run_pipeline(PipelineConfig(**{**PIPELINE, "finetune_steps": 128}), out, **QUIET)
    with pytest.raises(ValueError, match="holds a pipeline run with other settings"):
        run_pipeline(PipelineConfig(**{**PIPELINE, "test_seeds": [100, 101]}), out, **QUIET)
    assert {path: path.stat().st_mtime_ns for path in out.rglob("*") if path.is_file()} == files


def test_pipeline_resumes_a_run_from_before_a_setting_existed(pipeline, tmp_path):
    """A pipeline.yaml written before ``anchor`` existed resumes as anchor=False (the default), and only so."""
    import shutil

    old = tmp_path / "old"
    shutil.copytree(pipeline[0], old)
    record = yaml.safe_load((old / "pipeline.yaml").read_text())
    del record["config"]["anchor"]
    (old / "pipeline.yaml").write_text(yaml.safe_dump(record))
    with pytest.raises(ValueError, match="holds a pipeline run with other settings"):
        run_pipeline(PipelineConfig(**PIPELINE), old, **QUIET)  # anchor=True differs from the old default
    lines = []
    run_pipeline(PipelineConfig(**{**PIPELINE, "anchor": False}), old, show_progress=False, log=lines.append)
    assert sum(line.endswith("skipped") for line in lines) == 1 + 4 + 1


def test_pipeline_resumes_from_a_record_without_datasets_and_training_runs(pipeline, tmp_path):
    """A finished task needs only its canonical models, test evaluations and choices: a record of the run
    kept without the datasets, the run folders and the training runs' models resumes without training, and
    writes the same report."""
    import shutil

    record = tmp_path / "record"
    shutil.copytree(pipeline[0], record)
    for folder in ("datasets", "runs", "report"):
        shutil.rmtree(record / folder)
    for model in (record / "models").glob("*-seed*.zip"):
        model.unlink()
    lines = []
    run_pipeline(PipelineConfig(**PIPELINE), record, show_progress=False, log=lines.append)
    assert "dpr pipeline: navigation: its canonical models and test evaluations exist, skipped" in lines
    assert not (record / "datasets").exists() or not any((record / "datasets").iterdir())
    assert not any((record / "models").glob("*-seed*.zip"))
    original = (pipeline[0] / "report" / "results.md").read_text()  # names its sources by path
    assert (record / "report" / "results.md").read_text() == original.replace(str(pipeline[0]), str(record))


def test_pipeline_with_training_seeds_chooses_the_median_run_on_validation_seeds(tmp_path):
    """Three training seeds: every run is scored on the validation seeds, the canonical model is the median
    run there (not the best), and the report's interval rows hold every run on the test seeds."""
    settings = {**PIPELINE, "anchor": False, "train_seeds": [0, 1, 2], "validation_seeds": [200, 201]}
    out = tmp_path / "run"
    with pytest.MonkeyPatch.context() as patch:
        shrink_rollouts(patch, TINY_PPO)
        report = run_pipeline(PipelineConfig(**settings), out, **QUIET)
    choices = yaml.safe_load((out / "choices.yaml").read_text())
    for method in METHODS[1:]:
        medians = choices[f"navigation-{method}"]["validation_medians"]
        for seed, median in medians.items():
            payload = json.loads((out / "eval" / "validation" / f"navigation-{method}-seed{seed}.json").read_text())
            assert payload["seeds"] == [200, 201]
            assert median == pytest.approx(float(np.median([e["projected_displacement"] for e in payload["episodes"]])))
        chosen = choices[f"navigation-{method}"]["chosen_seed"]
        assert sorted(medians, key=lambda s: (medians[s], s))[1] == chosen
        weights = {
            run: load_model(out / "models" / f"navigation-{method}{run}.zip")[0].policy.state_dict()
            for run in ("", "-seed0", "-seed1", "-seed2")
        }
        same = [run for run in weights if run and all((weights[run][k] == v).all() for k, v in weights[""].items())]
        assert same == [f"-seed{chosen}"]  # the canonical model is the chosen run's weights, and no other's
    assert not list((out / "eval" / "test").glob("*200*"))
    text = (report / "results.md").read_text()
    assert "| Navigation | bc-ppo | 3 × 1 |" in text and "| Navigation | wave | 1 × 1 |" in text


def test_canonical_models_are_slim_copies_that_act_as_their_run(pipeline):
    """The canonical model is its median run without the optimizer's moments: smaller, and the same policy."""
    out, _ = pipeline
    canonical, run = out / "models" / "navigation-bc-ppo.zip", out / "models" / "navigation-bc-ppo-seed0.zip"
    assert canonical.stat().st_size < 0.5 * run.stat().st_size
    assert read_model_info(canonical) == read_model_info(run)
    (slim, _), (full, _) = load_model(canonical), load_model(run)
    observations = np.random.default_rng(0).normal(size=(16, *slim.observation_space.shape)).astype(np.float32)
    np.testing.assert_array_equal(
        slim.predict(observations, deterministic=True)[0], full.predict(observations, deterministic=True)[0]
    )
    for name, tensor in full.policy.state_dict().items():
        assert (slim.policy.state_dict()[name] == tensor).all(), name
