"""`dpr view`: episodes in rerun, from a dataset, an MCAP log, or policies rolled out side by side."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from dpr.cli.common import (
    EXAMPLE_ENV_ID,
    Command,
    check_env_kwargs,
    check_rrd_output,
    check_seed,
    default_argument,
    defaults,
    env_kwarg_argument,
    flag_message,
    swarm_arguments,
)

# dpr.viz parameters said as the flags that set them: the policies rolled out, and save_rrd's file.
VIEW_FLAGS = {"policy": "--policies", "path": "--save"}


def policy_names(text: str) -> list[str]:
    """'wave,random' -> ['wave', 'random']."""
    names = [part.strip() for part in text.split(",")]
    if not all(names):
        raise argparse.ArgumentTypeError(f"--policies must be comma-separated names like 'wave,random', got {text!r}")
    return names


def episode_index(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"--episode takes episode indices >= 0, got {text!r}")
    return value


def view_arguments(parser: argparse.ArgumentParser) -> None:
    from dpr.policies.registry import WAVE
    from dpr.viz.episodes import ViewRollout

    rollout = defaults(ViewRollout)
    parser.add_argument("source", nargs="?", help="dataset folder or .mcap file (omit with --env)")
    parser.add_argument(
        "--episode",
        nargs="+",
        type=episode_index,
        metavar="K",
        help="dataset episode indices to show side by side (default 0)",
    )
    parser.add_argument("--env", help=f"env id to roll policies out on, e.g. {EXAMPLE_ENV_ID}")
    parser.add_argument(
        "--policies",
        type=policy_names,
        help=f"comma-separated policies for --env (default {WAVE}), e.g. wave,random",
    )
    parser.add_argument(
        "--transfer",
        action="store_true",
        help="with --env, run model files on a task other than the one they were trained on, as they are "
        "(zero-shot transfer, as `dpr evaluate --transfer`): the task must have their observation and action spaces",
    )
    default_argument(parser, "--seed", 0, "reset seed of every rollout", type=int)
    swarm_arguments(parser, rollout)
    default_argument(parser, "--steps", rollout["steps"], "max physics steps per rollout")
    env_kwarg_argument(parser, "object_type=box")
    parser.add_argument("--save", metavar="OUT.rrd", help="write a new .rrd file instead of starting a viewer")
    parser.add_argument("--serve", action="store_true", help="serve over gRPC (connect with `rerun URL`) until Ctrl-C")


def _view_error(error: Exception | str) -> int:
    message = flag_message(error, VIEW_FLAGS) if isinstance(error, Exception) else error
    print(f"dpr view: error: {message}", file=sys.stderr)
    return 2


def _load_view_source(args, parser) -> list:
    """The episodes of a dataset folder or an MCAP file (argument errors exit through parser.error)."""
    from dpr.datasets.lerobot import LeRobotReader
    from dpr.viz import episode_from_dataset, episode_from_mcap

    source = Path(args.source)
    for flag, given in (("--policies", args.policies is not None), ("--transfer", args.transfer)):
        if given:
            parser.error(f"{flag} rolls policies out with --env; it does not apply to a dataset or MCAP file")
    if not source.exists():
        parser.error(f"SOURCE: {source} does not exist (expected a dataset folder or a .mcap file)")
    if source.is_dir():
        episodes = args.episode if args.episode is not None else [0]
        if len(set(episodes)) != len(episodes):
            parser.error(f"--episode lists an episode twice: {episodes}")
        reader = LeRobotReader(source)
        return [episode_from_dataset(reader, index) for index in episodes]
    if source.suffix != ".mcap":
        parser.error(f"SOURCE: {source} is neither a dataset folder nor a .mcap file")
    if args.episode is not None:
        parser.error("--episode picks episodes of a dataset; an MCAP file holds one episode")
    return [episode_from_mcap(source)]


def _roll_out_policies(args, parser) -> list:
    from tqdm import tqdm

    from dpr.policies.registry import WAVE
    from dpr.viz import ViewRollout, check_view_policy, rollout_episode

    if args.episode is not None:
        parser.error("--episode picks episodes of a dataset; with --env, policies are rolled out live")
    policies = args.policies or [WAVE]
    if len(set(policies)) != len(policies):
        parser.error(f"--policies lists a policy twice: {policies}")
    check_seed(args, parser)
    for name in policies:
        check_view_policy(name)
    env_kwargs = dict(args.env_kwarg or [])
    check_env_kwargs([args.env], {"n_robots": args.n_robots, "robot_model": args.robot_model, **env_kwargs}, parser)
    episodes = []
    for name in policies:
        # counts physics steps, whatever the policy's action_repeat: a model deciding every k steps moves it k a time
        with tqdm(total=args.steps, desc=f"roll out {name}", unit="step", leave=False) as bar:
            episodes.append(
                rollout_episode(
                    ViewRollout(
                        args.env,
                        name,
                        args.seed,
                        n_robots=args.n_robots,
                        robot_model=args.robot_model,
                        steps=args.steps,
                        env_kwargs=env_kwargs,
                        transfer=args.transfer,
                    ),
                    on_step=lambda done: bar.update(min(done, bar.total) - bar.n),
                )
            )
            if bar.n < bar.total:  # the episode ended early (goal reached, physics blow-up): that is its whole length
                bar.total = bar.n
                bar.refresh()
    return episodes


def cmd_view(args, parser) -> int:
    from dpr.datasets.lerobot import DatasetError
    from dpr.viz import ViewError

    if (args.source is None) == (args.env is None):
        parser.error("give either SOURCE (a dataset folder or a .mcap file) or --env ID to roll policies out")
    check_rrd_output(args.save, parser, "--save")
    if args.save is not None and args.serve:
        parser.error("--save writes a file; --serve serves a viewer: choose one")
    try:
        episodes = _load_view_source(args, parser) if args.source is not None else _roll_out_policies(args, parser)
    except (DatasetError, ViewError, IndexError) as error:
        return _view_error(error)

    from dpr.viz import save_rrd, serve, spawn_viewer

    title = f"dpr view {args.source if args.source is not None else args.env}"
    if args.save is not None:
        try:
            save_rrd(episodes, args.save, title=title)
        except ViewError as error:
            return _view_error(error)
        print(f"wrote {args.save} ({len(episodes)} episode(s)); open it with: rerun {args.save}")
        return 0
    try:
        if args.serve:
            serve(episodes, title=title)
        else:
            spawn_viewer(episodes, title=title)
    except ViewError as error:
        return _view_error(error)
    except (OSError, RuntimeError) as error:  # no viewer binary, no display, a port in use
        return _view_error(f"cannot start the rerun viewer ({error}); use --save OUT.rrd instead")
    return 0


COMMANDS = (
    Command(
        "view",
        help="inspect episodes in rerun: a dataset, an MCAP log, or policies rolled out side by side",
        description="Log episodes to rerun: robots (radius following their expansion), magnets, walls, object, "
        "goal, the centre-of-mass trail, and reward, distance to goal and the paper's metrics over time, on a "
        "`step` (physics steps) and a `sim_time` (simulated seconds) timeline: a model deciding every k physics "
        "steps shows its state at each decision, on the same clock as the policies beside it. SOURCE is a "
        "dataset folder written by `dpr collect` (pick episodes with --episode) or one of its MCAP logs; or give "
        "--env and --policies to roll policies out from the same start and see them side by side. Without --save "
        "or --serve a rerun viewer is spawned.",
        arguments=view_arguments,
        run=cmd_view,
        flags=VIEW_FLAGS,
    ),
)
