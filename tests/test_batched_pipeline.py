"""`dpr pipeline --engine batched`: the tiny preset on the batched engine end to end (demonstrations, evaluations and
RL from scratch stepped there, cloning and fine-tuning on pymunk's disk model), the engine in every such stage's key,
and a pymunk run's keys unchanged."""

import json

import pytest
import yaml

from dpr.checks import ParameterError
from dpr.cli import main
from dpr.datasets.lerobot import LeRobotReader
from dpr.pipeline.campaign import task_stages
from dpr.pipeline.config import PipelineConfig, preset_config
from dpr.policies.model_file import read_model_info

TINY = ["--preset", "tiny", "--tasks", "navigation", "--train-seeds", "0"]


def settings_of(stages) -> list[dict]:
    every = [stages.teacher, *stages.candidates.values(), *stages.models.values(), *stages.evaluations.values()]
    every += [need for stage in every for need in stage.needs.values()]
    return [stage.settings for stage in every]


def test_the_engine_is_part_of_every_batched_stages_key_and_pymunk_keys_stay():
    pymunk = task_stages(preset_config("tiny", tasks=["navigation"]), "navigation")
    batched = task_stages(preset_config("tiny", tasks=["navigation"], engine="batched"), "navigation")
    assert not any("engine" in settings for settings in settings_of(pymunk))  # the keys stored runs were made with
    for name, stage in batched.models.items():  # a clone through its demonstrations' key
        assert stage.key != pymunk.models[name].key
        if stage.kind == "rl":
            assert stage.settings["engine"] == "batched" and stage.settings["robot_model"] == "disk"
    for name, stage in batched.evaluations.items():
        assert stage.settings["engine"] == "batched" and stage.key != pymunk.evaluations[name].key
    with pytest.raises(ParameterError, match="engine"):
        PipelineConfig(engine="jax")


def test_a_tiny_pipeline_runs_on_the_batched_engine_and_resumes(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["pipeline", *TINY, "--engine", "batched", "--out", str(out)]) == 0
    assert "| Navigation | ppo |" in (out / "report" / "results.md").read_text()
    assert yaml.safe_load((out / "pipeline.yaml").read_text())["config"]["engine"] == "batched"
    for model in (out / "models").iterdir():
        assert read_model_info(model).env_kwargs["robot_model"] == "disk"
    (dataset,) = (out / "stages" / "demonstrations").glob("*/dataset")
    assert LeRobotReader(dataset).info["dpr"]["engine"] == "batched"
    engines = sorted(
        yaml.safe_load(path.read_text())["config"]["engine"] for path in (out / "stages" / "rl").glob("*/config.yaml")
    )
    assert engines == ["batched", "pymunk"]  # from scratch on the batched engine, fine-tuning on pymunk
    wave = json.loads((out / "eval" / "test" / "navigation-wave.json").read_text())
    assert wave["env_kwargs"]["robot_model"] == "disk"
    capsys.readouterr()
    assert main(["pipeline", *TINY, "--engine", "batched", "--out", str(out)]) == 0  # stored: nothing to build
    assert ", 0 to build" in capsys.readouterr().err
