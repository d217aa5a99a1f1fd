"""LeRobot's recipe tools on dpr data: ``tools/lerobot_recipe.py`` trains with ``lerobot-train`` (and resumes), and
a trained policy is scored in both evaluations, ``tools/lerobot_policies.py evaluate`` (dpr's metrics) and LeRobot's
own ``lerobot-eval`` through the ``lerobot_env_dpr`` plugin; bad input is refused before any work.

LeRobot is not a dependency of dpr: these run only where ``lerobot`` is importable (``make lerobot-env``, then
``.venv-lerobot/bin/python -m pytest tests/test_lerobot_recipe.py``) and are skipped everywhere else.
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest

if importlib.util.find_spec("lerobot") is None:
    pytest.skip("lerobot is not installed: `make lerobot-env` builds its side environment", allow_module_level=True)

from test_lerobot_compat import load_tool  # noqa: E402

TOOLS = Path(__file__).resolve().parents[1] / "tools"
# a Diffusion Policy a CPU trains a few steps of in seconds, on 4 disk robots
TINY_DIFFUSION = {"type": "diffusion", "device": "cpu", "push_to_hub": False, "crop_shape": None,
                  "down_dims": [16, 32], "horizon": 8, "n_action_steps": 4, "diffusion_step_embed_dim": 16,
                  "noise_scheduler_type": "DDIM", "num_inference_steps": 2,
                  "normalization_mapping": {"VISUAL": "MEAN_STD", "STATE": "MIN_MAX", "ENV": "MIN_MAX",
                                            "ACTION": "MIN_MAX"}}  # fmt: skip
LEROBOT_EVAL_ENV = ["--env.type=dpr", "--env.discover_packages_path=lerobot_env_dpr", "--env.n_robots=4",
                    "--env.robot_model=disk", "--env.action_repeat=2", "--env.obs_last_action=false",
                    "--env.episode_physics_steps=40"]  # fmt: skip


@pytest.fixture(scope="module")
def tools(tmp_path_factory: pytest.TempPathFactory) -> tuple[ModuleType, ModuleType, ModuleType]:
    """tools/check_lerobot_load.py, lerobot_policies.py and lerobot_recipe.py as modules, LeRobot offline."""
    check = load_tool(TOOLS / "check_lerobot_load.py")
    check.prepare_environment(tmp_path_factory.mktemp("hf-cache"))
    check.make_torchvision_importable()
    return check, load_tool(TOOLS / "lerobot_policies.py"), load_tool(TOOLS / "lerobot_recipe.py")


@pytest.fixture
def tiny_recipe(tools, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> dict:
    """A recipe folder holding one recipe, "tiny": 2 steps of a small Diffusion Policy on Navigation, 4 robots."""
    _, _, recipe = tools
    folder = tmp_path / "recipes"
    folder.mkdir()
    config = {"policy": TINY_DIFFUSION, "steps": 2, "batch_size": 4, "num_workers": 0, "eval_freq": 0,
              "log_freq": 1, "save_freq": 2, "wandb": {"enable": False}}  # fmt: skip
    (folder / "tiny.json").write_text(json.dumps(config))
    version = importlib.metadata.version("lerobot")
    row = {"config": "tiny.json", "env_id": "dpr/Navigation-v0", "n_robots": 4, "lerobot_versions": [version],
           "cpu_hours": 0.01, "validation_seeds": "600-601"}  # fmt: skip
    (folder / "recipes.json").write_text(json.dumps({"tiny": row}))
    monkeypatch.setattr(recipe, "RECIPES", folder)
    return recipe.load_recipe("tiny")


def _lerobot_eval(policy: Path, seed: int, out: Path, *extra: str) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "lerobot.scripts.lerobot_eval", f"--policy.path={policy}", *LEROBOT_EVAL_ENV,
               "--eval.n_episodes=1", "--eval.batch_size=1", f"--seed={seed}", f"--output_dir={out}",
               *extra]  # fmt: skip
    path = os.pathsep.join([str(TOOLS.parent), str(TOOLS / "lerobot_plugin"), os.environ.get("PYTHONPATH", "")])
    env = {**os.environ, "PYTHONPATH": path, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"}
    return subprocess.run(command, env=env, capture_output=True, text=True)


def test_a_recipe_trains_resumes_and_both_evaluations_agree(tools, tiny_recipe: dict, tmp_path: Path) -> None:
    """lerobot-train runs the recipe, and run again with more steps it resumes from its checkpoint; dpr's
    evaluation and lerobot-eval then score the policy's episode on one seed alike (sum_reward is the episode's
    projected displacement; the seeded reset draws Diffusion's noise alike)."""
    check, policies, recipe = tools
    dataset = check.record(tmp_path / "ds", pixels=False, episodes=2, steps=30, action_repeat=2)
    run = tmp_path / "run"
    assert recipe.train(tiny_recipe, dataset, run, seed=0) == 0 and recipe.trained_steps(run) == 2
    assert recipe.train(tiny_recipe, dataset, run, seed=0) == 0  # done: nothing to run
    assert recipe.train(tiny_recipe, dataset, run, seed=0, steps=3) == 0 and recipe.trained_steps(run) == 3
    sessions = json.loads((run / recipe.RECORD).read_text())["sessions"]
    assert [s["until_step"] for s in sessions] == [2, 3] and "--resume=true" in sessions[1]["command"]
    policies.evaluate(run, [5], 40, tmp_path / "dpr.json")
    done = _lerobot_eval(policies.policy_folder(run), 5, tmp_path / "lerobot-eval")
    assert done.returncode == 0, done.stderr[-3000:]
    (theirs, ours), *_ = recipe.agreement(tmp_path / "lerobot-eval" / "eval_info.json", tmp_path / "dpr.json").values()
    assert theirs == pytest.approx(ours, abs=recipe.AGREEMENT)


def test_checkpoints_average_into_a_policy_that_scores(tools, tiny_recipe: dict, tmp_path: Path) -> None:
    """A recipe that names ``average_steps`` leaves in its finished run the mean of those checkpoints' weights, a
    policy folder that dpr's evaluation scores; ``average`` refuses an existing --out, a missing checkpoint and a
    single step, and writes nothing then."""
    import torch
    from safetensors.torch import load_file

    check, policies, recipe = tools
    dataset = check.record(tmp_path / "ds", pixels=False, episodes=2, steps=10, action_repeat=2)
    run = tmp_path / "run"
    averaging = {**tiny_recipe, "average_steps": [4, 2]}
    assert recipe.train(averaging, dataset, run, seed=0, steps=2) == 0
    assert not (run / recipe.AVERAGED_FOLDER).exists()  # a run short of the averaged checkpoints has no average
    assert recipe.train(averaging, dataset, run, seed=0, steps=4) == 0  # checkpoints at steps 2 and 4
    out = run / recipe.AVERAGED_FOLDER
    first, last = (
        load_file(run / "checkpoints" / f"00000{s}" / "pretrained_model" / "model.safetensors") for s in (2, 4)
    )
    mean = load_file(out / "model.safetensors")
    changed = [
        name for name, tensor in last.items() if tensor.is_floating_point() and not torch.equal(tensor, first[name])
    ]
    assert changed and all(torch.allclose(mean[n], (first[n] + last[n]) / 2, atol=1e-7) for n in changed)
    assert json.loads((out / recipe.AVERAGED_FILE).read_text())["steps"] == [2, 4]
    policies.evaluate(out, [5], 40, tmp_path / "dpr.json")
    assert len(json.loads((tmp_path / "dpr.json").read_text())["episodes"]) == 1
    with pytest.raises(ValueError, match="exists"):
        recipe.average(run, [2, 4], out)
    with pytest.raises(ValueError, match="no checkpoint weights at .*000006"):
        recipe.average(run, [2, 6], tmp_path / "other")
    with pytest.raises(ValueError, match="at least two"):
        recipe.average(run, [4, 4], tmp_path / "other")
    assert not (tmp_path / "other").exists() and not (tmp_path / "other.partial").exists()


def test_bad_input_is_refused_before_any_work(tools, tiny_recipe: dict, tmp_path: Path) -> None:
    """A dataset of another env or swarm size than the recipe's, a LeRobot version it was not checked with, and a
    policy whose features do not fit the env (in both evaluations): errors that name what differs."""
    check, policies, recipe = tools
    dataset = check.record(tmp_path / "ds", pixels=False, episodes=2, steps=10, action_repeat=2)
    with pytest.raises(ValueError, match="dpr/Navigation-v0 with 4 robots; recipe tiny is for dpr/Gate-v2"):
        recipe.train({**tiny_recipe, "env_id": "dpr/Gate-v2"}, dataset, tmp_path / "run", seed=0)
    with pytest.raises(ValueError, match="with 4 robots; recipe tiny is for dpr/Navigation-v0 with 9"):
        recipe.train({**tiny_recipe, "n_robots": 9}, dataset, tmp_path / "run", seed=0)
    assert not (tmp_path / "run").exists()
    with pytest.raises(ValueError, match="checked with LeRobot 0.0.1, and this is LeRobot"):
        recipe.check_lerobot_version({**tiny_recipe, "lerobot_versions": ["0.0.1"]})
    assert recipe.check_lerobot_version({**tiny_recipe, "lerobot_versions": ["0.0.1"]}, allow_unchecked=True)
    run = tmp_path / "run"
    assert recipe.train(tiny_recipe, dataset, run, seed=0) == 0
    with pytest.raises(ValueError, match=r"does not fit the env.*action: policy \[4\], env \[5\]"):
        policies.evaluate(run, [5], 40, tmp_path / "dpr.json", env_overrides={"n_robots": 5})
    assert not (tmp_path / "dpr.json").exists()
    refused = _lerobot_eval(policies.policy_folder(run), 5, tmp_path / "lerobot-eval", "--env.n_robots=5")
    assert refused.returncode != 0 and "does not fit --env" in refused.stderr
    assert "observation.state: policy [" in refused.stderr


def test_actions_decode_to_the_env_action(tools) -> None:
    """0/1 values above one half; phases within half a decision of the most advanced (the recorded action where
    that one is 1, and some robot always expands)."""
    sys.path.insert(0, str(TOOLS / "lerobot_plugin"))
    from lerobot_env_dpr import decode_actions

    assert decode_actions([0.9, 0.2, 0.6]).tolist() == [1, 0, 1]
    assert decode_actions([1.0, 0.0, -2.0, 1.0], "phase").tolist() == [1, 0, 0, 1]
    assert decode_actions([0.3, -0.4, 0.1, -3.0], "phase").tolist() == [1, 0, 1, 0]  # none above 1/2: the leaders
    with pytest.raises(ValueError, match="action kind"):
        decode_actions([0.0], "angle")
