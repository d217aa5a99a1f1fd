"""`dpr` command line: record datasets, train and evaluate policies, benchmark the simulator.

One module per command group (:mod:`~dpr.cli.evaluate`, :mod:`~dpr.cli.learn`, :mod:`~dpr.cli.pipeline`,
:mod:`~dpr.cli.compare`, :mod:`~dpr.cli.bc`, :mod:`~dpr.cli.data`, :mod:`~dpr.cli.view`, :mod:`~dpr.cli.bench`)
owns its commands' arguments and handlers; :mod:`~dpr.cli.main` builds the parser from them and dispatches;
:mod:`~dpr.cli.common` holds what they share.
"""

from dpr.cli.common import ALL_ENVS, PARAMETER_FLAGS, TASK_NAMES, flag_message, parse_seeds, positive_int
from dpr.cli.main import COMMANDS, build_parser, main

__all__ = [
    "ALL_ENVS",
    "COMMANDS",
    "PARAMETER_FLAGS",
    "TASK_NAMES",
    "build_parser",
    "flag_message",
    "main",
    "parse_seeds",
    "positive_int",
]
