"""A task defined outside ``dpr`` (examples/pillar_task.py, the worked example of docs/add-a-task.md) is an env like
the built-in ones, and every command takes it through ``--env-package``: collect, replay, bc, evaluate and the
pipeline's smallest preset. The commands run in subprocesses, so that the task never joins this process's
registry (other tests count the registered tasks)."""

from __future__ import annotations

import importlib
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.envs.registration import registry
from gymnasium.utils.env_checker import check_env

from dpr.envs import ParticleSwarmEnv, register_task, tasks
from dpr.envs.tasks import ENV_PACKAGES_VARIABLE
from tests.test_start_layouts import robot_overlaps

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
ENV_ID = "pillar_task/Pillar-v0"
DPR = [sys.executable, "-m", "dpr.cli"]


@pytest.fixture
def pillar(monkeypatch):
    """The example module imported here, and the registries as they were afterwards."""
    saved = {name: dict(getattr(tasks, name)) for name in ("TASK_CLASSES", "ENV_IDS", "TASKS", "HYPERPARAMS_OF")}
    monkeypatch.syspath_prepend(str(EXAMPLES))
    sys.modules.pop("pillar_task", None)
    module = importlib.import_module("pillar_task")
    yield module
    sys.modules.pop("pillar_task", None)
    registry.pop(ENV_ID, None)
    for name, value in saved.items():
        getattr(tasks, name).clear()
        getattr(tasks, name).update(value)


def run(args: list[str], cwd: Path, env_package: str | None = "pillar_task") -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(EXAMPLES), str(ROOT)])}
    env.pop(ENV_PACKAGES_VARIABLE, None)
    argv = [*DPR, *(["--env-package", env_package] if env_package else []), *args]
    return subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=600)


def test_the_example_task_passes_gymnasiums_checks(pillar):
    env = gym.make(ENV_ID)
    check_env(env.unwrapped, skip_render_check=True)
    _, info = env.reset(seed=0)
    assert info[pillar.PILLAR_CONTACT_STEP] == -1
    assert tasks.TASKS[ENV_ID] == "pillar" and tasks.ENV_IDS["pillar"] == ENV_ID
    assert tasks.HYPERPARAMS_OF[ENV_ID] == "dpr/Navigation-v0"


@pytest.mark.parametrize(("robot_model", "n_robots"), [("paddle", 9), ("paddle", 49), ("disk", 100), ("disk", 1000)])
def test_the_pillar_stands_between_a_clear_start_and_the_goal(pillar, robot_model, n_robots):
    env = gym.make(ENV_ID, n_robots=n_robots, robot_model=robot_model).unwrapped
    for seed in (0, 1):
        env.reset(seed=seed)
        assert robot_overlaps(env.world) == 0
        (pillar_corners,) = env._walls(env.start)
        centre = pillar_corners.mean(axis=0)
        to_goal = env.goal - env.start
        along = (centre - env.start) @ to_goal / np.linalg.norm(to_goal) ** 2
        assert 0 < along < 1, "the pillar is not between the start and the goal"


def test_registering_again_is_harmless_and_a_taken_name_or_id_is_refused(pillar):
    register_task("pillar", pillar.PillarEnv, ENV_ID)  # the module imported twice
    with pytest.raises(ValueError, match="'pillar' is taken"):
        register_task("pillar", type("Other", (pillar.PillarEnv,), {}), "other/Pillar-v0")
    with pytest.raises(ValueError, match="registered already"):
        register_task("navigation2", type("Nav2", (ParticleSwarmEnv,), {"task": "navigation2"}), "dpr/Navigation-v0")
    with pytest.raises(TypeError, match="subclass of ParticleSwarmEnv"):
        register_task("cartpole", gym.Env, "other/Cart-v0")
    with pytest.raises(ValueError, match="lower case"):
        register_task("Pillar", pillar.PillarEnv, "other/Pillar-v0")
    with pytest.raises(ValueError, match=r"\.task is 'pillar'"):
        register_task("column", pillar.PillarEnv, "other/Column-v0")
    with pytest.raises(ValueError, match="hyperparams_from"):
        register_task("column", type("C", (ParticleSwarmEnv,), {"task": "column"}), "o/C-v0", hyperparams_from="x")
    assert "column" not in tasks.TASK_CLASSES and "other/Column-v0" not in registry


def test_every_command_takes_the_task_through_env_package(tmp_path):
    steps = ["--steps", "120"]
    collect = run(["collect", "--env", ENV_ID, "--policy", "wave", "--episodes", "2", *steps, "--out", "ds"], tmp_path)
    assert collect.returncode == 0, collect.stderr
    info = json.loads((tmp_path / "ds" / "meta" / "info.json").read_text())
    assert ENV_ID in json.dumps(info)
    replay = run(["replay", "ds"], tmp_path)
    assert replay.returncode == 0 and "2/2 episodes replay bit-identically" in replay.stdout + replay.stderr
    bc = run(["bc", "--dataset", "ds", "--env", ENV_ID, "--epochs", "1", "--out", "bc"], tmp_path)
    assert bc.returncode == 0, bc.stderr
    evaluate = run(["evaluate", "--policy", "bc/model.zip", "--env", ENV_ID, "--seeds", "7", *steps], tmp_path)
    assert evaluate.returncode == 0, evaluate.stderr
    assert "| pillar_task/Pillar-v0 | bc/model.zip | pillar_touched |" in evaluate.stdout

    unknown = run(["evaluate", "--policy", "wave", "--env", ENV_ID], tmp_path, env_package=None)
    assert unknown.returncode == 2 and "--env-package PKG" in unknown.stderr
    missing = run(["--env-package", "no_such_tasks", "evaluate", "--policy", "wave", "--env", ENV_ID], tmp_path)
    assert missing.returncode == 2 and "env package 'no_such_tasks' does not import" in missing.stderr


def test_the_smallest_pipeline_preset_runs_the_task(tmp_path):
    result = run(["pipeline", "--preset", "tiny", "--tasks", "pillar", "--workers", "2", "--out", "run"], tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    evaluations = sorted(path.name for path in (tmp_path / "run" / "eval" / "test").glob("*.json"))
    assert "pillar-bc-ppo-seed0.json" in evaluations and "pillar-wave.json" in evaluations
    episode = json.loads((tmp_path / "run" / "eval" / "test" / "pillar-wave.json").read_text())["episodes"][0]
    assert "pillar_contact_step" in episode
    assert "| Pillar | bc-ppo |" in (tmp_path / "run" / "report" / "results.md").read_text()


def test_the_how_to_shows_the_example_as_it_is():
    how_to = (ROOT / "docs" / "add-a-task.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", how_to, flags=re.S)
    assert (EXAMPLES / "pillar_task.py").read_text() in blocks


# -- a robot model of the user's own: examples/long_magnet_disk.py (docs/add-a-robot-model.md) -------------------
ROBOT_MODEL = "disk-long-magnets"


@pytest.fixture
def long_magnets(monkeypatch):
    """The example robot model imported here, and the registry as it was afterwards."""
    from dpr.sim import models

    saved_classes, saved_names = dict(models._SWARM_CLASSES), list(models.ROBOT_MODELS)
    monkeypatch.syspath_prepend(str(EXAMPLES))
    sys.modules.pop("long_magnet_disk", None)
    yield importlib.import_module("long_magnet_disk")
    sys.modules.pop("long_magnet_disk", None)
    models._SWARM_CLASSES.clear()
    models._SWARM_CLASSES.update(saved_classes)
    models.ROBOT_MODELS[:] = saved_names


def test_the_example_robot_model_runs_every_task_and_the_wave(long_magnets):
    from dpr.policies.wave import MODEL_DEFAULTS, WavePolicy
    from dpr.sim import register_robot_model

    assert MODEL_DEFAULTS[ROBOT_MODEL] == MODEL_DEFAULTS["disk"]  # the disk's wave, inherited
    register_robot_model(long_magnets.LongMagnetDiskSwarm)  # imported twice: nothing happens
    with pytest.raises(ValueError, match="'disk' is taken"):
        register_robot_model(type("Other", (long_magnets.LongMagnetDiskSwarm,), {"model": "disk"}))
    for env_id in ("dpr/Navigation-v0", "dpr/Gate-v1", "dpr/Unresponsive-v0", "dpr/Manipulation-v0"):
        env = gym.make(env_id, robot_model=ROBOT_MODEL, n_robots=9)
        check_env(env.unwrapped, skip_render_check=True)
        env.reset(seed=0)
        assert robot_overlaps(env.unwrapped.world) == 0
    magnets = {}
    for model in ("disk", ROBOT_MODEL):  # diagonal neighbours are tied too, once the swarm moves
        env = gym.make("dpr/Navigation-v0", robot_model=model)
        policy, (obs, _) = WavePolicy.from_env(env), env.reset(seed=0)
        policy.reset()
        for _ in range(100):
            obs, *_ = env.step(policy(obs))
        magnets[model] = len(env.unwrapped.world.swarm.magnet_segments())
    assert magnets[ROBOT_MODEL] > magnets["disk"]


def test_commands_take_the_robot_model_through_env_package(tmp_path):
    flags = ["--env", "dpr/Navigation-v0", "--robot-model", ROBOT_MODEL]

    def run_model(args):
        return run(args, tmp_path, env_package="long_magnet_disk")

    collect = run_model(["collect", *flags, "--policy", "wave", "--episodes", "2", "--steps", "40", "--out", "ds"])
    assert collect.returncode == 0, collect.stderr
    assert json.loads((tmp_path / "ds" / "meta" / "info.json").read_text())["robot_type"] == ROBOT_MODEL
    replay = run_model(["replay", "ds"])
    assert replay.returncode == 0, replay.stderr
    evaluate = run_model(["evaluate", "--policy", "wave", *flags, "--seeds", "3", "--steps", "40"])
    assert evaluate.returncode == 0 and "| dpr/Navigation-v0 | wave | projected_displacement |" in evaluate.stdout


def test_the_robot_model_how_to_shows_the_example_as_it_is():
    how_to = (ROOT / "docs" / "add-a-robot-model.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", how_to, flags=re.S)
    assert (EXAMPLES / "long_magnet_disk.py").read_text() in blocks


def test_an_env_package_that_raises_is_one_clean_error_and_help_imports_none(tmp_path):
    """A package whose import raises stops the command with exit 2, naming the option (or variable), the package
    and what it raised, without a traceback; --help never imports a package (importing one runs its code)."""
    (tmp_path / "raising_tasks.py").write_text("raise RuntimeError('boom at import')\n")
    (tmp_path / "marking_tasks.py").write_text(f"open({str(tmp_path / 'imported')!r}, 'w').close()\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(ROOT)])}
    env.pop(ENV_PACKAGES_VARIABLE, None)
    evaluate = ["evaluate", "--policy", "wave", "--env", "dpr/Navigation-v0", "--seeds", "0", "--steps", "10"]

    def dpr(argv, **extra):
        return subprocess.run([*DPR, *argv], cwd=tmp_path, env={**env, **extra}, capture_output=True, text=True)

    for result, name in [
        (dpr(["--env-package", "raising_tasks", *evaluate]), "--env-package"),
        (dpr(evaluate, **{ENV_PACKAGES_VARIABLE: "raising_tasks"}), ENV_PACKAGES_VARIABLE),
    ]:
        assert result.returncode == 2, result.stderr
        assert (
            f"{name}: env package 'raising_tasks' does not import: its code raised RuntimeError: boom at import"
        ) in result.stderr
        assert "Traceback" not in result.stderr
    for argv in (["--env-package", "marking_tasks", "--help"], ["--env-package", "marking_tasks", "evaluate", "-h"]):
        assert dpr(argv).returncode == 0
        assert not (tmp_path / "imported").exists(), argv
    assert "runs with your rights" in (ROOT / "docs" / "add-a-task.md").read_text()
