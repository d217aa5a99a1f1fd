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


def campaign(tmp_path, validation, test, stage="finetune"):
    for seed, (val, tst) in enumerate(zip(validation, test)):
        folder = tmp_path / "unresponsive" / f"seed-{seed}"
        name = "finetuned_validation.json" if stage == "finetune" else "zero_shot_validation.json"
        write_evaluation(folder / name, val)
        (folder / stage).mkdir(parents=True)
        (folder / stage / "model.zip").write_bytes(b"")
        write_evaluation(folder / f"test_{stage}.json", tst)
    write_evaluation(tmp_path / "unresponsive" / "wave_test.json", 20.0)


def report(tmp_path, capsys, test=True):
    tool = load_tool("disk_ppo")
    tool.dpr = pytest.fail  # every evaluation is on disk: nothing may run
    tool.report(argparse.Namespace(tasks=["unresponsive"], out=tmp_path, test=test))
    return capsys.readouterr().out


def test_report_ships_the_validation_median_run_and_scores_the_median_test_run(tmp_path, capsys):
    campaign(tmp_path, validation=[44.0, 41.0, 42.0], test=[30.0, 22.0, 26.0])
    out = report(tmp_path, capsys)
    assert "the one to ship: seed-2 (finetune)" in out
    assert "seed-0 (" in out and "150%" in out  # each run's test median against the wave's 20
    assert "median of 3 runs on the test seeds: 130% of the paddle wave" in out


def test_report_does_not_test_runs_at_different_stages(tmp_path, capsys):
    campaign(tmp_path, validation=[44.0, 41.0], test=[30.0, 22.0])
    write_evaluation(tmp_path / "unresponsive" / "seed-2" / "zero_shot_validation.json", 10.0)
    out = report(tmp_path, capsys)
    assert "not tested, its runs are at different stages (finetune, pretrain)" in out
    assert "median of" not in out
