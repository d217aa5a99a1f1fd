"""dpr.evaluation.compare and `dpr compare`: two recipes' validation IQMs, task by task, and the adoption rule."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers import run_cli

from dpr.checks import ParameterError
from dpr.evaluation.compare import compare, validation_runs
from dpr.evaluation.statistics import iqm

RECORDS = Path(__file__).resolve().parents[1] / "docs" / "results"
HEADLINE = RECORDS / "full-lr3e4"  # the headline record: three runs of each method on the validation seeds
PARTIAL = RECORDS / "gate-v1-partial"  # a run folder with validation evaluations (its teacher's), but no runs yet
TASKS = ["navigation", "gate", "unresponsive", "manipulation"]


def _copy_validation(record: str, dest: Path, tasks, scale: float = 1.0) -> Path:
    """A run folder holding ``record``'s validation evaluations of ``tasks``, every displacement times ``scale``."""
    (dest / "eval" / "validation").mkdir(parents=True)
    (dest / "eval" / "test").mkdir()  # never read: its files would break the comparison if they were
    (dest / "eval" / "test" / "navigation-bc-ppo-seed0.json").write_text("not json")
    for path in (RECORDS / record / "eval" / "validation").glob("*.json"):
        if path.name.split("-")[0] in tasks:
            payload = json.loads(path.read_text())
            for episode in payload["episodes"]:
                episode["projected_displacement"] *= scale
            (dest / "eval" / "validation" / path.name).write_text(json.dumps(payload))
    return dest


def test_the_rule_is_the_mean_of_the_per_task_iqm_ratios(tmp_path, capsys):
    current = _copy_validation("full-lr3e4", tmp_path / "current", TASKS)
    better = _copy_validation("full-lr3e4", tmp_path / "better", TASKS, scale=1.1)
    rows, mean = compare(current, better, TASKS, "bc-ppo")
    assert {(row["task"], row["method"]) for row in rows} == {(t, m) for t in TASKS for m in ("bc", "bc-ppo", "ppo")}
    assert all(row["runs"] == (3, 3) and row["ratio"] == pytest.approx(1.1) for row in rows)
    assert mean == pytest.approx(1.1)
    assert compare(current, better) == (rows, mean)  # every task and bc-ppo by default
    files = sorted((current / "eval" / "validation").glob("navigation-bc-ppo-seed*.json"))
    values = np.concatenate(
        [[e["projected_displacement"] for e in json.loads(f.read_text())["episodes"]] for f in files]
    )
    row = next(row for row in rows if row["task"] == "navigation" and row["method"] == "bc-ppo")
    assert row["iqm"][0] == pytest.approx(float(iqm(values)))
    assert run_cli(["compare", str(better), str(current)]) == 0
    out = capsys.readouterr().out
    assert out.startswith(
        "| task | method | runs | IQM current | IQM candidate | ratio |\n|---|---|---|---:|---:|---:|\n"
    )
    assert "-> keep the current recipe" in out  # 1/1.1 < 1


def test_no_decision_comes_from_unfinished_tasks(tmp_path, capsys):
    """A candidate with one task finished, or a task with fewer runs, gets its rows and no verdict."""
    assert compare(HEADLINE, HEADLINE, TASKS, "bc-ppo")[1] == pytest.approx(1.0)
    partial = _copy_validation("full-lr3e4", tmp_path / "partial", ["navigation"])
    assert run_cli(["compare", str(HEADLINE), str(partial)]) == 0
    out = capsys.readouterr().out
    assert "| navigation | bc-ppo | 3 / 3 |" in out and "| gate |" not in out and "no decision yet" in out
    # one task asked for, and finished: a verdict on it alone
    assert run_cli(["compare", str(HEADLINE), str(partial), "--tasks", "navigation", "--method", "bc"]) == 0
    assert "mean bc ratio over 1 tasks: 1.000 -> keep the current recipe" in capsys.readouterr().out
    # every task present, but one of them with two of its three runs: still no verdict
    tasks_in_progress = _copy_validation("full-lr3e4", tmp_path / "in-progress", TASKS, scale=1.1)
    (tasks_in_progress / "eval" / "validation" / "gate-bc-ppo-seed2.json").unlink()
    rows, mean = compare(HEADLINE, tasks_in_progress, TASKS, "bc-ppo")
    assert mean is None and next(r for r in rows if r["task"] == "gate" and r["method"] == "bc-ppo")["runs"] == (3, 2)
    assert run_cli(["compare", str(HEADLINE), str(tasks_in_progress)]) == 0
    assert "no decision yet" in capsys.readouterr().out


def test_folders_that_cannot_be_compared_are_refused(tmp_path, capsys):
    other = _copy_validation("full-lr3e4", tmp_path / "other", ["navigation"])
    for seed in range(3):
        path = other / "eval" / "validation" / f"navigation-bc-seed{seed}.json"
        payload = json.loads(path.read_text())
        payload["seeds"] = [s + 1000 for s in payload["seeds"]]
        path.write_text(json.dumps(payload))
        if seed == 0:  # the runs of one method disagree
            with pytest.raises(ValueError, match="navigation-bc-seed1.json: scored otherwise than .*validation seeds"):
                compare(HEADLINE, other, ["navigation"], "bc-ppo")
    with pytest.raises(
        ParameterError, match="navigation-bc: the two folders scored their runs differently .validation seeds"
    ):
        compare(HEADLINE, other, ["navigation"], "bc-ppo")
    assert run_cli(["compare", str(HEADLINE), str(other)]) == 2
    assert (
        "CANDIDATE: navigation-bc: the two folders scored their runs differently (validation seeds"
        in capsys.readouterr().err
    )
    shutil.rmtree(other / "eval" / "validation")
    with pytest.raises(ParameterError, match="no eval/validation folder") as error:
        compare(HEADLINE, other, ["navigation"], "bc-ppo")
    assert error.value.parameter == "candidate"
    assert run_cli(["compare", str(HEADLINE), str(other)]) == 2
    assert f"dpr compare: error: CANDIDATE: {other}: no eval/validation folder" in capsys.readouterr().err
    assert run_cli(["compare", str(other), str(HEADLINE)]) == 2
    assert f"error: CURRENT: {other}: no eval/validation folder" in capsys.readouterr().err


@pytest.mark.parametrize(
    "argv, message",
    [
        (["nowhere", "docs/results/full-lr3e4"], "CURRENT: nowhere: no such folder"),
        (["docs/results/full-lr3e4", "docs/results/gate-v1-partial", "nowhere"], "CANDIDATE: nowhere: no such folder"),
        (
            ["docs/results/full-lr3e4", "docs/results/gate-v1-partial", "docs/results/gate-v1-partial/"],
            "CANDIDATE: docs/results/gate-v1-partial: given twice",
        ),
        (["docs/results/full-lr3e4", "docs/results/gate-v1-partial", "--tasks", "swimming"], "--tasks: invalid choice"),
        (["docs/results/full-lr3e4"], "the following arguments are required: CANDIDATE"),
    ],
)
def test_bad_input_is_refused_naming_its_argument(argv, message, capsys, monkeypatch):
    monkeypatch.chdir(Path(__file__).resolve().parents[1])
    assert run_cli(["compare", *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("usage: dpr compare") and message in err


def test_the_library_refuses_bad_arguments_before_reading_any_run():
    with pytest.raises(ParameterError, match="given twice") as error:
        compare(HEADLINE, [PARTIAL, PARTIAL])
    assert error.value.parameter == "candidate"
    with pytest.raises(ParameterError, match="swimming") as error:
        compare(HEADLINE, PARTIAL, ["navigation", "swimming"])
    assert error.value.parameter == "tasks"
    with pytest.raises(ParameterError, match="each task must appear once"):
        compare(HEADLINE, PARTIAL, ["gate", "gate"])
    with pytest.raises(ParameterError, match="at least one run folder"):
        compare(HEADLINE, [])


def test_help_states_the_rule_and_reads_only_validation_seeds(capsys):
    assert run_cli(["compare", "--help"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "usage: dpr compare [-h]" in out and "[--tasks" in out and "CURRENT CANDIDATE [CANDIDATE ...]" in out
    assert "mean over --tasks of the --method ratios is above 1" in out
    assert "Only validation evaluations are read, never test ones" in out
    assert "(default bc-ppo)" in out


def test_a_candidate_run_task_by_task_is_judged_across_its_folders(tmp_path, capsys):
    """Tasks run side by side, each in a folder of its own, compare as one folder holding them all; a task in two
    folders is refused."""
    whole = _copy_validation("full-lr3e4", tmp_path / "whole", TASKS, scale=1.1)
    per_task = [_copy_validation("full-lr3e4", tmp_path / task, [task], scale=1.1) for task in TASKS]
    assert compare(HEADLINE, per_task, TASKS, "bc-ppo") == compare(HEADLINE, whole, TASKS, "bc-ppo")
    assert validation_runs(*per_task).keys() == validation_runs(whole).keys()
    assert run_cli(["compare", str(HEADLINE), *map(str, per_task)]) == 0
    assert "mean bc-ppo ratio over 4 tasks: 1.100 -> adopt the candidate" in capsys.readouterr().out
    with pytest.raises(ParameterError, match=r"gate: runs in both .*whole and .*gate"):
        compare(HEADLINE, [whole, per_task[1]], TASKS, "bc-ppo")
    assert run_cli(["compare", str(HEADLINE), str(whole), str(per_task[1])]) == 2
    assert "CANDIDATE: gate: runs in both" in capsys.readouterr().err


@pytest.mark.parametrize(
    "change, named",
    [
        ({"steps": 2000}, "steps (episode length) 2500 and 2000"),
        ({"env_ids": ["dpr/Navigation-v1"]}, "env id (task version) ['dpr/Navigation-v0'] and ['dpr/Navigation-v1']"),
        ({"env_kwargs": {"n_robots": 16}}, "N (n_robots) 9 and 16"),
        ({"env_kwargs": {"robot_model": "disk"}}, "robot model 'paddle' and 'disk'"),
        ({"env_kwargs": {"start_radius": 300.0}}, "env kwargs {} and {'start_radius': 300.0}"),
    ],
)
def test_runs_scored_differently_are_refused_naming_what_differs(tmp_path, capsys, change, named):
    """Not only other validation seeds: another episode length, env version, swarm size, robot model or task
    kwarg scores other episodes, and the two folders' IQMs are then not comparable."""
    other = _copy_validation("full-lr3e4", tmp_path / "other", ["navigation"])
    for path in (other / "eval" / "validation").glob("navigation-*-seed*.json"):
        payload = json.loads(path.read_text())
        for key, value in change.items():
            payload[key] = {**payload[key], **value} if isinstance(value, dict) else value
        path.write_text(json.dumps(payload))
    with pytest.raises(ParameterError, match="the two folders scored their runs differently") as error:
        compare(HEADLINE, other, ["navigation"], "bc-ppo")
    assert named in str(error.value)
    assert run_cli(["compare", str(HEADLINE), str(other), "--tasks", "navigation"]) == 2
    assert named in capsys.readouterr().err


def test_the_policys_own_env_kwargs_may_differ(tmp_path):
    """A candidate that decides at another rate or sees other observations is scored on the same episodes."""
    other = _copy_validation("full-lr3e4", tmp_path / "other", ["navigation"])
    for path in (other / "eval" / "validation").glob("navigation-*-seed*.json"):
        payload = json.loads(path.read_text())
        payload["env_kwargs"] = {**payload["env_kwargs"], "action_repeat": 8, "obs_last_action": False}
        path.write_text(json.dumps(payload))
    rows, mean = compare(HEADLINE, other, ["navigation"], "bc-ppo")
    assert mean == pytest.approx(1.0)
