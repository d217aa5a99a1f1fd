#!/usr/bin/env python
"""Pipeline runs of the same settings, each on some of the tasks, merged into one record of them all.

On 2 cores a full-preset task takes one to two hours, so tasks are often run side by side, each into a folder of
its own (`dpr pipeline --preset full --tasks navigation --out runs/a`, `... --tasks manipulation --out runs/b`).
This tool checks that the runs' settings agree on everything but their tasks, and writes a new folder holding:
``pipeline.yaml`` (the settings with every task), ``choices.yaml`` (every choice), ``eval/`` (every validation
and test evaluation), the canonical models ``models/<task>-<method>.zip``, and ``report/`` written from the test
evaluations as the pipeline writes it. The pipeline resumes that folder as a finished run: the same command with
``--tasks`` naming all its tasks only reprints the report. ``merged_from`` in its ``pipeline.yaml`` names the run
folder each task came from (a merged record merged again keeps its tasks' first folders). Datasets, run folders
and training runs' models stay where they are. A task that is not finished in its run (its canonical models and
test evaluations), or that two runs hold, is refused.

    python tools/merge_runs.py runs/full-bins-all runs/full-bins runs/full-bins-manip
"""

from __future__ import annotations

import argparse
import shutil
import sys
from dataclasses import asdict
from pathlib import Path

from dpr.envs import ENV_IDS
from dpr.rl.pipeline_config import PipelineConfig, saved_settings
from dpr.rl.report import write_report
from dpr.rl.run_folder import load_choices, read_run_settings, report_evaluations, save_choices, write_run_settings


def _first_folder(entry: dict, run: Path, task: str) -> str:
    """The name of the folder ``task`` was run in: the record's own ``merged_from`` if it is a merge, else its name."""
    earlier = entry.get("merged_from")
    return earlier[task] if isinstance(earlier, dict) and task in earlier else run.name


def merge(out: Path, runs: list[Path]) -> PipelineConfig:
    """Write the merged record of ``runs`` into the new folder ``out``; returns its settings."""
    if out.exists():
        raise ValueError(f"{out} exists; the merged record goes into a new folder")
    saved = [read_run_settings(run) for run in runs]
    configs = [PipelineConfig(**saved_settings(entry["config"])) for entry in saved]
    first = {**asdict(configs[0]), "tasks": None}
    for run, config in zip(runs[1:], configs[1:]):
        differ = sorted(name for name, value in {**asdict(config), "tasks": None}.items() if value != first[name])
        if differ:
            raise ValueError(f"{run}: other settings than {runs[0]} ({', '.join(differ)}); only the tasks may differ")
    owner: dict[str, Path] = {}
    folders: dict[str, str] = {}
    for run, config, entry in zip(runs, configs, saved):
        for task in config.tasks:
            if task in owner:
                raise ValueError(f"{task}: run in both {owner[task]} and {run}; merge each task once")
            owner[task], folders[task] = run, _first_folder(entry, run, task)
    tasks = [task for task in ENV_IDS if task in owner]
    merged = PipelineConfig(**{**asdict(configs[0]), "tasks": tasks})
    choices: dict = {}
    copies: dict[Path, Path] = {}  # destination -> source
    for task in tasks:
        run, single = owner[task], PipelineConfig(**{**asdict(merged), "tasks": [task]})
        run_choices = load_choices(run)
        choices.update({key: value for key, value in run_choices.items() if key.startswith(f"{task}-")})
        needed = [path for path, _ in report_evaluations(single, run)]
        needed += [run / "models" / f"{task}-{method}.zip" for method in merged.learned_methods()]
        missing = [str(path) for path in needed if not path.exists()]
        if missing:
            raise ValueError(f"{task} is not finished in {run}: missing {', '.join(missing[:3])}")
        for path in [*needed, *(run / "eval" / "validation").glob(f"{task}-*.json")]:
            copies[out / path.relative_to(run)] = path
    for target, source in copies.items():
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(source, target)
    started = min(str(entry.get("started", "")) for entry in saved)
    write_run_settings(out, merged, started, merged_from={task: folders[task] for task in tasks})
    save_choices(out, choices)
    evaluations = report_evaluations(merged, out)
    write_report([path for path, _ in evaluations], out / "report", labels=[method for _, method in evaluations])
    return merged


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path, help="the new record folder")
    parser.add_argument("runs", type=Path, nargs="+", help="pipeline run folders, each with some of the tasks")
    args = parser.parse_args(argv)
    try:
        merged = merge(args.out, args.runs)
    except ValueError as error:
        parser.error(str(error))
    print(f"{args.out}: {', '.join(merged.tasks)} from {len(args.runs)} runs; report in {args.out / 'report'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
