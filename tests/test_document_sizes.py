"""The documents, the shipped records and the modules stay within their size budgets.

A reference document that outgrows its budget keeps what holds now and its headline tables; the story of how they
were reached, superseded figures and long per-run narratives move to a dated entry of the research log
(docs/research/), whose index is docs/research/README.md. A record in docs/results/ keeps what its reports and the
documents read, compactly, and no pickles."""

from __future__ import annotations

import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
KB = 1024
MB = 1024 * KB

# file -> its budget in bytes
DOCUMENT_BUDGETS = {
    "README.md": 8_000,
    "RESULTS.md": 10 * KB,
    "docs/learning.md": 15 * KB,
}
RESULTS_TABLE_HEADER = "| task | method | runs × seeds |"  # RESULTS.md's headline table (tools/record_tables.py)
RESULTS_TABLE_WITHIN = 30  # lines: a reader sees the headline without scrolling past the story
RECORDS = "docs/results"
RECORDS_BUDGET = 10 * MB
PICKLE_SUFFIXES = (".pkl", ".pickle")
MODULES = "dpr"
MODULE_LINES = 600


def over_budget(path: Path, budget: int, root: Path = ROOT) -> str | None:
    """A message naming ``path``, its size and ``budget`` when the file is larger than ``budget`` bytes."""
    size = path.stat().st_size
    if size > budget:
        return f"{path.relative_to(root)} is {size:,} bytes, over its budget of {budget:,} bytes"
    return None


def table_too_late(path: Path, header: str, within: int, root: Path = ROOT) -> str | None:
    """A message when the table starting with ``header`` is not wholly within the first ``within`` lines."""
    lines = path.read_text().splitlines()
    start = next((i for i, line in enumerate(lines) if line.startswith(header)), None)
    if start is None:
        return f"{path.relative_to(root)} has no table starting {header!r}"
    end = start
    while end + 1 < len(lines) and lines[end + 1].startswith("|"):
        end += 1
    if end + 1 > within:
        return (
            f"{path.relative_to(root)}: its results table ends on line {end + 1}, past its budget of the first "
            f"{within} lines"
        )
    return None


def folder_over_budget(folder: Path, budget: int, root: Path = ROOT) -> str | None:
    """A message naming ``folder``, its total size and ``budget`` when its files together pass ``budget`` bytes."""
    files = [path for path in folder.rglob("*") if path.is_file()]
    size = sum(path.stat().st_size for path in files)
    if size > budget:
        largest = sorted(files, key=lambda path: path.stat().st_size, reverse=True)[:5]
        named = ", ".join(f"{path.relative_to(root)} ({path.stat().st_size:,})" for path in largest)
        return f"{folder.relative_to(root)} holds {size:,} bytes, over its budget of {budget:,} bytes; largest: {named}"
    return None


def is_pickle(path: Path) -> bool:
    """Named as a pickle, starting with a pickle's protocol header (PROTO, protocols 2-5), or a zip archive holding
    one (as torch.save writes them)."""
    if path.suffix.lower() in PICKLE_SUFFIXES:
        return True
    with path.open("rb") as file:
        head = file.read(2)
    if len(head) == 2 and head[0] == 0x80 and 2 <= head[1] <= 5:
        return True
    if zipfile.is_zipfile(path):
        with zipfile.ZipFile(path) as archive:
            return any(name.lower().endswith(PICKLE_SUFFIXES) for name in archive.namelist())
    return False


def pickles_in(folder: Path, root: Path = ROOT) -> list[str]:
    """Every pickle under ``folder``, by its path."""
    return sorted(str(path.relative_to(root)) for path in folder.rglob("*") if path.is_file() and is_pickle(path))


def long_modules(folder: Path, limit: int, root: Path = ROOT) -> list[str]:
    """A message for every Python module under ``folder`` of more than ``limit`` lines."""
    problems = []
    for path in sorted(folder.rglob("*.py")):
        with path.open("rb") as file:
            lines = sum(1 for _ in file)
        if lines > limit:
            problems.append(f"{path.relative_to(root)} has {lines} lines, over the budget of {limit} per module")
    return problems


@pytest.mark.parametrize("name", list(DOCUMENT_BUDGETS))
def test_each_document_is_within_its_budget(name):
    problem = over_budget(ROOT / name, DOCUMENT_BUDGETS[name])
    assert problem is None, problem


def test_the_results_table_is_within_results_mds_first_30_lines():
    problem = table_too_late(ROOT / "RESULTS.md", RESULTS_TABLE_HEADER, RESULTS_TABLE_WITHIN)
    assert problem is None, problem


def test_the_records_are_within_their_budget():
    problem = folder_over_budget(ROOT / RECORDS, RECORDS_BUDGET)
    assert problem is None, problem


def test_the_records_hold_no_pickles():
    pickles = pickles_in(ROOT / RECORDS)
    assert pickles == [], f"{RECORDS} must hold no pickles (a record is data anyone may open): {pickles}"


def test_no_module_is_over_600_lines():
    problems = long_modules(ROOT / MODULES, MODULE_LINES)
    assert problems == [], "; ".join(problems)


# The checks bite: each is shown a file past its budget.


def test_a_readme_past_its_budget_is_named(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text((ROOT / "README.md").read_text() + "x" * 8_001)
    problem = over_budget(readme, DOCUMENT_BUDGETS["README.md"], root=tmp_path)
    assert problem == f"README.md is {readme.stat().st_size:,} bytes, over its budget of 8,000 bytes"
    readme.write_text("x" * 8_000)  # at the budget is within it
    assert over_budget(readme, DOCUMENT_BUDGETS["README.md"], root=tmp_path) is None


def test_a_results_table_pushed_down_is_named(tmp_path):
    results = tmp_path / "RESULTS.md"
    results.write_text("intro\n" * 20 + (ROOT / "RESULTS.md").read_text())
    problem = table_too_late(results, RESULTS_TABLE_HEADER, RESULTS_TABLE_WITHIN, root=tmp_path)
    assert problem is not None and problem.startswith("RESULTS.md: its results table ends on line ")
    results.write_text("# Results\n")
    assert "has no table starting" in table_too_late(results, RESULTS_TABLE_HEADER, RESULTS_TABLE_WITHIN, tmp_path)


def test_a_records_folder_past_its_budget_and_its_pickles_are_named(tmp_path):
    import pickle

    records = tmp_path / "docs" / "results"
    (records / "run" / "eval").mkdir(parents=True)
    (records / "run" / "eval" / "big.json").write_bytes(b" " * 2_000)
    (records / "run" / "buffer.bin").write_bytes(pickle.dumps({"obs": [1, 2]}, protocol=4))
    (records / "run" / "rollouts.pkl").write_bytes(b"")
    with zipfile.ZipFile(records / "run" / "model.pt", "w") as archive:
        archive.writestr("model/data.pkl", pickle.dumps([1]))
    problem = folder_over_budget(records, 1_000, root=tmp_path)
    assert problem is not None and problem.startswith("docs/results holds ")
    assert "over its budget of 1,000 bytes" in problem and "docs/results/run/eval/big.json (2,000)" in problem
    (records / "run" / "report.png").write_bytes(b"\x89PNG\r\n")
    assert pickles_in(records, root=tmp_path) == [
        f"docs/results/run/{name}" for name in ("buffer.bin", "model.pt", "rollouts.pkl")
    ]


def test_a_long_module_is_named(tmp_path):
    package = tmp_path / "dpr" / "sub"
    package.mkdir(parents=True)
    (package / "short.py").write_text("x = 1\n" * MODULE_LINES)
    (package / "long.py").write_text("x = 1\n" * (MODULE_LINES + 1))
    assert long_modules(tmp_path / "dpr", MODULE_LINES, root=tmp_path) == [
        "dpr/sub/long.py has 601 lines, over the budget of 600 per module"
    ]
