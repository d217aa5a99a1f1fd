"""Where a ``dpr pipeline`` run folder gives each model and evaluation its readable name, and where its report
goes (the layout the pipeline, ``dpr compare`` and the docs' tools share):

- ``pipeline.yaml``: the settings; ``choices.yaml``: every choice made on the validation (or teacher) seeds;
- ``models/<task>-<method>-seed<s>.zip``: a training run; ``models/<task>-<method>.zip``: the method's canonical
  model (its median run on the validation seeds);
- ``eval/<split>/<task>-<method>[-seed<s>].json``: an evaluation on the validation or test seeds;
- ``report/``: the report (``report-2``... beside it when a newer one is written).
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import yaml

from dpr.atomic import atomic_write_text
from dpr.bounded_io import load_yaml
from dpr.limits import MAX_RECORD_BYTES
from dpr.pipeline.config import BASELINE, TEACHER, PipelineConfig
from dpr.runs import attempt_paths, fresh_path

__all__ = [
    "evaluation_path",
    "evaluation_splits",
    "load_choices",
    "model_path",
    "read_run_settings",
    "save_choices",
    "tested_runs",
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
    return load_yaml(path, "config", MAX_RECORD_BYTES)


def load_choices(out: Path) -> dict[str, Any]:
    """``choices.yaml``: every choice made on the validation seeds so far."""
    path = out / "choices.yaml"
    return load_yaml(path, "out", MAX_RECORD_BYTES, missing={})


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


def report_folder(out: Path, sources: Sequence[Path], log: Callable[[str], None]) -> Path:
    """The folder the report belongs in: the latest report (``report``, ``report-2``...) if it was made of
    ``sources`` and none is newer than it, else a new folder beside it (reports are never overwritten; the older one
    is kept). A report folder without results.md (written last) was stopped part-way; it is kept, and the report
    goes beside it."""
    from dpr.evaluation.report import REPORT_FILES

    attempts = attempt_paths(out / "report")
    written = [folder for folder in attempts if (folder / REPORT_FILES[0]).exists()]  # results.md comes last
    if written:
        kept = written[-1]
        made = (kept / REPORT_FILES[0]).stat().st_mtime_ns
        named = re.findall(r"`([^`]+)`", (kept / REPORT_FILES[0]).read_text().rstrip().rsplit("\n", 1)[-1])
        same = named == [os.path.relpath(source, out) for source in sources]
        if same and all(source.stat().st_mtime_ns <= made for source in sources):
            return kept
        why = f"evaluations newer than {kept}" if same else f"{kept} reports other evaluations"
    else:
        unfinished = [folder for folder in attempts if folder.is_dir() and any(folder.iterdir())]
        if not unfinished:
            return out / "report"
        kept = unfinished[-1]
        why = f"{kept} was stopped part-way (no {REPORT_FILES[0]})"
    fresh = fresh_path(out / "report")
    log(f"dpr pipeline: {why}: the report goes into {fresh}, {kept} is kept")
    return fresh
