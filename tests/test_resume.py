"""A training run stopped part-way resumes from its snapshot to the very model an uninterrupted run makes
(dpr.rl.resume), and an env rebuilt from its ReplayLog steps as the original does (dpr.envs.replay)."""

from __future__ import annotations

import functools
import json
import pickle
import zipfile

import gymnasium as gym
import numpy as np
import pytest
import torch
import yaml
from helpers import stopped_after_snapshots

import dpr  # noqa: F401
from dpr.checks import ParameterError
from dpr.envs.parallel import parallel_env
from dpr.envs.replay import ParallelReplayLog, ReplayLog, replay, replay_parallel
from dpr.rl import resume as resume_state
from dpr.rl.plain_state import write_state
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


def test_replayed_parallel_env_steps_like_the_original():
    """The PettingZoo swarm of a per-robot run, rebuilt from its record, observes and rewards as the original."""

    def make():
        return ParallelReplayLog(
            parallel_env("unresponsive", n_robots=4, robot_model="disk", max_episode_steps=12, local_obs=True)
        )

    rng = np.random.default_rng(0)
    env = make()
    env.reset(seed=5)
    for _ in range(30):
        *_, truncations, _ = env.step(dict(zip(env.possible_agents, rng.integers(0, 2, 4))))
        if any(truncations.values()):
            env.reset()
    record = env.episode()
    assert record["seed"] is None and 0 < len(record["actions"]) < 12
    clone = replay_parallel(make, record)
    for _ in range(40):
        actions = dict(zip(env.possible_agents, rng.integers(0, 2, 4)))
        ours, theirs = env.step(actions), clone.step(actions)
        for a, b in zip(ours[:4], theirs[:4], strict=True):  # observations, rewards, terminations, truncations
            for agent in env.possible_agents:
                np.testing.assert_array_equal(a[agent], b[agent])
        if any(ours[3].values()):
            first, second = env.reset()[0], clone.reset()[0]
            assert all(np.array_equal(first[agent], second[agent]) for agent in env.possible_agents)
    assert replay_parallel(make, None).episode() is None


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
    record_path = tmp_path / "run" / "config.yaml"
    record = yaml.safe_load(record_path.read_text())
    del record["config"]["exploration_temperature"]  # as a run recorded before the setting existed
    record_path.write_text(yaml.safe_dump(record))
    assert resumable(tmp_path / "run", config)  # it ran at the default, 1
    record["config"]["exploration_temperature"] = 2.0
    record_path.write_text(yaml.safe_dump(record))
    assert not resumable(tmp_path / "run", config)
    (tmp_path / "empty").mkdir()
    with pytest.raises(ParameterError, match="no snapshot"):
        train(config, tmp_path / "empty", show_progress=False, resume=True, log=lambda _: None)


def test_snapshot_of_another_version_is_refused(tmp_path):
    folder = resume_state.snapshot_path(tmp_path)
    folder.mkdir()
    (folder / resume_state.WEIGHTS_FILE).write_bytes(b"")
    state = {"version": resume_state.STATE_VERSION + 1}
    write_state(state, folder / resume_state.STATE_FILE, folder / resume_state.ARRAYS_FILE)
    with pytest.raises(ValueError, match="snapshot version"):
        resume_state.load_snapshot(tmp_path)


class _CreatesAFile:
    """Unpickling it creates the file ``path``: what a crafted snapshot would do."""

    def __init__(self, path):
        self.path = str(path)

    def __reduce__(self):
        return (open, (self.path, "w"))


def test_a_snapshot_is_plain_files(tmp_path):
    """A snapshot holds JSON, an npz without objects and torch weights: nothing of it is a pickle."""
    config = _config(timesteps=128)
    with stopped_after_snapshots(2):
        train(config, tmp_path / "run", show_progress=False, log=lambda _: None)
    folder = resume_state.snapshot_path(tmp_path / "run")
    assert sorted(p.name for p in folder.iterdir()) == ["arrays.npz", "state.json", "weights.pt"]
    state = json.loads((folder / "state.json").read_text())
    assert state["version"] == resume_state.STATE_VERSION and state["reached"] > 0
    with np.load(folder / "arrays.npz", allow_pickle=False) as arrays:
        assert all(not arrays[name].dtype.hasobject for name in arrays.files)
    torch.load(folder / "weights.pt", weights_only=True)


def test_a_pickled_snapshot_is_refused_unread(tmp_path):
    """The pickled layout of an earlier dpr (state.pkl beside model.zip) is refused with how to go on, and a
    crafted one creates nothing: it is never unpickled."""
    config = _config(timesteps=128)
    marker = tmp_path / "created"
    run = tmp_path / "run"
    with stopped_after_snapshots():
        train(config, run, show_progress=False, log=lambda _: None)
    folder = resume_state.snapshot_path(run)
    for child in folder.iterdir():
        child.unlink()
    (folder / "model.zip").write_bytes(b"PK")
    (folder / resume_state.OLD_STATE_FILE).write_bytes(pickle.dumps({"version": 1, "x": _CreatesAFile(marker)}))
    with pytest.raises(ValueError, match=r"state.pkl is a snapshot of an earlier dpr.*cannot be read safely"):
        resume_state.load_snapshot(run)
    assert not resumable(run, config)
    with pytest.raises(ParameterError, match=r"out.*cannot be read safely.*Start the run again in a new folder"):
        train(config, run, show_progress=False, resume=True, log=lambda _: None)
    assert not marker.exists()


def test_crafted_snapshot_files_are_refused_unread(tmp_path):
    """A weights file or an arrays file that holds a pickle is refused by torch (weights_only) and numpy
    (allow_pickle=False); the object in it is never made."""
    config = _config(timesteps=128)
    run = tmp_path / "run"
    with stopped_after_snapshots():
        train(config, run, show_progress=False, log=lambda _: None)
    folder = resume_state.snapshot_path(run)
    marker = tmp_path / "created"
    weights = folder / resume_state.WEIGHTS_FILE
    good = weights.read_bytes()
    torch.save({"policy": _CreatesAFile(marker)}, weights)
    with pytest.raises(ParameterError, match=r"out.*weights.pt: not the weights of a snapshot"):
        train(config, run, show_progress=False, resume=True, log=lambda _: None)
    weights.write_bytes(good)
    np.savez(folder / resume_state.ARRAYS_FILE, a0=np.array([_CreatesAFile(marker)], dtype=object))
    with pytest.raises(ValueError, match="not a snapshot dpr can read"):
        resume_state.load_snapshot(run)
    assert not marker.exists()


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


def test_plain_state_gives_back_each_value_as_written(tmp_path):
    from dpr.rl.plain_state import read_state

    tree = {
        "python": (3, tuple(range(5)), None),
        "numpy": ("MT19937", np.arange(4, dtype=np.uint32), 2, 0, 0.0),
        "torch": torch.arange(3, dtype=torch.uint8),
        "scalars": [np.int64(7), np.float32(0.1), np.bool_(True), float("-inf"), 2**100],
        "actions": [np.array(1), np.array(0)],
        "by_number": {1: "a", "$x": [np.ones((2, 2), dtype=np.float32)]},
    }
    write_state(tree, tmp_path / "s.json", tmp_path / "s.npz")
    back = read_state(tmp_path / "s.json", tmp_path / "s.npz")
    assert back["python"] == tree["python"] and isinstance(back["python"][1], tuple)
    assert back["numpy"][0] == "MT19937" and np.array_equal(back["numpy"][1], tree["numpy"][1])
    assert back["numpy"][1].dtype == np.uint32 and torch.equal(back["torch"], tree["torch"])
    assert [type(v) for v in back["scalars"]] == [type(v) for v in tree["scalars"]] and back["scalars"] == tree[
        "scalars"
    ]
    assert all(a.shape == () and a.dtype == b.dtype for a, b in zip(back["actions"], tree["actions"], strict=True))
    assert list(back["by_number"]) == [1, "$x"] and back["by_number"][1] == "a"
    assert back["by_number"]["$x"][0].dtype == np.float32
    with pytest.raises(TypeError, match="cannot be stored without pickling"):
        write_state({"f": lambda: 0}, tmp_path / "t.json", tmp_path / "t.npz")
