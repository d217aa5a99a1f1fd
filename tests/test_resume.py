"""A training run stopped part-way resumes from its snapshot to the very model an uninterrupted run makes
(dpr.rl.resume), and an env rebuilt from its ReplayLog steps as the original does (dpr.envs.replay)."""

from __future__ import annotations

import functools
import io
import zipfile

import gymnasium as gym
import numpy as np
import pytest
import yaml
from helpers import stopped_after_snapshots

import dpr  # noqa: F401
from dpr.checks import ParameterError
from dpr.envs.replay import ReplayLog, replay
from dpr.rl import resume as resume_state
from dpr.rl.train import TrainConfig, resumable, train

ENV_KWARGS = {"obs_last_action": True, "action_repeat": 2}


def make_env():
    return ReplayLog(gym.make("dpr/Unresponsive-v0", n_robots=4, max_episode_steps=12, **ENV_KWARGS))


def test_replayed_env_steps_like_the_original():
    rng = np.random.default_rng(0)
    env = make_env()
    env.reset(seed=5)
    for _ in range(30):  # across two episode ends: the record is the current episode's only
        if env.step(rng.integers(0, 2, 4))[3]:
            env.reset()
    record = env.episode()
    assert record["seed"] is None and 0 < len(record["actions"]) < 12
    clone = replay(make_env, record)
    for _ in range(40):
        action = rng.integers(0, 2, 4)
        ours, theirs = env.step(action), clone.step(action)
        for a, b in zip(ours[:4], theirs[:4], strict=True):
            assert np.array_equal(a, b)
        if ours[3]:
            assert np.array_equal(env.reset()[0], clone.reset()[0])
    assert replay(make_env, None).episode() is None  # never reset: made as new


def _config(**overrides) -> TrainConfig:
    settings = dict(
        algo="ppo",
        env_id="dpr/Navigation-v0",
        n_robots=4,
        timesteps=320,
        seed=3,
        n_envs=2,
        steps_per_episode=12,
        env_kwargs=ENV_KWARGS,
        hyperparams={"n_steps": 16, "batch_size": 16, "n_epochs": 2},
        eval_episodes=1,
    )
    return TrainConfig(**{**settings, **overrides})


def _weights(path) -> dict[str, bytes]:
    with zipfile.ZipFile(path) as archive:
        return {name: archive.read(name) for name in ("policy.pth", "policy.optimizer.pth")}


def test_dqn_runs_keep_no_snapshot(tmp_path, monkeypatch):
    monkeypatch.setattr(resume_state, "SNAPSHOT_SECONDS", 0.0)
    written = []
    monkeypatch.setattr(resume_state, "save_snapshot", lambda *args, **kwargs: written.append(1))
    config = _config(algo="dqn", timesteps=64, hyperparams={"learning_starts": 16})
    train(config, tmp_path / "dqn", show_progress=False, log=lambda _: None)
    assert not written


def _evaluations(run_dir) -> dict[str, np.ndarray]:
    return dict(np.load(run_dir / "eval" / "evaluations.npz"))


SWARM_ACTOR = {"policy": "SwarmPolicy", "policy_kwargs": {"net_arch": [16], "robot_net": [16, 8]}}


@pytest.mark.parametrize(
    "algo, fine_tune, actor",
    [("ppo", False, {}), ("ppo", True, {}), ("a2c", False, {}), ("ppo", True, SWARM_ACTOR)],
    ids=["from-scratch", "fine-tune", "a2c", "fine-tune-swarm-actor"],
)
def test_resumed_run_ends_with_the_uninterrupted_model(tmp_path, algo, fine_tune, actor):
    extra = {"algo": algo, "hyperparams": {"n_steps": 16}} if algo == "a2c" else {}
    if fine_tune:  # a fine-tuning after a critic warm-up, as the pipeline's: the snapshot comes after the warm-up
        hyperparams = {**_config().hyperparams, **actor}
        start = _config(timesteps=64, seed=1, hyperparams=hyperparams)
        start = train(start, tmp_path / "start", show_progress=False, log=lambda _: None)
        extra = {"init_from": str(start.model_path), "critic_warmup": 32, "hyperparams": hyperparams}
    config = _config(**extra)
    whole = train(config, tmp_path / "whole", show_progress=False, log=lambda _: None)
    assert not resume_state.snapshot_path(whole.run_dir).exists()  # a finished run drops its snapshot

    with stopped_after_snapshots(4):
        train(config, tmp_path / "stopped", show_progress=False, log=lambda _: None)
    stopped = tmp_path / "stopped"
    assert not (stopped / "model.zip").exists() and resumable(stopped, config)
    reached = resume_state.load_snapshot(stopped).reached
    assert 0 < reached < whole.timesteps + (32 if fine_tune else 0)

    lines = []
    resumed = train(config, stopped, show_progress=False, resume=True, log=lines.append)
    assert f"resumed at step {reached}" in lines[0]
    assert _weights(resumed.model_path) == _weights(whole.model_path)
    for name, values in _evaluations(whole.run_dir).items():
        np.testing.assert_array_equal(_evaluations(stopped)[name], values)
    record = yaml.safe_load(resumed.config_path.read_text())
    assert [r["from_timesteps"] for r in record["resumed"]] == [reached]
    assert record["timesteps_done"] == yaml.safe_load(whole.config_path.read_text())["timesteps_done"]
    assert not resume_state.snapshot_path(stopped).exists()


def test_a_stop_while_the_snapshot_is_replaced_keeps_one(tmp_path):
    config = _config(timesteps=128)
    with stopped_after_snapshots(2):
        train(config, tmp_path / "run", show_progress=False, log=lambda _: None)
    folder = resume_state.snapshot_path(tmp_path / "run")
    folder.rename(folder.with_name("resume.new"))  # as if stopped between the two renames
    assert resumable(tmp_path / "run", config) and not folder.exists()  # asking changes nothing
    assert resume_state.load_snapshot(tmp_path / "run").reached > 0 and folder.is_dir()  # loading puts it back


def test_resume_refuses_other_settings_and_folders_without_a_snapshot(tmp_path):
    config = _config(timesteps=128)
    with stopped_after_snapshots():
        train(config, tmp_path / "run", show_progress=False, log=lambda _: None)
    before = sorted(p.name for p in (tmp_path / "run").iterdir())
    other = _config(timesteps=128, seed=4)
    assert not resumable(tmp_path / "run", other)
    with pytest.raises(ParameterError, match=r"out.*other settings.*seed"):
        train(other, tmp_path / "run", show_progress=False, resume=True, log=lambda _: None)
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == before  # refused before touching anything
    (tmp_path / "empty").mkdir()
    with pytest.raises(ParameterError, match="no snapshot"):
        train(config, tmp_path / "empty", show_progress=False, resume=True, log=lambda _: None)


def test_snapshot_of_another_version_is_refused(tmp_path):
    folder = resume_state.snapshot_path(tmp_path)
    folder.mkdir()
    (folder / resume_state.MODEL_FILE).write_bytes(b"")
    buffer = io.BytesIO()
    import pickle

    pickle.dump({"version": resume_state.STATE_VERSION + 1}, buffer)
    (folder / resume_state.STATE_FILE).write_bytes(buffer.getvalue())
    with pytest.raises(ValueError, match="snapshot version"):
        resume_state.load_snapshot(tmp_path)


def test_replay_is_picklable_for_subprocesses():
    """The factories a resumed SubprocVecEnv gets travel to its workers."""
    import cloudpickle

    record = {"random_state": None, "seed": 2, "options": None, "actions": [np.ones(4, dtype=np.int8)]}
    factory = cloudpickle.loads(cloudpickle.dumps(functools.partial(replay, make_env, record)))
    assert len(factory().episode()["actions"]) == 1


def test_cli_resume_names_the_stopped_run_folder(tmp_path, capsys):
    from helpers import run_cli

    train = ["train", "--algo", "ppo", "--env", "dpr/Navigation-v0", "--n-robots", "4", "--timesteps", "64"]
    assert run_cli([*train, "--resume"]) == 2
    assert "--resume: name the stopped run's folder with --out" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert run_cli([*train, "--resume", "--out", str(tmp_path / "empty")]) == 2
    assert "--out: " in (err := capsys.readouterr().err) and "holds no snapshot" in err
    assert not any((tmp_path / "empty").iterdir())
