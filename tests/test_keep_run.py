"""tools/keep_run.py: what a pipeline run folder needs to resume, kept small, resumes training only what is missing."""

import json
import shutil

import pytest
import yaml
from helpers import (
    THREE_SEEDS,
    assert_same_policy,
    copy_without_run,
    load_tool,
    run_tiny,
    stopped_after_snapshots,
    trained_runs,
)


@pytest.fixture(scope="module")
def tool():
    return load_tool("keep_run")


@pytest.fixture
def finished(three_seeds):
    """A tiny finished pipeline run with three training seeds (conftest's, shared: copied before any change)."""
    return three_seeds[0]


def test_a_finished_run_keeps_no_training_run_and_resumes_as_finished(tool, finished, tmp_path, capsys):
    kept = tmp_path / "kept"
    assert tool.main([str(finished), str(kept)]) == 0
    assert "training runs' models still needed: none" in capsys.readouterr().out
    assert not list((kept / "models").glob("*-seed*.zip")) and not (kept / "datasets").exists()
    assert sorted(p.name for p in (kept / "models").iterdir()) == sorted(
        p.name for p in (finished / "models").iterdir() if "-seed" not in p.name
    )
    _, lines = run_tiny(THREE_SEEDS, kept)
    assert "dpr pipeline: navigation: its canonical models and test evaluations exist, skipped" in lines
    assert not trained_runs(lines)


def test_a_run_stopped_midway_keeps_the_models_it_still_needs_and_resumes_without_training(
    tool, finished, tmp_path, capsys
):
    """Stopped before the fine-tuned runs were chosen from and before one run from scratch was tested: those runs'
    models are kept (slim), and the kept folder resumes to the same canonical model and test scores, training
    nothing."""
    run = tmp_path / "run"
    shutil.copytree(finished, run)
    (run / "models" / "navigation-bc-ppo.zip").unlink()
    choices = yaml.safe_load((run / "choices.yaml").read_text())
    del choices["navigation-bc-ppo"]
    (run / "choices.yaml").write_text(yaml.safe_dump(choices))
    (run / "eval" / "test" / "navigation-ppo-seed1.json").unlink()
    kept = tmp_path / "kept"
    assert tool.main([str(run), str(kept)]) == 0
    needed = ["navigation-bc-ppo-seed0.zip", "navigation-bc-ppo-seed1.zip", "navigation-bc-ppo-seed2.zip"]
    needed.append("navigation-ppo-seed1.zip")
    assert sorted(p.name for p in (kept / "models").glob("*-seed*.zip")) == needed
    assert (kept / "models" / needed[0]).stat().st_size < 0.5 * (run / "models" / needed[0]).stat().st_size
    _, lines = run_tiny(THREE_SEEDS, kept)
    assert not trained_runs(lines)
    assert_same_policy(kept / "models" / "navigation-bc-ppo.zip", finished / "models" / "navigation-bc-ppo.zip")
    retested, tested = (
        json.loads((folder / "eval" / "test" / "navigation-ppo-seed1.json").read_text())["episodes"]
        for folder in (kept, finished)
    )
    assert [e["projected_displacement"] for e in retested] == [e["projected_displacement"] for e in tested]


def test_a_clone_is_kept_while_its_fine_tuning_is_still_to_train(tool, finished, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(finished, run)
    for name in ("models/navigation-bc-ppo-seed2.zip", "eval/validation/navigation-bc-ppo-seed2.json"):
        (run / name).unlink()
    (run / "models" / "navigation-bc-ppo.zip").unlink()
    kept = tmp_path / "kept"
    assert tool.main([str(run), str(kept)]) == 0
    assert "navigation-bc-seed2.zip" in {p.name for p in (kept / "models").iterdir()}
    assert "navigation-bc-seed1.zip" not in {p.name for p in (kept / "models").iterdir()}


def test_keep_run_refuses_an_existing_folder_and_a_folder_that_is_not_a_run(tool, finished, tmp_path, capsys):
    (tmp_path / "taken").mkdir()
    with pytest.raises(SystemExit):
        tool.main([str(finished), str(tmp_path / "taken")])
    assert "taken exists; what is kept goes into a new folder" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        tool.main([str(tmp_path), str(tmp_path / "new")])
    assert "no pipeline.yaml; expected a `dpr pipeline` run folder" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()


def test_a_training_run_stopped_part_way_is_kept_and_resumes_from_its_snapshot(tool, finished, tmp_path):
    """A run killed mid-training keeps its snapshot (not its run folder's other files); the kept folder resumes it
    there and ends with the uninterrupted run's model."""
    run = copy_without_run(finished, tmp_path / "run", "navigation-ppo-seed1")
    with stopped_after_snapshots():
        run_tiny(THREE_SEEDS, run)
    snapshot = run / "runs" / "navigation-ppo-seed1" / "resume"
    snapshot.rename(snapshot.with_name("resume.new"))  # as if stopped while a snapshot replaced the last
    kept = tmp_path / "kept"
    assert tool.main([str(run), str(kept)]) == 0
    assert sorted(p.name for p in (kept / "runs" / "navigation-ppo-seed1").iterdir()) == ["config.yaml", "resume"]
    _, lines = run_tiny(THREE_SEEDS, kept)
    assert trained_runs(lines) == ["ppo, seed 1"] and any("resumed at step" in line for line in lines)
    retested, tested = (
        json.loads((folder / "eval" / "test" / "navigation-ppo-seed1.json").read_text())["episodes"]
        for folder in (kept, finished)
    )
    for episode in retested + tested:
        del episode["policy"]  # the model's path, in one folder or the other
    assert retested == tested


def test_a_run_stopped_by_ctrl_c_is_kept_though_it_saved_a_model(tool, finished, tmp_path):
    """Ctrl-C saves the model as it is (config.yaml: interrupted) beside the snapshot; the run is still stopped."""
    import shutil

    import yaml

    run = copy_without_run(finished, tmp_path / "run", "navigation-ppo-seed1")
    with stopped_after_snapshots():
        run_tiny(THREE_SEEDS, run)
    stopped = run / "runs" / "navigation-ppo-seed1"
    shutil.copyfile(finished / "models" / "navigation-ppo-seed0.zip", stopped / "model.zip")
    record = yaml.safe_load((stopped / "config.yaml").read_text()) if (stopped / "config.yaml").exists() else {}
    (stopped / "config.yaml").write_text(yaml.safe_dump({**(record or {}), "interrupted": True}))
    assert tool.main([str(run), str(tmp_path / "kept")]) == 0
    assert (tmp_path / "kept" / "runs" / "navigation-ppo-seed1" / "resume").is_dir()
