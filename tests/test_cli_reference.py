"""docs/cli.md is what tools/cli_reference.py writes from the parsers now: a flag, default or help text changed in
dpr/cli fails here until the page is written again (`python tools/cli_reference.py`)."""

from __future__ import annotations

import os

from helpers import load_tool


def test_cli_reference_is_current(capsys):
    tool = load_tool("cli_reference")
    assert tool.main(["--check"]) == 0, capsys.readouterr().out


def test_cli_reference_has_every_command_and_ignores_the_terminal_width(monkeypatch):
    from dpr.cli import COMMANDS

    tool = load_tool("cli_reference")
    monkeypatch.setenv("COLUMNS", "60")
    page = tool.reference()
    for command in COMMANDS:
        assert f"## `dpr {command.name}`" in page
        assert f"usage: dpr {command.name} " in page
    assert page == tool.REFERENCE.read_text()


def test_check_fails_and_shows_the_difference_when_the_page_is_stale(tmp_path, monkeypatch, capsys):
    tool = load_tool("cli_reference")
    stale = tmp_path / "cli.md"
    stale.write_text(tool.REFERENCE.read_text().replace("--episodes EPISODES", "--episode-count N"))
    monkeypatch.setattr(tool, "REFERENCE", stale)
    monkeypatch.setattr(tool, "ROOT", tmp_path)
    assert tool.main(["--check"]) == 1
    out = capsys.readouterr()
    assert "-" in out.out and "--episode-count N" in out.out and "out of date" in out.err
    assert tool.main([]) == 0 and tool.main(["--check"]) == 0
    assert os.listdir(tmp_path) == ["cli.md"]
