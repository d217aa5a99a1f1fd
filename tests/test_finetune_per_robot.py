"""Fine-tuning a per-robot model with PPO on every robot of one or more swarms (`dpr finetune-decentralised`,
dpr.rl.finetune_per_robot), and the VecEnv of several swarms it trains on (SwarmsAsVecEnv)."""

import json
import re

import gymnasium as gym
import numpy as np
import pytest
import torch
import yaml
from helpers import assert_per_robot_model_acts_and_trains, drive, tree_hash
from helpers import run_cli as run

from dpr.checks import ParameterError
from dpr.datasets.collect import CollectSpec, collect
from dpr.envs import parallel_env
from dpr.envs.parallel import AgentsAsVecEnv, SwarmsAsVecEnv
from dpr.imitation import PerRobotCloneConfig
from dpr.imitation.per_robot import behaviour_clone_per_robot
from dpr.policies.decentralised import PerRobotPolicyAdapter
from dpr.policies.hyperparams import load_hyperparams
from dpr.policies.model_file import ModelInfo, model_env_kwargs, read_model_info
from dpr.policies.registry import make_policy
from dpr.policies.sb3 import actor_parameters, build_model, load_model, make_vec_env
from dpr.policies.sb3 import save_model as save_sb3_model
from dpr.rl.finetune_per_robot import PerRobotFinetuneConfig, finetune_per_robot
from dpr.rl.train import EVAL_SEED_OFFSET

ENV = "dpr/Navigation-v0"
DISK = {"robot_model": "disk"}
STEPS = 24  # the clone's episode length: training and validation episodes are this long
# 16 steps of each swarm per rollout, so that a budget of 64 swarm steps is a few updates.
TINY_PPO = {"n_steps": 16, "batch_size": 16, "n_epochs": 2}
QUIET = {"show_progress": False, "log": lambda line: None}


@pytest.fixture(scope="module")
def cloned(tmp_path_factory):
    """A per-robot clone of the decentralised wave: three 24-step episodes of 4 disk robots, a few epochs."""
    root = tmp_path_factory.mktemp("ft_per_robot")
    spec = CollectSpec(ENV, policy="decentralised-wave", n_robots=4, steps=STEPS, **DISK)
    collect(root / "demos", spec, episodes=3)
    return behaviour_clone_per_robot(
        root / "demos", ENV, PerRobotCloneConfig(epochs=3, batch_size=64), out=root / "bc", log=lambda _: None
    )


def finetune(cloned, out, **kwargs):
    settings = dict(n_robots=(4,), timesteps=64, critic_warmup=32, hyperparams=TINY_PPO, eval_episodes=1)
    config = PerRobotFinetuneConfig(str(cloned.model_path), ENV, **{**settings, **kwargs})
    return finetune_per_robot(config, out, **QUIET)


@pytest.fixture(scope="module")
def finetuned(cloned, tmp_path_factory):
    return finetune(cloned, tmp_path_factory.mktemp("ft_run") / "run")


def test_the_run_writes_a_per_robot_model_with_the_same_layout(cloned, finetuned):
    names = sorted(p.name for p in finetuned.run_dir.iterdir())
    assert {"model.zip", "best_model.zip", "config.yaml", "checkpoints", "eval"} <= set(names)
    start, end = (read_model_info(p) for p in (cloned.model_path, finetuned.model_path))
    assert (end.algo, end.env_id, end.env_kwargs, end.max_episode_steps) == ("ppo", ENV, DISK, STEPS)
    assert end.per_robot == start.per_robot  # trained on N=4 both times
    for path in (finetuned.best_model_path, *(finetuned.run_dir / "checkpoints").glob("*.zip")):
        assert read_model_info(path).per_robot == start.per_robot
    config = yaml.safe_load(finetuned.config_path.read_text())
    assert (config["timesteps"], config["critic_warmup"], config["n_robots"]) == (64, 32, [4])
    assert config["timesteps_done"] == 32 + 64 and config["shared_reward"] is True
    assert config["sb3_timesteps"] == 64 * 4  # one swarm step of 4 robots is 4 of SB3's steps
    assert "swarm steps" in config["step_unit"] and config["hyperparameters"]["preset"] == "finetune"
    evaluations = json.loads((finetuned.run_dir / "eval" / "evaluations.json").read_text())
    assert evaluations["seeds"] == [EVAL_SEED_OFFSET] and evaluations["n_robots"] == [4]
    rows = evaluations["evaluations"]
    assert rows[0]["model"] == "start" and rows[-1]["model"] == "final" and rows[-1]["swarm_steps"] == 96
    assert [row["best"] for row in rows].count(True) >= 1 and rows[0]["best"]
    assert not (finetuned.run_dir / "eval" / "candidate.zip").exists()


def test_ppo_moved_the_shared_weights(cloned, finetuned):
    start, _ = load_model(cloned.model_path)
    end, _ = load_model(finetuned.model_path)
    changed = [
        not torch.equal(a, b) for a, b in zip(actor_parameters(start.policy), actor_parameters(end.policy), strict=True)
    ]
    assert any(changed)
    value_start, value_end = start.policy.value_net.weight, end.policy.value_net.weight
    assert not torch.equal(value_start, value_end)  # the warm-up fitted the critic the clone left untrained


@pytest.mark.parametrize("n_robots", [1, 4, 16])
def test_the_fine_tuned_model_runs_at_any_size(finetuned, n_robots):
    env = gym.make(ENV, n_robots=n_robots, max_episode_steps=6, **DISK)
    policy = make_policy(str(finetuned.model_path), env)
    assert isinstance(policy, PerRobotPolicyAdapter)
    drive(env, policy, steps=6, seed=5)


def test_the_fine_tuned_model_runs_in_the_pettingzoo_env_and_trains_again(finetuned):
    assert_per_robot_model_acts_and_trains(finetuned.model_path, 7)


def test_two_swarm_sizes_train_side_by_side(cloned, tmp_path):
    result = finetune(cloned, tmp_path / "run", n_robots=(4, 6), timesteps=64, critic_warmup=0, eval_episodes=2)
    assert result.n_robots == (4, 6)
    info = read_model_info(result.model_path)
    assert info.per_robot["trained_n_robots"] == [4, 6]  # the clone's sizes and this run's
    config = yaml.safe_load(result.config_path.read_text())
    # 64 swarm steps over two swarms: 32 steps of each, every step 4 + 6 robot steps for SB3
    assert config["sb3_timesteps"] == 32 * 10 and config["timesteps_done"] == 64
    evaluations = json.loads((result.run_dir / "eval" / "evaluations.json").read_text())
    assert evaluations["n_robots"] == [4, 6]
    for row in evaluations["evaluations"]:
        assert set(row["by_n"]) == {"4", "6"} and all(len(v["returns"]) == 2 for v in row["by_n"].values())
        returns = [r for v in row["by_n"].values() for r in v["returns"]]
        assert row["mean_return"] == pytest.approx(np.mean(returns))


def test_one_size_may_be_given_as_a_number():
    assert PerRobotFinetuneConfig("model.zip", ENV, n_robots=9).n_robots == (9,)
    assert PerRobotFinetuneConfig("model.zip", ENV, n_robots=[9, 25]).n_robots == (9, 25)


def test_swarms_of_several_sizes_are_one_vec_env():
    kwargs = {"local_obs": True, "clock_period": 16, **DISK}
    venv = SwarmsAsVecEnv([parallel_env("navigation", n_robots=n, **kwargs) for n in (2, 3)])
    assert venv.num_envs == 5 and venv.offsets == [0, 2]
    assert venv.get_attr("n_robots") == [2, 2, 3, 3, 3] and venv.get_attr("n_robots", [1, 2]) == [2, 3]
    venv.seed(10)
    observations = venv.reset()
    assert observations.shape == (5, *venv.observation_space.shape)
    alone = AgentsAsVecEnv(parallel_env("navigation", n_robots=3, **kwargs))
    alone.seed(12)  # the second swarm's seed: 10 + its offset
    np.testing.assert_array_equal(observations[2:], alone.reset())
    observations, rewards, dones, infos = venv.step(np.ones(5, dtype=np.int64))
    assert observations.shape[0] == rewards.shape[0] == dones.shape[0] == len(infos) == 5
    assert rewards[0] == rewards[1] and rewards[2] == rewards[3] == rewards[4]  # each swarm shares its reward
    assert venv.env_method("state", indices=[0, 4])[1].shape == (6 * 3,)
    venv.close()
    alone.close()


# -- refused before any folder is made ------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def centralised_model(tmp_path_factory):
    """An untrained model of the centralised env (the whole swarm's state in, every robot's action out)."""
    kwargs = {"n_robots": 4, **DISK}
    env = make_vec_env(ENV, kwargs, STEPS, 1)
    model = build_model(load_hyperparams("ppo", ENV), env, 0, None)
    path = tmp_path_factory.mktemp("central") / "central.zip"
    save_sb3_model(model, path, ModelInfo("ppo", ENV, kwargs, STEPS))
    env.close()
    return path


@pytest.mark.parametrize(
    ("change", "error", "message"),
    [
        ({"init_from": "missing.zip"}, ParameterError, "init_from: no model file"),
        ({"env_id": "dpr/Gate-v0"}, ParameterError, "env_id: .*trained on dpr/Navigation-v0"),
        ({"env_kwargs": {"robot_model": "paddle"}}, ParameterError, "robot_model='disk'"),
        ({"env_kwargs": {"clock_period": 8}}, ParameterError, "env_kwargs: must not set"),
        ({"env_kwargs": {"action_type": "continuous"}}, ParameterError, "init_from: .*action_space"),
        ({"n_robots": (4, 0)}, ParameterError, "n_robots"),
        ({"algo": "dqn"}, ParameterError, "algo"),
        ({"hyperparams": {"batch_size": 1}}, ParameterError, "hyperparams: ppo refuses"),
    ],
)
def test_bad_input_is_refused_before_any_folder(cloned, tmp_path, change, error, message):
    settings = dict(init_from=str(cloned.model_path), env_id=ENV, n_robots=(4,), hyperparams=TINY_PPO)
    config = PerRobotFinetuneConfig(**{**settings, **change})
    with pytest.raises(error, match=message):
        finetune_per_robot(config, tmp_path / "run", **QUIET)
    assert not (tmp_path / "run").exists()


def test_a_centralised_model_is_refused(centralised_model, tmp_path):
    config = PerRobotFinetuneConfig(str(centralised_model), ENV, n_robots=(4,))
    with pytest.raises(ParameterError, match="init_from: .*centralised model"):
        finetune_per_robot(config, tmp_path / "run", **QUIET)
    assert not (tmp_path / "run").exists()


def test_a_per_robot_model_of_another_robot_model_is_refused(cloned, tmp_path):
    """A file whose layout says paddle while its env kwargs say disk: the PettingZoo env built is the disk one."""
    model, info = load_model(cloned.model_path)
    path = tmp_path / "paddle.zip"
    save_sb3_model(model, path, ModelInfo(info.algo, ENV, DISK, STEPS, {**info.per_robot, "robot_model": "paddle"}))
    config = PerRobotFinetuneConfig(str(path), ENV, n_robots=(4,))
    with pytest.raises(ValueError, match="paddle robot model"):
        finetune_per_robot(config, tmp_path / "run", **QUIET)
    assert not (tmp_path / "run").exists()


def test_a_per_robot_model_runs_only_on_its_own_robot_model(cloned):
    """A centralised model may run on the other robot model; a per-robot one's local observation is its own's."""
    with pytest.raises(ValueError, match="trained with robot_model='disk'; robot_model='paddle'"):
        model_env_kwargs(cloned.model_path, ENV, {"robot_model": "paddle"})


def test_critic_warmup_none_is_a_tenth_of_the_run(cloned, tmp_path):
    """What `dpr finetune-decentralised` passes without --critic-warmup: a tenth of the swarm steps, at most 10000;
    the library's own default is none."""
    assert PerRobotFinetuneConfig(str(cloned.model_path), ENV).critic_warmup == 0
    result = finetune(cloned, tmp_path / "run", timesteps=40, critic_warmup=None)
    assert yaml.safe_load(result.config_path.read_text())["critic_warmup"] == 4


# -- the command ----------------------------------------------------------------------------------------------------
def test_cli_finetune_decentralised_then_evaluate_at_another_size(cloned, centralised_model, tmp_path, capsys):
    out = tmp_path / "cli"
    argv = ["finetune-decentralised", "--from", str(cloned.model_path), "--env", ENV, "--n-robots", "4", "5"]
    argv += ["--timesteps", "32", "--critic-warmup", "0", "--eval-episodes", "1"]
    argv += [arg for name, value in TINY_PPO.items() for arg in ("--hyperparam", f"{name}={value}")]
    assert run([*argv, "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert f"dpr evaluate --policy {out / 'model.zip'} --env {ENV} --n-robots 4" in printed
    assert read_model_info(out / "model.zip").per_robot["trained_n_robots"] == [4, 5]
    evaluate = ["evaluate", "--policy", str(out / "model.zip"), "--env", ENV, "--n-robots", "9"]
    assert run([*evaluate, "--seeds", "100", "--steps", "8", "--workers", "1"]) == 0
    capsys.readouterr()
    before = tree_hash(tmp_path)
    assert run([*argv, "--out", str(out)]) == 2  # never overwrites a run
    assert "--out" in capsys.readouterr().err
    bad = [*argv[:2], str(centralised_model), *argv[3:], "--out", str(tmp_path / "other")]
    assert run(bad) == 2
    assert "--from: " in capsys.readouterr().err
    assert run([*argv, "--env-kwarg", "clock_period=8", "--out", str(tmp_path / "other")]) == 2
    assert "--env-kwarg: must not set" in capsys.readouterr().err
    assert tree_hash(tmp_path) == before


def test_cli_finetune_points_a_per_robot_model_to_finetune_decentralised(cloned, tmp_path, capsys):
    argv = ["finetune", "--from", str(cloned.model_path), "--env", ENV, "--out", str(tmp_path / "ft")]
    assert run(argv) == 2
    assert "dpr finetune-decentralised" in capsys.readouterr().err and not (tmp_path / "ft").exists()


# -- resume ------------------------------------------------------------------------------------------------------
def _same_weights(path, other) -> bool:
    """Whether two model files hold the same policy weights and optimizer state, value for value (the bytes of
    equal optimizer states may differ: torch pickles the tensors a loaded state made in another order)."""
    import io
    import zipfile

    def flat(value, prefix=""):
        if isinstance(value, dict):
            return {k: v for key, item in value.items() for k, v in flat(item, f"{prefix}/{key}").items()}
        if isinstance(value, (list, tuple)):
            return {k: v for i, item in enumerate(value) for k, v in flat(item, f"{prefix}/{i}").items()}
        return {prefix: value}

    def state(file, name):
        with zipfile.ZipFile(file) as archive:
            return flat(torch.load(io.BytesIO(archive.read(name)), weights_only=True))

    for name in ("policy.pth", "policy.optimizer.pth"):
        ours, theirs = state(path, name), state(other, name)
        if ours.keys() != theirs.keys():
            return False
        for key, value in ours.items():
            same = torch.equal(value, theirs[key]) if isinstance(value, torch.Tensor) else value == theirs[key]
            if not same:
                return False
    return True


def test_a_stopped_run_resumes_to_the_uninterrupted_model(cloned, tmp_path, capsys):
    """Two swarm sizes, a warm-up, evaluations and checkpoints: stopped after its third snapshot and resumed, the
    run ends with the weights, validation results and step count of a run never stopped; `--resume` of other
    settings, or of a folder with no snapshot, is refused naming --out."""
    from helpers import stopped_after_snapshots

    from dpr.rl import resume as resume_state
    from dpr.rl.finetune_per_robot import check_resumable

    settings = dict(n_robots=(4, 5), timesteps=160, critic_warmup=32, eval_episodes=1)
    whole = finetune(cloned, tmp_path / "whole", **settings)
    assert not resume_state.snapshot_path(whole.run_dir).exists()  # a finished run drops its snapshot
    with stopped_after_snapshots(3):
        finetune(cloned, tmp_path / "stopped", **settings)
    stopped = tmp_path / "stopped"
    assert not (stopped / "model.zip").exists()
    reached = resume_state.load_snapshot(stopped).reached
    assert 0 < reached < yaml.safe_load(whole.config_path.read_text())["sb3_timesteps"]

    config = PerRobotFinetuneConfig(str(cloned.model_path), ENV, hyperparams=TINY_PPO, **settings)
    lines = []
    resumed = finetune_per_robot(config, stopped, show_progress=False, resume=True, log=lines.append)
    at, after_warmup = map(
        int, re.search(r"resumed at swarm step (\d+) \((\d+) of 160 after the warm-up\)", lines[0]).groups()
    )
    assert (
        at == reached // sum(settings["n_robots"]) * len(settings["n_robots"])
        and at - after_warmup == settings["critic_warmup"]
    )
    assert _same_weights(resumed.model_path, whole.model_path)
    assert _same_weights(resumed.best_model_path, whole.best_model_path)
    evaluations = [json.loads((run / "eval" / "evaluations.json").read_text()) for run in (whole.run_dir, stopped)]
    assert evaluations[0] == evaluations[1]
    assert sorted(p.name for p in (stopped / "checkpoints").iterdir()) == sorted(
        p.name for p in (whole.run_dir / "checkpoints").iterdir()
    )
    record = yaml.safe_load(resumed.config_path.read_text())
    assert len(record["resumed"]) == 1 and record["timesteps_done"] == whole_steps(whole)
    assert not resume_state.snapshot_path(stopped).exists()

    with pytest.raises(ParameterError, match="holds no snapshot"):  # finished: nothing left to resume
        check_resumable(stopped, config)
    argv = ["finetune-decentralised", "--from", str(cloned.model_path), "--env", ENV, "--resume", "--n-robots", "4"]
    argv += ["5", "--timesteps", "160", "--critic-warmup", "32", "--eval-episodes", "1"]
    argv += [arg for name, value in TINY_PPO.items() for arg in ("--hyperparam", f"{name}={value}")]
    assert run(argv) == 2
    assert "--resume: name the stopped run's folder with --out" in capsys.readouterr().err
    with stopped_after_snapshots(1):
        finetune(cloned, tmp_path / "again", **settings)
    before = tree_hash(tmp_path / "again")
    assert run([*argv, "--out", str(tmp_path / "again"), "--seed", "7"]) == 2
    err = capsys.readouterr().err
    assert "--out: " in err and "differing: ['seed']" in err
    assert tree_hash(tmp_path / "again") == before
    assert run([*argv, "--out", str(tmp_path / "again")]) == 0
    assert _same_weights(tmp_path / "again" / "model.zip", whole.model_path)


def whole_steps(result) -> int:
    return yaml.safe_load(result.config_path.read_text())["timesteps_done"]
