"""ACT's recipe trains on phases (tools/lerobot_recipe.py): 1 minus the decisions until each robot next expands,
from which the env's 0/1 action is recovered exactly by thresholding at one half. No LeRobot needed."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dpr.datasets.collect import CollectSpec, collect
from dpr.datasets.lerobot import LeRobotReader


@pytest.fixture(scope="module")
def recipe():
    import importlib.util
    import sys
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "tools" / "lerobot_recipe.py"
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_phases_count_the_decisions_to_the_next_expansion_and_threshold_back(recipe) -> None:
    expand = np.array([[1, 0], [0, 0], [0, 1], [1, 0], [0, 0], [0, 0]], dtype=np.float32)
    phase = recipe.phases(expand, cap=2)
    assert phase[:, 0].tolist() == [1, -1, 0, 1, -1, -1]  # 0, 2, 1, 0, then capped at 2 (none ahead)
    assert phase[:, 1].tolist() == [-1, 0, 1, -1, -1, -1]
    rng = np.random.default_rng(0)
    random = (rng.random((200, 9)) < 0.25).astype(np.float32)
    assert np.array_equal(recipe.phases(random, cap=4) > 0.5, random > 0.5)


def test_a_phase_dataset_is_a_dpr_dataset_of_the_same_episodes(recipe, tmp_path) -> None:
    source = tmp_path / "ds"
    collect(source, CollectSpec("dpr/Navigation-v0", n_robots=4, robot_model="disk", steps=12), episodes=2)
    out = recipe.phase_dataset(source, tmp_path / "phase")
    before, after = LeRobotReader(source), LeRobotReader(out)
    assert [e["seed"] for e in after.episodes] == [e["seed"] for e in before.episodes]
    for index in range(2):
        old, new = before.episode(index), after.episode(index)
        assert np.array_equal(new["action"] > 0.5, old["action"] > 0.5)
        assert np.array_equal(new["observation.state"], old["observation.state"])
    names = json.loads((out / "meta" / "info.json").read_text())["features"]["action"]["names"]
    assert names[0] == "robot0.phase"
    with pytest.raises(ValueError, match="exists"):
        recipe.phase_dataset(source, out)


def test_agreement_pairs_the_seeds_lerobot_eval_ran(recipe, tmp_path) -> None:
    """`agree --seed S` pairs lerobot-eval's episodes with seeds S, S+1, ... of a dpr file that holds more; without
    it the file must hold exactly those seeds; a missing seed is named."""
    eval_info = tmp_path / "eval_info.json"
    eval_info.write_text(json.dumps({"per_task": [{"metrics": {"sum_rewards": [1.5, 2.5]}}]}))
    dpr_file = tmp_path / "dpr.json"
    episodes = [{"seed": seed, "projected_displacement": seed / 10} for seed in range(320, 325)]
    dpr_file.write_text(json.dumps({"episodes": episodes}))
    assert recipe.agreement(eval_info, dpr_file, 321) == {321: (1.5, 32.1), 322: (2.5, 32.2)}
    with pytest.raises(ValueError, match="give --seed"):
        recipe.agreement(eval_info, dpr_file)
    with pytest.raises(ValueError, match=r"seeds \[325\]"):
        recipe.agreement(eval_info, dpr_file, 324)


def test_every_recipe_row_names_a_config_lerobot_train_can_read(recipe) -> None:
    """Each row of recipes.json: its config file is JSON of a policy LeRobot has, for a dpr env and swarm size, on
    the kind of actions the row says (a phase recipe trains on a phase dataset), with validation seeds; the
    checkpoints it averages into its policy are ones its run saves."""
    import gymnasium

    import dpr.envs  # noqa: F401  (registers the ids)
    from dpr.cli.common import parse_seeds

    rows = json.loads((recipe.RECIPES / "recipes.json").read_text())
    assert rows
    for name in rows:
        row = recipe.load_recipe(name)
        config = json.loads(row["config"].read_text())
        assert config["policy"]["type"] in {"act", "diffusion"}, name
        assert row["env_id"] in gymnasium.registry and row["n_robots"] > 0, name
        assert row["actions"] in {"expand", "phase"}, name
        assert config["dataset"]["root"].endswith("-phase") == (row["actions"] == "phase"), name
        assert parse_seeds(row["validation_seeds"]) and row["cpu_hours"] <= 3.0, name
        averaged = row.get("average_steps", [])  # checkpoints the run saves, at least two of them
        assert not averaged or len(set(averaged)) >= 2, name
        assert all(0 < step <= config["steps"] and step % config["save_freq"] == 0 for step in averaged), name


def test_a_stopped_training_session_is_waited_for_so_that_it_is_still_recorded(recipe) -> None:
    """SIGTERM to `train` goes on to lerobot-train, and `train` waits for it (then writes the session's CPU time)
    instead of dying first; its own handler is back afterwards."""
    import os
    import signal
    import sys
    import threading
    import time

    before = signal.getsignal(signal.SIGTERM)
    threading.Timer(0.5, os.kill, (os.getpid(), signal.SIGTERM)).start()
    started = time.monotonic()
    status = recipe.run_to_its_end([sys.executable, "-c", "import time; time.sleep(30)"])
    assert status == -signal.SIGTERM and time.monotonic() - started < 10
    assert signal.getsignal(signal.SIGTERM) is before
