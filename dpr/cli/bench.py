"""`dpr bench`: env steps/s against physics-only steps/s for both robot models (dpr.bench)."""

from __future__ import annotations

import argparse
import sys

from dpr.cli.common import (
    Command,
    check_output,
    compile_argument,
    default_argument,
    defaults,
    flag_message,
    json_argument,
    positive_int,
    write_json,
)
from dpr.sim.models import ROBOT_MODELS


def bench_arguments(parser: argparse.ArgumentParser) -> None:
    from dpr.bench import BATCHED_ROBOTS, run_batched_benchmarks, run_benchmarks

    bench = defaults(run_benchmarks)
    parser.add_argument("--models", nargs="+", choices=ROBOT_MODELS, default=list(bench["models"]))
    parser.add_argument("--sizes", nargs="+", type=positive_int, default=list(bench["sizes"]))
    default_argument(parser, "--steps", bench["steps"], "env steps per timed block at N=9")
    batched = defaults(run_batched_benchmarks)
    parser.add_argument(
        "--repeats",
        type=positive_int,
        help=f"timed blocks; medians are reported (default {bench['repeats']}; batched: {batched['repeats']} a row, "
        "each after a block of the pymunk disk env)",
    )
    parser.add_argument(
        "--engine",
        choices=("pymunk", "batched"),
        default="pymunk",
        help="pymunk: env against physics-only steps/s of both robot models (default); batched: the batched disk "
        "engine's env steps/s at N=9 for each --ks and at each --batched-sizes, beside the pymunk disk env",
    )
    parser.add_argument("--ks", nargs="+", type=positive_int, default=list(batched["ks"]), help="batched: K at N=9")
    parser.add_argument(
        "--batched-sizes",
        nargs="*",
        type=positive_int,
        default=list(batched["sizes"]),
        help="batched: N, each with K*N near --batched-robots robots (none: N=9 only)",
    )
    parser.add_argument(
        "--batched-robots",
        type=positive_int,
        default=batched["robots"],
        help=f"batched: robots per call in the --batched-sizes rows (default {BATCHED_ROBOTS}; a GPU fills at more)",
    )
    parser.add_argument("--device", default=batched["device"], help="batched: torch device, cpu or cuda")
    compile_argument(parser)
    json_argument(parser, "the rows")


def cmd_bench(args, parser) -> int:
    check_output(args.json, parser, "--json")
    if args.engine == "batched":
        _check_batched_rows(args, parser)
    rows, table = _batched_rows(args) if args.engine == "batched" else _pymunk_rows(args)
    print(table)
    if args.json:
        write_json(args.json, rows)
    return 0


def _check_batched_rows(args, parser) -> None:
    """A usage error, before any work, for a row the machine cannot hold or a device it lacks."""
    from dpr.bench import batched_cases
    from dpr.checks import ParameterError

    try:
        batched_cases(args.ks, args.batched_sizes, args.batched_robots, args.device)
    except ParameterError as error:
        parser.error(flag_message(error, {"num_envs": "--ks or --batched-robots"}))


def _given_repeats(args) -> dict:
    """--repeats where given; else each engine's bench keeps its own default."""
    return {} if args.repeats is None else {"repeats": args.repeats}


def _pymunk_rows(args) -> tuple[list[dict], str]:
    from dpr.bench import format_table, run_benchmarks

    rows = run_benchmarks(
        models=args.models,
        sizes=args.sizes,
        steps=args.steps,
        **_given_repeats(args),
        progress=lambda r: print(
            f"{r['robot_model']:>6} N={r['n_robots']:<4} env {r['env_steps_per_s']:8.0f}/s  "
            f"physics {r['physics_steps_per_s']:8.0f}/s  ({r['env_over_physics']:.0%})",
            file=sys.stderr,
        ),
    )
    return rows, format_table(rows)


def _batched_rows(args) -> tuple[list[dict], str]:
    from dpr.bench import format_batched_table, run_batched_benchmarks

    rows = run_batched_benchmarks(
        args.ks,
        args.batched_sizes,
        device=args.device,
        compile=args.compile,
        robots=args.batched_robots,
        **_given_repeats(args),
        progress=lambda r: print(
            f"batched N={r['n_robots']:<5} K={r['num_envs']:<6} {r['env_steps_per_s']:10.0f} env steps/s",
            file=sys.stderr,
        ),
    )
    return rows, format_batched_table(rows)


COMMANDS = (
    Command(
        "bench",
        help="env steps/s vs physics-only steps/s for both robot models, or of the batched engine",
        description="Time env.step with random actions against the pymunk part of the same steps "
        "(see dpr.bench); prints a markdown table for BENCHMARKS.md.",
        arguments=bench_arguments,
        run=cmd_bench,
    ),
)
