#!/usr/bin/env python
"""The headline's tables, written from full-preset records, and a check that the docs quote them.

A record (``docs/results/<name>``: ``pipeline.yaml``, ``choices.yaml``, ``eval/``, ``report/``) is the source of
every headline figure. The headline may rest on several records, each task's rows from the last one listed that
ran it (a task run again on its own replaces that task's rows of a record of all four). RESULTS.md quotes the
interval tables and the canonical models' test medians; models/README.md quotes each canonical model's chosen run,
test median and interval; models/card.yaml names each chosen run's seed; docs/pipeline.md shows what `make run`
prints for the shipped models, which are the records' test episodes on the small preset's five test seeds.
This tool prints those rows from the records; ``--write`` puts them in the docs in place of the rows they hold
(the prose around them, and the recipe cells such as a model's budget, are left to the person adopting a record);
``--check`` lists every row the docs lack or misquote (exit status 1), which the tests run on the headline records.

    python tools/record_tables.py                        # the headline records' rows
    python tools/record_tables.py runs/full-new          # another finished full-preset run folder's
    python tools/record_tables.py docs/results/full-new --write   # adopting a record: its rows into the docs
    python tools/record_tables.py docs/results/full-lr3e4 docs/results/gate-new --write   # Gate's rows from the second
    python tools/record_tables.py --check                # do the docs agree with the headline records?
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Sequence
from functools import cached_property
from pathlib import Path

import yaml

from dpr.envs import ENV_IDS
from dpr.evaluation.report import load_evaluation, results_table, task_name
from dpr.pipeline.config import PipelineConfig
from dpr.policies.wave import BIN_WIDTH

ROOT = Path(__file__).resolve().parents[1]
# the records the full preset's headline comes from, each task's rows from the last one that ran it
HEADLINE_RECORDS = (ROOT / "docs" / "results" / "full-lr3e4", ROOT / "docs" / "results" / "gate-v2-averaged")
LEARNED = ("bc", "bc-ppo", "ppo")
HEADLINE = "bc-ppo"  # its cells are bold in RESULTS.md's tables
METHOD_NAMES = {"wave": "wave", "bc": "BC", "bc-ppo": "BC→PPO", "ppo": "PPO from scratch"}
INTERVAL_HEADER = "| task | method | runs × seeds |"
CANONICAL_HEADER = "| task | BC (seed) |"
MAKE_RUN_HEADER = "| task | policy | median |"


class Record:
    """One record: its choices, its test evaluations and its report; ``tasks``, those whose rows it gives."""

    def __init__(self, folder: Path):
        self.folder = Path(folder)
        for part in ("choices.yaml", "eval/test", "report/results.md"):
            if not (self.folder / part).exists():
                raise FileNotFoundError(f"{self.folder / part}: missing; expected a finished `dpr pipeline` record")
        self.choices = yaml.safe_load((self.folder / "choices.yaml").read_text())
        self.tasks = [task for task in ENV_IDS if f"{task}-{HEADLINE}" in self.choices]
        settings = self.folder / "pipeline.yaml"
        config = yaml.safe_load(settings.read_text()).get("config", {}) if settings.is_file() else {}
        self.env_ids = dict(config.get("env_ids") or {})  # the tasks it ran on an earlier registered id
        self._test: dict[str, dict] = {}  # every table reads the wave's and the chosen runs' files: read each once

    def task_name(self, task: str) -> str:
        """The name the record's report gives ``task``'s rows."""
        return task_name(self.env_ids.get(task, ENV_IDS[task]))

    def test_evaluation(self, task: str, method: str, seed: int | None = None) -> dict:
        name = f"{task}-{method}" + ("" if seed is None else f"-seed{seed}")
        if name not in self._test:
            self._test[name] = load_evaluation(self.folder / "eval" / "test" / f"{name}.json")
        return self._test[name]

    def test_median(self, task: str, method: str, seed: int | None = None) -> float:
        evaluation = self.test_evaluation(task, method, seed)
        return float(evaluation["summary"]["projected_displacement"]["median"])

    def chosen(self, task: str, method: str) -> tuple[int, dict[int, float]]:
        """The chosen training seed of a method and every run's validation median."""
        choice = self.choices[f"{task}-{method}"]
        return int(choice["chosen_seed"]), {int(s): float(v) for s, v in choice["validation_medians"].items()}

    def interval_rows(self) -> list[list[str]]:
        """The cells of the report's interval table, one list per row (new lists: callers may change them)."""
        return [list(cells) for cells in self._interval_cells]

    @cached_property
    def _interval_cells(self) -> list[tuple[str, ...]]:
        # every task of the record reads the table: the report is read once
        path = self.folder / "report" / "results.md"
        lines = path.read_text().splitlines()
        return [tuple(_cells(line)) for line in lines[slice(*_table_body(lines, INTERVAL_HEADER, path))]]


def load_records(folders: Sequence[Path]) -> list[Record]:
    """The records in ``folders``, each giving the rows of the tasks that no later one ran."""
    records, later = [], set()
    for folder in reversed(folders):
        record = Record(folder)
        record.tasks = [task for task in record.tasks if task not in later]
        later.update(record.tasks)
        records.insert(0, record)
    return records


def _by_task(records: Sequence[Record]) -> list[tuple[str, Record]]:
    """(task, the record giving its rows), in the tasks' order."""
    owner = {task: record for record in records for task in record.tasks}
    return [(task, owner[task]) for task in ENV_IDS if task in owner]


def _cells(row: str) -> list[str]:
    """The cells of a markdown table row."""
    return [cell.strip() for cell in row.strip("|").split("|")]


def _table_body(lines: list[str], header: str, where: Path) -> tuple[int, int]:
    """The first and one-past-last line of the rows of the first table whose header line starts with ``header``
    (after the header and its separator line)."""
    start = next((i for i, line in enumerate(lines) if line.startswith(header)), None)
    if start is None:
        raise ValueError(f"{where}: no table starting {header!r}")
    end = start + 2
    while end < len(lines) and lines[end].startswith("|"):
        end += 1
    return start + 2, end


def _teacher_name(record: Record, task: str) -> str:
    teacher = record.choices[f"{task}-teacher"]  # an entry that names no bin width chose at the wave's
    return f"teacher (hold {teacher['hold_steps']}, bins {teacher.get('bin_width', BIN_WIDTH):g})"


def headline_rows(records: Sequence[Record]) -> list[str]:
    """RESULTS.md's headline table: the reports' interval rows, named as RESULTS.md names them."""
    rows = []
    for task, record in _by_task(records):
        for cells in record.interval_rows():
            if cells[0] != record.task_name(task):
                continue
            method = cells[1]
            cells[1] = _teacher_name(record, task) if method == "teacher" else METHOD_NAMES[method]
            if method == HEADLINE:
                cells[5] = f"**{cells[5]}**"
            rows.append("| " + " | ".join(cells) + " |")
    return rows


def canonical_rows(records: Sequence[Record]) -> list[str]:
    """RESULTS.md's table of the canonical models' test medians, as % of the wave's, and every BC→PPO run's."""
    rows = []
    for task, record in _by_task(records):
        wave = record.test_median(task, "wave")
        cells = []
        for method in LEARNED:
            seed, _ = record.chosen(task, method)
            median = record.test_median(task, method, seed)
            percent = f"{100 * median / wave:.0f}%"
            cells.append(f"{median:.1f}, {f'**{percent}**' if method == HEADLINE else percent} ({seed})")
        _, runs = record.chosen(task, HEADLINE)
        every_run = ", ".join(f"{100 * record.test_median(task, HEADLINE, s) / wave:.0f}%" for s in sorted(runs))
        rows.append(f"| {record.task_name(task)} | " + " | ".join(cells) + f" | {every_run} |")
    return rows


def model_card_cells(records: Sequence[Record]) -> dict[str, str]:
    """models/README.md: file -> the last three cells of its row (chosen run, its test median, the method's IQM
    % of the wave)."""
    cells = {}
    for task, record in _by_task(records):
        ratios = {(row[0], row[1]): row[5] for row in record.interval_rows()}
        wave = record.test_median(task, "wave")
        for method in LEARNED:
            seed, medians = record.chosen(task, method)
            median = record.test_median(task, method, seed)
            validation = " / ".join(f"{medians[s]:.1f}" for s in sorted(medians))
            ratio = ratios[(record.task_name(task), method)]
            cells[f"{task}-{method}.zip"] = (
                f"| seed {seed} ({validation}) | {median:.1f} ({100 * median / wave:.0f}%) | {ratio} |"
            )
    return cells


def shipped_rows(records: Sequence[Record], seeds: list[int] | None = None) -> list[str]:
    """What `make run` prints for the wave and the shipped canonical models (``shipped <method>``): `dpr report`'s
    rows of their episodes in the records on ``seeds`` (default: the small preset's test seeds), without the
    success, n and seeds columns, which docs/pipeline.md leaves out."""
    seeds = set(PipelineConfig().test_seeds if seeds is None else seeds)
    evaluations = []
    for task, record in _by_task(records):
        runs = [("wave", record.test_evaluation(task, "wave"))]
        runs += [(f"shipped {m}", record.test_evaluation(task, m, record.chosen(task, m)[0])) for m in LEARNED]
        for label, evaluation in runs:
            episodes = [episode for episode in evaluation["episodes"] if episode["seed"] in seeds]
            evaluations.append({**evaluation, "label": label, "episodes": episodes})
    rows = results_table(evaluations).splitlines()[2:]
    # columns 6-8 are success, n and seeds
    return ["| " + " | ".join(cells[:6] + cells[9:]) + " |" for cells in map(_cells, rows)]


def card_seeds(records: Sequence[Record]) -> dict[str, int]:
    """models/card.yaml: file -> the training seed its ``made_by`` must name."""
    return {
        f"{task}-{method}.zip": record.chosen(task, method)[0]
        for task, record in _by_task(records)
        for method in LEARNED
    }


def check(records: Sequence[Record], root: Path = ROOT) -> list[str]:
    """Every place where RESULTS.md, models/README.md or models/card.yaml disagree with ``records``."""
    problems = []
    results = (root / "RESULTS.md").read_text().splitlines()
    for row in headline_rows(records) + canonical_rows(records):
        if row not in results:
            problems.append(f"RESULTS.md lacks the row {row}")
    readme = (root / "models" / "README.md").read_text().splitlines()
    for file, tail in model_card_cells(records).items():
        rows = [line for line in readme if line.startswith(f"| `{file}` |")]
        if len(rows) != 1 or not rows[0].endswith(tail):
            problems.append(f"models/README.md: the row of {file} should end {tail}, found {rows or 'no row'}")
    pipeline = (root / "docs" / "pipeline.md").read_text().splitlines()
    for row in shipped_rows(records):
        if row not in pipeline:
            problems.append(f"docs/pipeline.md (make run's table) lacks the row {row}")
    card = yaml.safe_load((root / "models" / "card.yaml").read_text())
    made_by = {entry["file"]: entry.get("made_by", "") for entry in card["models"]}
    for file, seed in card_seeds(records).items():
        if not made_by.get(file, "").endswith(f"(seed {seed})"):
            problems.append(
                f"models/card.yaml: made_by of {file} should end (seed {seed}), found {made_by.get(file)!r}"
            )
    return problems


def _replace_keyed_rows(lines: list[str], header: str, rows: list[str], where: Path) -> None:
    """In the first table under ``header``, replace each row whose first two cells are those of one of ``rows``."""
    new = {tuple(_cells(row)[:2]): row for row in rows}
    for i in range(*_table_body(lines, header, where)):
        lines[i] = new.pop(tuple(_cells(lines[i])[:2]), lines[i])
    if new:
        raise ValueError(f"{where}: the table starting {header!r} has no row for {sorted(new)}")


def write(records: Sequence[Record], root: Path = ROOT) -> list[Path]:
    """Put the records' rows in the docs under ``root``, in place of the rows they hold; the files written."""
    path = root / "RESULTS.md"
    lines = path.read_text().splitlines()
    lines[slice(*_table_body(lines, INTERVAL_HEADER, path))] = headline_rows(records)
    lines[slice(*_table_body(lines, CANONICAL_HEADER, path))] = canonical_rows(records)
    path.write_text("\n".join(lines) + "\n")

    path = root / "models" / "README.md"
    lines = path.read_text().splitlines()
    for file, tail in model_card_cells(records).items():
        rows = [i for i, line in enumerate(lines) if line.startswith(f"| `{file}` |")]
        if len(rows) != 1:
            raise ValueError(f"{path}: expected one row of {file}, found {len(rows)}")
        recipe = _cells(lines[rows[0]])[:3]  # file, method, data and budget: the recipe, not the record's figures
        lines[rows[0]] = "| " + " | ".join(recipe) + " " + tail
    path.write_text("\n".join(lines) + "\n")

    path = root / "docs" / "pipeline.md"
    lines = path.read_text().splitlines()
    _replace_keyed_rows(lines, MAKE_RUN_HEADER, shipped_rows(records), path)
    path.write_text("\n".join(lines) + "\n")

    path = root / "models" / "card.yaml"
    seeds, file, lines = card_seeds(records), None, path.read_text().splitlines()
    for i, line in enumerate(lines):  # edited as text, so that the card's comments stay
        if match := re.match(r"\s*file: (\S+)", line):
            file = match.group(1)
        elif line.lstrip().startswith("made_by:") and file in seeds:
            lines[i] = re.sub(r"\(seed \d+\)\"$", f'(seed {seeds[file]})"', line)
    path.write_text("\n".join(lines) + "\n")
    return [root / name for name in ("RESULTS.md", "models/README.md", "docs/pipeline.md", "models/card.yaml")]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "records",
        nargs="*",
        type=Path,
        default=list(HEADLINE_RECORDS),
        help="finished full-preset records, each task's rows from the last one that ran it (default: the headline's)",
    )
    action = parser.add_mutually_exclusive_group()
    action.add_argument("--check", action="store_true", help="list where the docs disagree with the records")
    action.add_argument("--write", action="store_true", help="put the records' rows in the docs in place of theirs")
    args = parser.parse_args(argv)
    records = load_records(args.records)
    if args.write:
        for path in write(records):
            print(f"wrote {path.relative_to(ROOT)}")
    if args.write or args.check:
        problems = check(records)
        print("\n".join(problems) or f"the docs agree with {' and '.join(map(str, args.records))}")
        return 1 if problems else 0
    print(f"RESULTS.md, headline table:\n{INTERVAL_HEADER} ...")
    print("\n".join(headline_rows(records)))
    print("\nRESULTS.md, canonical models:")
    print("\n".join(canonical_rows(records)))
    print("\nmodels/README.md, last three cells of each row:")
    print("\n".join(f"`{file}` {tail}" for file, tail in model_card_cells(records).items()))
    print("\ndocs/pipeline.md, make run's wave and shipped rows:")
    print("\n".join(shipped_rows(records)))
    print("\nmodels/card.yaml, made_by ends:")
    print("\n".join(f"{file}: (seed {seed})" for file, seed in card_seeds(records).items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
