"""`dpr collect` (policy rollouts recorded as a LeRobot v3.0 dataset and MCAP logs) and `dpr replay` (recorded
episodes re-run and compared bit for bit)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from dpr.cli.common import (
    ENV_ID_LIST,
    SWARM_DEFAULTS,
    Command,
    apply_engine_defaults,
    check_output,
    check_seed,
    default_argument,
    defaults,
    engine_arguments,
    env_kwarg_argument,
    flag_message,
    json_argument,
    markov_env_kwargs,
    parse_seeds,
    policy_env_kwargs,
    positive_int,
    swarm_arguments,
    workers_argument,
    write_json,
)

DEFAULT_EPISODES = 10


def collect_arguments(parser: argparse.ArgumentParser) -> None:
    from dpr.datasets.collect import BACKENDS, CollectSpec, RolloutWorkers, collect

    spec = defaults(CollectSpec)
    run = defaults(collect)
    workers = defaults(RolloutWorkers)
    parser.add_argument("--env", required=True, help=f"env id: {ENV_ID_LIST}")
    parser.add_argument(
        "--policy",
        default=spec["policy"],
        help="'wave', 'wave-markov' (either may name its hold and bins: 'wave-markov:hold_steps=6,bin_width=50'; "
        "wave-markov reads the previous action, so it records with --env-kwarg obs_last_action=true by default), "
        "'decentralised-wave' (or 'decentralised-wave:n_phases=6'), 'random' or a model .zip: any policy "
        f"`dpr evaluate` accepts (default {spec['policy']})",
    )
    parser.add_argument(
        "--label-policy",
        help="record this policy's action on every observation instead of the "
        "action --policy took (DAgger data: a clone drives, an expert labels), e.g. wave-markov",
    )
    default_argument(parser, "--episodes", DEFAULT_EPISODES, "number of episodes (seeds) to hold")
    parser.add_argument(
        "--out", required=True, help="dataset folder (created, or resumed if it holds the same dataset)"
    )
    default_argument(parser, "--seed", run["seed"], "first seed", type=int)
    swarm_arguments(parser)  # default: a model's swarm, else the env's
    parser.add_argument(
        "--steps",
        type=positive_int,
        help="frames (env steps) per episode (default: a whole episode, 2500 physics steps / action_repeat)",
    )
    parser.add_argument("--pixels", action="store_true", help="also record render() frames as observation.image (PNG)")
    default_argument(parser, "--image-size", spec["image_size"], "frame size for --pixels")
    parser.add_argument("--mcap", action="store_true", help="also write one MCAP log per episode into OUT/mcap/")
    parser.add_argument(
        "--compact",
        action="store_true",
        help="once every episode is recorded, pack the per-episode files into LeRobot's ~100 MB files "
        "(crash-safe: a kill during packing loses no episode; a resume may add episodes and pack again)",
    )
    parser.add_argument(
        "--verify",
        action="store_true",
        help="then read the whole dataset back: every column of every episode against its checksum and meta "
        "row, stats.json against the episodes' own stats, and fps against the decision rate (one frame per "
        "action_repeat physics steps); exit 2 at the first problem, named",
    )
    _worker_arguments(parser, workers["batch"])
    env_kwarg_argument(parser, "object_type=box")
    parser.add_argument(
        "--backend",
        choices=BACKENDS,
        default=workers["backend"],
        help="run rollouts in local worker processes or as Ray tasks (pip install -e '.[distributed]'; "
        f"default {workers['backend']})",
    )
    parser.add_argument(
        "--address", help="with --backend ray: the address of a running Ray cluster (default: start a local one)"
    )
    json_argument(parser, "the summary")


def _worker_arguments(parser: argparse.ArgumentParser, batch: int) -> None:
    """--workers, --engine, --device and --batch: what runs the rollouts."""
    workers_argument(parser, "rollout processes")
    engine_arguments(parser)
    default_argument(parser, "--batch", batch, "with --engine batched: episodes stepped together in one vector env")


def _check_backend(args, parser) -> None:
    if args.address and args.backend != "ray":
        parser.error("--address is the Ray cluster for --backend ray")
    if args.backend == "ray":
        import importlib.util

        if importlib.util.find_spec("ray") is None:
            parser.error("--backend ray needs Ray: pip install -e '.[distributed]'")


def _collect_spec(args, parser):
    """The :class:`~dpr.datasets.collect.CollectSpec` the flags ask for, checked, and an env made from it (a bad
    --env-kwarg name or value fails here, before anything is written); a problem is a usage error naming flags."""
    from dpr.datasets.collect import CollectSpec
    from dpr.policies.model_file import is_model_path

    # a model records on the env it was trained on: its own kwargs, which the flags may only repeat (or, for a
    # SwarmPolicy model, give another --n-robots)
    swarm = {name: getattr(args, name) for name in SWARM_DEFAULTS}
    env_kwargs = dict(args.env_kwarg or [])  # swarm kwargs here are refused by CollectSpec: they are its fields
    if is_model_path(args.policy):
        env_kwargs = policy_env_kwargs(args, [args.env], parser)  # the model's, --env-kwarg included
        swarm.update((name, env_kwargs.pop(name)) for name in SWARM_DEFAULTS if name in env_kwargs)
    env_kwargs = markov_env_kwargs(args, env_kwargs, parser, "collect")
    try:
        spec = CollectSpec(
            args.env,
            policy=args.policy,
            **{name: value for name, value in swarm.items() if value is not None},
            steps=args.steps,
            pixels=args.pixels,
            image_size=args.image_size,
            env_kwargs=env_kwargs,
            label_policy=args.label_policy,
            mcap=args.mcap,
            engine=args.engine,
        )
    except ValueError as error:
        parser.error(flag_message(error))
    try:
        spec.make_env().close()
    except (TypeError, ValueError) as error:
        parser.error(
            f"cannot make {spec.env_id} from --n-robots/--robot-model/--env-kwarg {spec.make_kwargs()}: {error}"
        )
    return spec


def _progress_bar(total: int, description: str):
    """A tqdm bar of episodes, and the ``progress(record, index)`` callback that moves it and shows the frames
    recorded and their rate (from the first episode's start)."""
    import time

    from tqdm import tqdm

    bar = tqdm(total=total, desc=description, unit="episode")
    frames = 0
    started = None

    def progress(record, index):
        nonlocal frames, started
        if started is None:
            started = time.perf_counter() - record.seconds
        frames += record.frames
        bar.update(1)
        bar.set_postfix(frames=frames, fps=f"{frames / max(time.perf_counter() - started, 1e-9):.0f}")

    return bar, progress


def cmd_collect(args, parser) -> int:
    check_output(args.json, parser, "--json")
    check_seed(args, parser)
    apply_engine_defaults(args)

    from dpr.datasets.collect import RolloutWorkers, collect
    from dpr.datasets.collect_summary import format_summary

    spec = _collect_spec(args, parser)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        parser.error(f"--out: {out} exists and is not a folder")
    _check_backend(args, parser)
    bar, progress = _progress_bar(args.episodes, f"collect {spec.policy} {spec.env_id}")
    try:
        workers = RolloutWorkers(args.workers, args.backend, args.address, batch=args.batch, device=args.device)
        summary = collect(
            out, spec, args.episodes, seed=args.seed, workers=workers, progress=progress, compact=args.compact
        )
    except ValueError as error:  # a DatasetError, or a policy that cannot run on this env
        bar.close()
        print(f"dpr collect: error: {flag_message(error)}", file=sys.stderr)
        return 2
    bar.close()
    print(format_summary(summary))
    if args.json:
        write_json(args.json, summary.as_dict())
    if summary.interrupted:
        return 130
    return verify_dataset(out) if args.verify else 0


def verify_dataset(root) -> int:
    """`dpr collect --verify`: 0 when every episode and stats.json hold and the dataset records its simulated
    time (fps = the decision rate: dpr.datasets.timing), 2 (bad data, the file or the dataset named) otherwise."""
    from dpr.datasets.lerobot import DatasetError, LeRobotReader
    from dpr.datasets.timing import check_dataset_time

    try:
        reader = LeRobotReader(root)
        check_dataset_time(root, reader.info)
        frames = reader.verify()
    except DatasetError as error:
        print(f"dpr collect: verify: {error}", file=sys.stderr)
        return 2
    print(
        f"verified {root}: {reader.num_episodes} episodes, {frames} frames at {reader.fps:g} fps; checksums and "
        "stats.json hold"
    )
    return 0


def replay_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dataset", help="dataset folder written by `dpr collect`")
    parser.add_argument(
        "--episodes",
        type=lambda text: parse_seeds(text, "--episodes"),
        help="episode indices, e.g. 0-4 or 1,3 (default: all)",
    )


def cmd_replay(args, parser) -> int:
    from tqdm import tqdm

    from dpr.datasets.lerobot import DatasetError, LeRobotReader
    from dpr.datasets.replay import replay_dataset

    try:
        total = LeRobotReader(args.dataset).num_episodes
        episodes = args.episodes if args.episodes is not None else list(range(total))
        with tqdm(total=len(episodes), desc="replay", unit="episode") as bar:
            checks = replay_dataset(args.dataset, episodes, progress=lambda c: bar.update(1))
    except (DatasetError, ValueError) as error:
        print(f"dpr replay: error: {flag_message(error)}", file=sys.stderr)
        return 2
    bad = [c for c in checks if not c.equal]
    for c in bad:
        worst = {k: v for k, v in c.max_abs_difference.items() if v}
        print(
            f"episode {c.episode_index} (seed {c.seed}): differs from frame {c.first_mismatch} on; max |diff| {worst}"
        )
    print(
        f"{len(checks) - len(bad)}/{len(checks)} episodes replay bit-identically "
        f"({sum(c.frames for c in checks)} frames)"
    )
    return 1 if bad else 0


COMMANDS = (
    Command(
        "collect",
        help="record policy rollouts as a LeRobot v3.0 dataset (and MCAP logs)",
        description="Roll a policy out for --episodes seeds (--seed, --seed+1, ...) and append each episode to the "
        "LeRobot v3.0 dataset in --out. The dataset is valid after every episode; running the same command again "
        "resumes (seeds already recorded are skipped). An --out folder holding a dataset of another env, policy, "
        "kwargs or features is refused and left untouched.",
        arguments=collect_arguments,
        run=cmd_collect,
    ),
    Command(
        "replay",
        help="re-run recorded episodes and check they reproduce bit for bit",
        description="Re-run each episode of a dataset from its stored seed, env kwargs and actions, and compare "
        "observations, rewards and flags with the recording. Exit status 1 when any episode differs.",
        arguments=replay_arguments,
        run=cmd_replay,
    ),
)
