"""The whole pipeline (`dpr pipeline`: demonstrations -> BC -> fine-tuning beside RL from scratch -> evaluation ->
report, resumable; choices on validation seeds, canonical models)."""

import dataclasses
import json

import gymnasium as gym
import numpy as np
import pytest
import yaml
from helpers import (
    PIPELINE,
    QUIET,
    THREE_SEEDS,
    assert_same_policy,
    copy_without_run,
    run_tiny,
    stopped_after_snapshots,
    trained_runs,
)

from dpr.checks import ParameterError
from dpr.envs import ENV_IDS
from dpr.policies.sb3 import load_model, read_model_info
from dpr.rl.pipeline import run_pipeline
from dpr.rl.pipeline_config import PipelineConfig, saved_settings


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
        ({"teacher_holds": []}, "teacher_holds: expected a list of different holds"),
        ({"teacher_holds": [7, 7]}, "teacher_holds: expected a list of different holds"),
        ({"teacher_holds": [0]}, "teacher_holds: must be >= 1"),
        ({"teacher_holds": [21]}, "teacher_holds: must be <= 20"),
        ({"teacher_holds": [7, 10]}, "validation_seeds: several teacher_holds or teacher_bin_widths need"),
        ({"teacher_bin_widths": [50.0, 60.0]}, "validation_seeds: several teacher_holds or teacher_bin_widths need"),
        ({"teacher_bin_widths": []}, "teacher_bin_widths: expected a list of different widths > 0"),
        ({"teacher_bin_widths": [50, 50.0]}, "teacher_bin_widths: expected a list of different widths > 0"),
        ({"teacher_bin_widths": [0.0]}, "teacher_bin_widths: must be > 0"),
        ({"teacher_bin_widths": [float("inf")]}, "teacher_bin_widths: must be finite"),
        ({"teacher_bin_widths": ["50"]}, "teacher_bin_widths: expected a number"),
        ({"teacher_seeds": [299, 300]}, r"teacher_seeds: \[300\] are test seeds too"),
        ({"teacher_seeds": [1000]}, r"teacher_seeds: \[1000\] are demonstration seeds"),
        ({"teacher_seeds": [3, 3]}, "teacher_seeds: each seed must appear once"),
        ({"teacher_holds": [7, 10], "validation_seeds": [200]}, r"action_repeat: must divide every teacher hold"),
        ({"action_repeat": 3}, r"action_repeat: must divide every teacher hold \[10\]"),
        ({"action_repeat": -1}, "action_repeat: must be >= 0"),
        ({"scratch_physics_discount": "yes"}, "scratch_physics_discount: expected true or false"),
        ({"train_seeds": [300], "test_seeds": [300, 301]}, r"train_seeds: \[300\] are test seeds too"),
        ({"train_seeds": [0, 200], "validation_seeds": [200]}, r"train_seeds: \[200\] are validation seeds too"),
        ({"env_ids": {"gate": "dpr/Navigation-v0"}, "tasks": ["gate"]}, "env_ids: expected registered ids of"),
        ({"env_ids": {"gate": "dpr/Gate-v0"}}, r"env_ids: \['dpr/Gate-v0'\] belong to tasks this run does not run"),
    ],
)
def test_pipeline_config_refuses_bad_settings(kwargs, message):
    with pytest.raises(ValueError, match=message):
        PipelineConfig(**kwargs)


def test_pipeline_shapes_only_manipulation_rewards():
    config = PipelineConfig(tasks=list(ENV_IDS), action_repeat=1)
    assert config.rl_env_kwargs("manipulation", 10) == {"obs_last_action": True, "approach_reward": 1.0}
    for task in ("navigation", "gate", "unresponsive"):
        assert config.rl_env_kwargs(task, 10) == {"obs_last_action": True}
    unshaped = PipelineConfig(approach_reward=0, action_repeat=1)
    assert unshaped.rl_env_kwargs("manipulation", 10) == {"obs_last_action": True}
    for task in ENV_IDS:  # every task's env takes them
        gym.make(ENV_IDS[task], **config.rl_env_kwargs(task, 10)).close()


METHODS = ["wave", "bc", "bc-ppo", "ppo"]


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory):
    """One tiny pipeline run (PipelineConfig has no hyperparameter overrides: run_tiny shrinks the yaml's 1024-step
    PPO rollouts to 32 steps, so that a few dozen steps of RL are a few updates)."""
    out = tmp_path_factory.mktemp("pipeline") / "run"
    report, _ = run_tiny(PIPELINE, out)
    return out, report


def test_pipeline_trains_manipulation_with_the_shaping(tmp_path):
    """RL on Manipulation, fine-tuning and from scratch, gets the approach shaping; the clone and the
    evaluations do not need it (the metric follows the ball either way)."""
    settings = {**PIPELINE, "tasks": ["manipulation"], "anchor": False, "approach_reward": 0.5}
    run_tiny(settings, tmp_path / "run")
    for method in ("bc-ppo", "ppo"):
        info = read_model_info(tmp_path / "run" / "models" / f"manipulation-{method}.zip")
        assert info.env_kwargs["approach_reward"] == 0.5, method
    assert "approach_reward" not in read_model_info(tmp_path / "run" / "models" / "manipulation-bc.zip").env_kwargs


def test_pipeline_gives_every_learner_the_swarm_actor(tmp_path):
    """--actor swarm: the clone, its fine-tuning and the run from scratch all have the shared per-robot actor, and
    the choice is one of the settings a resume must match."""
    from dpr.policies.swarm_policy import SwarmActorCriticPolicy

    settings = {**PIPELINE, "anchor": False, "actor": "swarm"}
    out = tmp_path / "run"
    run_tiny(settings, out)
    for method in METHODS[1:]:
        model, _ = load_model(out / "models" / f"navigation-{method}.zip")
        assert isinstance(model.policy, SwarmActorCriticPolicy), method
    assert yaml.safe_load((out / "pipeline.yaml").read_text())["config"]["actor"] == "swarm"
    with pytest.raises(ParameterError, match="actor: 'swarm' there, 'mlp' here"):
        run_tiny({**settings, "actor": "mlp"}, out)
    bare = tmp_path / "bare"  # a folder holding only the settings: the refusal adds nothing to it
    bare.mkdir()
    (bare / "pipeline.yaml").write_bytes((out / "pipeline.yaml").read_bytes())
    with pytest.raises(ParameterError, match="actor"):
        run_tiny({**settings, "actor": "mlp"}, bare)
    assert [path.name for path in bare.iterdir()] == ["pipeline.yaml"]
    with pytest.raises(ParameterError, match="actor: expected one of"):
        PipelineConfig(actor="transformer")
    with pytest.raises(ParameterError, match="DQN from scratch has none"):
        PipelineConfig(actor="swarm", scratch_algos=["ppo", "dqn"])


@pytest.mark.parametrize("scratch_physics_discount", [False, True])
def test_pipeline_learners_decide_every_action_repeat_steps(tmp_path, scratch_physics_discount):
    """With action_repeat=10 the demonstrations, the clone and RL all decide every 10 physics steps; budgets and
    evaluations count physics steps, so the wave (every step) and the learners are scored over the same time.
    Fine-tuning discounts 0.99 per physics step (0.99^10 per decision); the runs from scratch do too with
    scratch_physics_discount, and keep the yaml's 0.99 per decision without it."""
    from dpr.datasets.lerobot import LeRobotReader

    settings = {**PIPELINE, "anchor": False, "action_repeat": 10, "steps": 60, "critic_warmup": 320}
    settings["scratch_physics_discount"] = scratch_physics_discount
    out = tmp_path / "run"
    run_tiny(settings, out)
    gammas = {}
    for method in METHODS[2:]:
        model, _ = load_model(out / "models" / f"navigation-{method}.zip")
        gammas[method] = model.gamma
    assert gammas == {"bc-ppo": 0.904, "ppo": 0.904 if scratch_physics_discount else 0.99}
    saved = yaml.safe_load((out / "pipeline.yaml").read_text())["config"]
    assert saved["scratch_physics_discount"] is scratch_physics_discount
    assert LeRobotReader(out / "datasets" / "navigation").info["total_frames"] == 2 * 6
    for method in METHODS[1:]:
        assert read_model_info(out / "models" / f"navigation-{method}.zip").env_kwargs["action_repeat"] == 10
        payload = json.loads((out / "eval" / "test" / f"navigation-{method}-seed0.json").read_text())
        assert payload["steps"] == 60
    assert json.loads((out / "eval" / "test" / "navigation-wave.json").read_text())["steps"] == 60
    config = yaml.safe_load((out / "runs").glob("navigation-ppo-seed0*").__next__().joinpath("config.yaml").read_text())
    assert config["timesteps"] == (2 * 60 + 320 + 64) // 10  # RL from scratch: the same physics steps, in decisions


@pytest.mark.parametrize(
    "bin_widths, teacher_seeds", [([60.0], []), ([50.0, 60.0], [210, 211, 212])], ids=["holds", "holds-and-bins"]
)
def test_pipeline_chooses_each_tasks_teacher_on_validation_seeds(tmp_path, bin_widths, teacher_seeds):
    """With several teacher holds (and bin widths), the Markov wave at each is scored on the teacher seeds (by
    default the validation seeds), the best median's is the teacher (recorded, read back on resume), its
    demonstrations are cloned, and with action_repeat 0 every learner decides once per teacher phase, fine-tuning
    discounting 0.99 per physics step. The teacher is scored on the test seeds beside the wave, which stays the
    paper's."""
    from dpr.datasets.lerobot import LeRobotReader
    from dpr.rl.pipeline_config import PER_PHASE, Teacher

    holds = [5, 10]
    settings = {**PIPELINE, "anchor": False, "teacher_holds": holds, "action_repeat": PER_PHASE, "steps": 60}
    settings.update(validation_seeds=[200, 201], critic_warmup=100, finetune_steps=200)
    settings.update(teacher_bin_widths=bin_widths, teacher_seeds=teacher_seeds)
    out = tmp_path / "run"
    report, _ = run_tiny(settings, out)
    record = yaml.safe_load((out / "choices.yaml").read_text())["navigation-teacher"]
    candidates = [Teacher(hold, width) for hold in holds for width in bin_widths]
    assert len(record["validation_medians"]) == len(candidates)
    for teacher in candidates:
        payload = json.loads((out / "eval" / "validation" / f"navigation-teacher-{teacher.stem}.json").read_text())
        assert payload["seeds"] == (teacher_seeds or [200, 201]) and payload["policy"] == teacher.policy
        assert payload["env_kwargs"]["action_repeat"] == teacher.hold
        median = float(np.median([e["projected_displacement"] for e in payload["episodes"]]))
        key = teacher.hold if bin_widths == [60.0] else teacher.stem  # the records before bin widths keyed by hold
        assert record["validation_medians"][key] == pytest.approx(median)
    best = max(record["validation_medians"].values())
    chosen = Teacher(record["hold_steps"], record.get("bin_width", 60.0))
    assert (
        chosen in candidates
        and best == record["validation_medians"][chosen.stem if len(bin_widths) > 1 else chosen.hold]
    )
    assert ("bin_width" in record) == (chosen.bin_width != 60.0)
    assert LeRobotReader(out / "datasets" / "navigation").info["total_frames"] == 2 * 60 // chosen.hold
    for method in METHODS[1:]:
        assert read_model_info(out / "models" / f"navigation-{method}.zip").env_kwargs["action_repeat"] == chosen.hold
    run = next((out / "runs").glob("navigation-bc-ppo-seed0*"))
    overrides = yaml.safe_load((run / "config.yaml").read_text())["hyperparameter_overrides"]
    assert overrides["gamma"] == round(0.99**chosen.hold, 3)
    scored = json.loads((out / "eval" / "test" / "navigation-teacher.json").read_text())
    assert scored["policy"] == chosen.policy and scored["seeds"] == [100]
    assert json.loads((out / "eval" / "test" / "navigation-wave.json").read_text())["policy"] == "wave"
    assert "| Navigation | teacher |" in (report / "results.md").read_text()
    lines = []
    run_pipeline(PipelineConfig(**settings), out, show_progress=False, log=lines.append)
    assert not any("evaluate on the validation seeds" in line for line in lines if "exists" not in line)


def test_a_teachers_name_says_its_hold_and_bins():
    """The teacher's policy name is what `dpr evaluate --policy` takes; the wave's Markov twin keeps the plain
    name, and file stems name the bins only when they are not the wave's."""
    from dpr.policies.registry import parse_scripted_name
    from dpr.rl.pipeline_config import Teacher

    assert Teacher().policy == "wave-markov" and Teacher().stem == "hold10"
    assert Teacher(8).policy == "wave-markov:hold_steps=8" and Teacher(8).stem == "hold8"
    assert Teacher(6, 50.0).policy == "wave-markov:hold_steps=6,bin_width=50" and Teacher(6, 50.0).stem == "hold6-bin50"
    assert parse_scripted_name(Teacher(6, 50.0).policy)[1] == {"hold_steps": 6, "bin_width": 50.0}
    config = PipelineConfig(teacher_holds=[6, 8], teacher_bin_widths=[50, 60], validation_seeds=[200], action_repeat=0)
    assert config.teachers() == [Teacher(6, 50.0), Teacher(6, 60.0), Teacher(8, 50.0), Teacher(8, 60.0)]
    assert config.teacher_choice_seeds() == [200]
    assert PipelineConfig(teacher_seeds=[7, 8]).teacher_choice_seeds() == [7, 8]
    assert "teacher" not in PipelineConfig().methods() and "teacher" in config.methods()


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
    # the task's runs (their canonical models and test evaluations exist), the wave's evaluation, the report
    assert len(skipped) == 1 + 1 + 1
    with pytest.raises(ValueError, match="^out: .* holds a pipeline run with other settings"):
        run_pipeline(PipelineConfig(**{**PIPELINE, "finetune_steps": 128}), out, **QUIET)
    with pytest.raises(ValueError, match="holds a pipeline run with other settings"):
        run_pipeline(PipelineConfig(**{**PIPELINE, "test_seeds": [100, 101]}), out, **QUIET)
    assert {path: path.stat().st_mtime_ns for path in out.rglob("*") if path.is_file()} == files


GATE_V0 = ["--env-id", "dpr/Gate-v0"]  # the records before Gate-v1
YAML_LR = [*GATE_V0, "--finetune-hyperparam", "learning_rate=null"]  # the records before the preset's learning rate
MLP = [*YAML_LR, "--actor", "mlp", "--bc-epochs", "15"]  # the records before the swarm actor's


@pytest.mark.parametrize(
    "record, flags",
    [
        ("full-lr3e4", GATE_V0),
        ("full-swarm", YAML_LR),
        ("full-ft600", [*MLP, "--finetune-steps", "600000"]),
        ("full-bins", [*MLP, "--finetune-steps", "300000"]),
        ("full", [*MLP, "--finetune-steps", "300000", "--teacher-bin-widths", "60", "--teacher-seeds", "none"]),
        (
            "full-hold10",
            [*MLP, "--finetune-steps", "300000", "--teacher-holds", "10", "--action-repeat", "10"]
            + ["--finetune-hyperparam", "gamma=0.904", "--teacher-bin-widths", "60", "--teacher-seeds", "none"],
        ),
    ],
)
def test_each_record_resumes_with_the_flags_results_md_gives(record, flags):
    """The settings `dpr pipeline --preset full --tasks all <flags>` makes are those a record in docs/results was
    made with (settings added since it started at their defaults), so its documented command resumes it."""
    from pathlib import Path

    from dpr.cli import build_parser
    from dpr.cli.pipeline import pipeline_config

    root = Path(__file__).resolve().parents[1]
    saved = yaml.safe_load((root / "docs" / "results" / record / "pipeline.yaml").read_text())["config"]
    args = build_parser().parse_args(["pipeline", "--preset", "full", "--tasks", "all", *flags])
    assert dataclasses.asdict(pipeline_config(args)) == saved_settings(saved)
    shown = " ".join((root / "RESULTS.md").read_text().replace("\\\n", " ").split())  # continued lines joined
    assert " ".join(["dpr pipeline --preset full --tasks all --out", f"runs/{record}", *flags, ""]) in shown


def test_a_record_from_before_gate_v1_ran_gate_on_v0_and_a_new_run_on_v1():
    """A pipeline.yaml without env_ids ran Gate on Gate-v0 (the id of then); a run of today runs Gate-v1, and
    --env-id dpr/Gate-v0 makes the settings of the older records."""
    from dpr.cli import build_parser
    from dpr.cli.pipeline import pipeline_config

    old = dataclasses.asdict(PipelineConfig(tasks=["navigation", "gate"]))
    del old["env_ids"]
    assert saved_settings(old)["env_ids"] == {"gate": "dpr/Gate-v0"}
    assert saved_settings({**old, "tasks": ["navigation"]})["env_ids"] == {}
    assert PipelineConfig(tasks=["gate"]).env_id("gate") == "dpr/Gate-v1"
    args = build_parser().parse_args(["pipeline", "--tasks", "gate", "--env-id", "dpr/Gate-v0"])
    assert pipeline_config(args).env_id("gate") == "dpr/Gate-v0"
    with pytest.raises(SystemExit):
        build_parser().parse_args(["pipeline", "--env-id", "dpr/Gate-v1"])  # the current id is no earlier one


def test_finetune_hyperparams_go_over_the_preset_and_null_drops_one():
    """--finetune-hyperparam NAME=VALUE goes over the preset's values; NAME=null drops the preset's, so the yaml's
    `finetune` entry stands for it (how the records before the full preset's learning rate are named)."""
    from dpr.cli import build_parser
    from dpr.cli.pipeline import pipeline_config
    from dpr.rl.pipeline_config import FINETUNE_AT_REPEAT, PRESETS

    parse = build_parser().parse_args
    assert PRESETS["full"].finetune_hyperparams["learning_rate"] == 3e-4
    over = pipeline_config(parse(["pipeline", "--preset", "full", "--finetune-hyperparam", "learning_rate=1e-4"]))
    assert over.finetune_hyperparams == {**FINETUNE_AT_REPEAT, "learning_rate": 1e-4}
    dropped = ["pipeline", "--preset", "full", "--finetune-hyperparam", "learning_rate=null"]
    assert pipeline_config(parse(dropped)).finetune_hyperparams == FINETUNE_AT_REPEAT
    small = ["pipeline", "--finetune-hyperparam", "n_epochs=null", "--finetune-hyperparam", "clip_range=0.2"]
    assert pipeline_config(parse(small)).finetune_hyperparams == {"n_steps": 512, "batch_size": 128, "clip_range": 0.2}


@pytest.mark.parametrize(
    "pair, expected",
    [("learning_rate=abc", "learning_rate: expected a number > 0"), ("learnin_rate=1e-4", "unknown hyperparameter")],
)
def test_a_bad_finetune_hyperparam_is_refused_naming_its_flag_before_any_work(pair, expected, tmp_path, capsys):
    """A misspelt fine-tuning hyperparameter, or a value the yaml would refuse, stops the command at once, not
    hours later when the first clone is fine-tuned."""
    from helpers import run_cli

    out = tmp_path / "run"
    argv = ["pipeline", "--preset", "full", "--tasks", "all", "--finetune-hyperparam", pair, "--out", str(out)]
    assert run_cli(argv) == 2
    error = capsys.readouterr().err
    assert "--finetune-hyperparam: " in error and expected in error
    assert not out.exists()


def test_scratch_physics_discount_is_a_flag_over_the_preset():
    """--scratch-physics-discount turns the setting on over any preset; without it the preset's (off) stands."""
    from dpr.cli import build_parser
    from dpr.cli.pipeline import pipeline_config

    parse = build_parser().parse_args
    full = pipeline_config(parse(["pipeline", "--preset", "full", "--scratch-physics-discount"]))
    assert full.scratch_physics_discount
    assert not pipeline_config(parse(["pipeline", "--preset", "full"])).scratch_physics_discount
    assert full.scratch_hyperparams_at(6) == {"policy": "SwarmPolicy", "gamma": 0.941}  # a decision per phase
    small = pipeline_config(parse(["pipeline", "--scratch-physics-discount"]))
    assert small.scratch_hyperparams_at(6) == {"policy": "SwarmPolicy", "gamma": 0.904}  # every 10 steps


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
    assert sum(line.endswith("skipped") for line in lines) == 1 + 1 + 1


def _evaluations_only(run, tmp_path):
    """A copy of the run folder ``run`` kept as a record is: without its datasets, run folders, report and training
    runs' models."""
    import shutil

    record = tmp_path / "record"
    shutil.copytree(run, record)
    for folder in ("datasets", "runs", "report"):
        shutil.rmtree(record / folder)
    for model in (record / "models").glob("*-seed*.zip"):
        model.unlink()
    return record


def test_pipeline_resumes_from_a_record_without_datasets_and_training_runs(pipeline, tmp_path):
    """A finished task needs only its canonical models, test evaluations and choices: a record of the run
    kept without the datasets, the run folders and the training runs' models resumes without training, and
    writes the same report."""
    record = _evaluations_only(pipeline[0], tmp_path)
    lines = []
    run_pipeline(PipelineConfig(**PIPELINE), record, show_progress=False, log=lines.append)
    assert "dpr pipeline: navigation: its canonical models and test evaluations exist, skipped" in lines
    assert not (record / "datasets").exists() or not any((record / "datasets").iterdir())
    assert not any((record / "models").glob("*-seed*.zip"))
    original = (pipeline[0] / "report" / "results.md").read_text()  # names its sources by path
    assert (record / "report" / "results.md").read_text() == original.replace(str(pipeline[0]), str(record))


def test_a_report_stopped_part_way_is_kept_and_written_anew_beside_it(pipeline, tmp_path):
    """results.md is the report's last file: a folder of figures without it (a kill while the report was written)
    is not taken for a finished report; the rerun writes the report whole beside it."""
    record = _evaluations_only(pipeline[0], tmp_path)
    run_pipeline(PipelineConfig(**PIPELINE), record, **QUIET)
    (record / "report" / "results.md").unlink()
    figures = sorted(path.name for path in (record / "report").iterdir())
    lines = []
    report = run_pipeline(PipelineConfig(**PIPELINE), record, show_progress=False, log=lines.append)
    assert report == record / "report-2" and (report / "results.md").exists()
    assert sorted(path.name for path in (record / "report").iterdir()) == figures  # kept as it was
    assert any("was stopped part-way" in line for line in lines)


def test_a_second_pipeline_on_one_folder_is_refused_naming_the_first_and_a_dead_ones_lock_is_taken(pipeline, tmp_path):
    import os

    from dpr.locks import FolderLock
    from dpr.rl.pipeline import RUN_LOCK

    record = _evaluations_only(pipeline[0], tmp_path)
    files = {path: path.stat().st_mtime_ns for path in record.rglob("*") if path.is_file()}
    with FolderLock(record / RUN_LOCK):  # another pipeline running there
        with pytest.raises(ParameterError, match=rf"another `dpr pipeline` \(process {os.getpid()}\) is running"):
            run_pipeline(PipelineConfig(**PIPELINE), record, **QUIET)
    assert {path: path.stat().st_mtime_ns for path in record.rglob("*") if path.is_file()} == files
    (record / RUN_LOCK).write_text("4194304\n")  # left by a pipeline that was killed: no one holds it
    assert run_pipeline(PipelineConfig(**PIPELINE), record, **QUIET) == record / "report"
    assert not (record / RUN_LOCK).exists()


def test_pipeline_with_training_seeds_chooses_the_median_run_on_validation_seeds(three_seeds):
    """Three training seeds: every run is scored on the validation seeds, the canonical model is the median
    run there (not the best), and the report's interval rows hold every run on the test seeds."""
    out, report, lines = three_seeds
    trained = [line.split(": ")[2].split(" (")[0] for line in lines if "physics steps" in line]
    # every seed's fine-tuning before any run from scratch, so the headline method's runs are done first
    assert trained == [f"{method}, seed {seed}" for method in ("bc-ppo", "ppo") for seed in (0, 1, 2)]
    # and scored on the validation seeds, chosen from and tested before it too, so that a candidate recipe can be
    # judged meanwhile, and their models are no longer needed once their group is done
    first_scratch = next(i for i, line in enumerate(lines) if ": ppo, seed 0 (" in line)
    cloned_runs = [f"navigation-{method}-seed{seed}" for method in ("bc", "bc-ppo") for seed in (0, 1, 2)]
    for split in ("validation", "test"):
        scored = [line.split(": ")[1] for line in lines[:first_scratch] if f"evaluate on the {split} seeds" in line]
        assert scored == cloned_runs
    assert sum("the median run is seed" in line for line in lines[:first_scratch]) == 2
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


def test_a_record_with_evaluations_only_resumes_training_only_what_is_missing(three_seeds, tmp_path):
    """A record kept with its evaluations and canonical models but no training runs resumes at any stage: a run
    is trained again only when an evaluation of it is missing, or when it is the chosen run and the canonical
    model is missing; a retrained chosen run must reproduce its validation episodes exactly."""
    out, report, _ = three_seeds
    record = _evaluations_only(out, tmp_path)
    (record / "models" / "navigation-bc-ppo.zip").unlink()  # as if the run had stopped before copying it
    (record / "eval" / "test" / "navigation-ppo-seed1.json").unlink()  # ... or before testing this run
    _, lines = run_tiny(THREE_SEEDS, record)
    chosen = yaml.safe_load((out / "choices.yaml").read_text())["navigation-bc-ppo"]["chosen_seed"]
    assert trained_runs(lines) == [f"bc-ppo, seed {chosen}", f"bc, seed {chosen}", "ppo, seed 1"]
    assert any(line.endswith(f"navigation-bc-ppo-seed{chosen}.json episode for episode") for line in lines)
    assert yaml.safe_load((record / "choices.yaml").read_text()) == yaml.safe_load((out / "choices.yaml").read_text())
    assert_same_policy(record / "models" / "navigation-bc-ppo.zip", out / "models" / "navigation-bc-ppo.zip")
    retested, tested = (
        json.loads((run / "eval" / "test" / "navigation-ppo-seed1.json").read_text()) for run in (record, out)
    )
    for episode in retested["episodes"] + tested["episodes"]:
        del episode["policy"]  # the model's path, in one folder or the other
    assert retested["episodes"] == tested["episodes"]
    text = (report / "results.md").read_text()
    assert (record / "report" / "results.md").read_text() == text.replace(str(out), str(record))


def test_a_retrained_run_that_does_not_reproduce_its_evaluation_is_refused(three_seeds, tmp_path):
    """Training again a chosen run whose model is gone must give the run that was evaluated: if its validation
    episodes differ (here by 1e-9 units in one episode), the pipeline stops, naming both files, and ships nothing."""
    out, _, _ = three_seeds
    record = _evaluations_only(out, tmp_path)
    (record / "models" / "navigation-bc.zip").unlink()
    chosen = yaml.safe_load((out / "choices.yaml").read_text())["navigation-bc"]["chosen_seed"]
    for seed in THREE_SEEDS["train_seeds"]:  # every run alike, so that the choice stays the same
        validation = record / "eval" / "validation" / f"navigation-bc-seed{seed}.json"
        payload = json.loads(validation.read_text())
        payload["episodes"][0]["projected_displacement"] += 1e-9
        validation.write_text(json.dumps(payload))
    with pytest.raises(RuntimeError, match=f"navigation-bc-seed{chosen}.zip was trained again .* does not reproduce"):
        run_tiny(THREE_SEEDS, record)
    assert not (record / "models" / "navigation-bc.zip").exists()


def test_a_training_run_stopped_part_way_resumes_from_its_snapshot(pipeline, tmp_path):
    """A run killed mid-training goes on from its last snapshot in its run folder (no new folder beside it; here
    one that an earlier attempt had started beside a first) and ends with the model the uninterrupted pipeline
    made."""
    from dpr.rl import resume as resume_state

    out = copy_without_run(pipeline[0], tmp_path / "run", "navigation-ppo-seed0", canonical=True)
    with stopped_after_snapshots():
        run_tiny(PIPELINE, out)
    assert resume_state.has_snapshot(out / "runs" / "navigation-ppo-seed0")
    (out / "runs" / "navigation-ppo-seed0").rename(out / "runs" / "navigation-ppo-seed0-2")
    _, lines = run_tiny(PIPELINE, out)
    assert trained_runs(lines) == ["ppo, seed 0"]
    assert any("resumed at step" in line and "navigation-ppo-seed0-2" in line for line in lines)
    names = {p.name for p in (pipeline[0] / "runs").iterdir()} - {"navigation-ppo-seed0"}
    assert {p.name for p in (out / "runs").iterdir()} == names | {"navigation-ppo-seed0-2"}
    assert_same_policy(out / "models" / "navigation-ppo.zip", pipeline[0] / "models" / "navigation-ppo.zip")
