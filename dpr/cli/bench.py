"""`dpr bench`: env steps/s against physics-only steps/s for both robot models (dpr.bench)."""

from __future__ import annotations

import argparse
import sys

from dpr.cli.common import (
    Command,
    check_output,
    default_argument,
    defaults,
    json_argument,
    positive_int,
    write_json,
)
from dpr.sim.models import ROBOT_MODELS


def bench_arguments(parser: argparse.ArgumentParser) -> None:
    from dpr.bench import run_benchmarks

    bench = defaults(run_benchmarks)
    parser.add_argument("--models", nargs="+", choices=ROBOT_MODELS, default=list(bench["models"]))
    parser.add_argument("--sizes", nargs="+", type=positive_int, default=list(bench["sizes"]))
    default_argument(parser, "--steps", bench["steps"], "env steps per timed block at N=9")
    default_argument(parser, "--repeats", bench["repeats"], "timed blocks; medians are reported")
    json_argument(parser, "the rows")


def cmd_bench(args, parser) -> int:
    from dpr.bench import format_table, run_benchmarks

    check_output(args.json, parser, "--json")
    rows = run_benchmarks(
        models=args.models,
        sizes=args.sizes,
        steps=args.steps,
        repeats=args.repeats,
        progress=lambda r: print(
            f"{r['robot_model']:>6} N={r['n_robots']:<4} env {r['env_steps_per_s']:8.0f}/s  "
            f"physics {r['physics_steps_per_s']:8.0f}/s  ({r['env_over_physics']:.0%})",
            file=sys.stderr,
        ),
    )
    print(format_table(rows))
    if args.json:
        write_json(args.json, rows)
    return 0


COMMANDS = (
    Command(
        "bench",
        help="env steps/s vs physics-only steps/s for both robot models",
        description="Time env.step with random actions against the pymunk part of the same steps "
        "(see dpr.bench); prints a markdown table for BENCHMARKS.md.",
        arguments=bench_arguments,
        run=cmd_bench,
    ),
)
