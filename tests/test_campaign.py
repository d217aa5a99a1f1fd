"""Campaigns at any scale: the tiny preset (the full preset's shape at budgets of seconds) gives one report whether
its stages run in this process, in two worker processes or on a local Ray cluster; a run killed at any point resumes
to the same report; two tasks run into one folder at once; settings files; bad input refused before any work."""

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from helpers import PIPELINE, run_cli, run_tiny, tree_hash

from dpr.pipeline.campaign import run_pipeline
from dpr.pipeline.config import PRESETS, load_config, preset_path, read_settings

DPR = [sys.executable, "-m", "dpr.cli"]
ENV = {**os.environ, "SDL_VIDEODRIVER": "dummy", "RAY_AUTH_MODE": "disabled"}


def tables(report: Path, task: str | None = None) -> list[str]:
    """The rows of every table in a report's results.md (only those of ``task``, when given)."""
    rows = [line for line in (report / "results.md").read_text().splitlines() if line.startswith("|")]
    return rows if task is None else [row for row in rows if row.split("|")[1].strip() == task]


def pipeline(*args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run([*DPR, "pipeline", *args], capture_output=True, text=True, env=ENV, timeout=timeout)


@pytest.fixture(scope="session")
def tiny(tmp_path_factory) -> Path:
    """The tiny preset run in this process (one worker): its run folder."""
    out = tmp_path_factory.mktemp("tiny") / "run"
    run_pipeline(load_config(preset="tiny"), out, show_progress=False, log=lambda line: None)
    return out


def test_the_tiny_preset_has_the_full_presets_shape(tiny):
    full, small = load_config(preset="full"), load_config(preset="tiny")
    assert small.tasks == full.tasks and len(small.train_seeds) == 2
    assert small.validation_seeds and small.test_seeds and len(small.teachers()) == 2
    choices = yaml.safe_load((tiny / "choices.yaml").read_text())
    assert {f"{task}-teacher" for task in full.tasks} <= set(choices)
    assert len(tables(tiny / "report")) > 4 * 5


@pytest.mark.parametrize(("backend", "tasks"), [("local", ["all"]), ("ray", ["navigation"])])
def test_two_workers_give_the_same_report_as_one_on_either_backend(tiny, tmp_path, backend, tasks):
    """Every stage runs on one CPU with one torch thread from the same settings, so the stage outputs, and the report
    made of them, do not depend on where they ran (on Ray, one task: a local cluster's start-up is the slow part)."""
    chosen = [] if tasks == ["all"] else ["--tasks", *tasks]
    result = pipeline(
        "--preset", "tiny", *chosen, "--workers", "2", "--backend", backend, "--out", str(tmp_path / "run")
    )
    assert result.returncode == 0, result.stderr[-3000:]
    total = 96 if tasks == ["all"] else 24
    assert f"stages: 0 stored, {total} to build by 2 {backend} workers" in result.stderr
    assert result.stderr.count(f"/{total}] ") == total  # one line per finished stage, with done/total and elapsed
    assert f"[{total}/{total}]" in result.stderr
    task = None if tasks == ["all"] else "Navigation"
    assert tables(tmp_path / "run" / "report", task) == tables(tiny / "report", task)
    evaluations = list((tmp_path / "run" / "eval" / "test").iterdir())
    assert evaluations and all(task is None or path.name.startswith("navigation-") for path in evaluations)
    for evaluation in evaluations:  # bit for bit
        assert (tiny / "eval" / "test" / evaluation.name).read_bytes() == evaluation.read_bytes()


KILLERS = {
    # after the first demonstration is saved: the collection resumes from its work folder
    "demonstrations": "import dpr.datasets.collect as m; original = m.save_record\n"
    "def patched(*a, **k):\n    result = original(*a, **k); kill()\nm.save_record = patched",
    # at the third PPO update of the first RL run
    "training": "from stable_baselines3 import PPO; original = PPO.train; calls = []\n"
    "def patched(self):\n    calls.append(1)\n    if len(calls) == 3: kill()\n    original(self)\nPPO.train = patched",
    # in the second episode of an evaluation, the first one done
    "evaluation": "import dpr.evaluation.scoring as m; original = m.run_episode; calls = []\n"
    "def patched(*a, **k):\n    calls.append(1)\n    if len(calls) == 2: kill()\n    return original(*a, **k)\n"
    "m.run_episode = patched",
}
KILLED_RUN = """
import os, signal, sys
from pathlib import Path
def kill():
    os.kill(os.getpid(), signal.SIGKILL)
{killer}
from dpr.pipeline.campaign import run_pipeline
from dpr.pipeline.config import load_config
run_pipeline(load_config(preset="tiny", tasks=["navigation"]), Path(sys.argv[1]), show_progress=False)
"""


def test_a_run_killed_during_demonstrations_training_and_evaluation_resumes_to_the_same_report(tiny, tmp_path):
    out = tmp_path / "run"
    stored = []
    for point, killer in KILLERS.items():
        killed = subprocess.run(
            [sys.executable, "-c", KILLED_RUN.format(killer=killer), str(out)], env=ENV, capture_output=True, text=True
        )
        assert killed.returncode == -signal.SIGKILL, (point, killed.stderr[-2000:])
        assert any((out / "work").iterdir()), point  # killed inside a stage
        done = sorted(path.name for path in (out / "stages").glob("*/*") if (path / "stage.json").exists())
        assert set(stored) <= set(done), point  # nothing built before the kill is lost
        stored = done
    assert len(stored) > 3
    result = pipeline("--preset", "tiny", "--tasks", "navigation", "--out", str(out))
    assert result.returncode == 0, result.stderr[-3000:]
    (summary,) = [line for line in result.stderr.splitlines() if " stages: " in line]
    assert int(summary.split(" stages: ")[1].split(" stored")[0]) >= 3  # what the killed runs built is used
    assert tables(out / "report", "Navigation") == tables(tiny / "report", "Navigation")


def test_two_tasks_run_into_one_folder_at_the_same_time(tmp_path, monkeypatch):
    """A Gate run joins the folder, and ends, while a Navigation run builds its stages: the Navigation run, which
    ends last, reports both tasks (a report of the tasks it started with would drop Gate's rows)."""
    import dpr.pipeline.campaign as module

    out = tmp_path / "run"
    build_stages = module.run_stages

    def gate_runs_meanwhile(*args, **kwargs):
        monkeypatch.setattr(module, "run_stages", build_stages)
        run_tiny({**PIPELINE, "tasks": ["gate"]}, out)
        build_stages(*args, **kwargs)

    monkeypatch.setattr(module, "run_stages", gate_runs_meanwhile)
    report, _ = run_tiny(PIPELINE, out)
    assert yaml.safe_load((out / "pipeline.yaml").read_text())["config"]["tasks"] == ["navigation", "gate"]
    assert report == out / "report-2"  # the Gate run's report is kept beside it
    assert any(row.startswith("| Gate | bc-ppo |") for row in tables(out / "report"))
    rows = tables(report)
    assert any(row.startswith("| Navigation | bc-ppo |") for row in rows)
    assert any(row.startswith("| Gate | bc-ppo |") for row in rows)


@pytest.mark.parametrize("name", PRESETS)
def test_every_preset_is_a_valid_settings_file(name):
    settings = read_settings(preset_path(name))
    assert load_config(preset=name).tasks == settings["tasks"]


def test_a_run_folders_settings_are_a_config_that_reuses_its_stages(tiny, tmp_path):
    """`--config RUN/pipeline.yaml` runs the same settings, taking RUN's stored stages; an override over it makes a
    candidate that builds only what differs."""
    result = pipeline("--config", str(tiny / "pipeline.yaml"), "--tasks", "navigation", "--out", str(tmp_path / "same"))
    assert result.returncode == 0, result.stderr[-3000:]
    assert "0 to build" in result.stderr and f"reused from {tiny}" in result.stderr
    assert tables(tmp_path / "same" / "report", "Navigation") == tables(tiny / "report", "Navigation")


@pytest.mark.parametrize(
    "content, message",
    [
        ("tasks: [navigation]\nfinetune_step: 5\n", "unknown key 'finetune_step'"),
        ("episodes: many\n", "episodes: expected an integer, got 'many'"),
        ("test_seeds: 300\n", "test_seeds: expected a list of integers"),
        ("- tasks\n", "expected a mapping of settings"),
        ("tasks: [navigation\n", "cannot read .* as yaml"),
    ],
)
def test_a_bad_settings_file_is_refused_naming_the_key_and_file_before_any_work(tmp_path, capsys, content, message):
    config = tmp_path / "settings.yaml"
    config.write_text(content)
    assert run_cli(["pipeline", "--config", str(config), "--out", str(tmp_path / "run")]) == 2
    error = capsys.readouterr().err
    assert "--config" in error and str(config) in error
    assert re.search(message, error), error
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    "args, message",
    [
        (["--test-seeds", "200-201", "--validation-seeds", "200-205", "--train-seeds", "0,1"], "--validation-seeds: "),
        (["--train-seeds", "300", "--test-seeds", "300-301"], r"--train-seeds: \[300\] are test seeds too"),
        (["--backend", "ray", "--address", "127.0.0.1:9"], "--address: no Ray cluster answers at '127.0.0.1:9'"),
        (["--address", "127.0.0.1:9"], "--address: joins a Ray cluster"),
        (["--anchor"], "unrecognized arguments: --anchor"),
        (["--scratch-physics-discount"], "unrecognized arguments: --scratch-physics-discount"),
        (["--seed", "0"], "unrecognized arguments: --seed"),
        (["--eval-seeds", "300"], "unrecognized arguments: --eval-seeds"),
        (["--preset", "tiny", "--config", "x.yaml"], "not allowed with argument"),
        (["--training-env-kwarg", "gate_distance=5"], "expected TASK:NAME=VALUE"),
        (
            ["--tasks", "gate", "--training-env-kwarg", "gate:gate_distance=[50, 5]"],
            r"--training-env-kwarg: gate: gate_distance: expected \[low, high\]",
        ),
    ],
)
def test_bad_pipeline_arguments_are_refused_before_any_work(tmp_path, capsys, args, message):
    started = time.perf_counter()
    assert run_cli(["pipeline", *args, "--out", str(tmp_path / "run")]) == 2
    assert re.search(message, capsys.readouterr().err)
    assert not (tmp_path / "run").exists() and time.perf_counter() - started < 30


def test_training_env_kwarg_flags_add_to_the_configs_per_task():
    import argparse

    from dpr.cli.pipeline import pipeline_arguments, pipeline_config

    parser = argparse.ArgumentParser()
    pipeline_arguments(parser)
    flags = ["--training-env-kwarg", "gate:gate_distance=[5, 200]", "--training-env-kwarg", "gate:gate_width=160"]
    config = pipeline_config(parser.parse_args(["--preset", "tiny", "--tasks", "gate", *flags]))
    assert config.training_env_kwargs == {"gate": {"gate_distance": [5, 200], "gate_width": 160}}


def test_a_refused_run_leaves_an_existing_folder_as_it_was(tiny, capsys):
    before = tree_hash(tiny)
    assert run_cli(["pipeline", "--preset", "tiny", "--finetune-steps", "800", "--out", str(tiny)]) == 2
    assert "holds a pipeline run with other settings" in capsys.readouterr().err
    assert tree_hash(tiny) == before


def test_stage_records_say_what_made_them(tiny):
    """stage.json: kind, key, settings, what it needed and each file's size and SHA-256."""
    record = json.loads(next((tiny / "stages" / "clone").glob("*/stage.json")).read_text())
    assert record["kind"] == "clone" and record["needs"]["demonstrations"].startswith("demonstrations/")
    assert set(record["files"]) >= {"model.zip", "config.yaml"}
    assert all(len(entry["sha256"]) == 64 for entry in record["files"].values())


def test_the_same_run_started_twice_at_once_into_one_folder_waits_and_reports_as_a_lone_run(tmp_path):
    """Two identical `dpr pipeline` commands started together into one folder: each stage is built once, the
    other run waits for it (and says so, naming the stage and the folder), both exit 0, and the report is a lone
    run's."""
    config = tmp_path / "config.yaml"
    config.write_text(yaml.safe_dump(PIPELINE))
    shared, lone = tmp_path / "shared", tmp_path / "lone"
    argv = [*DPR, "pipeline", "--config", str(config), "--out"]
    runs = [subprocess.Popen([*argv, str(shared)], stderr=subprocess.PIPE, text=True, env=ENV) for _ in range(2)]
    errors = [run.communicate(timeout=600)[1] for run in runs]
    assert [run.returncode for run in runs] == [0, 0], errors[0][-3000:] + errors[1][-3000:]
    waited = [line for err in errors for line in err.splitlines() if "waiting for another `dpr pipeline`" in line]
    assert waited and all(f"which is building {shared / 'stages'}" in line for line in waited), errors
    assert pipeline("--config", str(config), "--out", str(lone)).returncode == 0
    assert (shared / "report" / "results.md").read_text() == (lone / "report" / "results.md").read_text()
    assert not (shared / "report-2").exists() and not list((shared / "stages").glob("*/*.corrupt"))
    assert sorted(p.name for p in (shared / "stages").glob("*/*")) == sorted(
        p.name for p in (lone / "stages").glob("*/*")
    )
