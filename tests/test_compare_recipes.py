"""tools/compare_recipes.py: two recipes' validation IQMs, task by task, and the adoption rule."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers import load_tool

from dpr.rl.statistics import iqm

RECORDS = Path(__file__).resolve().parents[1] / "docs" / "results"


@pytest.fixture(scope="module")
def tool():
    return load_tool("compare_recipes")


def _copy_validation(record: str, dest: Path, tasks, scale: float = 1.0) -> Path:
    """A run folder holding ``record``'s validation evaluations of ``tasks``, every displacement times ``scale``."""
    (dest / "eval" / "validation").mkdir(parents=True)
    (dest / "eval" / "test").mkdir()  # never read: its files would break the tool if they were
    (dest / "eval" / "test" / "navigation-bc-ppo-seed0.json").write_text("not json")
    for path in (RECORDS / record / "eval" / "validation").glob("*.json"):
        if path.name.split("-")[0] in tasks:
            payload = json.loads(path.read_text())
            for episode in payload["episodes"]:
                episode["projected_displacement"] *= scale
            (dest / "eval" / "validation" / path.name).write_text(json.dumps(payload))
    return dest


def test_the_rule_is_the_mean_of_the_per_task_iqm_ratios(tool, tmp_path, capsys):
    tasks = ["navigation", "gate", "unresponsive", "manipulation"]
    current = _copy_validation("full", tmp_path / "current", tasks)
    better = _copy_validation("full", tmp_path / "better", tasks, scale=1.1)
    rows, mean = tool.compare(current, better, tasks, "bc-ppo")
    assert {(row["task"], row["method"]) for row in rows} == {(t, m) for t in tasks for m in ("bc", "bc-ppo", "ppo")}
    assert all(row["runs"] == (3, 3) and row["ratio"] == pytest.approx(1.1) for row in rows)
    assert mean == pytest.approx(1.1)
    files = sorted((current / "eval" / "validation").glob("navigation-bc-ppo-seed*.json"))
    values = np.concatenate(
        [[e["projected_displacement"] for e in json.loads(f.read_text())["episodes"]] for f in files]
    )
    row = next(row for row in rows if row["task"] == "navigation" and row["method"] == "bc-ppo")
    assert row["iqm"][0] == pytest.approx(float(iqm(values)))
    assert tool.main([str(better), str(current)]) == 0
    assert "-> keep the current recipe" in capsys.readouterr().out  # 1/1.1 < 1


def test_the_records_compare_and_no_decision_comes_from_unfinished_tasks(tool, tmp_path, capsys):
    """Each record against the one before it gives the ratio RESULTS.md quotes for its adoption; a candidate with
    one task finished, or a task with fewer runs, gets its rows and no verdict."""
    tasks = ["navigation", "gate", "unresponsive", "manipulation"]
    _, mean = tool.compare(RECORDS / "full-hold10", RECORDS / "full", tasks, "bc-ppo")
    assert mean == pytest.approx(1.065, abs=0.001)
    _, mean = tool.compare(RECORDS / "full", RECORDS / "full-bins", tasks, "bc-ppo")
    assert mean == pytest.approx(1.202, abs=0.001)
    _, mean = tool.compare(RECORDS / "full-bins", RECORDS / "full-ft600", tasks, "bc-ppo")
    assert mean == pytest.approx(1.060, abs=0.001)
    _, mean = tool.compare(RECORDS / "full-ft600", RECORDS / "full-swarm", tasks, "bc-ppo")
    assert mean == pytest.approx(1.205, abs=0.001)
    _, mean = tool.compare(RECORDS / "full-swarm", RECORDS / "full-lr3e4", tasks, "bc-ppo")
    assert mean == pytest.approx(1.032, abs=0.001)
    partial = _copy_validation("full", tmp_path / "partial", ["navigation"])
    assert tool.main([str(RECORDS / "full"), str(partial)]) == 0
    out = capsys.readouterr().out
    assert "| navigation | bc-ppo | 3 / 3 |" in out and "| gate |" not in out and "no decision yet" in out
    # every task present, but one of them with two of its three runs: still no verdict
    tasks_in_progress = _copy_validation("full", tmp_path / "in-progress", tasks, scale=1.1)
    (tasks_in_progress / "eval" / "validation" / "gate-bc-ppo-seed2.json").unlink()
    rows, mean = tool.compare(RECORDS / "full", tasks_in_progress, tasks, "bc-ppo")
    assert mean is None and next(r for r in rows if r["task"] == "gate" and r["method"] == "bc-ppo")["runs"] == (3, 2)
    assert tool.main([str(RECORDS / "full"), str(tasks_in_progress)]) == 0
    assert "no decision yet" in capsys.readouterr().out


def test_folders_that_cannot_be_compared_are_refused(tool, tmp_path, capsys):
    other = _copy_validation("full", tmp_path / "other", ["navigation"])
    for seed in range(3):
        path = other / "eval" / "validation" / f"navigation-bc-seed{seed}.json"
        payload = json.loads(path.read_text())
        payload["seeds"] = [s + 1000 for s in payload["seeds"]]
        path.write_text(json.dumps(payload))
        if seed == 0:  # the runs of one method disagree
            with pytest.raises(ValueError, match="navigation-bc-seed1.json: scored on other validation seeds"):
                tool.compare(RECORDS / "full", other, ["navigation"], "bc-ppo")
    with pytest.raises(ValueError, match="navigation-bc: the two folders used different validation seeds"):
        tool.compare(RECORDS / "full", other, ["navigation"], "bc-ppo")
    shutil.rmtree(other / "eval" / "validation")
    with pytest.raises(SystemExit):
        tool.main([str(RECORDS / "full"), str(other)])
    assert "no eval/validation folder" in capsys.readouterr().err


def test_a_candidate_run_task_by_task_is_judged_across_its_folders(tool, tmp_path, capsys):
    """Tasks run side by side, each in a folder of its own, compare as one folder holding them all; a task in two
    folders is refused."""
    tasks = ["navigation", "gate", "unresponsive", "manipulation"]
    whole = _copy_validation("full-bins", tmp_path / "whole", tasks)
    per_task = [_copy_validation("full-bins", tmp_path / task, [task]) for task in tasks]
    assert tool.compare(RECORDS / "full", per_task, tasks, "bc-ppo") == tool.compare(
        RECORDS / "full", whole, tasks, "bc-ppo"
    )
    assert tool.main([str(RECORDS / "full"), *map(str, per_task)]) == 0
    assert "mean bc-ppo ratio over 4 tasks: 1.202 -> adopt the candidate" in capsys.readouterr().out
    with pytest.raises(ValueError, match=r"gate: runs in both .*whole and .*gate"):
        tool.compare(RECORDS / "full", [whole, per_task[1]], tasks, "bc-ppo")
