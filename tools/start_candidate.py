#!/usr/bin/env python
"""Start a candidate recipe's run folder for one task from a record, with what the two share copied in.

A candidate that changes one method (say, the runs from scratch) makes the same teacher, demonstrations, clones and
fine-tuning as the record, so those need not run again (docs/learning.md, "Trying a new recipe", step 2). This tool
writes a new `dpr pipeline` folder holding the candidate's settings (the record's, with the given `dpr pipeline`
flags over them, for the one task), the record's choice of the task's teacher and of each ``--keep`` method, their
validation and test evaluations, and the record's canonical models of those methods (from ``--models``). The
pipeline, given the same flags, then trains and scores only the rest:

    python tools/start_candidate.py docs/results/full-lr3e4 runs/cand-gate --keep bc bc-ppo -- \\
        --preset full --tasks gate --scratch-physics-discount
    dpr pipeline --preset full --tasks gate --scratch-physics-discount --out runs/cand-gate
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

from dpr.cli import build_parser
from dpr.cli.pipeline import pipeline_config
from dpr.rl.pipeline_config import TEACHER, PipelineConfig, saved_settings
from dpr.rl.run_folder import load_choices, model_path, read_run_settings, save_choices, write_run_settings


def start(record: Path, out: Path, keep: list[str], flags: list[str], models: Path) -> PipelineConfig:
    """Write the candidate folder ``out``; returns its settings. Refused, before anything is written, when ``out``
    exists, the flags name more than one task, or a kept method is not one of the candidate's."""
    config = pipeline_config(build_parser().parse_args(["pipeline", *flags]))
    if out.exists():
        raise ValueError(f"{out} exists; a candidate starts in a new folder")
    if len(config.tasks) != 1:
        raise ValueError(f"--tasks: one task per candidate folder (they run side by side), got {config.tasks}")
    (task,) = config.tasks
    unknown = sorted(set(keep) - set(config.learned_methods()))
    if unknown:
        raise ValueError(f"--keep: {unknown} are not methods of the candidate ({config.learned_methods()})")
    if task not in read_run_settings(record)["config"]["tasks"]:
        raise ValueError(f"{record}: the record has no {task} runs")
    record_id = PipelineConfig(**saved_settings(read_run_settings(record)["config"])).env_id(task)
    if config.env_id(task) != record_id:  # the kept runs are the record's env's: the candidate must run it too
        raise ValueError(f"--env-id: the record ran {task} on {record_id}; give --env-id {record_id}")
    choices = load_choices(record)
    names = [f"{task}-{TEACHER}", *(f"{task}-{method}" for method in keep)]
    sources = [models / model_path(Path("."), task, method, None).name for method in keep]
    missing = [str(path) for path in sources if not path.is_file()]
    if missing:
        raise ValueError(f"--models: {missing} missing; expected the record's canonical models")
    out.mkdir(parents=True)
    write_run_settings(out, config, started_from=str(record))
    save_choices(out, {name: choices[name] for name in names if name in choices})
    prefixes = (f"{task}-{TEACHER}", f"{task}-wave", *(f"{task}-{method}-seed" for method in keep))
    for split in ("validation", "test"):
        (out / "eval" / split).mkdir(parents=True)
        for path in sorted((record / "eval" / split).glob(f"{task}-*.json")):
            if path.stem in prefixes or path.name.startswith(prefixes):
                shutil.copyfile(path, out / "eval" / split / path.name)
    (out / "models").mkdir()
    for source in sources:
        shutil.copyfile(source, out / "models" / source.name)
    return config


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("record", type=Path, help="the record (or run folder) whose runs the candidate shares")
    parser.add_argument("out", type=Path, help="the candidate's new run folder for one task")
    parser.add_argument("--keep", nargs="+", default=[], help="the methods whose runs the candidate shares")
    parser.add_argument("--models", type=Path, default=Path("models"), help="the record's canonical models")
    parser.usage = (
        "%(prog)s RECORD OUT [--keep METHOD ...] [--models DIR] -- FLAG ... (the candidate's `dpr pipeline` flags)"
    )
    argv = sys.argv[1:] if argv is None else argv
    split = argv.index("--") if "--" in argv else len(argv)
    args, flags = parser.parse_args(argv[:split]), argv[split + 1 :]
    try:
        config = start(args.record, args.out, args.keep, flags, args.models)
    except ValueError as error:
        parser.error(str(error))
    print(f"{args.out}: {config.tasks[0]}, sharing {[TEACHER, *args.keep]} with {args.record}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
