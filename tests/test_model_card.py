"""The model card (models/card.yaml): checked whole before any work, and its models evaluated by the pipeline."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import yaml
from helpers import QUIET, TINY_PIPELINE, TINY_PPO, shrink_rollouts
from helpers import run_cli as run

from dpr.checks import ParameterError
from dpr.envs import ENV_IDS
from dpr.evaluation.model_card import load_lerobot_policies, load_model_card, load_per_robot_models
from dpr.pipeline.campaign import run_pipeline
from dpr.pipeline.config import PipelineConfig
from dpr.rl.train import TrainConfig, train

REPO_CARD = Path(__file__).resolve().parents[1] / "models" / "card.yaml"


def write_card(folder: Path, entries: list[dict], **sections: list[dict]) -> Path:
    """``folder``/card.yaml with ``entries`` as its models and ``sections`` (``per_robot_models=[...]``, ...)."""
    card = folder / "card.yaml"
    card.write_text(yaml.safe_dump({"format": 1, "models": entries, **sections}))
    return card


def entry(task: str, file: str, method: str = "bc-ppo") -> dict:
    return {"task": task, "method": method, "file": file, "made_by": "a test"}


@pytest.fixture
def tiny_rollouts(monkeypatch):
    shrink_rollouts(monkeypatch, TINY_PPO)


def tiny_model(task: str, folder: Path, robot_model: str = "paddle") -> Path:
    """A PPO model of ``task`` on the tiny pipeline's swarm, copied to ``folder``/<task>.zip."""
    config = TrainConfig(
        "ppo",
        ENV_IDS[task],
        n_robots=TINY_PIPELINE["n_robots"],
        timesteps=32,
        steps_per_episode=TINY_PIPELINE["steps"],
        env_kwargs={"obs_last_action": True},
        eval_episodes=1,
        robot_model=robot_model,
    )
    result = train(config, folder / f"run-{task}", **QUIET)
    return Path(shutil.copy(result.model_path, folder / f"{task}.zip"))


def test_the_repository_card_names_existing_models_of_every_task():
    models = load_model_card(REPO_CARD)
    assert {model.task for model in models} == set(ENV_IDS)
    assert all(model.path.is_file() and model.path.suffix == ".zip" for model in models)
    entries = yaml.safe_load(REPO_CARD.read_text())["models"]
    assert all(len(entry.get("sha256", "")) == 64 for entry in entries)  # each file pinned by its content
    per_robot = {(model.robot_model, model.method): model.path.name for model in load_per_robot_models(REPO_CARD)}
    assert per_robot[("paddle", "bc-ppo")] == "decentralised-bc-ppo.zip"
    assert per_robot[("disk", "bc-ppo")] == "decentralised-disk-bc-ppo.zip"
    [diffusion] = load_lerobot_policies(REPO_CARD)
    assert (diffusion.task, diffusion.policy) == ("navigation", "diffusion")


def test_a_card_whose_file_changed_or_names_another_tasks_id_is_refused(tmp_path):
    import hashlib

    model = tmp_path / "navigation-bc.zip"
    shutil.copy(REPO_CARD.parent / "navigation-bc.zip", model)
    digest = hashlib.sha256(model.read_bytes()).hexdigest()
    assert load_model_card(write_card(tmp_path, [{**entry("navigation", model.name), "sha256": digest}]))
    card = write_card(tmp_path, [{**entry("navigation", model.name), "sha256": "0" * 64}])
    with pytest.raises(ValueError, match="sha256 differs"):
        load_model_card(card)
    card = write_card(tmp_path, [{**entry("gate", model.name), "env_id": "dpr/Navigation-v0"}])
    with pytest.raises(ValueError, match=r"env_id must be one of \['dpr/Gate-v2', 'dpr/Gate-v0', 'dpr/Gate-v1'\]"):
        load_model_card(card)


@pytest.mark.parametrize(
    "content, message",
    [
        (None, "no model card at"),
        ("format: 1\nmodels: [", "is not YAML"),
        ("models: []\n", "format: 1"),
        ("format: 1\nmodels: []\n", "non-empty list"),
        ({"task": "navigation", "method": "bc-ppo", "file": "x.zip"}, "must have the keys"),
        ({**entry("swimming", "x.zip")}, "task must be one of"),
        ({**entry("navigation", "missing.zip")}, "names missing.zip, but there is no file"),
    ],
)
def test_a_bad_card_is_refused_naming_the_card_and_the_entry(tmp_path, content, message):
    card = tmp_path / "card.yaml"
    if isinstance(content, str):
        card.write_text(content)
    elif isinstance(content, dict):
        card = write_card(tmp_path, [content])
    with pytest.raises(ParameterError, match=message) as raised:
        load_model_card(card)
    assert raised.value.parameter == "shipped"
    if isinstance(content, dict):
        assert "models[0]" in str(raised.value)


def test_per_robot_models_of_the_card_are_checked_with_it(tmp_path):
    shutil.copy(REPO_CARD.parent / "navigation-bc.zip", tmp_path / "central.zip")
    shutil.copy(REPO_CARD.parent / "decentralised-disk-bc.zip", tmp_path / "disk.zip")
    central = entry("navigation", "central.zip", "bc")

    def card(*per_robot: dict) -> Path:
        return write_card(tmp_path, [central], per_robot_models=list(per_robot))

    disk = {"robot_model": "disk", "method": "bc", "file": "disk.zip", "made_by": "a test"}
    assert [(m.robot_model, m.path.name) for m in load_per_robot_models(card(disk))] == [("disk", "disk.zip")]
    assert [m.task for m in load_model_card(card(disk))] == ["navigation"]  # the pipeline's rows: models only
    for bad, message in [
        ({**disk, "robot_model": "paddle"}, "per-robot model of the disk robot model, not of paddle"),
        ({**disk, "robot_model": "wheel"}, "robot_model must be one of"),
        ({**disk, "file": "central.zip"}, "centralised model"),
        ({**disk, "sha256": "0" * 64}, "sha256 differs"),
        ({k: v for k, v in disk.items() if k != "made_by"}, "must have the keys"),
    ]:
        with pytest.raises(ParameterError, match=message) as raised:
            load_model_card(card(bad))
        assert "per_robot_models[0]" in str(raised.value) or "centralised" in str(raised.value)
    with pytest.raises(ParameterError, match=r"per_robot_models\[1\]: a second disk bc model"):
        load_model_card(card(disk, disk))
    (tmp_path / "card.yaml").write_text(yaml.safe_dump({"format": 1, "models": [central], "extra": []}))
    with pytest.raises(ParameterError, match="per_robot_models"):
        load_model_card(tmp_path / "card.yaml")


def test_lerobot_policies_of_the_card_are_checked_without_lerobot(tmp_path):
    """A LeRobot policy folder on the card: LeRobot's files of the named type, its weights at the card's sha256, at
    most 10 MB, trained on the entry's task; dpr checks all of it without importing LeRobot."""
    import hashlib

    shutil.copy(REPO_CARD.parent / "navigation-bc.zip", tmp_path / "central.zip")
    folder = tmp_path / "nav-diffusion"
    folder.mkdir()
    (folder / "config.json").write_text(json.dumps({"type": "diffusion"}))
    (folder / "model.safetensors").write_bytes(b"weights")
    (folder / "dpr_env.json").write_text(json.dumps({"env_id": "dpr/Navigation-v0", "env_kwargs": {}}))
    digest = hashlib.sha256(b"weights").hexdigest()
    good = {"task": "navigation", "policy": "diffusion", "folder": "nav-diffusion", "made_by": "a test"}
    good["sha256"] = digest

    def card(*policies: dict) -> Path:
        return write_card(tmp_path, [entry("navigation", "central.zip", "bc")], lerobot_policies=list(policies))

    [policy] = load_lerobot_policies(card(good))
    assert (policy.task, policy.policy, policy.path) == ("navigation", "diffusion", folder)
    assert [m.task for m in load_model_card(card(good))] == ["navigation"]  # the pipeline's rows: models only
    for bad, message in [
        ({**good, "policy": "act"}, "holds a LeRobot 'diffusion' policy, not 'act'"),
        ({**good, "task": "gate"}, "trained on dpr/Navigation-v0, not on a gate env"),
        ({**good, "folder": "central.zip"}, "must be a LeRobot policy folder"),
        ({**good, "sha256": "0" * 64}, "sha256 differs"),
        ({k: v for k, v in good.items() if k != "made_by"}, "must have the keys"),
    ]:
        with pytest.raises(ParameterError, match=message) as raised:
            load_model_card(card(bad))
        assert "lerobot_policies[0]" in str(raised.value)
    with pytest.raises(ParameterError, match=r"lerobot_policies\[1\]: a second navigation diffusion policy"):
        load_model_card(card(good, good))
    (folder / "model.safetensors").write_bytes(b"\0" * 10_500_000)
    with pytest.raises(ParameterError, match="over 10 MB"):
        load_model_card(card({k: v for k, v in good.items() if k != "sha256"}))


def test_a_card_naming_one_task_and_method_twice_is_refused(tmp_path):
    (tmp_path / "a.zip").write_bytes(b"")
    card = write_card(tmp_path, [entry("gate", "a.zip"), entry("gate", "a.zip")])
    with pytest.raises(ParameterError, match=r"models\[1\]: a second gate bc-ppo model"):
        load_model_card(card)


def test_dpr_pipeline_refuses_a_card_with_a_missing_model_before_any_work(tmp_path, capsys):
    card = write_card(tmp_path, [entry("navigation", "navigation-bc-ppo.zip")])
    out = tmp_path / "run"
    assert run(["pipeline", "--shipped", str(card), "--out", str(out)]) == 2
    error = capsys.readouterr().err
    assert "--shipped" in error and "navigation-bc-ppo.zip" in error
    assert not out.exists()


def test_a_shipped_model_of_another_swarm_size_is_refused_before_any_work(tmp_path, tiny_rollouts):
    card = write_card(tmp_path, [entry("gate", tiny_model("gate", tmp_path).name)])
    out = tmp_path / "run"
    with pytest.raises(ValueError, match="n_robots"):
        run_pipeline(PipelineConfig(**{**TINY_PIPELINE, "n_robots": 5}), out, shipped=load_model_card(card), **QUIET)
    assert not out.exists()


def test_the_pipeline_reports_shipped_models_beside_the_wave_on_its_test_seeds(tmp_path, tiny_rollouts):
    """A shipped model of the pipeline's task and one of another task: both are scored on the test seeds, on the
    wave's paddle model even when learned on the disk model, the other task gets its wave row, and the report shows
    them as `shipped <method>`."""
    models = tmp_path / "models"
    models.mkdir()
    navigation, gate = tiny_model("navigation", models), tiny_model("gate", models, robot_model="disk")
    card = write_card(models, [entry("navigation", navigation.name), entry("gate", gate.name)])
    config = PipelineConfig(**TINY_PIPELINE, scratch_algos=[], test_seeds=[300, 301])
    out = tmp_path / "run"
    report = run_pipeline(config, out, shipped=load_model_card(card), **QUIET)
    for stem in ("navigation", "gate"):
        (evaluation,) = (out / "eval" / "shipped").glob(f"{stem}-*.json")
        payload = json.loads(evaluation.read_text())
        assert payload["seeds"] == [300, 301] and payload["policy"].endswith(f"{stem}.zip")
        assert payload["env_kwargs"]["robot_model"] == "paddle"
    assert json.loads((out / "eval" / "shipped" / "wave-Gate-v2.json").read_text())["seeds"] == [300, 301]
    text = (report / "results.md").read_text()
    for row in ("| Navigation | shipped bc-ppo |", "| Gate | wave |", "| Gate | shipped bc-ppo |"):
        assert row in text


def test_a_shipped_model_replaced_since_the_last_run_is_evaluated_again_into_a_new_report(tmp_path, tiny_rollouts):
    """Run again after `models/` changed, the pipeline scores the new file (its evaluation named by the file's
    content) and writes the report into a new folder, keeping the old evaluation and report; run once more, it
    only skips."""
    import zipfile

    models = tmp_path / "models"
    models.mkdir()
    card = write_card(models, [entry("navigation", tiny_model("navigation", models).name)])
    config = PipelineConfig(**TINY_PIPELINE, finetune_algos=[], scratch_algos=[], test_seeds=[300])
    out = tmp_path / "run"
    first = run_pipeline(config, out, shipped=load_model_card(card), **QUIET)
    (old_evaluation,) = (out / "eval" / "shipped").iterdir()
    old_report = (first / "results.md").read_text()
    with zipfile.ZipFile(models / "navigation.zip", "a") as model:  # another file, the same policy
        model.comment = b"replaced"
    lines = []
    second = run_pipeline(config, out, shipped=load_model_card(card), show_progress=False, log=lines.append)
    assert second == out / "report-2" and (first / "results.md").read_text() == old_report
    assert old_evaluation.exists() and len(list((out / "eval" / "shipped").iterdir())) == 2
    assert any(f"{first} is kept" in line for line in lines)
    files = {path: path.stat().st_mtime_ns for path in out.rglob("*") if path.is_file()}
    assert run_pipeline(config, out, shipped=load_model_card(card), **QUIET) == second
    assert {path: path.stat().st_mtime_ns for path in out.rglob("*") if path.is_file()} == files
