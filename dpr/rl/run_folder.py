"""Where a ``dpr pipeline`` run folder keeps each file, and what of a run is done: the layout that the pipeline,
``tools/merge_runs.py`` and ``tools/keep_run.py`` share.

- ``pipeline.yaml``: the settings; ``choices.yaml``: every choice made on the validation (or teacher) seeds;
- ``models/<task>-<method>-seed<s>.zip``: a training run; ``models/<task>-<method>.zip``: the method's canonical
  model (its median run on the validation seeds);
- ``eval/<split>/<task>-<method>[-seed<s>].json``: an evaluation on the validation or test seeds;
- ``datasets/``, ``runs/`` and ``report/``: the demonstrations, the training runs' own folders, the report.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import yaml

from dpr.atomic import atomic_write_text
from dpr.rl.pipeline_config import BASELINE, TEACHER, PipelineConfig
from dpr.runs import attempt_paths, fresh_path

__all__ = [
    "evaluated",
    "evaluation_path",
    "evaluation_splits",
    "load_choices",
    "model_path",
    "models_still_needed",
    "read_run_settings",
    "report_evaluations",
    "save_choices",
    "task_done",
    "tested_runs",
    "write_run_settings",
]


def evaluation_path(out: Path, task: str, method: str, seed: int | None, split: str) -> Path:
    """The evaluation of the wave or a method's training run (``seed``) on the ``split`` seeds."""
    name = f"{task}-{method}" if seed is None else f"{task}-{method}-seed{seed}"
    return out / "eval" / split / f"{name}.json"


def model_path(out: Path, task: str, method: str, seed: int | None) -> Path:
    """A training run's model (``seed``), or the method's canonical model (None)."""
    return out / "models" / (f"{task}-{method}.zip" if seed is None else f"{task}-{method}-seed{seed}.zip")


def read_run_settings(run: Path) -> dict[str, Any]:
    """A run folder's ``pipeline.yaml`` (its settings under ``config``); a folder without one is refused."""
    path = run / "pipeline.yaml"
    if not path.is_file():
        raise ValueError(f"{run}: no pipeline.yaml; expected a `dpr pipeline` run folder")
    return yaml.safe_load(path.read_text())


def write_run_settings(run: Path, config: PipelineConfig, started: str | None = None, **extra: Any) -> None:
    """Write ``run``'s ``pipeline.yaml``: ``config`` under ``config``, its RL budget, when it started (now unless
    given) and ``extra`` entries (where a merged or candidate folder came from)."""
    started = started or time.strftime("%Y-%m-%dT%H:%M:%S%z")
    record = {"config": asdict(config), "rl_steps": config.rl_steps, "started": started, **extra}
    atomic_write_text(run / "pipeline.yaml", yaml.safe_dump(record, sort_keys=False))


def load_choices(out: Path) -> dict[str, Any]:
    """``choices.yaml``: every choice made on the validation seeds so far."""
    path = out / "choices.yaml"
    return yaml.safe_load(path.read_text()) if path.exists() else {}


def save_choices(out: Path, choices: dict[str, Any]) -> None:
    atomic_write_text(out / "choices.yaml", yaml.safe_dump(choices, sort_keys=True))


def tested_runs(config: PipelineConfig) -> list[tuple[str, int | None]]:
    """(method, training seed) of every test evaluation of a task: the wave and the teacher once (seed None),
    every training run."""
    once = (BASELINE, TEACHER)
    return [
        (method, seed) for method in config.methods() for seed in ([None] if method in once else config.train_seeds)
    ]


def evaluation_splits(config: PipelineConfig) -> list[str]:
    """The seed sets every training run is evaluated on: the validation seeds when there is a choice to make (several
    training seeds), then the test seeds."""
    return ["validation", "test"] if len(config.train_seeds) > 1 else ["test"]


def evaluated(config: PipelineConfig, task: str, method: str, seed: int, out: Path) -> bool:
    """Whether a training run has every evaluation the pipeline makes of it (:func:`evaluation_splits`): its model
    is then needed only if it becomes the canonical one."""
    return all(evaluation_path(out, task, method, seed, split).exists() for split in evaluation_splits(config))


def task_done(config: PipelineConfig, task: str, out: Path) -> bool:
    """Whether ``task`` needs nothing more: every method's canonical model and every test evaluation exist. Its
    demonstrations and training runs are then not needed, so a record of the run without them (the models, the
    evaluations and ``choices.yaml``) resumes as it is."""
    return all(model_path(out, task, method, None).exists() for method in config.learned_methods()) and all(
        evaluation_path(out, task, method, seed, "test").exists() for method, seed in tested_runs(config)
    )


def models_still_needed(config: PipelineConfig, out: Path) -> list[Path]:
    """The training runs' models in the run folder ``out`` that resuming it would still use: a run with an
    evaluation still to make; any run of a method whose canonical model is missing, when its choice is not made
    or falls on it; and a clone whose fine-tuning is still to train. Everything else a resume needs is its
    ``pipeline.yaml``, ``choices.yaml``, ``eval/`` and canonical models (the datasets the same settings record
    again)."""
    out, choices = Path(out), load_choices(out)

    def used(task: str, method: str, seed: int) -> bool:  # by a resume, which trains the run first if missing
        chosen = choices.get(f"{task}-{method}", {}).get("chosen_seed")
        unchosen = not model_path(out, task, method, None).exists() and chosen in (None, seed)
        return unchosen or not evaluated(config, task, method, seed, out)

    def trained(task: str, method: str, seed: int) -> bool:  # by a resume
        return not model_path(out, task, method, seed).exists() and used(task, method, seed)

    fine_tuned = config.cloned_methods()[1:]
    return [
        model_path(out, task, method, seed)
        for task in config.tasks
        for method in config.learned_methods()
        for seed in config.train_seeds
        if model_path(out, task, method, seed).exists()
        and (used(task, method, seed) or (method == "bc" and any(trained(task, f, seed) for f in fine_tuned)))
    ]


def report_evaluations(config: PipelineConfig, out: Path) -> list[tuple[Path, str]]:
    """(file, method) of every test evaluation of ``config``'s tasks in the run folder ``out``, in the report's
    order: per task the wave, the teacher, then each method's training runs."""
    return [
        (evaluation_path(Path(out), task, method, seed, "test"), method)
        for task in config.tasks
        for method, seed in tested_runs(config)
    ]


def report_folder(out: Path, sources: Sequence[Path], log: Callable[[str], None]) -> Path:
    """The folder the report belongs in: the latest report (``report``, ``report-2``...) if none of ``sources`` is
    newer than it, else a new folder beside it (reports are never overwritten; the older one is kept). A report
    folder without results.md (written last) was stopped part-way; it is kept, and the report goes beside it."""
    from dpr.rl.report import REPORT_FILES

    attempts = attempt_paths(out / "report")
    written = [folder for folder in attempts if (folder / REPORT_FILES[0]).exists()]  # results.md comes last
    if written:
        kept = written[-1]
        made = (kept / REPORT_FILES[0]).stat().st_mtime_ns
        if all(source.stat().st_mtime_ns <= made for source in sources):
            return kept
        why = f"evaluations newer than {kept}"
    else:
        unfinished = [folder for folder in attempts if folder.is_dir() and any(folder.iterdir())]
        if not unfinished:
            return out / "report"
        kept = unfinished[-1]
        why = f"{kept} was stopped part-way (no {REPORT_FILES[0]})"
    fresh = fresh_path(out / "report")
    log(f"dpr pipeline: {why}: the report goes into {fresh}, {kept} is kept")
    return fresh
