"""Every relative link in the documents leads to a file that exists (and to a heading of it, where it names one),
and every model file the documents cite is in the repository or made by a command they give."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCUMENTS = sorted(
    path
    for path in [*ROOT.glob("*.md"), *ROOT.glob("docs/**/*.md"), *ROOT.glob("models/*.md")]
    if "docs/results/" not in path.relative_to(ROOT).as_posix()
)
# the research log's entry on the recipes before the pipeline names their models, which are not shipped, beside the
# commands that made them
HAND_RUN_RECIPES = ROOT / "docs" / "research" / "hand-run-recipes.md"
LINK = re.compile(r"\]\(([^)\s]+)\)")
MODEL_FILE = re.compile(r"(?<![\w/.-])models/[\w.-]+\.zip")


def github_anchor(heading: str) -> str:
    """The anchor GitHub gives a heading: lower case, punctuation but hyphens dropped, spaces to hyphens."""
    text = re.sub(r"[`*_]", "", heading.strip().lower())
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    text = re.sub(r"```.*?```", "", path.read_text(), flags=re.S)  # headings only, not comments in code blocks
    return {github_anchor(line.lstrip("#")) for line in text.splitlines() if re.match(r"#{1,6} ", line)}


def test_every_relative_link_leads_to_a_file_and_heading_that_exist():
    broken = []
    for document in DOCUMENTS:
        for target in LINK.findall(document.read_text()):
            if re.match(r"[a-z]+:", target):  # http:, https:, mailto:
                continue
            file, _, anchor = target.partition("#")
            path = (document.parent / file).resolve() if file else document
            where = f"{document.relative_to(ROOT)}: {target}"
            if not path.exists():
                broken.append(f"{where} (no such file)")
            elif anchor and path.suffix == ".md" and anchor not in anchors(path):
                broken.append(f"{where} (no such heading)")
    assert broken == []


def test_every_model_file_the_documents_cite_is_shipped():
    """(Except the models of the hand-run recipes: ``HAND_RUN_RECIPES``.)"""
    assert HAND_RUN_RECIPES in DOCUMENTS
    shipped = {f"models/{path.name}" for path in (ROOT / "models").glob("*.zip")}
    cited = {
        f"{document.relative_to(ROOT)}: {name}"
        for document in DOCUMENTS
        if document != HAND_RUN_RECIPES
        for name in MODEL_FILE.findall(document.read_text())
        if name not in shipped
    }
    assert cited == set()


def test_the_documents_record_demonstrations_as_the_readme_does():
    """The README's `dpr collect` (its teacher and decision interval) is the one datasets.md and learning.md show."""
    collect = re.compile(r"dpr collect --env dpr/Navigation-v0 (--policy \S+ --env-kwarg action_repeat=\d+)")
    (readme,) = collect.findall((ROOT / "README.md").read_text())
    for name in ("docs/datasets.md", "docs/learning.md"):
        assert collect.findall((ROOT / name).read_text()) == [readme], name
