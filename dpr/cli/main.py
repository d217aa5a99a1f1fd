"""The `dpr` entry point: one parser with a subcommand per :class:`~dpr.cli.common.Command`, and dispatch."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable

from dpr import interrupts
from dpr.cli import bc, bench, compare, data, evaluate, learn, pipeline, view
from dpr.cli.common import ALL_ENVS, OUTPUT_FLAGS, check_bounds, unwritable_destination
from dpr.envs import TASKS, load_env_packages
from dpr.envs.tasks import ENV_PACKAGE_ERRORS, ENV_PACKAGES_VARIABLE

COMMANDS = (
    *evaluate.COMMANDS,
    *learn.COMMANDS,
    *pipeline.COMMANDS,
    *compare.COMMANDS,
    *bc.COMMANDS,
    *data.COMMANDS,
    *bench.COMMANDS,
    *view.COMMANDS,
)


class CommandParser(argparse.ArgumentParser):
    """A subcommand's parser whose arguments are added on first use (parsing, help or usage): `dpr --help` and
    every other command never import the modules that one command's defaults come from."""

    def __init__(self, *args, arguments: Callable[[argparse.ArgumentParser], None] | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self._add_arguments = arguments

    def _define(self) -> None:
        add, self._add_arguments = self._add_arguments, None
        if add is not None:
            add(self)

    def parse_known_args(self, args=None, namespace=None):
        self._define()
        return super().parse_known_args(args, namespace)

    def format_usage(self) -> str:
        self._define()
        return super().format_usage()

    def format_help(self) -> str:
        self._define()
        return super().format_help()


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="dpr", description="Deep Particle Robot: particle-robot swarms for robot learning."
    )
    env_package_argument(parser)
    sub = parser.add_subparsers(dest="command", required=True, parser_class=CommandParser)
    for command in COMMANDS:
        command_parser = sub.add_parser(
            command.name, help=command.help, description=command.description, arguments=command.arguments
        )
        env_package_argument(command_parser)
        command_parser.set_defaults(func=command.run, command_parser=command_parser)
    return parser


ENV_PACKAGE_FLAG = "--env-package"


def env_package_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        ENV_PACKAGE_FLAG,
        action="append",
        default=[],
        metavar="PKG",
        help="import PKG first, a package whose import registers more tasks (dpr.envs.register_task) or robot "
        "models (dpr.sim.register_robot_model), so that every --env, --tasks, --robot-model and dataset or model of "
        "them is accepted; repeat for several (also: DPR_ENV_PACKAGES=PKG1,PKG2; docs/add-a-task.md, "
        "docs/add-a-robot-model.md)",
    )


def requested_env_packages(argv: list[str] | None) -> list[str]:
    """The --env-package values anywhere on the command line: they are imported before the command's arguments
    are defined, since its choices of tasks are the registered ones."""
    scan = argparse.ArgumentParser(add_help=False, allow_abbrev=False)  # --env is not --env-package
    env_package_argument(scan)
    known, _ = scan.parse_known_args(argv)
    return known.env_package


def wants_help(argv: list[str] | None) -> bool:
    """Whether the command line asks for help (``-h``/``--help``): then no --env-package is imported, since
    importing one runs its code."""
    return any(arg in ("-h", "--help") for arg in (sys.argv[1:] if argv is None else argv) if arg != "--")


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    if ENV_PACKAGE_ERRORS:  # DPR_ENV_PACKAGES names a package whose import failed when dpr was imported
        parser.error(f"{ENV_PACKAGES_VARIABLE}: {ENV_PACKAGE_ERRORS[0]}")
    if not wants_help(argv):
        try:
            load_env_packages(requested_env_packages(argv))
        except ValueError as error:
            parser.error(f"{ENV_PACKAGE_FLAG}: {error}")
    args = parser.parse_args(argv)
    parser = args.command_parser  # errors are the command's, with its usage: "dpr pipeline: error: ..."
    interrupts.install()  # a Ctrl-C is never lost in a callback from C code (dpr.interrupts)
    check_bounds(args, parser)  # every count within its bound, before any work (dpr.limits)
    if getattr(args, "env", None) and args.env != [ALL_ENVS]:
        requested = [args.env] if isinstance(args.env, str) else args.env
        unknown = [e for e in requested if e not in TASKS]
        if unknown:
            parser.error(
                f"--env: unknown env id(s) {unknown}; choose from {list(TASKS)} or '{ALL_ENVS}' "
                f"(a task of another package: {ENV_PACKAGE_FLAG} PKG)"
            )
    for name in OUTPUT_FLAGS:
        value = getattr(args, name, None)
        problem = unwritable_destination(value) if isinstance(value, str) else None
        if problem:
            parser.error(f"--{name}: {problem}")
    try:
        return args.func(args, parser)
    except KeyboardInterrupt:  # commands that keep work on Ctrl-C say so and return 130 themselves
        print(f"{parser.prog}: interrupted", file=sys.stderr)
        return 130
