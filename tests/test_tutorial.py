"""docs/tutorial.md's commands, and the chain README.md shows, run as written at budgets of seconds: neither can rot.

Its `dpr ...` lines (from its bash blocks, in order) run through ``dpr.cli.main`` in a scratch folder, so that their
relative output paths land there; only their budgets are rewritten (:data:`BUDGETS`, :data:`HYPERPARAMETERS`: episodes,
frames, epochs, env steps, seeds), every other word stays the tutorial's. A renamed command or flag fails the run; a
flag the tutorial spells that is no longer the command's own fails too, even where argparse would accept it as the
abbreviation of a longer one.
"""

from __future__ import annotations

import functools
import re
import shlex
from pathlib import Path

import pytest
from helpers import load_tool, run_cli

ROOT = Path(__file__).resolve().parents[1]
TUTORIAL = ROOT / "docs" / "tutorial.md"
README = ROOT / "README.md"
BASH_BLOCK = re.compile(r"^```bash\n(.*?)^```", re.S | re.M)
# The chain each document walks, in this order (other commands may come between).
CHAINS = {
    TUTORIAL: ("collect", "replay", "bc", "finetune", "evaluate", "view"),
    README: ("collect", "bc", "finetune", "evaluate", "report"),
}
DOCUMENTS = pytest.mark.parametrize("document", list(CHAINS), ids=lambda path: path.name)
# Per command, the budget flags and their small values: set where the tutorial gives them, added where it does not.
# Frames and physics steps are few (a few decisions of a model deciding every 10 steps); two demonstrations are the
# fewest behaviour cloning takes (one is held out).
BUDGETS = {
    "collect": {"--episodes": "2", "--steps": "3"},
    "replay": {"--episodes": "0"},
    "bc": {"--epochs": "1"},
    "finetune": {"--timesteps": "16", "--critic-warmup": "16"},
    "evaluate": {"--seeds": "300", "--steps": "30"},
    "view": {"--steps": "30"},
}
# PPO's rollout and update sizes for the RL commands (--hyperparam NAME=VALUE), set or added likewise.
HYPERPARAMETERS = {"n_steps": "8", "batch_size": "8", "n_epochs": "1"}
RL_COMMANDS = ("finetune", "train")
# Where each command writes (the flag naming it, and the file that must be there after it ran).
OUTPUTS = {
    "collect": ("--out", "meta/info.json"),
    "bc": ("--out", "model.zip"),
    "finetune": ("--out", "model.zip"),
    "train": ("--out", "model.zip"),
    "evaluate": ("--json", ""),
    "report": ("--out", "results.md"),
    "view": ("--save", ""),
}


def tutorial_commands(text: str) -> list[list[str]]:
    """The arguments of every `dpr` line of ``text``'s bash blocks, in order (continued lines joined, comments
    dropped)."""
    commands = []
    for block in BASH_BLOCK.findall(text):
        for line in block.replace("\\\n", " ").splitlines():
            words = shlex.split(line, comments=True)
            if words[:1] == ["dpr"]:
                commands.append(words[1:])
    return commands


def set_flag(argv: list[str], flag: str, value: str) -> list[str]:
    """``argv`` with ``flag``'s one value replaced by ``value``, or with ``flag value`` appended."""
    if flag in argv:
        at = argv.index(flag)
        return [*argv[: at + 1], value, *argv[at + 2 :]]
    return [*argv, flag, value]


def set_hyperparameter(argv: list[str], name: str, value: str) -> list[str]:
    for at, word in enumerate(argv[:-1]):
        if word == "--hyperparam" and argv[at + 1].partition("=")[0] == name:
            return [*argv[: at + 1], f"{name}={value}", *argv[at + 2 :]]
    return [*argv, "--hyperparam", f"{name}={value}"]


def shrink(argv: list[str]) -> list[str]:
    """``argv`` at the test's budgets; every other word as it was."""
    command = argv[0]
    for flag, value in BUDGETS.get(command, {}).items():
        argv = set_flag(argv, flag, value)
    if command in RL_COMMANDS:
        for name, value in HYPERPARAMETERS.items():
            argv = set_hyperparameter(argv, name, value)
    return argv


@functools.cache
def command_flags() -> dict[str, set[str]]:
    """Every `dpr` command's option strings, by command."""
    from dpr.cli import build_parser

    flags = {}
    for name, parser in load_tool("cli_reference").command_parsers(build_parser()).items():
        parser.format_usage()  # a command's arguments are added on first use
        flags[name] = set(parser._option_string_actions)
    return flags


def unknown_flags(argv: list[str]) -> list[str]:
    """The flags of ``argv`` that are not, spelled out in full, flags of its command (``--x=1`` counts as ``--x``)."""
    known = command_flags().get(argv[0])
    if known is None:
        return [argv[0]]
    return [word for word in argv[1:] if word.startswith("-") and word.partition("=")[0] not in known]


@DOCUMENTS
def test_the_document_walks_the_whole_chain(document):
    names = [argv[0] for argv in tutorial_commands(document.read_text())]
    remaining = iter(names)
    assert all(step in remaining for step in CHAINS[document]), names  # a subsequence of the document's commands
    assert set(names) <= set(BUDGETS) | set(OUTPUTS), f"a command the test has no budgets for: {names}"


@DOCUMENTS
def test_every_flag_of_the_document_is_its_commands_own(document):
    unknown = {" ".join(argv): unknown_flags(argv) for argv in tutorial_commands(document.read_text())}
    assert {command: flags for command, flags in unknown.items() if flags} == {}


@DOCUMENTS
def test_the_document_runs_at_small_budgets(document, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for argv in tutorial_commands(document.read_text()):
        small = shrink(argv)
        assert run_cli(small) == 0, f"dpr {shlex.join(small)}"
        if argv[0] in OUTPUTS:
            flag, inside = OUTPUTS[argv[0]]
            assert flag in argv, f"dpr {shlex.join(argv)}: no {flag}"
            written = tmp_path / argv[argv.index(flag) + 1] / inside
            assert written.is_file(), f"dpr {shlex.join(small)}: no {written}"


def test_commands_are_read_from_bash_blocks_and_only_budgets_change():
    text = "\n".join(
        [
            "```bash",
            "dpr collect --env dpr/Navigation-v0 --episodes 20 \\",
            "            --out datasets/nav9   # a comment",
            "python -c 'print(1)'",
            "```",
            "```text",
            "dpr printed this",
            "```",
            "```bash",
            "dpr finetune --from m.zip --hyperparam gamma=0.9 --hyperparam n_steps=512 --out ft",
            "```",
        ]
    )
    collect, finetune = tutorial_commands(text)
    assert collect == ["collect", "--env", "dpr/Navigation-v0", "--episodes", "20", "--out", "datasets/nav9"]
    assert shrink(collect) == [*collect[:4], "2", *collect[5:], "--steps", "3"]
    assert shrink(finetune) == [
        *["finetune", "--from", "m.zip", "--hyperparam", "gamma=0.9", "--hyperparam", "n_steps=8", "--out", "ft"],
        *["--timesteps", "16", "--critic-warmup", "16", "--hyperparam", "batch_size=8", "--hyperparam", "n_epochs=1"],
    ]
    assert unknown_flags(["collect", "--episode", "2", "--out=x"]) == ["--episode"]
    assert unknown_flags(["collects", "--out", "x"]) == ["collects"]
