"""tools/merge_runs.py: per-task pipeline runs merged into one record that the pipeline resumes as finished."""

import json

import pytest
import yaml
from helpers import PIPELINE, load_tool, run_tiny

from dpr.rl.pipeline import run_pipeline
from dpr.rl.pipeline_config import PipelineConfig


@pytest.fixture(scope="module")
def tool():
    return load_tool("merge_runs")


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Two tiny pipeline runs of the same settings, one on Gate, one on Navigation (listed in that order)."""
    root = tmp_path_factory.mktemp("runs")
    for task in ("gate", "navigation"):
        run_tiny({**PIPELINE, "anchor": False, "tasks": [task]}, root / task)
    return root / "gate", root / "navigation"


def test_the_merged_record_holds_every_task_and_resumes_as_finished(tool, runs, tmp_path, capsys):
    out = tmp_path / "record"
    assert tool.main([str(out), *map(str, runs)]) == 0
    saved = yaml.safe_load((out / "pipeline.yaml").read_text())
    assert saved["config"]["tasks"] == ["navigation", "gate"]  # the envs' order, not the runs'
    assert saved["merged_from"] == {"navigation": "navigation", "gate": "gate"}
    choices = yaml.safe_load((out / "choices.yaml").read_text())
    for run in runs:
        assert set(yaml.safe_load((run / "choices.yaml").read_text())).issubset(choices)
    for path in runs[1].joinpath("eval").rglob("navigation-*.json"):
        assert (out / path.relative_to(runs[1])).read_bytes() == path.read_bytes()
    assert sorted(p.name for p in (out / "models").iterdir()) == sorted(
        f"{task}-{method}.zip" for task in ("gate", "navigation") for method in ("bc", "bc-ppo", "ppo")
    )
    table = (out / "report" / "results.md").read_text()
    assert "| Navigation | wave |" in table and "| Gate | bc-ppo |" in table
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    lines = []
    config = PipelineConfig(**{**PIPELINE, "anchor": False, "tasks": ["navigation", "gate"]})
    run_pipeline(config, out, show_progress=False, log=lines.append)
    assert all("skipped" in line or "done in" in line for line in lines), lines
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    tool.merge(tmp_path / "again", [out])  # a merged record merged again names the folders its tasks ran in
    assert yaml.safe_load((tmp_path / "again" / "pipeline.yaml").read_text())["merged_from"] == saved["merged_from"]


def test_runs_that_cannot_be_merged_are_refused_before_writing(tool, runs, tmp_path, capsys):
    gate, navigation = runs
    cases = [
        ([gate, gate], "gate: run in both"),
        ([gate, tmp_path], "no pipeline.yaml"),
    ]
    other = tmp_path / "other"
    other.mkdir()
    saved = yaml.safe_load((navigation / "pipeline.yaml").read_text())
    saved["config"]["episodes"] = 3
    (other / "pipeline.yaml").write_text(yaml.safe_dump(saved))
    cases.append(([gate, other], "other settings than .* \\(episodes\\); only the tasks may differ"))
    unfinished = tmp_path / "unfinished"
    unfinished.mkdir()
    (unfinished / "pipeline.yaml").write_bytes((navigation / "pipeline.yaml").read_bytes())
    cases.append(([gate, unfinished], "navigation is not finished in .*unfinished: missing"))
    for sources, message in cases:
        with pytest.raises(ValueError, match=message):
            tool.merge(tmp_path / "record", sources)
        assert not (tmp_path / "record").exists()
    (tmp_path / "record").mkdir()
    with pytest.raises(SystemExit):
        tool.main([str(tmp_path / "record"), str(gate)])
    assert "exists; the merged record goes into a new folder" in capsys.readouterr().err
    assert json.loads(next((gate / "eval" / "test").glob("gate-wave.json")).read_text())["seeds"] == [100]
