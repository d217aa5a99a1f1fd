"""The learners run with torch.distributions' argument checks off (dpr.policies.distributions), give the setting back
after, and the batched PPO stops on an update whose terms are not numbers."""

import math

import pytest
import stable_baselines3
import torch
from helpers import QUIET, small_batched_config
from torch.distributions import Bernoulli, Distribution

import dpr  # noqa: F401
import dpr.rl.batched_ppo as batched_ppo
from dpr.imitation.bc import fit_with_early_stopping
from dpr.policies.distributions import unchecked_distributions
from dpr.rl.batched_train import build_batched_run, train_batched
from dpr.rl.train import TrainConfig, train

NAN_LOGITS = torch.tensor([math.nan])


@pytest.fixture(autouse=True)
def checks_on():
    """torch's own default (on unless Python runs with -O), whatever a test leaves behind."""
    before = Distribution._validate_args
    Distribution.set_default_validate_args(True)
    yield
    Distribution.set_default_validate_args(before)


def test_the_checks_are_off_within_and_back_after_even_on_an_error():
    with pytest.raises(ValueError, match="Expected parameter logits"):
        Bernoulli(logits=NAN_LOGITS)
    with unchecked_distributions():
        assert Bernoulli(logits=NAN_LOGITS).logits.isnan().all()
    with pytest.raises(ValueError, match="Expected parameter logits"):
        Bernoulli(logits=NAN_LOGITS)
    with pytest.raises(KeyError), unchecked_distributions():
        raise KeyError("a learner stopped")
    assert Distribution._validate_args
    Distribution.set_default_validate_args(False)  # a caller's own choice stays too
    with unchecked_distributions():
        pass
    assert not Distribution._validate_args


def _recording(monkeypatch, owner, name: str) -> list[bool]:
    """Calls of ``owner.name`` record whether distributions check their arguments at that moment."""
    seen, original = [], getattr(owner, name)

    def wrapped(*args, **kwargs):
        seen.append(Distribution._validate_args)
        return original(*args, **kwargs)

    monkeypatch.setattr(owner, name, wrapped)
    return seen


def test_sb3_training_on_pymunk_runs_without_the_checks(tmp_path, monkeypatch):
    seen = _recording(monkeypatch, stable_baselines3.PPO, "train")
    config = TrainConfig(
        "ppo",
        "dpr/Navigation-v0",
        n_robots=4,
        robot_model="disk",
        timesteps=128,
        steps_per_episode=32,
        hyperparams={"n_steps": 32, "batch_size": 32, "n_epochs": 1},
        eval_episodes=0,
        n_envs=2,
        env_processes=False,
    )
    train(config, tmp_path / "run", **QUIET)
    assert seen and not any(seen)
    assert Distribution._validate_args


@pytest.mark.parametrize("learner", ["torch", "sb3"])
def test_batched_training_runs_without_the_checks(tmp_path, monkeypatch, learner):
    if learner == "torch":
        seen = _recording(monkeypatch, batched_ppo, "update")
    else:
        seen = _recording(monkeypatch, stable_baselines3.PPO, "train")
    train_batched(small_batched_config(learner=learner), tmp_path / "run", **QUIET)
    assert seen and not any(seen)
    assert Distribution._validate_args


def test_behaviour_cloning_fits_without_the_checks():
    policy = torch.nn.Linear(2, 2)
    policy.set_training_mode = policy.train
    seen = []

    def run_epoch(epoch: int) -> dict:
        seen.append(Distribution._validate_args)
        return {"val_nll": 1.0 / epoch, "val_accuracy": 0.5}

    bar = type("Bar", (), {"set_postfix": lambda self, **kwargs: None})()
    fit = fit_with_early_stopping(policy, {"val_nll": 2.0, "val_accuracy": 0.0}, run_epoch, 3, 2, bar)
    assert seen == [False, False, False] and fit.best["epoch"] == 3
    assert Distribution._validate_args


def test_the_batched_ppo_stops_on_an_update_that_is_not_a_number():
    """Without the checks, a policy gone bad would train on: an env's rewards that are not numbers make an update's
    losses none either, and the loop says so after that update."""
    venv, model, *_ = build_batched_run(small_batched_config())
    env = venv.unwrapped
    step = env.step_tensors

    def poisoned(actions):
        observation, reward, *rest = step(actions)
        return (observation, torch.full_like(reward, math.nan), *rest)

    env.step_tensors = poisoned
    with pytest.raises(FloatingPointError, match="update 1 gave terms that are not numbers"):
        batched_ppo.learn(model, env, 64, seed=0)
    assert next(model.policy.parameters()).device.type == "cpu"
