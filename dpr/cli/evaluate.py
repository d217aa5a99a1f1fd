"""`dpr evaluate` (a policy scored with the paper's metrics over seeds) and `dpr report` (tables and figures from
its JSON files)."""

from __future__ import annotations

import argparse
import sys

from dpr.cli.common import (
    ALL_ENVS,
    ENV_ID_LIST,
    EXAMPLE_ENV_ID,
    Command,
    apply_engine_defaults,
    check_output,
    check_rerun_output,
    compile_argument,
    defaults,
    engine_arguments,
    env_kwarg_argument,
    flag_message,
    json_argument,
    markov_env_kwargs,
    parse_seeds,
    policy_env_kwargs,
    positive_int,
    rerun_argument,
    swarm_arguments,
    workers_argument,
)

DEFAULT_SEEDS = "0-4"


def evaluate_arguments(parser: argparse.ArgumentParser) -> None:
    from dpr.evaluation.scoring import evaluate
    from dpr.policies.registry import WAVE

    parser.add_argument(
        "--policy",
        default=WAVE,
        help="'wave' (the paper's hand-crafted policy), 'wave-markov' "
        "(its phase read from the observation), either with another hold or bin width "
        "('wave-markov:hold_steps=6,bin_width=50'), "
        "'decentralised-wave' (every robot decides from its own local "
        "observation; 'decentralised-wave:n_phases=6' for six phases a cycle), 'random', or a model file "
        "MODEL.zip written by `dpr train`/`dpr bc` (run with the env kwargs it was trained with)",
    )
    parser.add_argument("--env", nargs="+", default=[EXAMPLE_ENV_ID], help=f"env ids ({ENV_ID_LIST}) or '{ALL_ENVS}'")
    parser.add_argument(
        "--seeds",
        type=parse_seeds,
        default=parse_seeds(DEFAULT_SEEDS),
        help=f"e.g. 0-4 or 1,3,7 (default {DEFAULT_SEEDS})",
    )
    swarm_arguments(parser)
    steps = defaults(evaluate)["steps"]
    parser.add_argument(
        "--steps",
        type=positive_int,
        default=steps,
        help=f"physics steps per episode (default {steps}; a model that decides every k steps, env kwarg "
        "action_repeat=k, makes steps/k decisions)",
    )
    parser.add_argument(
        "--transfer",
        action="store_true",
        help="run a model file on a task other than the one it was trained on, as it is (zero-shot transfer): "
        "its env kwargs apply, and the task must have its observation and action spaces",
    )
    workers_argument(parser, "episodes run in this many processes")
    engine_arguments(parser)
    compile_argument(parser)
    env_kwarg_argument(parser, "object_start=paper")
    json_argument(parser, "episodes and summary")
    rerun_argument(parser, "also save every evaluated episode (replayed with full state) to this new rerun file")


def cmd_evaluate(args, parser) -> int:
    from dpr.envs import ENV_IDS
    from dpr.evaluation.scoring import format_table, save_evaluation

    env_ids = list(ENV_IDS.values()) if args.env == [ALL_ENVS] else args.env
    check_output(args.json, parser, "--json")
    check_rerun_output(args, parser)
    apply_engine_defaults(args)
    env_kwargs = markov_env_kwargs(args, policy_env_kwargs(args, env_ids, parser), parser, "evaluate")
    try:
        if args.engine == "batched":
            from dpr.evaluation.batched import evaluate_batched

            results = evaluate_batched(
                env_ids, args.policy, args.seeds, args.steps, env_kwargs, args.device, compile=args.compile
            )
        else:
            results = _evaluate_on_pymunk(args, env_ids, env_kwargs)
    except ValueError as error:
        parser.error(flag_message(error))
    print(format_table(results))
    if args.json:
        save_evaluation(args.json, args.policy, env_ids, env_kwargs, args.steps, args.seeds, results)
        print(f"wrote {args.json}")
    if args.rerun:
        _log_evaluation_to_rerun(args, env_ids, env_kwargs)
    return 0


def _evaluate_on_pymunk(args, env_ids: list[str], env_kwargs: dict):
    from tqdm import tqdm

    from dpr.evaluation.scoring import evaluate

    with tqdm(total=len(env_ids) * len(args.seeds), desc=f"evaluate {args.policy}", unit="episode") as bar:
        return evaluate(
            env_ids,
            args.policy,
            args.seeds,
            steps=args.steps,
            env_kwargs=env_kwargs,
            workers=args.workers,
            progress=lambda r: bar.update(1),
            transfer=args.transfer,
        )


def _log_evaluation_to_rerun(args, env_ids: list[str], env_kwargs: dict) -> None:
    """Replay the evaluated episodes (the simulator is deterministic, so they are the same episodes) with
    every robot's state recorded, and save them side by side in a new .rrd file."""
    from tqdm import tqdm

    from dpr.envs.particle_env import split_swarm_kwargs
    from dpr.viz.episodes import ViewRollout, rollout_episode
    from dpr.viz.rerun_log import save_rrd

    swarm, extra = split_swarm_kwargs(env_kwargs)
    episodes = []
    for env_id in tqdm(env_ids, desc="log to rerun", unit="env"):
        for seed in args.seeds:
            task = env_id.split("/")[-1].removesuffix("-v0").lower()
            episodes.append(
                rollout_episode(
                    ViewRollout(
                        env_id, args.policy, seed, steps=args.steps, env_kwargs=extra, transfer=args.transfer, **swarm
                    ),
                    name=f"{task}_seed{seed}",
                )
            )
    save_rrd(episodes, args.rerun, title=f"dpr evaluate {args.policy}")
    print(f"wrote {args.rerun}")


def report_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("evaluations", nargs="+", metavar="EVAL.json", help="files written by `dpr evaluate --json`")
    parser.add_argument("--out", required=True, metavar="DIR", help="folder for the report (created if missing)")
    parser.add_argument(
        "--label",
        nargs="+",
        metavar="NAME",
        help="display name of each file's policy, one per file "
        "in order (default: the policy's name; a model file's stem, e.g. navigation-bc-ppo). Files of one label "
        "are training runs of one method; the same policy in two of them, on other seeds, is one run scored in parts",
    )
    parser.add_argument(
        "--seed",
        type=int,
        help="seed of the episodes drawn in trajectories.png (default: per task, the smallest seed every policy has)",
    )


def cmd_report(args, parser) -> int:
    import warnings

    from dpr.evaluation.report import write_report

    if args.label is not None and len(args.label) != len(args.evaluations):
        parser.error(f"--label: give one name per file ({len(args.evaluations)} file(s), {len(args.label)} label(s))")
    with warnings.catch_warnings(record=True) as caught:  # policies left out of a figure: say so plainly
        warnings.simplefilter("always")
        try:
            written = write_report(args.evaluations, args.out, labels=args.label, seed=args.seed)
        except (ValueError, FileExistsError) as error:
            parser.error(flag_message(error))
    for warning in caught:
        print(f"dpr report: warning: {warning.message}", file=sys.stderr)
    print(written[0].read_text())
    for path in written:
        print(f"wrote {path}")
    return 0


COMMANDS = (
    Command(
        "evaluate",
        help="score a policy with the paper's metrics over seeds",
        description="Run a policy on one or more tasks and print projected displacement, net displacement, "
        "total distance and success (median, min, max, mean ± std over seeds).",
        arguments=evaluate_arguments,
        run=cmd_evaluate,
    ),
    Command(
        "report",
        help="markdown results table and the paper's figures from `dpr evaluate --json` files",
        description="Results table (markdown) and figures (bars per task and policy; trajectories from one start) "
        "from `dpr evaluate --json` files. Files are merged: one policy evaluated task by task, or several "
        'policies, give one row per (task, policy), with "% of wave" where the wave policy was evaluated on '
        "the same seeds. Writes results.md, bars.png and trajectories.png into --out (never overwritten).",
        arguments=report_arguments,
        run=cmd_report,
    ),
)
