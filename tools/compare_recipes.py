#!/usr/bin/env python
"""Two recipes compared on validation seeds: the rule that decides whether a candidate replaces the full preset.

Each argument is a `dpr pipeline` run folder (or a record of one, such as ``docs/results/full``). For every task
and learned method both have finished, the tool pools the episodes of every training run on the validation seeds
(``eval/validation/<task>-<method>-seed<S>.json``) and prints their IQM in each folder and the ratio, candidate over
current. The last line applies the adoption rule of docs/learning.md: the candidate wins if the mean over tasks of
the ``--method`` ratios (default ``bc-ppo``) is above 1, once every task has as many runs in both folders. Test
evaluations are never read, so running this before looking at a candidate's test seeds keeps them unseen. Runs
scored on different validation seeds are refused.

    python tools/compare_recipes.py docs/results/full runs/full-bins
    python tools/compare_recipes.py docs/results/full runs/full-bins --tasks navigation --method bc
    python tools/compare_recipes.py docs/results/full-bins runs/cand-navigation runs/cand-gate ...

The pipeline scores each fine-tuned run on the validation seeds before its runs from scratch start, so a
candidate run task by task can be judged as soon as its fine-tuning is done.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import numpy as np

from dpr.envs import ENV_IDS
from dpr.rl.report import load_evaluation
from dpr.rl.statistics import iqm

RUN_FILE = re.compile(r"(?P<task>[a-z]+)-(?P<method>[a-z0-9-]+)-seed(?P<seed>\d+)\.json")


def validation_runs(*folders: Path) -> dict[tuple[str, str], list[Path]]:
    """(task, method) -> the validation evaluations of its training runs in the run folders ``folders`` (a
    recipe's tasks run side by side, each in a folder of its own); a task in two of them is refused."""
    runs: dict[tuple[str, str], list[Path]] = {}
    owner: dict[str, Path] = {}
    for folder in folders:
        if not (folder / "eval" / "validation").is_dir():
            raise ValueError(f"{folder}: no eval/validation folder; expected a `dpr pipeline` run folder")
        for path in sorted((folder / "eval" / "validation").glob("*-seed*.json")):
            match = RUN_FILE.fullmatch(path.name)
            if match and match["task"] in ENV_IDS:
                if owner.setdefault(match["task"], folder) != folder:
                    raise ValueError(f"{match['task']}: runs in both {owner[match['task']]} and {folder}")
                runs.setdefault((match["task"], match["method"]), []).append(path)
    return runs


def pooled(paths: list[Path]) -> tuple[np.ndarray, list[int]]:
    """Every episode's projected displacement over ``paths``, and the validation seeds they share."""
    values, seeds = [], None
    for path in paths:
        payload = load_evaluation(path)
        if seeds is not None and payload["seeds"] != seeds:
            raise ValueError(f"{path}: scored on other validation seeds than {paths[0]}")
        seeds = payload["seeds"]
        values += [episode["projected_displacement"] for episode in payload["episodes"]]
    return np.array(values), seeds


def compare(
    current: Path, candidate: Path | list[Path], tasks: list[str], method: str
) -> tuple[list[dict], float | None]:
    """One row per (task, method) both recipes hold, and the mean over ``tasks`` of ``method``'s ratios (None if a
    task lacks it in either, or the candidate has fewer or more of its runs than the current recipe). The candidate
    is one run folder or several, each holding some of its tasks."""
    candidates = [candidate] if isinstance(candidate, Path) else list(candidate)
    before, after = validation_runs(current), validation_runs(*candidates)
    rows = []
    for key in sorted(set(before) & set(after), key=lambda key: (list(ENV_IDS).index(key[0]), key[1])):
        if key[0] not in tasks:
            continue
        (old, old_seeds), (new, new_seeds) = pooled(before[key]), pooled(after[key])
        if old_seeds != new_seeds:
            raise ValueError(f"{key[0]}-{key[1]}: the two folders used different validation seeds; not comparable")
        rows.append(
            {
                "task": key[0],
                "method": key[1],
                "runs": (len(before[key]), len(after[key])),
                "iqm": (float(iqm(old)), float(iqm(new))),
                "ratio": float(iqm(new) / iqm(old)),
            }
        )
    ratios = [row["ratio"] for row in rows if row["method"] == method]
    # a task counts once the candidate has as many training runs as the current recipe: a verdict on the first
    # runs to finish would be a choice made on part of the candidate
    finished = all(row["runs"][0] == row["runs"][1] for row in rows if row["method"] == method)
    complete = len(ratios) == len(tasks) and finished
    return rows, (float(np.mean(ratios)) if complete else None)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("current", type=Path, help="run folder of the recipe in force (e.g. docs/results/full)")
    parser.add_argument(
        "candidate", type=Path, nargs="+", help="run folder of the candidate recipe, or one per task run side by side"
    )
    parser.add_argument("--tasks", nargs="+", default=list(ENV_IDS), choices=list(ENV_IDS))
    parser.add_argument("--method", default="bc-ppo", help="the method the rule compares (default bc-ppo)")
    args = parser.parse_args(argv)
    try:
        rows, mean = compare(args.current, args.candidate, args.tasks, args.method)
    except ValueError as error:
        parser.error(str(error))
    print("| task | method | runs | IQM current | IQM candidate | ratio |\n|---|---|---|---:|---:|---:|")
    for row in rows:
        runs = " / ".join(map(str, row["runs"]))
        scores = f"{row['iqm'][0]:.1f} | {row['iqm'][1]:.1f} | {row['ratio']:.2f}"
        print(f"| {row['task']} | {row['method']} | {runs} | {scores} |")
    if mean is None:
        print(
            f"\n{args.method}: not every task of {args.tasks} is finished in both folders with as many runs; "
            "no decision yet"
        )
    else:
        verdict = "adopt the candidate" if mean > 1 else "keep the current recipe"
        print(f"\nmean {args.method} ratio over {len(args.tasks)} tasks: {mean:.3f} -> {verdict}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
