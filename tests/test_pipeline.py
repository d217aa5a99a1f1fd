"""The whole pipeline (`dpr pipeline`: demonstrations -> BC -> fine-tuning beside RL from scratch -> evaluation ->
report; choices on validation seeds, canonical models), run in this process at budgets of seconds."""

import json
import zipfile

import gymnasium as gym
import numpy as np
import pytest
import torch
import yaml
from helpers import PIPELINE, QUIET, built_stages, run_tiny

from dpr.checks import ParameterError
from dpr.envs import ENV_IDS
from dpr.pipeline.campaign import run_pipeline, task_stages
from dpr.pipeline.config import PipelineConfig, learner_env_kwargs
from dpr.pipeline.stages import Backend
from dpr.policies.model_file import read_model_info
from dpr.policies.sb3 import load_model

METHODS = ["wave", "bc", "bc-ppo", "ppo"]


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
        ({"tasks": ["swimming"]}, "tasks: expected some of"),
        ({"tasks": []}, "tasks: expected some of"),
        ({"tasks": "navigation"}, "tasks: expected a list of strings"),
        ({"finetune_algos": ["dqn"]}, "finetune_algos: expected some of"),
        ({"scratch_algos": ["sac"]}, "scratch_algos: expected some of"),
        ({"episodes": 1}, "episodes: must be >= 2"),
        ({"steps": 0}, "steps: must be >= 1"),
        ({"n_envs": 0}, "n_envs: must be >= 1"),
        ({"critic_warmup": -1}, "critic_warmup: must be >= 0"),
        ({"approach_reward": -1.0}, "approach_reward: must be >= 0"),
        ({"approach_reward": "1"}, "approach_reward: expected a number"),
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
        ({"teacher_bin_widths": ["50"]}, "teacher_bin_widths: expected a list of numbers"),
        ({"teacher_seeds": [299, 300]}, r"teacher_seeds: \[300\] are test seeds too"),
        ({"teacher_seeds": [1000]}, r"teacher_seeds: \[1000\] are demonstration seeds"),
        ({"teacher_seeds": [3, 3]}, "teacher_seeds: each seed must appear once"),
        ({"teacher_holds": [7, 10], "validation_seeds": [200]}, r"action_repeat: must divide every teacher hold"),
        ({"action_repeat": 3}, r"action_repeat: must divide every teacher hold \[10\]"),
        ({"action_repeat": -1}, "action_repeat: must be >= 0"),
        ({"train_seeds": [300], "test_seeds": [300, 301]}, r"train_seeds: \[300\] are test seeds too"),
        ({"train_seeds": [0, 200], "validation_seeds": [200]}, r"train_seeds: \[200\] are validation seeds too"),
        ({"env_ids": {"gate": "dpr/Navigation-v0"}, "tasks": ["gate"]}, "env_ids: expected registered ids of"),
        ({"env_ids": {"gate": "dpr/Gate-v0"}}, r"env_ids: \['dpr/Gate-v0'\] belong to tasks this run does not run"),
        ({"env_ids": {"navigation": {}}}, "env_ids: expected a mapping to strings"),  # not a TypeError
        ({"finetune_hyperparams": {"n_stepz": 8}}, "finetune_hyperparams: .*n_stepz"),
        ({"scratch_hyperparams": {"n_stepz": 8}}, "scratch_hyperparams: .*n_stepz"),
        ({"actor": "transformer"}, "actor: expected one of"),
        ({"average_checkpoints": ["swimming"]}, "average_checkpoints: expected some of"),
        ({"average_checkpoints": "gate"}, "average_checkpoints: expected a list of strings"),
        ({"scratch_algos": ["ppo", "dqn"]}, "DQN from scratch has none"),
    ],
)
def test_pipeline_config_refuses_bad_settings(kwargs, message):
    with pytest.raises(ParameterError, match=message):
        PipelineConfig(**kwargs)


def test_learners_env_kwargs_decide_every_action_repeat_steps_or_once_per_teacher_phase():
    assert learner_env_kwargs(10, 8) == {"obs_last_action": True, "action_repeat": 10}
    assert learner_env_kwargs(0, 8) == {"obs_last_action": True, "action_repeat": 8}
    assert learner_env_kwargs(1, 8) == {"obs_last_action": True}  # deciding every step: the env's default
    for env_id in ENV_IDS.values():  # every task's env takes them
        gym.make(env_id, **learner_env_kwargs(0, 8)).close()


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory):
    """One tiny pipeline run: (its folder, report, log lines)."""
    out = tmp_path_factory.mktemp("pipeline") / "run"
    report, lines = run_tiny(PIPELINE, out)
    return out, report, lines


def stored(out, kind: str) -> list:
    """The stage outputs of ``kind`` in the run folder ``out``, as their stage.json records."""
    return [json.loads(path.read_text()) for path in sorted((out / "stages" / kind).glob("*/stage.json"))]


def test_pipeline_writes_every_stage_and_names_its_outputs(pipeline):
    out, report, lines = pipeline
    assert report == out / "report"
    kinds = {kind: len(stored(out, kind)) for kind in ("teacher", "demonstrations", "clone", "rl", "evaluate")}
    assert kinds == {"teacher": 1, "demonstrations": 1, "clone": 1, "rl": 2, "evaluate": 4}
    assert "dpr pipeline: 9 stages: 0 stored, 9 to build" in lines
    assert len(built_stages(lines)) == 9 and not (out / "work").exists() or not any((out / "work").iterdir())
    (dataset,) = stored(out, "demonstrations")
    assert "dataset/meta/info.json" in dataset["files"]
    models = [f"navigation-{m}{run}.zip" for m in METHODS[1:] for run in ("", "-seed0")]  # one run: its own median
    assert sorted(p.name for p in (out / "models").iterdir()) == sorted(models)
    evaluations = ["navigation-wave.json", *(f"navigation-{m}-seed0.json" for m in METHODS[1:])]
    assert sorted(p.name for p in (out / "eval" / "test").iterdir()) == sorted(evaluations)
    assert not (out / "eval" / "validation").exists()  # one training seed: nothing to choose
    assert {"results.md", "bars.png", "trajectories.png", "intervals.png"} <= {p.name for p in report.iterdir()}
    for model in (out / "models").iterdir():
        info = read_model_info(model)
        assert info.env_kwargs == {"n_robots": 4, "robot_model": "paddle", "obs_last_action": True}
        assert info.max_episode_steps == 30
    (clone,) = stored(out, "clone")
    finetune, scratch = sorted(stored(out, "rl"), key=lambda record: "clone" not in record["needs"])
    assert finetune["needs"]["clone"] == f"clone/{clone['key']}"
    config = yaml.safe_load((out / "stages" / "rl" / finetune["key"] / "config.yaml").read_text())
    assert config["init_from"] == str((out / "stages" / "clone" / clone["key"] / "model.zip").resolve())
    assert config["critic_warmup"] == 32 and config["timesteps"] == 64 and config["n_envs"] == 1
    config = yaml.safe_load((out / "stages" / "rl" / scratch["key"] / "config.yaml").read_text())
    assert config["timesteps"] == PipelineConfig(**PIPELINE).rl_steps == 2 * 30 + 32 + 64
    assert config["init_from"] is None and config["hyperparameters"]["preset"] == "default"


def test_pipeline_evaluates_every_method_on_the_same_swarm(pipeline):
    out, _, _ = pipeline
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


def test_pipeline_report_has_a_row_per_method_and_names_its_sources_in_the_run_folder(pipeline):
    _, report, _ = pipeline
    text = (report / "results.md").read_text()
    rows = [line.split("|") for line in text.split("## Interval estimates")[0].splitlines()]
    assert [row[2].strip() for row in rows if row[1:2] == [" Navigation "]] == METHODS
    assert "Sources: `eval/test/navigation-wave.json` (wave: Navigation" in text


def test_pipeline_resumes_without_changing_anything_and_refuses_other_settings(pipeline):
    out, _, _ = pipeline
    files = {path: path.stat().st_mtime_ns for path in out.rglob("*") if path.is_file()}
    _, lines = run_tiny(PIPELINE, out)
    assert {path: path.stat().st_mtime_ns for path in out.rglob("*") if path.is_file()} == files
    # the demonstrations are not needed once the clone is stored, but they are checked as stored stages
    assert "dpr pipeline: 9 stages: 9 stored, 0 to build" in lines and not built_stages(lines)
    with pytest.raises(ParameterError, match=r"^out: .* holds a pipeline run with other settings .*finetune_steps"):
        run_tiny({**PIPELINE, "finetune_steps": 128}, out)
    with pytest.raises(ParameterError, match="holds a pipeline run with other settings"):
        run_tiny({**PIPELINE, "test_seeds": [100, 101]}, out)
    assert {path: path.stat().st_mtime_ns for path in out.rglob("*") if path.is_file()} == files


def test_a_run_folder_from_before_a_setting_was_added_resumes_with_its_default(pipeline, tmp_path):
    import shutil

    out = tmp_path / "run"
    shutil.copytree(pipeline[0], out)
    record = yaml.safe_load((out / "pipeline.yaml").read_text())
    del record["config"]["env_ids"]  # as a folder written before the setting existed
    (out / "pipeline.yaml").write_text(yaml.safe_dump(record, sort_keys=False))
    _, lines = run_tiny(PIPELINE, out)
    assert not built_stages(lines)


def test_stored_models_hold_no_optimizer_state(pipeline):
    """What a run folder keeps is small enough to commit: models without the optimizer's moments, no pickles."""
    out, _, _ = pipeline
    for model in (out / "stages").glob("*/*/model.zip"):
        with zipfile.ZipFile(model) as archive:
            state = torch.load(archive.open("policy.optimizer.pth"), weights_only=True)
        assert state["state"] == {}, model
    assert not list(out.rglob("*.pkl"))


def test_a_damaged_stored_output_is_set_aside_and_built_again(pipeline, tmp_path):
    """A truncated model in the store is refused (its SHA-256 no longer matches stage.json), kept aside, and built
    again, with everything after it: the same report."""
    import shutil

    out, report, _ = pipeline
    copy = tmp_path / "run"
    shutil.copytree(out, copy, ignore=shutil.ignore_patterns("report"))
    (clone,) = stored(copy, "clone")
    model = copy / "stages" / "clone" / clone["key"] / "model.zip"
    model.write_bytes(model.read_bytes()[:1000])
    again, lines = run_tiny(PIPELINE, copy)
    assert any("navigation: bc, seed 0: " in line and "is damaged (model.zip does not match" in line for line in lines)
    assert (copy / "stages" / "clone" / f"{clone['key']}.corrupt" / "model.zip").stat().st_size == 1000
    assert built_stages(lines) == ["navigation: bc, seed 0"]  # everything that needs it is stored whole
    assert (again / "results.md").read_text() == (report / "results.md").read_text()


def test_a_damaged_input_that_no_target_needs_any_more_is_caught_on_rerun(pipeline, tmp_path):
    """One flipped byte in the stored demonstrations (read by the clones, which are stored) fails its stage.json
    SHA-256 on the next run: the dataset is set aside and recorded again, the run says so, and the report is the
    same."""
    import shutil

    out, report, _ = pipeline
    copy = tmp_path / "run"
    shutil.copytree(out, copy, ignore=shutil.ignore_patterns("report"))
    (demonstrations,) = stored(copy, "demonstrations")
    folder = copy / "stages" / "demonstrations" / demonstrations["key"]
    data = sorted((folder / "dataset" / "data").rglob("*.parquet"))[0]
    damaged = bytearray(data.read_bytes())
    damaged[len(damaged) // 2] ^= 0x01
    data.write_bytes(bytes(damaged))
    again, lines = run_tiny(PIPELINE, copy)
    relative = data.relative_to(folder).as_posix()
    assert any(f"is damaged ({relative} does not match its size and SHA-256" in line for line in lines), lines
    assert (folder.with_name(f"{folder.name}.corrupt") / relative).read_bytes() == bytes(damaged)
    assert built_stages(lines) == ["navigation: 2 demonstrations"]
    assert data.read_bytes() == (out / data.relative_to(copy)).read_bytes()  # recorded again, as it was
    assert (again / "results.md").read_text() == (report / "results.md").read_text()


def test_a_candidate_that_changes_only_fine_tuning_reuses_the_teacher_demonstrations_and_clones(pipeline, tmp_path):
    out, _, _ = pipeline
    candidate = {**PIPELINE, "finetune_hyperparams": {**PIPELINE["finetune_hyperparams"], "learning_rate": 1e-4}}
    _, lines = run_tiny(candidate, tmp_path / "candidate", reuse=[out])
    # the teacher, the clone, the run from scratch and three evaluations (the wave, bc, ppo) come from the record
    assert f"dpr pipeline: 8 stages: 6 stored (6 reused from {out}), 2 to build" in lines
    assert built_stages(lines) == [
        "navigation: bc-ppo, seed 0",
        "navigation: evaluate bc-ppo, seed 0, on the test seeds",
    ]
    kinds = {path.name for path in (tmp_path / "candidate" / "stages").iterdir()}
    assert kinds == {"teacher", "clone", "evaluate", "rl"}
    with pytest.raises(ParameterError, match="reuse: .* holds no stages/ folder"):
        run_tiny(PIPELINE, tmp_path / "other", reuse=[tmp_path / "nothing"])


def test_pipeline_with_training_seeds_chooses_the_median_run_on_validation_seeds(three_seeds):
    """Three training seeds: every run is scored on the validation seeds, the canonical model is the median
    run there (not the best), and the report's interval rows hold every run on the test seeds."""
    out, report, _ = three_seeds
    choices = yaml.safe_load((out / "choices.yaml").read_text())
    for method in METHODS[1:]:
        medians = choices[f"navigation-{method}"]["validation_medians"]
        for seed, median in medians.items():
            payload = json.loads((out / "eval" / "validation" / f"navigation-{method}-seed{seed}.json").read_text())
            assert payload["seeds"] == [200, 201]
            assert median == pytest.approx(float(np.median([e["projected_displacement"] for e in payload["episodes"]])))
        chosen = choices[f"navigation-{method}"]["chosen_seed"]
        assert sorted(medians, key=lambda s: (medians[s], s))[1] == chosen
        canonical = out / "models" / f"navigation-{method}.zip"
        assert [s for s in (0, 1, 2) if canonical.samefile(out / "models" / f"navigation-{method}-seed{s}.zip")] == [
            chosen
        ]
    assert not list((out / "eval" / "test").glob("*200*"))
    text = (report / "results.md").read_text()
    assert "| Navigation | bc-ppo | 3 × 1 |" in text and "| Navigation | wave | 1 × 1 |" in text


def test_pipeline_trains_manipulation_with_the_shaping(tmp_path):
    """RL on Manipulation, fine-tuning and from scratch, gets the approach shaping; the clone does not need it."""
    out = tmp_path / "run"
    run_tiny({**PIPELINE, "tasks": ["manipulation"], "approach_reward": 0.5}, out)
    for method in ("bc-ppo", "ppo"):
        assert read_model_info(out / "models" / f"manipulation-{method}.zip").env_kwargs["approach_reward"] == 0.5
    assert "approach_reward" not in read_model_info(out / "models" / "manipulation-bc.zip").env_kwargs


def test_pipeline_trains_a_task_on_its_training_env_kwargs(tmp_path):
    """Gate's RL runs gather experience with the walls drawn over a spread; their models are Gate's as evaluated,
    and the runs' config.yaml records the spread. The clone is untouched, and so are other tasks' stage keys."""
    spread = {"gate": {"gate_distance": [5.0, 50.0]}}
    out = tmp_path / "run"
    run_tiny({**PIPELINE, "tasks": ["gate"], "training_env_kwargs": spread}, out)
    for method in ("bc", "bc-ppo", "ppo"):
        assert "gate_distance" not in read_model_info(out / "models" / f"gate-{method}.zip").env_kwargs
    records = [yaml.safe_load(path.read_text()) for path in (out / "stages" / "rl").glob("*/config.yaml")]
    assert len(records) == 2 and all(r["training_env_kwargs"] == spread["gate"] for r in records)
    plain, spread_config = (
        PipelineConfig(**{**PIPELINE, "tasks": ["navigation", "gate"], "training_env_kwargs": kwargs})
        for kwargs in ({}, spread)
    )

    def keys(config, task):
        stages = task_stages(config, task)
        return [stage.key for stage in (*stages.models.values(), *stages.evaluations.values())]

    assert keys(plain, "navigation") == keys(spread_config, "navigation")
    assert keys(plain, "gate")[0] == keys(spread_config, "gate")[0]  # the clone
    assert keys(plain, "gate")[1:] != keys(spread_config, "gate")[1:]


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"swimming": {"gate_distance": 5.0}}, "training_env_kwargs: expected task -> mapping"),
        ({"gate": [5.0, 50.0]}, "training_env_kwargs: expected task -> mapping"),
        ({"gate": {"gate_distance": [50.0, 5.0]}}, r"training_env_kwargs: gate: gate_distance: expected \[low"),
        ({"gate": {"observe_opening": False}}, "training_env_kwargs: gate: .* observation or action space"),
    ],
)
def test_bad_training_env_kwargs_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        PipelineConfig(**{**PIPELINE, "tasks": ["gate"], "training_env_kwargs": kwargs})


def test_a_training_env_kwarg_of_a_task_not_run_is_passed_over():
    config = PipelineConfig(**{**PIPELINE, "training_env_kwargs": {"gate": {"gate_distance": "far"}}})
    assert config.tasks == ["navigation"]


def test_a_task_named_in_average_checkpoints_keeps_the_mean_of_its_fine_tuned_weights(tmp_path, monkeypatch):
    """Its fine-tuned model holds the mean of the policy's weights at the run's first three checkpoints (a quarter,
    half and three quarters of the way) and at its end. Its clone, its run from scratch and the stages of tasks
    not named keep their keys."""
    import dpr.policies.sb3 as sb3

    seen = {}
    save_slim_copy = sb3.save_slim_copy

    def remember_the_mean(source, target, average_with=()):
        if average_with:  # the checkpoints still exist: the pipeline deletes the run's work folder afterwards
            states = [load_model(path)[0].policy.state_dict() for path in (source, *average_with)]
            seen["averaged"] = [path.name for path in average_with]
            seen["mean"] = {name: sum(state[name] for state in states) / len(states) for name in states[0]}
            seen["last"] = states[0]
        return save_slim_copy(source, target, average_with)

    monkeypatch.setattr(sb3, "save_slim_copy", remember_the_mean)
    out = tmp_path / "run"
    run_tiny({**PIPELINE, "average_checkpoints": ["navigation"]}, out)
    assert seen["averaged"] == [f"model_{32 + steps}_steps.zip" for steps in (16, 32, 48)]  # after the warm-up
    stored = load_model(out / "models" / "navigation-bc-ppo.zip")[0].policy.state_dict()
    for name, mean in seen["mean"].items():
        torch.testing.assert_close(stored[name], mean)
    assert any(not torch.equal(stored[name], seen["last"][name]) for name in stored)

    def keys(**settings):
        stages = task_stages(PipelineConfig(**{**PIPELINE, "tasks": ["navigation", "gate"], **settings}), "navigation")
        return {method: stage.key for (method, _), stage in stages.models.items()}

    plain, averaged = keys(), keys(average_checkpoints=["navigation"])
    assert {m for m in plain if plain[m] != averaged[m]} == {"bc-ppo"}
    assert keys(average_checkpoints=["gate"]) == plain


def test_pipeline_gives_every_learner_its_actor(pipeline, tmp_path):
    """The swarm actor (the default) for the clone, its fine-tuning and the run from scratch; mlp on request."""
    from dpr.policies.swarm_policy import SwarmActorCriticPolicy

    out, _, _ = pipeline
    for method in METHODS[1:]:
        model, _ = load_model(out / "models" / f"navigation-{method}.zip")
        assert isinstance(model.policy, SwarmActorCriticPolicy), method
    run_tiny({**PIPELINE, "actor": "mlp", "scratch_algos": []}, tmp_path / "mlp")
    model, _ = load_model(tmp_path / "mlp" / "models" / "navigation-bc-ppo.zip")
    assert not isinstance(model.policy, SwarmActorCriticPolicy)


def test_pipeline_learners_decide_every_action_repeat_steps(tmp_path):
    """With action_repeat=10 the demonstrations, the clone and RL all decide every 10 physics steps; budgets and
    evaluations count physics steps, so the wave (every step) and the learners are scored over the same time.
    Fine-tuning discounts 0.99 per physics step (0.99^10 per decision); the runs from scratch keep the yaml's."""
    from dpr.datasets.lerobot import LeRobotReader

    settings = {**PIPELINE, "action_repeat": 10, "steps": 60, "critic_warmup": 320}
    out = tmp_path / "run"
    run_tiny(settings, out)
    gammas = {method: load_model(out / "models" / f"navigation-{method}.zip")[0].gamma for method in METHODS[2:]}
    assert gammas == {"bc-ppo": 0.904, "ppo": 0.99}
    (dataset,) = (out / "stages" / "demonstrations").glob("*/dataset")
    assert LeRobotReader(dataset).info["total_frames"] == 2 * 6
    for method in METHODS[1:]:
        assert read_model_info(out / "models" / f"navigation-{method}.zip").env_kwargs["action_repeat"] == 10
        assert json.loads((out / "eval" / "test" / f"navigation-{method}-seed0.json").read_text())["steps"] == 60
    assert json.loads((out / "eval" / "test" / "navigation-wave.json").read_text())["steps"] == 60
    scratch = next(r for r in stored(out, "rl") if "clone" not in r["needs"])
    config = yaml.safe_load((out / "stages" / "rl" / scratch["key"] / "config.yaml").read_text())
    assert config["timesteps"] == (2 * 60 + 320 + 64) // 10  # RL from scratch: the same physics steps, in decisions


@pytest.mark.parametrize(
    "bin_widths, teacher_seeds", [([60.0], []), ([50.0, 60.0], [210, 211, 212])], ids=["holds", "holds-and-bins"]
)
def test_pipeline_chooses_each_tasks_teacher_on_validation_seeds(tmp_path, bin_widths, teacher_seeds):
    """With several teacher holds (and bin widths), the Markov wave at each is scored on the teacher seeds (by
    default the validation seeds), the best median's is the teacher, its demonstrations are cloned, and with
    action_repeat 0 every learner decides once per teacher phase, fine-tuning discounting 0.99 per physics step.
    The teacher is scored on the test seeds beside the wave, which stays the paper's."""
    from dpr.datasets.lerobot import LeRobotReader
    from dpr.pipeline.config import PER_PHASE, Teacher

    holds = [5, 10]
    settings = {**PIPELINE, "teacher_holds": holds, "action_repeat": PER_PHASE, "steps": 60, "scratch_algos": []}
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
        assert record["validation_medians"][teacher.stem] == pytest.approx(median)
    chosen = Teacher(record["hold_steps"], record["bin_width"])
    assert chosen in candidates and record["validation_medians"][chosen.stem] == max(
        record["validation_medians"].values()
    )
    (dataset,) = (out / "stages" / "demonstrations").glob("*/dataset")
    assert LeRobotReader(dataset).info["total_frames"] == 2 * 60 // chosen.hold
    for method in METHODS[1:3]:
        assert read_model_info(out / "models" / f"navigation-{method}.zip").env_kwargs["action_repeat"] == chosen.hold
    assert load_model(out / "models" / "navigation-bc-ppo.zip")[0].gamma == round(0.99**chosen.hold, 3)
    scored = json.loads((out / "eval" / "test" / "navigation-teacher.json").read_text())
    assert scored["env_kwargs"]["action_repeat"] == chosen.hold and scored["seeds"] == [100]
    assert json.loads((out / "eval" / "test" / "navigation-wave.json").read_text())["policy"] == "wave"
    assert "| Navigation | teacher |" in (report / "results.md").read_text()


def test_a_teachers_name_says_its_hold_and_bins():
    """The teacher's policy name is what `dpr evaluate --policy` takes; the wave's Markov twin keeps the plain
    name, and file stems name the bins only when they are not the wave's."""
    from dpr.pipeline.config import Teacher
    from dpr.policies.registry import parse_scripted_name

    assert Teacher().policy == "wave-markov" and Teacher().stem == "hold10"
    assert Teacher(8).policy == "wave-markov:hold_steps=8" and Teacher(8).stem == "hold8"
    assert Teacher(6, 50.0).policy == "wave-markov:hold_steps=6,bin_width=50" and Teacher(6, 50.0).stem == "hold6-bin50"
    assert parse_scripted_name(Teacher(6, 50.0).policy)[1] == {"hold_steps": 6, "bin_width": 50.0}
    config = PipelineConfig(teacher_holds=[6, 8], teacher_bin_widths=[50, 60], validation_seeds=[200], action_repeat=0)
    assert config.teachers() == [Teacher(6, 50.0), Teacher(6, 60.0), Teacher(8, 50.0), Teacher(8, 60.0)]
    assert config.teacher_choice_seeds() == [200]
    assert PipelineConfig(teacher_seeds=[7, 8]).teacher_choice_seeds() == [7, 8]
    assert "teacher" not in PipelineConfig().methods() and "teacher" in config.methods()


def test_a_bad_out_or_shipped_model_is_refused_before_any_work(tmp_path):
    afile = tmp_path / "file"
    afile.write_text("")
    with pytest.raises(ParameterError, match="out: .* is not a folder"):
        run_pipeline(PipelineConfig(**PIPELINE), afile, **QUIET)
    with pytest.raises(ParameterError, match="backend: expected one of"):
        run_pipeline(PipelineConfig(**PIPELINE), tmp_path / "run", backend=Backend("slurm"), **QUIET)
    with pytest.raises(ParameterError, match="address: joins a Ray cluster"):
        run_pipeline(PipelineConfig(**PIPELINE), tmp_path / "run2", backend=Backend(address="127.0.0.1:1"), **QUIET)


def test_shipped_rows_and_their_wave_run_on_the_paddle_model_whatever_the_run_engine(tmp_path):
    from dpr.evaluation.model_card import ShippedModel
    from dpr.pipeline.campaign import shipped_stages

    model = tmp_path / "gate-disk-ppo.zip"
    model.write_bytes(b"a model's bytes")
    config = PipelineConfig(**{**PIPELINE, "tasks": ["navigation"], "engine": "batched"})
    stages = shipped_stages(config, [ShippedModel("gate", "disk-ppo", model, "a test")])
    (wave, wave_label, _), (shipped, shipped_label, _) = stages
    assert (wave_label, shipped_label) == ("wave", "shipped disk-ppo")
    for stage in (wave, shipped):
        assert stage.settings["env_kwargs"]["robot_model"] == "paddle"
        assert "engine" not in stage.settings
