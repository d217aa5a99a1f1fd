"""tools/record_tables.py: RESULTS.md, models/README.md, models/card.yaml and docs/pipeline.md quote the headline
record."""

import re
import shutil
from pathlib import Path

import pytest
import yaml
from helpers import load_tool

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def tool():
    return load_tool("record_tables")


HEADLINE = ROOT / "docs" / "results" / "full-lr3e4"  # the record of all four tasks
GATE = ROOT / "docs" / "results" / "gate-v2-averaged"  # Gate's record (dpr/Gate-v2), whose rows replace the first one's


@pytest.fixture(scope="module")
def records(tool):
    return tool.load_records(tool.HEADLINE_RECORDS)


def test_the_docs_quote_the_headline_record(tool, records):
    assert tool.check(records) == []
    assert tool.main(["--check"]) == 0
    assert len(tool.headline_rows(records)) == 4 * 5  # wave, teacher and three learned methods per task
    assert len(tool.model_card_cells(records)) == 12
    assert len(tool.shipped_rows(records)) == 4 * 4  # the wave and three shipped models per task


DOCS = ("RESULTS.md", "models/README.md", "models/card.yaml", "docs/pipeline.md")


def _docs_copy(dest: Path) -> Path:
    for name in DOCS:
        (dest / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(ROOT / name, dest / name)
    return dest


def _replace_once(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert text.count(old) == 1, old
    path.write_text(text.replace(old, new))


def _misquoted(row: str) -> str:
    """``row`` with its first figure changed."""
    return re.sub(r"\d", lambda digit: str((int(digit.group()) + 1) % 10), row, count=1)


def test_a_misquoted_figure_is_named(tool, records, tmp_path):
    docs = _docs_copy(tmp_path)
    headline = next(row for row in tool.headline_rows(records) if row.startswith("| Unresponsive | BC→PPO |"))
    _replace_once(docs / "RESULTS.md", headline, _misquoted(headline))
    tail = tool.model_card_cells(records)["unresponsive-bc-ppo.zip"]
    _replace_once(docs / "models/README.md", tail, _misquoted(tail))
    seed = tool.card_seeds(records)["navigation-bc-ppo.zip"]
    card = (docs / "models/card.yaml").read_text().splitlines()  # Navigation's made_by may read as Gate's: by line
    at = next(i for i in range(card.index("    file: navigation-bc-ppo.zip"), len(card)) if "made_by:" in card[i])
    card[at] = card[at].replace(f"(seed {seed})", f"(seed {seed + 1})")
    (docs / "models/card.yaml").write_text("\n".join(card) + "\n")
    shipped = next(row for row in tool.shipped_rows(records) if row.startswith("| Gate | shipped bc-ppo |"))
    _replace_once(docs / "docs/pipeline.md", shipped, _misquoted(shipped))
    problems = tool.check(records, docs)
    assert len(problems) == 4, problems
    assert problems[0] == f"RESULTS.md lacks the row {headline}"
    assert "unresponsive-bc-ppo.zip" in problems[1] and tail in problems[1]
    assert problems[2] == f"docs/pipeline.md (make run's table) lacks the row {shipped}"
    assert problems[3].startswith(f"models/card.yaml: made_by of navigation-bc-ppo.zip should end (seed {seed})")


def _other_record(tool, folder: Path, tasks=("navigation", "unresponsive", "manipulation"), source=HEADLINE) -> Path:
    """A record of ``tasks`` in ``folder`` unlike ``source``: the same evaluations, another chosen run of every
    learned method and other figures in its report's interval table."""
    (folder / "report").mkdir(parents=True)
    (folder / "eval").symlink_to(source / "eval", target_is_directory=True)
    choices = yaml.safe_load((source / "choices.yaml").read_text())
    choices = {name: choice for name, choice in choices.items() if name.startswith(tuple(f"{t}-" for t in tasks))}
    for choice in choices.values():
        if "chosen_seed" in choice:
            seeds = sorted(choice["validation_medians"])
            choice["chosen_seed"] = seeds[(seeds.index(choice["chosen_seed"]) + 1) % len(seeds)]
    (folder / "choices.yaml").write_text(yaml.safe_dump(choices))
    report = folder / "report" / "results.md"
    lines = (source / "report" / "results.md").read_text().splitlines()
    for i in range(*tool._table_body(lines, tool.INTERVAL_HEADER, report)):
        cells = tool._cells(lines[i])
        shifted = [re.sub(r"\d", lambda digit: str((int(digit.group()) + 1) % 10), cell) for cell in cells[2:]]
        lines[i] = "| " + " | ".join(cells[:2] + shifted) + " |"
    report.write_text("\n".join(lines) + "\n")
    return folder


def test_write_puts_a_records_rows_in_the_docs_and_nothing_else(tool, records, tmp_path):
    """Writing another record's rows makes the docs quote it; writing the headline's back restores every file to
    the byte."""
    docs = _docs_copy(tmp_path)
    others = [_other_record(tool, tmp_path / "other"), _other_record(tool, tmp_path / "gate", ["gate"], GATE)]
    other = tool.load_records(others)
    assert not set(tool.headline_rows(other)) & set(tool.headline_rows(records))
    assert all(tool.card_seeds(other)[file] != seed for file, seed in tool.card_seeds(records).items())
    tool.write(other, docs)
    assert tool.check(other, docs) == []
    assert len(tool.check(records, docs)) > 10
    results = (docs / "RESULTS.md").read_text()
    assert "PPO from scratch for 1,410,000 physics steps" in results  # the prose is the adopter's to change
    tool.write(records, docs)
    for name in DOCS:
        assert (docs / name).read_bytes() == (ROOT / name).read_bytes(), name


def test_a_record_of_one_task_gives_its_rows_beside_a_record_of_all(tool, records, tmp_path):
    """Listed after the record of all four tasks, a record of Gate alone gives Gate's rows, the first the others'."""
    docs = _docs_copy(tmp_path)
    gate = _other_record(tool, tmp_path / "gate", ["gate"], GATE)
    both = tool.load_records([HEADLINE, gate])
    assert [record.tasks for record in both] == [["navigation", "unresponsive", "manipulation"], ["gate"]]
    rows, own = tool.headline_rows(both), set(tool.headline_rows(records))
    assert len(rows) == 4 * 5 and rows[5:10] == tool.headline_rows(tool.load_records([gate]))
    assert [row in own for row in rows] == [not row.startswith("| Gate |") for row in rows]
    tool.write(both, docs)
    assert tool.check(both, docs) == []
    problems = tool.check(records, docs)
    assert problems and all("gate" in problem.lower() for problem in problems), problems


def test_write_refuses_docs_without_the_tables(tool, records, tmp_path):
    docs = _docs_copy(tmp_path)
    (docs / "RESULTS.md").write_text("# Results\n")
    with pytest.raises(ValueError, match="RESULTS.md: no table starting"):
        tool.write(records, docs)


def test_a_folder_that_is_not_a_record_is_refused(tool, tmp_path):
    with pytest.raises(FileNotFoundError, match="choices.yaml: missing"):
        tool.Record(tmp_path)


@pytest.mark.parametrize("record, tasks", [(HEADLINE, 4), (GATE, 1)], ids=["full-lr3e4", "gate-v2-averaged"])
def test_the_headline_records_reprint_their_reports_from_their_sources(tool, tmp_path, record, tasks):
    """`dpr report` over the files and labels a record's results.md names gives its tables again: the record is
    evidence on its own, with no campaign tool and no resume. (full-lr3e4 was written before dpr/Gate-v1, when the
    report named its Gate-v0 rows "Gate".)"""
    from dpr.evaluation.report import write_report

    text = (record / "report" / "results.md").read_text()
    sources = re.findall(r"`([^`]+\.json)` \(([^:]+):", text.splitlines()[-1])
    assert len(sources) == tasks * (2 + 3 * 3)  # per task: the wave, the teacher, three runs of three methods
    write_report([ROOT / path for path, _ in sources], tmp_path, labels=[label for _, label in sources], root=ROOT)
    rows = [line.replace("| Gate-v0 |", "| Gate |") for line in (tmp_path / "results.md").read_text().splitlines()]
    rows = [line for line in rows if line.startswith("|")]
    assert rows == [line for line in text.splitlines() if line.startswith("|")]
