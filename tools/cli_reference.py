#!/usr/bin/env python
"""docs/cli.md, the command-line reference, written from the `dpr` parsers themselves, and a check that it is current.

Every command's help line (what `dpr --help` says of it) and its full `--help` text, formatted at a fixed width
(:data:`WIDTH` columns, whatever the terminal) so that the file is the same on every machine. The flags, defaults and
help texts live in one place, the parsers (dpr/cli); this page is their copy, so it is never edited by hand:
``--check`` exits 1 when the page differs from what the parsers say now, which tests/test_cli_reference.py runs.

    python tools/cli_reference.py           # write docs/cli.md
    python tools/cli_reference.py --check   # is docs/cli.md current? (exit status 1, and the first differences)
"""

from __future__ import annotations

import argparse
import difflib
import functools
import sys
import textwrap
from pathlib import Path

from dpr.atomic import atomic_write_text
from dpr.cli import COMMANDS, build_parser

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT / "docs" / "cli.md"
WIDTH = 100  # columns of every help text, as if COLUMNS=100
PAGE_WIDTH = 120  # the page's own prose
SHOWN_DIFFERENCES = 40  # lines of the diff --check prints


def command_parsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """Each subcommand's parser, by name."""
    (subparsers,) = (action for action in parser._actions if isinstance(action, argparse._SubParsersAction))
    return dict(subparsers.choices)


def help_text(parser: argparse.ArgumentParser) -> str:
    """``parser``'s `--help` text at :data:`WIDTH` columns."""
    parser.formatter_class = functools.partial(argparse.HelpFormatter, width=WIDTH)
    return parser.format_help().rstrip() + "\n"


def anchor(name: str) -> str:
    """The anchor GitHub gives the heading "`dpr <name>`"."""
    return f"dpr-{name}"


def table_cell(text: str) -> str:
    return text.replace("|", "\\|")


def bounds_section() -> list[str]:
    """The bounds every integer flag (and the same setting of a `dpr pipeline` config file) is checked against
    before a command starts (dpr.cli.common.FLAG_BOUNDS, dpr.limits)."""
    from dpr.cli.common import FLAG_BOUNDS
    from dpr.limits import MAX_MODEL_SEED, MAX_RAY_WORKERS, MAX_SETTINGS_BYTES, MiB

    # where a command narrows a flag's bound: --seed seeds a model or a run (numpy's global seed) but in dpr report
    narrower = {"seed": f"0 to {MAX_MODEL_SEED:,} (`dpr report`: 0 to {FLAG_BOUNDS['seed'][1]:,})"}
    rows = [
        f"| `--{dest.replace('_', '-')}` | {narrower.get(dest, f'{low:,} to {high:,}')} |"
        for dest, (low, high) in sorted(FLAG_BOUNDS.items())
    ]
    prose = (
        "Every count a command or a `dpr pipeline` config file takes is checked before any work, and a value out of "
        "range exits 2 naming the flag, the value and the range (dpr/limits.py). `--workers` may be at most this "
        f"machine's CPUs (at most {MAX_RAY_WORKERS:,} with `--backend ray`); what depends on several values at once "
        "(envs x robots, demonstrations x steps) is estimated and refused, with the estimate, when it cannot fit "
        f"this machine's memory. Settings files are read up to {MAX_SETTINGS_BYTES // MiB} MiB, without duplicate "
        "keys and with few yaml aliases."
    )
    return ["## Bounds", "", *textwrap.wrap(prose, PAGE_WIDTH), "", "| flag | allowed |", "|---|---|", *rows, ""]


def reference() -> str:
    """The whole of docs/cli.md."""
    parser = build_parser()
    parsers = command_parsers(parser)
    lines = [
        "# Command-line reference",
        "",
        *textwrap.wrap(
            f"Every `dpr` command's `--help`, written from the parsers by `python tools/cli_reference.py` (at {WIDTH} "
            "columns); do not edit it by hand: `tests/test_cli_reference.py` fails when it differs from what the "
            "parsers say. The main commands in order, with what they print, are in [tutorial.md](tutorial.md).",
            PAGE_WIDTH,
        ),
        "",
        "| command | what it does |",
        "|---|---|",
        *(f"| [`{c.name}`](#{anchor(c.name)}) | {table_cell(c.help)} |" for c in COMMANDS),
        "",
        *bounds_section(),
        "## `dpr`",
        "",
        "```text",
        help_text(parser).rstrip(),
        "```",
    ]
    for command in COMMANDS:
        lines += ["", f"## `dpr {command.name}`", "", command.help[:1].upper() + command.help[1:] + ".", ""]
        lines += ["```text", help_text(parsers[command.name]).rstrip(), "```"]
    return "\n".join(lines) + "\n"


def differences(written: str, current: str) -> list[str]:
    """The unified diff from the page on disk to the page the parsers make now."""
    return list(
        difflib.unified_diff(
            written.splitlines(), current.splitlines(), "docs/cli.md", "the parsers now", lineterm="", n=1
        )
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 when docs/cli.md differs from the parsers")
    args = parser.parse_args(argv)
    current = reference()
    if args.check:
        written = REFERENCE.read_text() if REFERENCE.exists() else ""
        if written == current:
            return 0
        diff = differences(written, current)
        print(*diff[:SHOWN_DIFFERENCES], sep="\n")
        if len(diff) > SHOWN_DIFFERENCES:
            print(f"... {len(diff) - SHOWN_DIFFERENCES} more lines")
        print(f"{REFERENCE.relative_to(ROOT)} is out of date: run `python tools/cli_reference.py`", file=sys.stderr)
        return 1
    atomic_write_text(REFERENCE, current)
    print(f"wrote {REFERENCE.relative_to(ROOT)} ({len(COMMANDS)} commands)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
