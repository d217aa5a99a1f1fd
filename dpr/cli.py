"""`dpr` command line: evaluate policies and benchmark the simulator."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

ALL_ENVS = "all"


def parse_seeds(text: str) -> list[int]:
    """'0-4' -> [0..4], '1,3,7' -> [1, 3, 7], '5' -> [5]."""
    seeds: list[int] = []
    try:
        for part in text.split(","):
            if "-" in part.strip()[1:]:
                lo, hi = part.split("-", 1)
                lo_i, hi_i = int(lo), int(hi)
                if hi_i < lo_i:
                    raise ValueError
                seeds.extend(range(lo_i, hi_i + 1))
            else:
                seeds.append(int(part))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--seeds must look like '0-4' or '1,3,7', got {text!r}") from None
    if not seeds or min(seeds) < 0:
        raise argparse.ArgumentTypeError(f"--seeds must be non-negative integers, got {text!r}")
    return seeds


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}")
    return value


def _check_output(path: str | None, parser: argparse.ArgumentParser, flag: str) -> None:
    if path is None:
        return
    p = Path(path)
    if p.exists():
        parser.error(f"{flag}: {p} already exists; choose another path (results are never overwritten)")
    if not p.parent.exists():
        parser.error(f"{flag}: folder {p.parent} does not exist")


def cmd_evaluate(args, parser) -> int:
    from tqdm import tqdm

    from dpr.envs import ENV_IDS
    from dpr.rl.evaluation import evaluate, format_table, summary

    env_ids = list(ENV_IDS.values()) if args.env == [ALL_ENVS] else args.env
    _check_output(args.json, parser, "--json")
    env_kwargs = {"n_robots": args.n_robots, "robot_model": args.robot_model}
    try:
        with tqdm(total=len(env_ids) * len(args.seeds), desc=f"evaluate {args.policy}", unit="episode") as bar:
            results = evaluate(
                env_ids, args.policy, args.seeds, steps=args.steps, env_kwargs=env_kwargs,
                workers=args.workers, progress=lambda r: bar.update(1),
            )
    except ValueError as error:
        parser.error(str(error))
    print(format_table(results))
    if args.json:
        payload = {
            "policy": args.policy,
            "env_ids": env_ids,
            "env_kwargs": env_kwargs,
            "steps": args.steps,
            "seeds": args.seeds,
            "episodes": [r.as_dict() for r in results],
            "summary": summary(results) if len(env_ids) > 1 else summary(results)[env_ids[0]],
        }
        Path(args.json).write_text(json.dumps(payload, indent=2))
        print(f"wrote {args.json}")
    return 0


def cmd_bench(args, parser) -> int:
    from dpr.bench import format_table, run_benchmarks

    _check_output(args.json, parser, "--json")
    rows = run_benchmarks(
        models=args.models, sizes=args.sizes, steps=args.steps, repeats=args.repeats,
        progress=lambda r: print(
            f"{r['robot_model']:>6} N={r['n_robots']:<4} env {r['env_steps_per_s']:8.0f}/s  "
            f"physics {r['physics_steps_per_s']:8.0f}/s  ({r['env_over_physics']:.0%})",
            file=sys.stderr,
        ),
    )
    print(format_table(rows))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))
        print(f"wrote {args.json}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="dpr", description="Deep Particle Robot: particle-robot swarms for robot learning.")
    sub = parser.add_subparsers(dest="command", required=True)

    ev = sub.add_parser(
        "evaluate",
        help="score a policy with the paper's metrics over seeds",
        description="Run a policy on one or more tasks and print projected displacement, net displacement, "
        "total distance and success (median, min, max, mean ± std over seeds).",
    )
    ev.add_argument("--policy", default="wave", help="'wave' (the paper's hand-crafted policy) or 'random'")
    ev.add_argument("--env", nargs="+", default=["dpr/Navigation-v0"],
                    help="env ids (dpr/Navigation-v0, dpr/Gate-v0, dpr/Unresponsive-v0, dpr/Manipulation-v0) or 'all'")
    ev.add_argument("--seeds", type=parse_seeds, default=parse_seeds("0-4"), help="e.g. 0-4 or 1,3,7 (default 0-4)")
    ev.add_argument("--n-robots", type=positive_int, default=9, help="swarm size N (default 9)")
    ev.add_argument("--robot-model", choices=("paddle", "disk"), default="paddle",
                    help="paddle: the paper's robot (default); disk: the fast single-body model")
    ev.add_argument("--steps", type=positive_int, default=2500, help="steps per episode (default 2500)")
    ev.add_argument("--workers", type=positive_int, default=min(2, os.cpu_count() or 1),
                    help="episodes run in this many processes (default: up to 2)")
    ev.add_argument("--json", help="also write episodes and summary to this new JSON file")
    ev.set_defaults(func=cmd_evaluate)

    be = sub.add_parser(
        "bench",
        help="env steps/s vs physics-only steps/s for both robot models",
        description="Time env.step with random actions against the pymunk part of the same steps "
        "(see dpr.bench); prints a markdown table for BENCHMARKS.md.",
    )
    be.add_argument("--models", nargs="+", choices=("paddle", "disk"), default=["paddle", "disk"])
    be.add_argument("--sizes", nargs="+", type=positive_int, default=[9, 25, 49, 100])
    be.add_argument("--steps", type=positive_int, default=200, help="env steps per timed block at N=9 (default 200)")
    be.add_argument("--repeats", type=positive_int, default=5, help="timed blocks; medians are reported (default 5)")
    be.add_argument("--json", help="also write the rows to this new JSON file")
    be.set_defaults(func=cmd_bench)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "env", None) and args.env != [ALL_ENVS]:
        from dpr.envs import ENV_IDS

        unknown = [e for e in args.env if e not in ENV_IDS.values()]
        if unknown:
            parser.error(f"--env: unknown env id(s) {unknown}; choose from {list(ENV_IDS.values())} or 'all'")
    return args.func(args, parser)


if __name__ == "__main__":
    sys.exit(main())
