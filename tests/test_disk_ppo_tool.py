"""tools/disk_ppo.py's report: the run to ship is the validation-median one, and the test score is the median run's
over every run's test evaluation (no training or evaluation runs here: evaluation files are written beforehand)."""

import argparse
import json

import pytest
from helpers import load_tool


def write_evaluation(path, medians_of):
    """An evaluation file whose projected displacements have median ``medians_of``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    episodes = [{"projected_displacement": medians_of + offset} for offset in (-1.0, 0.0, 1.0)]
    path.write_text(json.dumps({"episodes": episodes}))


def campaign(tmp_path, validation, test, stage="finetune", zero_shot=0.0):
    """Runs whose ``stage`` scored ``validation`` (and, fine-tuned, ``zero_shot`` before) and ``test``."""
    for seed, (val, tst) in enumerate(zip(validation, test)):
        folder = tmp_path / "unresponsive" / f"seed-{seed}"
        write_evaluation(folder / "zero_shot_validation.json", val if stage == "pretrain" else zero_shot)
        if stage == "finetune":
            write_evaluation(folder / "finetuned_validation.json", val)
        (folder / stage).mkdir(parents=True)
        (folder / stage / "model.zip").write_bytes(b"")
        write_evaluation(folder / f"test_{stage}.json", tst)
    write_evaluation(tmp_path / "unresponsive" / "wave_test.json", 20.0)


def report(tmp_path, capsys, test=True, rounds=None):
    tool = load_tool("disk_ppo")
    tool.dpr = pytest.fail  # every evaluation is on disk: nothing may run
    given = dict(tasks=["unresponsive"], out=tmp_path, test=test, pretrained_in=None, finetune_rounds=rounds)
    tool.report(argparse.Namespace(**given))
    return capsys.readouterr().out


def test_report_ships_the_validation_median_run_and_scores_the_median_test_run(tmp_path, capsys):
    campaign(tmp_path, validation=[44.0, 41.0, 42.0], test=[30.0, 22.0, 26.0])
    out = report(tmp_path, capsys)
    assert "the one to ship: seed-2 (finetune)" in out
    assert "seed-0 (" in out and "150%" in out  # each run's test median against the wave's 20
    assert "median of 3 runs on the test seeds: 130% of the paddle wave" in out


def test_report_does_not_test_a_campaign_whose_fine_tunes_are_not_all_done(tmp_path, capsys):
    campaign(tmp_path, validation=[44.0, 41.0], test=[30.0, 22.0])
    write_evaluation(tmp_path / "unresponsive" / "seed-2" / "zero_shot_validation.json", 10.0)
    out = report(tmp_path, capsys)
    assert "not tested, 2 of its 3 runs reached finetune" in out
    assert "median of" not in out


def test_a_run_whose_fine_tune_scored_lower_on_validation_keeps_its_pretrained_actor(tmp_path, capsys):
    campaign(tmp_path, validation=[44.0, 41.0, 42.0], test=[30.0, 22.0, 26.0], zero_shot=30.0)
    seed_1 = tmp_path / "unresponsive" / "seed-1"
    write_evaluation(seed_1 / "zero_shot_validation.json", 50.0)  # above its fine-tune's 41
    (seed_1 / "pretrain").mkdir()
    (seed_1 / "pretrain" / "model.zip").write_bytes(b"")
    write_evaluation(seed_1 / "test_pretrain.json", 40.0)
    out = report(tmp_path, capsys)
    assert "the one to ship: seed-0 (finetune)" in out  # 42 < 44 < 50 on validation
    assert "pretrain/model.zip): test median 40.0" in out
    assert "median of 3 runs on the test seeds: 150% of the paddle wave" in out  # 30, 40, 26 against 20


def test_a_second_round_ships_where_it_scores_highest_on_validation(tmp_path, capsys):
    campaign(tmp_path, validation=[44.0, 41.0, 42.0], test=[30.0, 22.0, 26.0], zero_shot=30.0)
    for seed, (val, tst) in enumerate([(45.0, 34.0), (40.0, 99.0), (46.0, 28.0)]):  # seed 1's second round is lower
        folder = tmp_path / "unresponsive" / f"seed-{seed}"
        write_evaluation(folder / "finetuned-2_validation.json", val)
        (folder / "finetune-2").mkdir()
        (folder / "finetune-2" / "model.zip").write_bytes(b"")
        write_evaluation(folder / "test_finetune-2.json", tst)
    (tmp_path / "unresponsive" / "seed-1" / "finetuned-2_validation.json").rename(tmp_path / "seed-1-round-2")
    assert "not tested, 2 of its 3 runs reached finetune-2" in report(tmp_path, capsys, rounds=2)
    (tmp_path / "seed-1-round-2").rename(tmp_path / "unresponsive" / "seed-1" / "finetuned-2_validation.json")
    out = report(tmp_path, capsys, rounds=2)
    assert "the one to ship: seed-0 (finetune-2)" in out  # 41 < 45 < 46 on validation
    assert "seed-1 (" in out and "finetune/model.zip): test median 22.0" in out
    assert "median of 3 runs on the test seeds: 140% of the paddle wave" in out  # 34, 22, 28 against 20


def run_args(**given) -> argparse.Namespace:
    """The tool's command line for tiny runs, with ``given`` over its defaults."""
    defaults = dict(
        pretrain_steps=10,
        num_envs=2,
        compile=False,
        finetune_steps=10,
        finetune_rounds=1,
        finetune_hyperparam=[],
        finetune_temperature=1.0,
        pretrain_env_kwarg=[],
        pretrain_hyperparam=[],
    )
    return argparse.Namespace(**{**defaults, "pretrained_in": None, **given})


def test_each_task_trains_with_the_full_presets_settings(tmp_path):
    """Manipulation's runs are paid for the approach; Gate's fine-tune spreads the walls, ships its weights' mean."""
    tool = load_tool("disk_ppo")
    commands = []
    tool.dpr = lambda *arguments: commands.append(arguments)
    args = run_args(out=tmp_path)
    tool.run("gate", 0, args)
    train, _, finetune, validation = commands
    assert train[train.index("--training-env-kwarg") + 1] == "gate_width=200"  # a wider opening, experience only
    assert "approach_reward=1.0" not in train
    assert "gate_distance=[5, 200]" in finetune and "--average-checkpoints" in finetune
    assert validation[validation.index("--policy") + 1].endswith("finetune/averaged_model.zip")
    commands.clear()
    tool.run("manipulation", 0, args)
    assert all("approach_reward=1.0" in command for command in (commands[0], commands[2]))
    assert commands[3][commands[3].index("--policy") + 1].endswith("finetune/model.zip")


def test_another_fine_tuning_recipe_starts_from_the_pretrained_actors_of_another_campaign(tmp_path):
    """--pretrained-in: no pretraining runs, the zero-shot score is taken over, the fine-tune starts from the other
    campaign's actor with the hyperparameter given over the recipe's, and the other campaign is not written."""
    tool = load_tool("disk_ppo")
    commands = []
    tool.dpr = lambda *arguments: commands.append(arguments)
    source = tmp_path / "disk-ppo" / "navigation" / "seed-1"
    (source / "pretrain").mkdir(parents=True)
    (source / "pretrain" / "model.zip").write_bytes(b"")
    write_evaluation(source / "zero_shot_validation.json", 30.0)
    before = sorted(p.name for p in source.rglob("*"))
    args = run_args(
        out=tmp_path / "variant",
        finetune_hyperparam=["learning_rate=3e-4"],
        finetune_temperature=3.0,
        pretrained_in=tmp_path / "disk-ppo",
    )
    tool.run("navigation", 1, args)
    finetune, _ = commands  # the fine-tune and its validation; the pretraining and zero-shot are the other campaign's
    assert finetune[0] == "finetune"
    assert finetune[finetune.index("--from") + 1] == str(source / "pretrain" / "model.zip")
    hyper = [finetune[i + 1] for i, word in enumerate(finetune) if word == "--hyperparam"]
    assert hyper[-1] == "learning_rate=3e-4" and "gamma=0.941" in hyper  # given last: it wins over the recipe's
    assert finetune[finetune.index("--exploration-temperature") + 1] == "3.0"
    assert finetune[finetune.index("--out") + 1] == str(tmp_path / "variant" / "navigation" / "seed-1" / "finetune")
    assert (tmp_path / "variant" / "navigation" / "seed-1" / "zero_shot_validation.json").is_file()
    assert sorted(p.name for p in source.rglob("*")) == before
    with pytest.raises(SystemExit, match="--pretrained-in"):
        tool.run("navigation", 2, args)  # seed 2 was never pretrained there


def test_pretraining_on_a_variant_of_the_task_changes_its_experience_only(tmp_path):
    """--pretrain-env-kwarg reaches the pretraining as a training-env kwarg, --pretrain-hyperparam as a hyperparameter;
    the evaluations and the fine-tune run the task as it is, with their own hyperparameters."""
    tool = load_tool("disk_ppo")
    commands = []
    tool.dpr = lambda *arguments: commands.append(arguments)
    given = dict(pretrain_env_kwarg=["n_robots=16"], pretrain_hyperparam=["ent_coef=0.01"])
    tool.run("navigation", 0, run_args(out=tmp_path, **given))
    train, zero_shot, finetune, validation = commands
    assert train[train.index("--training-env-kwarg") + 1] == "n_robots=16"
    assert train[train.index("--hyperparam") + 1] == "ent_coef=0.01"
    assert all("n_robots=16" not in command for command in (zero_shot, finetune, validation))
    assert "ent_coef=0.01" not in finetune
    commands.clear()
    tool.run("gate", 0, run_args(out=tmp_path, pretrain_env_kwarg=["gate_width=250"]))
    kwargs = [commands[0][i + 1] for i, word in enumerate(commands[0]) if word == "--training-env-kwarg"]
    assert kwargs == ["gate_width=200", "gate_width=250"]  # the task's, then the one given, which wins


def stage_timesteps(tmp_path, stage: str, task: str, **given) -> int:
    """The ``--timesteps`` that the tool's run of ``task`` gives its ``stage`` (``train`` or ``finetune``)."""
    tool = load_tool("disk_ppo")
    commands = []
    tool.dpr = lambda *arguments: commands.append(arguments)
    tool.run(task, 0, run_args(out=tmp_path / stage / task / str(given), **given))
    command = next(command for command in commands if command[0] == stage)
    return int(command[command.index("--timesteps") + 1])


def test_gate_pretrains_twice_as_long_unless_the_steps_are_given(tmp_path):
    def pretrain_steps(task, **given):
        return stage_timesteps(tmp_path, "train", task, finetune_steps=0, **given)

    assert pretrain_steps("gate", pretrain_steps=None) == 1_200_000
    assert pretrain_steps("navigation", pretrain_steps=None) == 600_000
    assert pretrain_steps("gate", pretrain_steps=10) == 10
    assert pretrain_steps("gate", pretrain_steps=0) == 0  # given, so passed on (dpr train judges it), not replaced


def test_gate_fine_tunes_three_times_as_long_unless_the_steps_are_given(tmp_path):
    def finetune_steps(task, **given):
        return stage_timesteps(tmp_path, "finetune", task, **given)

    assert finetune_steps("gate", finetune_steps=None) == 300_000
    assert finetune_steps("navigation", finetune_steps=None) == 100_000
    assert finetune_steps("gate", finetune_steps=10) == 10


def test_gate_fine_tunes_in_two_rounds_the_second_from_the_first_ones_averaged_actor(tmp_path):
    tool = load_tool("disk_ppo")
    commands = []
    tool.dpr = lambda *arguments: commands.append(arguments)
    tool.run("gate", 0, run_args(out=tmp_path, finetune_rounds=None))
    _, _, first, first_validation, second, second_validation = commands
    run = tmp_path / "gate" / "seed-0"
    assert second[second.index("--from") + 1] == str(run / "finetune" / "averaged_model.zip")
    assert second[second.index("--out") + 1] == str(run / "finetune-2")
    assert second_validation[second_validation.index("--policy") + 1] == str(run / "finetune-2" / "averaged_model.zip")
    assert second_validation[second_validation.index("--json") + 1] == str(run / "finetuned-2_validation.json")
    assert first_validation[first_validation.index("--json") + 1] == str(run / "finetuned_validation.json")
    commands.clear()
    tool.run("navigation", 0, run_args(out=tmp_path, finetune_rounds=None))
    assert [command[0] for command in commands] == ["train", "evaluate", "finetune", "evaluate"]


def test_zero_fine_tuning_rounds_is_refused_before_any_work(monkeypatch, tmp_path, capsys):
    tool = load_tool("disk_ppo")
    tool.dpr = pytest.fail
    monkeypatch.setattr("sys.argv", ["disk_ppo.py", "--finetune-rounds", "0", "--out", str(tmp_path / "campaign")])
    with pytest.raises(SystemExit) as usage_error:
        tool.main()
    assert usage_error.value.code == 2 and "--finetune-rounds: expected 1 or more" in capsys.readouterr().err
    assert not (tmp_path / "campaign").exists()
