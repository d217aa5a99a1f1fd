"""tools/record_tables.py: RESULTS.md, models/README.md, models/card.yaml and docs/learning.md quote the headline
record."""

import shutil
from pathlib import Path

import pytest
from helpers import load_tool

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def tool():
    return load_tool("record_tables")


@pytest.fixture(scope="module")
def record(tool):
    return tool.Record(tool.HEADLINE_RECORD)


def test_the_docs_quote_the_headline_record(tool, record):
    assert tool.check(record) == []
    assert tool.main(["--check"]) == 0
    assert len(tool.headline_rows(record)) == 4 * 5  # wave, teacher and three learned methods per task
    assert len(tool.model_card_cells(record)) == 12
    assert len(tool.shipped_rows(record)) == 4 * 4  # the wave and three shipped models per task


def _docs_copy(dest: Path) -> Path:
    for name in ("RESULTS.md", "models/README.md", "models/card.yaml", "docs/learning.md"):
        (dest / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(ROOT / name, dest / name)
    return dest


def _replace_once(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert text.count(old) == 1, old
    path.write_text(text.replace(old, new))


def test_a_misquoted_figure_is_named(tool, record, tmp_path):
    docs = _docs_copy(tmp_path)
    _replace_once(docs / "RESULTS.md", "**111% [101, 120]**", "**125% [101, 120]**")
    _replace_once(docs / "models/README.md", "33.9 (110%)", "38.5 (125%)")
    _replace_once(
        docs / "models/card.yaml",
        "PPO 600k physics steps; median of training seeds 0-2 (seed 1)",
        "PPO 600k physics steps; median of training seeds 0-2 (seed 0)",
    )
    _replace_once(docs / "docs/learning.md", "| Gate | shipped bc-ppo | 72.7 |", "| Gate | shipped bc-ppo | 77.2 |")
    problems = tool.check(record, docs)
    assert len(problems) == 4, problems
    assert problems[0].startswith("RESULTS.md lacks the row | Unresponsive | BC→PPO |")
    assert "unresponsive-bc-ppo.zip" in problems[1] and "33.9 (110%)" in problems[1]
    assert problems[2] == (
        "docs/learning.md (make run's table) lacks the row "
        "| Gate | shipped bc-ppo | 72.7 | 33.1 | 80.7 | 64.9 ± 17.6 | 142% |"
    )
    assert problems[3].startswith("models/card.yaml: made_by of navigation-bc-ppo.zip should end (seed 1)")


def test_a_folder_that_is_not_a_record_is_refused(tool, tmp_path):
    with pytest.raises(FileNotFoundError, match="choices.yaml: missing"):
        tool.Record(tmp_path)


@pytest.mark.parametrize("name", ["full-bins", "full", "full-hold10"])
def test_the_earlier_records_print_their_tables_too(tool, name):
    record = tool.Record(ROOT / "docs" / "results" / name)
    assert record.tasks == ["navigation", "gate", "unresponsive", "manipulation"]
    assert len(tool.canonical_rows(record)) == 4
    assert {row.split(" | ")[1] for row in tool.headline_rows(record)} >= {"wave", "BC", "BC→PPO", "PPO from scratch"}
