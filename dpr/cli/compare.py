"""`dpr compare`: two recipes' validation IQMs, task by task, and the adoption rule (dpr.evaluation.compare)."""

from __future__ import annotations

import argparse
from pathlib import Path

from dpr.cli.common import TASK_NAMES, Command, defaults, flag_message
from dpr.envs import ENV_IDS

COMPARE_FLAGS = {"current": "CURRENT", "candidate": "CANDIDATE"}


def compare_arguments(parser: argparse.ArgumentParser) -> None:
    from dpr.evaluation.compare import compare

    parser.add_argument(
        "current", metavar="CURRENT", type=Path, help="run folder of the recipe in force (e.g. docs/results/full-lr3e4)"
    )
    parser.add_argument(
        "candidate",
        metavar="CANDIDATE",
        type=Path,
        nargs="+",
        help="run folder of the candidate recipe, or one per task where its tasks ran side by side",
    )
    parser.add_argument(
        "--tasks",
        nargs="+",
        default=list(TASK_NAMES),
        choices=tuple(ENV_IDS),  # the registered ones: an --env-package's too
        metavar="TASK",
        help=f"the tasks the rule averages over, of {', '.join(ENV_IDS)} (default: the built-in four)",
    )
    method = defaults(compare)["method"]
    parser.add_argument(
        "--method",
        default=method,
        help=f"the learned method whose ratios decide: bc, bc-ppo or ppo, as the run files name it (default {method})",
    )


def cmd_compare(args, parser) -> int:
    from dpr.evaluation.compare import compare, format_comparison

    try:
        rows, mean = compare(args.current, args.candidate, args.tasks, args.method)
    except ValueError as error:
        parser.error(flag_message(error, COMPARE_FLAGS))
    print(format_comparison(rows, mean, args.tasks, args.method))
    return 0


COMMANDS = (
    Command(
        "compare",
        help="decide on validation seeds whether a candidate recipe replaces the current one",
        description="Compare two `dpr pipeline` run folders (or records of them) on their validation seeds. For "
        "every task and learned method both hold, the episodes of every training run on the validation seeds "
        "(eval/validation/<task>-<method>-seed<S>.json) are pooled; the table gives their IQM in each folder and "
        "the ratio candidate / current. The last line applies the adoption rule: the candidate wins if the mean "
        "over --tasks of the --method ratios is above 1, once every task has as many runs in both folders; until "
        "then it says no decision yet. Only validation evaluations are read, never test ones, so a candidate's "
        "test seeds stay unseen. Runs scored differently are refused, naming what differs: other validation seeds, "
        "episode lengths (steps), env ids (task versions), N, robot models or env kwargs that set the task (those of "
        "the policy's own interface, such as action_repeat or obs_last_action, may differ). A candidate whose tasks "
        "ran side by side is given as one folder per task.",
        arguments=compare_arguments,
        run=cmd_compare,
        flags=COMPARE_FLAGS,
    ),
)
