#!/usr/bin/env python
"""Keep what a `dpr pipeline` run folder needs to resume, small enough to commit: a run of many hours then
outlives the machine it ran on.

A run folder holds demonstrations, training-run folders and every run's model; a resume needs far less. This tool
copies into a new folder ``pipeline.yaml``, ``choices.yaml``, ``eval/`` (every evaluation), ``report/`` if written,
the canonical models and, as slim copies (:func:`dpr.policies.sb3.save_slim_copy`: the same policy without the
optimizer's moments), only the training runs' models a resume would still use
(:func:`dpr.rl.run_folder.models_still_needed`), and of each training run stopped part-way its ``config.yaml`` and
last snapshot (``resume/``, :mod:`dpr.rl.resume`). `dpr pipeline` with the run's settings resumes the copy, training
only what is missing (a stopped run from its snapshot, where its settings, paths included, are the same); a chosen
run that must be trained again has to reproduce its validation episodes exactly.

    python tools/keep_run.py runs/ft1200-unresponsive docs/results/full-ft1200-partial/unresponsive
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

from dpr.policies.sb3 import save_slim_copy
from dpr.rl.pipeline_config import PipelineConfig, saved_settings
from dpr.rl.resume import SNAPSHOT_DIR, snapshot_folder
from dpr.rl.run_folder import model_path, models_still_needed, read_run_settings


def keep(run: Path, out: Path) -> list[Path]:
    """Copy what ``run`` needs to resume into the new folder ``out``; returns the training runs' models kept."""
    config = PipelineConfig(**saved_settings(read_run_settings(run)["config"]))
    if out.exists():
        raise ValueError(f"{out} exists; what is kept goes into a new folder")
    runs = models_still_needed(config, run)
    canonical = [model_path(run, task, method, None) for task in config.tasks for method in config.learned_methods()]
    (out / "models").mkdir(parents=True)
    for name in ("pipeline.yaml", "choices.yaml"):
        if (run / name).exists():
            shutil.copyfile(run / name, out / name)
    for folder in ("eval", "report"):
        if (run / folder).is_dir():
            shutil.copytree(run / folder, out / folder)
    for model in [path for path in canonical if path.exists()]:
        shutil.copyfile(model, out / "models" / model.name)
    for model in runs:
        save_slim_copy(model, out / "models" / model.name)
    for stopped in sorted((run / "runs").glob("*")) if (run / "runs").is_dir() else []:
        snapshot = snapshot_folder(stopped)  # resume/, or where a stop while it was replaced left it
        if snapshot is not None:  # a finished run drops its snapshot: one left is a run the pipeline resumes
            shutil.copytree(snapshot, out / "runs" / stopped.name / SNAPSHOT_DIR)
            shutil.copyfile(stopped / "config.yaml", out / "runs" / stopped.name / "config.yaml")
    return runs


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path, help="a `dpr pipeline` run folder")
    parser.add_argument("out", type=Path, help="the new folder to keep it in")
    args = parser.parse_args(argv)
    try:
        runs = keep(args.run, args.out)
    except ValueError as error:
        parser.error(str(error))
    size = sum(path.stat().st_size for path in args.out.rglob("*") if path.is_file())
    kept = ", ".join(path.name for path in runs) or "none"
    stopped = ", ".join(path.name for path in sorted((args.out / "runs").glob("*"))) or "none"
    print(f"{args.out}: {size / 1e6:.1f} MB; training runs' models still needed: {kept}; stopped runs kept: {stopped}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
