"""The documents and modules stay within the sizes that keep them readable.

Each budget fails with the file, its size and the budget. History goes into the dated research log
(docs/research/), not into these files.
"""

from __future__ import annotations

import pickletools
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
KB = 1024
FILE_BUDGETS = {"README.md": 8_000, "RESULTS.md": 10 * KB, "docs/learning.md": 15 * KB}
RESULTS_TABLE_WITHIN = 30  # lines: RESULTS.md opens with its results table
RECORDS = "docs/results"
RECORDS_BUDGET = 10 * KB * KB
PICKLE_SUFFIXES = (".pkl", ".pickle", ".pt", ".pth", ".joblib")
MODULE_LINES = 600


def over_budget(path: Path, budget: int) -> str | None:
    """A message naming ``path``, its size and ``budget`` when the file is larger; None when it fits."""
    size = path.stat().st_size
    shown = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path
    return f"{shown}: {size:,} bytes, over its budget of {budget:,}" if size > budget else None


def folder_size(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


def is_pickle(path: Path) -> bool:
    """A pickle by name, or by content: a pickle protocol 2+ header (``\\x80`` and the protocol) that
    ``pickletools`` can walk."""
    if path.suffix in PICKLE_SUFFIXES:
        return True
    head = path.read_bytes()[:2]
    if len(head) < 2 or head[0] != 0x80 or not 2 <= head[1] <= 5:
        return False
    try:
        for _ in pickletools.genops(path.read_bytes()):
            pass
    except Exception:
        return False
    return True


@pytest.mark.parametrize("name", sorted(FILE_BUDGETS))
def test_each_document_fits_its_budget(name):
    assert over_budget(ROOT / name, FILE_BUDGETS[name]) is None, over_budget(ROOT / name, FILE_BUDGETS[name])


def test_the_budget_check_names_a_grown_readme(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text((ROOT / "README.md").read_text() + "x" * 8_001)
    message = over_budget(readme, FILE_BUDGETS["README.md"])
    assert message is not None and "README.md" in message and "8,000" in message
    readme.write_text("short")
    assert over_budget(readme, FILE_BUDGETS["README.md"]) is None


def test_results_opens_with_its_table():
    lines = (ROOT / "RESULTS.md").read_text().splitlines()[:RESULTS_TABLE_WITHIN]
    assert any(line.startswith("| task |") for line in lines), (
        f"RESULTS.md: its results table must start within its first {RESULTS_TABLE_WITHIN} lines"
    )


def test_the_records_fit_their_budget_and_hold_no_pickles():
    size = folder_size(ROOT / RECORDS)
    assert size <= RECORDS_BUDGET, f"{RECORDS}: {size:,} bytes, over its budget of {RECORDS_BUDGET:,}"
    pickles = [str(p.relative_to(ROOT)) for p in (ROOT / RECORDS).rglob("*") if p.is_file() and is_pickle(p)]
    assert pickles == [], f"{RECORDS} holds pickles (records are data that runs no code): {pickles}"


def test_the_pickle_check_finds_one_by_content(tmp_path):
    import pickle

    disguised = tmp_path / "scores.json"
    disguised.write_bytes(pickle.dumps({"median": 1.0}))
    plain = tmp_path / "plain.json"
    plain.write_text('{"median": 1.0}')
    assert is_pickle(disguised) and not is_pickle(plain)


def test_no_module_is_over_its_line_budget():
    long = {
        str(p.relative_to(ROOT)): n
        for p in (ROOT / "dpr").rglob("*.py")
        if (n := len(p.read_text().splitlines())) > MODULE_LINES
    }
    assert long == {}, f"modules over {MODULE_LINES} lines: {long}"
