"""What the `dpr` commands share: the command record, argument types, argument groups, output checks, and the
mapping from library parameter names to flags.

Only names that ``import dpr`` has loaded already come in at module level (the env ids, the robot models, the
env's defaults): `dpr --help` must not pay for torch, stable-baselines3, rerun or pyarrow. Each command's
arguments are added when that command runs (:attr:`Command.arguments`), so their defaults can come from the
library's own configs and signatures.
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import json
import os
import sys
import tempfile
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from dpr.envs import BUILT_IN_TASKS, ENV_IDS
from dpr.envs.particle_env import IMAGE_SIZE_RANGE, SWARM_KWARGS, ParticleSwarmEnv
from dpr.limits import (
    MAX_BATCH_SIZE,
    MAX_EPISODE_SEED,
    MAX_EPISODES,
    MAX_EPOCHS,
    MAX_MODEL_SEED,
    MAX_N_ENVS,
    MAX_N_ROBOTS,
    MAX_ROUNDS,
    MAX_SEEDS,
    MAX_STEPS_PER_EPISODE,
    MAX_TIMESTEPS,
)
from dpr.sim.models import ROBOT_MODELS

ALL_ENVS = "all"  # --env all / --tasks all: every task
TASK_NAMES = BUILT_IN_TASKS  # navigation, gate, unresponsive, manipulation
ENV_ID_LIST = ", ".join(ENV_IDS[task] for task in TASK_NAMES) + " or a task of an --env-package"  # for help texts
EXAMPLE_ENV_ID = ENV_IDS["navigation"]
# Worker processes by default: two, the cores the laptop-sized budgets were measured on (fewer on a smaller machine).
DEFAULT_WORKERS = min(2, os.cpu_count() or 1)
DEFAULT_WORKERS_TEXT = "min(2, CPUs)"


@dataclass(frozen=True)
class Command:
    """One `dpr` command: what `dpr --help` says of it, the function that adds its arguments to its parser
    (called only when the command is used), its handler, and the flags its library parameters are said as."""

    name: str
    help: str
    description: str
    arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace, argparse.ArgumentParser], int]
    flags: Mapping[str, str] = field(default_factory=dict)  # library parameter -> flag, beside PARAMETER_FLAGS


# Library parameters whose flag is not "--" + the name with dashes in any command (see dpr.checks.ParameterError);
# a command's own Command.flags come first.
PARAMETER_FLAGS = {
    "env_id": "--env",
    "env_ids": "--env",
    "env_kwargs": "--env-kwarg",
    "training_env_kwargs": "--training-env-kwarg",
    "hyperparams": "--hyperparam",
}


def flag_for(parameter: str, flags: Mapping[str, str] | None = None) -> str:
    """The flag that sets the library parameter ``parameter`` (``flags``: the command's own names)."""
    return (flags or {}).get(parameter) or PARAMETER_FLAGS.get(parameter) or "--" + parameter.replace("_", "-")


def flag_message(error: Exception, flags: Mapping[str, str] | None = None) -> str:
    """``error``'s message, with a library parameter name (dpr.checks.ParameterError) said as its CLI flag."""
    from dpr.checks import ParameterError

    if isinstance(error, ParameterError):
        return f"{flag_for(error.parameter, flags)}: {error.problem}"
    return str(error)


def defaults(target: Callable) -> dict[str, Any]:
    """The default of every parameter of a function or class (a dataclass: of its fields, factories called):
    what the library does when a flag is not given, and so the flag's default."""
    if dataclasses.is_dataclass(target):
        return {
            f.name: f.default if f.default is not dataclasses.MISSING else f.default_factory()
            for f in dataclasses.fields(target)
            if f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING
        }
    parameters = inspect.signature(target).parameters.values()
    return {p.name: p.default for p in parameters if p.default is not inspect.Parameter.empty}


# The env's own swarm defaults (N 9, the paddle model): what runs when neither a flag nor a model file says.
SWARM_DEFAULTS = {name: value for name, value in defaults(ParticleSwarmEnv).items() if name in SWARM_KWARGS}


def shown(value: Any) -> str:
    """A default as help texts write it: 0.001 and 1 rather than 1e-03 and 1.0, lists space-separated."""
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, (list, tuple)):
        return " ".join(map(shown, value))
    return str(value)


# -- argument types ----------------------------------------------------------------------------------------------


def parse_seeds(text: str, flag: str = "--seeds") -> list[int]:
    """'0-4' -> [0..4], '1,3,7' -> [1, 3, 7], '5' -> [5]; each seed once, at most :data:`MAX_SEEDS`."""
    seeds: list[int] = []
    try:
        for part in text.split(","):
            if "-" in part.strip()[1:]:
                lo, hi = part.split("-", 1)
                lo_i, hi_i = int(lo), int(hi)
                if hi_i < lo_i:
                    raise ValueError
                if len(seeds) + hi_i - lo_i + 1 > MAX_SEEDS:
                    raise argparse.ArgumentTypeError(f"{flag} names more than {MAX_SEEDS} seeds: {text!r}")
                seeds.extend(range(lo_i, hi_i + 1))
            else:
                seeds.append(int(part))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{flag} must look like '0-4' or '1,3,7', got {text!r}") from None
    if not seeds or min(seeds) < 0:
        raise argparse.ArgumentTypeError(f"{flag} must be non-negative integers, got {text!r}")
    if len(set(seeds)) != len(seeds):
        raise argparse.ArgumentTypeError(f"{flag} names a seed twice: {text!r}")
    return seeds


def seeds_text(seeds: Iterable[int]) -> str:
    """[100..104] -> '100-104', [1, 3, 7] -> '1,3,7': what :func:`parse_seeds` reads back."""
    seeds = list(seeds)
    if len(seeds) > 1 and seeds == list(range(seeds[0], seeds[-1] + 1)):
        return f"{seeds[0]}-{seeds[-1]}"
    return ",".join(map(str, seeds))


INT_FLAG_LIMIT = 2**63 - 1  # any integer flag, before its own bound (FLAG_BOUNDS) says more precisely


def positive_int(text: str) -> int:
    """An integer in [1, :data:`INT_FLAG_LIMIT`] (each flag's own bound: :data:`FLAG_BOUNDS`)."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if not 1 <= value <= INT_FLAG_LIMIT:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}")
    return value


def non_negative_int(text: str) -> int:
    """An integer in [0, :data:`INT_FLAG_LIMIT`] (each flag's own bound: :data:`FLAG_BOUNDS`)."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= INT_FLAG_LIMIT:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}")
    return value


# The bounds of every integer flag of every command, by the flag's dest: (minimum, maximum), checked on the parsed
# arguments before a command starts (:func:`check_bounds`); a list flag's every value is checked. A flag of a
# setting of `dpr pipeline` is checked again, with the config file's value, by dpr.pipeline.config.PipelineConfig.
FLAG_BOUNDS = {
    "episodes": (0, MAX_EPISODES),  # `dpr replay --episodes` names indices from 0; a count is >= 1 by its type
    "episode": (0, MAX_EPISODES),
    "eval_episodes": (0, MAX_EPISODES),
    "dagger_episodes": (1, MAX_EPISODES),
    "steps": (1, MAX_STEPS_PER_EPISODE),
    "steps_per_episode": (1, MAX_STEPS_PER_EPISODE),
    "hold_steps": (1, MAX_STEPS_PER_EPISODE),
    "n_phases": (1, MAX_STEPS_PER_EPISODE),
    "action_repeat": (0, MAX_STEPS_PER_EPISODE),
    "timesteps": (1, MAX_TIMESTEPS),
    "finetune_steps": (1, MAX_TIMESTEPS),
    "critic_warmup": (0, MAX_TIMESTEPS),
    "epochs": (1, MAX_EPOCHS),
    "bc_epochs": (1, MAX_EPOCHS),
    "patience": (1, MAX_EPOCHS),
    "batch_size": (1, MAX_BATCH_SIZE),
    "n_envs": (1, MAX_N_ENVS),
    "ks": (1, MAX_N_ENVS),
    "n_robots": (1, MAX_N_ROBOTS),
    "sizes": (1, MAX_N_ROBOTS),
    "batched_sizes": (1, MAX_N_ROBOTS),
    "max_neighbours": (1, MAX_N_ROBOTS),
    "seed": (0, MAX_EPISODE_SEED),
    "seeds": (0, MAX_EPISODE_SEED),
    "dagger_seed": (0, MAX_EPISODE_SEED),
    "demo_seed": (0, MAX_EPISODE_SEED - MAX_EPISODES),
    "train_seeds": (0, MAX_MODEL_SEED),
    "validation_seeds": (0, MAX_EPISODE_SEED),
    "test_seeds": (0, MAX_EPISODE_SEED),
    "teacher_seeds": (0, MAX_EPISODE_SEED),
    "dagger_rounds": (0, MAX_ROUNDS),
    "repeats": (1, MAX_ROUNDS),
    "image_size": IMAGE_SIZE_RANGE,
}


def check_bounds(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """A parser error (exit 2) naming the flag, the value and the allowed range for an integer flag outside its
    :data:`FLAG_BOUNDS`, a number that is not finite (NaN, inf), or more worker processes than
    :func:`dpr.limits.workers_limit` allows: before the command does anything."""
    import math

    from dpr.checks import ParameterError
    from dpr.limits import check_workers

    for dest, value in vars(args).items():
        flag = "--" + dest.replace("_", "-")
        for item in value if isinstance(value, list) else [value]:
            if isinstance(item, float) and not math.isfinite(item):
                parser.error(f"{flag}: must be a finite number, got {item}")
            bounds = FLAG_BOUNDS.get(dest, (-INT_FLAG_LIMIT, INT_FLAG_LIMIT))
            if bounds and isinstance(item, int) and not isinstance(item, bool) and not bounds[0] <= item <= bounds[1]:
                parser.error(f"{flag}: must be in [{bounds[0]}, {bounds[1]}], got {item}")
    if isinstance(getattr(args, "workers", None), int):
        try:
            check_workers("--workers", args.workers, getattr(args, "backend", "local"))
        except ParameterError as error:
            parser.error(str(error))


def name_and_value(text: str, flag: str) -> tuple[str, str]:
    """'NAME=VALUE' -> (NAME, VALUE text), NAME a Python identifier (a keyword argument)."""
    key, sep, value = text.partition("=")
    if not sep or not key.isidentifier():
        raise argparse.ArgumentTypeError(f"{flag} must look like NAME=VALUE, got {text!r}")
    return key, value


PYTHON_CONSTANTS = {"True": True, "False": False, "None": None}  # as a gym.make call would spell them


def env_kwarg(text: str, flag: str = "--env-kwarg") -> tuple[str, object]:
    """'object_type=box' -> ('object_type', 'box'); values parse as JSON when they can (numbers, true, [..]), and
    True, False and None as in Python. ``flag`` names the option in the error for text that is not NAME=VALUE."""
    key, value = name_and_value(text, flag)
    if value in PYTHON_CONSTANTS:
        return key, PYTHON_CONSTANTS[value]
    try:
        return key, json.loads(value)
    except ValueError:
        return key, value


# -- arguments ---------------------------------------------------------------------------------------------------
def default_argument(
    parser: argparse.ArgumentParser, flag: str, default: Any, what: str, type: Callable = positive_int, **kwargs
) -> None:
    """``flag`` with its default said at the end of its help: "``what`` (default ``default``)"."""
    parser.add_argument(flag, type=type, default=default, help=f"{what} (default {shown(default)})", **kwargs)


def swarm_arguments(
    parser: argparse.ArgumentParser, config: Mapping[str, Any] | None = None, engine_default: bool = False
) -> None:
    """--n-robots and --robot-model, defaulting to ``config``'s (the defaults of the library call they go to).
    Without ``config`` they default to None: a saved model's own values apply, else the env's. ``engine_default``:
    --robot-model defaults to None, for the command to choose by its --engine (disk for the batched one)."""
    given = config or {}
    shown_defaults = config or SWARM_DEFAULTS
    or_model = "" if config else ", or a model's"
    if engine_default:
        given = {**given, "robot_model": None}
        or_model += "; disk with --engine batched"
    parser.add_argument(
        "--n-robots",
        type=positive_int,
        default=given.get("n_robots"),
        help=f"swarm size N (default {shown_defaults['n_robots']}{or_model and or_model + ' N'})",
    )
    parser.add_argument(
        "--robot-model",
        choices=ROBOT_MODELS,
        default=given.get("robot_model"),
        help="paddle: the paper's robot; disk: the fast single-body model "
        f"(default {shown_defaults['robot_model']}{or_model})",
    )


def env_kwarg_argument(parser: argparse.ArgumentParser, example: str) -> None:
    parser.add_argument(
        "--env-kwarg",
        action="append",
        type=env_kwarg,
        metavar="NAME=VALUE",
        help=f"extra gym.make kwarg, e.g. {example} (repeatable)",
    )


def workers_argument(parser: argparse.ArgumentParser, what: str, flag: str = "--workers") -> None:
    """A count of processes (``what`` they do), :data:`DEFAULT_WORKERS` by default."""
    parser.add_argument(
        flag, type=positive_int, default=DEFAULT_WORKERS, help=f"{what} (default: {DEFAULT_WORKERS_TEXT})"
    )


ENGINES = ("pymunk", "batched")  # dpr.sim (the reference, one swarm per call) and dpr.sim.batched (K swarms per call)


def engine_arguments(parser: argparse.ArgumentParser) -> None:
    """--engine and --device: the pymunk reference engine, or the batched disk engine on a torch device."""
    parser.add_argument(
        "--engine",
        choices=ENGINES,
        default=ENGINES[0],
        help="pymunk: the reference engine, one swarm per env (default); batched: the disk model for every episode "
        "at once in torch (dpr.sim.batched; robot model disk, which it takes by default)",
    )
    parser.add_argument("--device", default="cpu", help="torch device of the batched engine: cpu or cuda (default cpu)")


def compile_argument(parser: argparse.ArgumentParser, learner: bool = False) -> None:
    """--compile: torch.compile the batched engine's physics (and, for a command that trains, the learner's loss)."""
    loss = " and PPO's mini-batch loss (about 1.1 times the update's speed)" if learner else ""
    parser.add_argument(
        "--compile",
        action="store_true",
        help=f"with --engine batched: torch.compile each physics substep (swarms of up to 32 robots){loss}: seconds "
        "of compiling at the first step, then about 3 times the physics' speed on a CPU",
    )


def apply_engine_defaults(args) -> None:
    """The batched engine's robot model, disk, where --robot-model was not given (a model file's own applies)."""
    if args.engine == "batched" and args.robot_model is None and not args.policy.endswith(".zip"):
        args.robot_model = "disk"


def json_argument(parser: argparse.ArgumentParser, what: str) -> None:
    parser.add_argument("--json", help=f"also write {what} to this new JSON file")


def rerun_argument(parser: argparse.ArgumentParser, what: str) -> None:
    """--rerun OUT.rrd: checked by :func:`check_rerun_output`."""
    parser.add_argument("--rerun", metavar="OUT.rrd", help=what)


# -- checks ------------------------------------------------------------------------------------------------------
# Flags that name something a command writes: each is checked writable before the command does any work.
OUTPUT_FLAGS = ("out", "json", "save", "rerun")


def unwritable_destination(path: str) -> str | None:
    """Why nothing can be written at ``path`` (a file or a folder, which may not exist yet), or None: its
    nearest existing folder must take a new file, so that hours of work never end in a failed write."""
    target = Path(path).absolute()
    base = target if target.is_dir() else target.parent
    while not base.exists():
        base = base.parent
    if not base.is_dir():
        return f"{base} is not a folder"
    try:
        with tempfile.TemporaryFile(dir=base):
            pass
    except OSError as error:
        return f"cannot write in {base}: {error.strerror or error}"
    return None


def check_output(path: str | None, parser: argparse.ArgumentParser, flag: str) -> None:
    """A new file in an existing folder: results are never overwritten."""
    if path is None:
        return
    p = Path(path)
    if p.exists():
        parser.error(f"{flag}: {p} already exists; choose another path (results are never overwritten)")
    if not p.parent.exists():
        parser.error(f"{flag}: folder {p.parent} does not exist")


def check_rrd_output(path: str | None, parser: argparse.ArgumentParser, flag: str) -> None:
    """A new file ending in .rrd (`dpr view --save`, ``--rerun`` of `dpr evaluate`, `dpr train`, `dpr finetune`)."""
    check_output(path, parser, flag)
    if path is not None and Path(path).suffix != ".rrd":
        parser.error(f"{flag}: {path} must end in .rrd")


def check_rerun_output(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    check_rrd_output(args.rerun, parser, "--rerun")


def check_seed(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """--seed of a model: numpy's global seed, which stable-baselines3 sets from it, takes [0, 2^32 - 1]."""
    if not 0 <= args.seed <= MAX_MODEL_SEED:
        parser.error(f"--seed must be in [0, {MAX_MODEL_SEED}], got {args.seed}")


def check_env_kwargs(
    env_ids: list[str], env_kwargs: dict, parser: argparse.ArgumentParser, engine: str = "pymunk"
) -> None:
    """Build each env once on ``engine`` (a vector env of one for the batched engine, whose kwargs such as
    ``wall_give`` a pymunk env refuses), so that a bad kwarg is reported before any episode runs."""
    import gymnasium as gym

    for env_id in env_ids:
        try:
            if engine == "batched":
                gym.make_vec(env_id, num_envs=1, vectorization_mode="vector_entry_point", **env_kwargs).close()
            else:
                gym.make(env_id, **env_kwargs).close()
        except (TypeError, ValueError) as error:
            parser.error(f"{env_id} with {env_kwargs}: {error}")


def policy_env_kwargs(args, env_ids: list[str], parser: argparse.ArgumentParser) -> dict:
    """The env kwargs that run ``args.policy`` on ``env_ids`` (``dpr evaluate``, ``dpr collect``): for a scripted
    policy the flags (--n-robots, --robot-model, --env-kwarg; the env's swarm by default); for a ``.zip`` model its
    own kwargs, where a flag given explicitly must agree with them (a parser error naming the flag)."""
    from dpr.policies.model_file import is_model_path, model_env_kwargs

    given = {"n_robots": args.n_robots, "robot_model": args.robot_model}
    flags = {"n_robots": "--n-robots", "robot_model": "--robot-model"}
    explicit = {**{k: v for k, v in given.items() if v is not None}, **dict(args.env_kwarg or [])}
    engine = getattr(args, "engine", "pymunk")
    if not is_model_path(args.policy):
        env_kwargs = {**SWARM_DEFAULTS, **explicit}
        check_env_kwargs(env_ids, env_kwargs, parser, engine)
        return env_kwargs
    resolved = {}
    transfer = getattr(args, "transfer", False)  # dpr evaluate's flag; dpr collect has none
    for env_id in env_ids:
        try:
            resolved[env_id] = model_env_kwargs(args.policy, env_id, explicit, transfer=transfer)
        except ValueError as error:
            message = flag_message(error)
            for name, flag in flags.items():  # name the flag the user typed, not the kwarg
                if given[name] is not None:
                    message = message.replace(f"; {name}={given[name]!r}", f"; {flag} {given[name]}")
            parser.error(message)
    check_env_kwargs(env_ids, resolved[env_ids[0]], parser, engine)
    return resolved[env_ids[0]]


def write_json(path: str, payload: Any) -> None:
    """``--json``: what a command printed, for scripts, in a new file (checked by :func:`check_output` first)."""
    from dpr.atomic import atomic_write_json

    atomic_write_json(path, payload, indent=2, exclusive=True)
    print(f"wrote {path}")


def markov_env_kwargs(args, env_kwargs: dict, parser: argparse.ArgumentParser, command: str) -> dict:
    """``env_kwargs`` for a Markov wave among --policy and --label-policy (`dpr collect`, `dpr evaluate`): it reads
    the previous action from the observation, so obs_last_action=True is set (and said) where no flag or model set
    it; a parser error naming the flag where obs_last_action is off."""
    from dpr.policies.model_file import is_model_path
    from dpr.policies.registry import WAVE_MARKOV

    markov = [
        flag
        for flag, name in (("--policy", args.policy), ("--label-policy", getattr(args, "label_policy", None)))
        if name is not None and name.partition(":")[0] == WAVE_MARKOV
    ]
    if not markov:
        return env_kwargs
    value = env_kwargs.get("obs_last_action")
    if value is None and not is_model_path(args.policy):
        print(
            f"dpr {command}: {markov[0]} {WAVE_MARKOV} reads the previous action from the observation: "
            f"{'recording' if command == 'collect' else 'running'} with obs_last_action=True "
            "(--env-kwarg obs_last_action=true)",
            file=sys.stderr,
        )
        return {**env_kwargs, "obs_last_action": True}
    if not value:
        given = (
            f"the model {args.policy} was trained without it"
            if is_model_path(args.policy)
            else f"got obs_last_action={value!r}"
        )
        parser.error(
            f"{markov[0]} {WAVE_MARKOV} reads the previous action and its held steps from the observation: it needs "
            f"--env-kwarg obs_last_action=true ({given})"
        )
    return env_kwargs
