"""tools/start_candidate.py: a candidate's run folder for one task, sharing a record's teacher and kept methods."""

import dataclasses
from pathlib import Path

import pytest
import yaml
from helpers import load_tool

from dpr.rl.pipeline_config import saved_settings
from dpr.rl.run_folder import read_run_settings

ROOT = Path(__file__).resolve().parents[1]
RECORD = ROOT / "docs" / "results" / "full-lr3e4"
FLAGS = ["--preset", "full", "--tasks", "gate", "--env-id", "dpr/Gate-v0", "--scratch-physics-discount"]


@pytest.fixture(scope="module")
def tool():
    return load_tool("start_candidate")


def test_the_candidate_shares_the_kept_methods_and_resumes_with_its_flags(tool, tmp_path):
    out = tmp_path / "cand-gate"
    config = tool.start(RECORD, out, ["bc", "bc-ppo"], FLAGS, ROOT / "models")
    settings = saved_settings(read_run_settings(out)["config"])
    assert settings == dataclasses.asdict(config)  # `dpr pipeline <FLAGS> --out` resumes it, and only those flags
    assert config.tasks == ["gate"] and config.scratch_physics_discount
    record = saved_settings(read_run_settings(RECORD)["config"])
    differ = {name for name, value in settings.items() if record[name] != value}
    assert differ == {"tasks", "scratch_physics_discount"}
    choices = yaml.safe_load((out / "choices.yaml").read_text())
    assert sorted(choices) == ["gate-bc", "gate-bc-ppo", "gate-teacher"]
    assert choices["gate-bc-ppo"] == yaml.safe_load((RECORD / "choices.yaml").read_text())["gate-bc-ppo"]
    for split in ("validation", "test"):
        names = {path.name for path in (out / "eval" / split).iterdir()}
        record_names = {path.name for path in (RECORD / "eval" / split).glob("gate-*.json")}
        assert names == {name for name in record_names if not name.startswith("gate-ppo-")}, split  # all but scratch
        assert (out / "eval" / split / "gate-bc-ppo-seed2.json").read_bytes() == (
            RECORD / "eval" / split / "gate-bc-ppo-seed2.json"
        ).read_bytes()
    assert sorted(p.name for p in (out / "models").iterdir()) == ["gate-bc-ppo.zip", "gate-bc.zip"]


@pytest.mark.parametrize(
    "keep, flags, message",
    [
        (["bc"], ["--preset", "full", "--tasks", "gate", "navigation"], "--tasks: one task per candidate folder"),
        (["bc", "sac"], FLAGS, r"--keep: \['sac'\] are not methods of the candidate"),
        (["bc"], ["--preset", "full", "--tasks", "gate"], "--env-id: the record ran gate on dpr/Gate-v0"),
    ],
)
def test_bad_requests_are_refused_before_anything_is_written(tool, tmp_path, keep, flags, message):
    out = tmp_path / "cand"
    with pytest.raises(ValueError, match=message):
        tool.start(RECORD, out, keep, flags, ROOT / "models")
    assert not out.exists()
    with pytest.raises(ValueError, match="--models: .* missing"):
        tool.start(RECORD, out, ["bc"], FLAGS, tmp_path)
    assert not out.exists()
    out.mkdir()
    with pytest.raises(ValueError, match="exists; a candidate starts in a new folder"):
        tool.start(RECORD, out, ["bc"], FLAGS, ROOT / "models")
    assert not any(out.iterdir())


def test_the_command_line_takes_the_pipeline_flags_after_a_double_dash(tool, tmp_path, capsys):
    out = tmp_path / "cand"
    assert tool.main([str(RECORD), str(out), "--keep", "bc", "--models", str(ROOT / "models"), "--", *FLAGS]) == 0
    assert "gate, sharing ['teacher', 'bc']" in capsys.readouterr().out
    assert read_run_settings(out)["config"]["scratch_physics_discount"] is True
    with pytest.raises(SystemExit):
        tool.main([str(RECORD), str(tmp_path / "other"), "--", "--preset", "full", "--tasks", "gate", "navigation"])
    assert "--tasks: one task per candidate folder" in capsys.readouterr().err
