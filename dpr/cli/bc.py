"""`dpr bc`: behaviour cloning of recorded demonstrations into an SB3 model, optionally followed by DAgger rounds;
`dpr bc-decentralised`: the same demonstrations cloned into one per-robot model that runs any swarm size."""

from __future__ import annotations

import argparse

from dpr.cli.common import (
    EXAMPLE_ENV_ID,
    Command,
    check_seed,
    default_argument,
    defaults,
    flag_message,
    positive_int,
    workers_argument,
)
from dpr.sim.models import ROBOT_MODELS

# The parameters and settings fields of dpr.imitation.bc, .dagger and .config, said as the flags that set them.
BC_FLAGS = {
    "dataset_dirs": "--dataset",
    "rounds": "--dagger-rounds",
    "episodes_per_round": "--dagger-episodes",
    "first_seed": "--dagger-seed",
}


# The fit's settings (fields of dpr.imitation.config.FitConfig), each set by --<field>: its type and what it is, where
# {unit} is what one sample is and {held_out} what validation holds out.
FIT_FLAGS = (
    ("epochs", positive_int, "maximum epochs"),
    ("batch_size", positive_int, "{unit} per gradient step"),
    ("lr", float, "Adam learning rate"),
    ("val_fraction", float, "{held_out}"),
    ("patience", positive_int, "stop after this many epochs without a better validation log-likelihood"),
    ("seed", int, "seed of the model, the split and the shuffling"),
)
# The DaggerConfig fields `dpr bc` sets besides --dagger-rounds (which defaults to none): flag, type, what it is.
DAGGER_FLAGS = (
    ("episodes_per_round", "--dagger-episodes", positive_int, "episodes per DAgger round"),
    ("first_seed", "--dagger-seed", int, "first seed of the DAgger episodes; must not be a demonstration seed"),
    ("expert", "--expert", str, "policy that labels the DAgger states; a function of the observation"),
)


def add_fit_flags(parser, clone: dict, unit: str, held_out: str) -> None:
    """The flags of a cloning run's fit (:data:`FIT_FLAGS`), defaulting to ``clone``'s."""
    for name, type_, what in FIT_FLAGS:
        flag = "--" + name.replace("_", "-")
        default_argument(parser, flag, clone[name], what.format(unit=unit, held_out=held_out), type=type_)


def dataset_arguments(parser: argparse.ArgumentParser, datasets: str, env: str, env_default: str) -> None:
    """--dataset, one or more folders (``datasets`` says which), and --env (``env`` says which; by default
    ``env_default``)."""
    parser.add_argument("--dataset", required=True, nargs="+", help=datasets)
    parser.add_argument("--env", help=f"{env}, e.g. {EXAMPLE_ENV_ID} (default: {env_default})")


def hyperparam_argument(parser: argparse.ArgumentParser) -> None:
    from dpr.cli.learn import hyperparam
    from dpr.policies.model_file import SWARM_POLICY

    parser.add_argument(
        "--hyperparam",
        action="append",
        type=hyperparam,
        metavar="NAME=VALUE",
        help="override a value of the yaml entry the model is built from, e.g. 'policy_kwargs={net_arch: [256, "
        f"256]}}' (repeatable). The actor of ppo and a2c is {SWARM_POLICY} unless set here (one network shared by "
        "the robots, the pipeline's choice); policy=MlpPolicy gives the yaml's MLP over the whole observation. "
        "dqn keeps the yaml's policy. The model file records its network, and `dpr finetune` builds the same",
    )


def dagger_arguments(parser: argparse.ArgumentParser) -> None:
    """--dagger-rounds (0 by default: plain cloning) and the other DAgger settings (:data:`DAGGER_FLAGS`)."""
    from dpr.imitation.config import DaggerConfig

    dagger_run = defaults(DaggerConfig)
    parser.add_argument(
        "--dagger-rounds",
        type=int,
        default=0,
        help="DAgger rounds after cloning: roll the clone out, label its states with --expert, clone "
        "again on everything (default 0: plain behaviour cloning)",
    )
    for name, flag, type_, what in DAGGER_FLAGS:
        default_argument(parser, flag, dagger_run[name], what, type=type_)
    workers_argument(parser, "processes that roll out DAgger episodes")


def bc_arguments(parser: argparse.ArgumentParser) -> None:
    from dpr.imitation.config import CloneConfig
    from dpr.policies.sb3 import BC_ALGOS

    clone = defaults(CloneConfig)
    dataset_arguments(
        parser,
        "dataset folder(s) written by `dpr collect` on the same env; validation episodes come from the first",
        "env id the dataset was recorded on",
        "the one its episodes name",
    )
    parser.add_argument(
        "--algo",
        choices=BC_ALGOS,
        default=clone["algo"],
        help=f"model to clone into (default {clone['algo']}; dqn: its Q-network as a classifier over 2^N actions)",
    )
    parser.add_argument("--n-robots", type=positive_int, help="swarm size N; only checked: it must be the dataset's")
    parser.add_argument("--robot-model", choices=ROBOT_MODELS, help="only checked: it must be the dataset's")
    add_fit_flags(parser, clone, "frames", "fraction of episodes held out for validation")
    hyperparam_argument(parser)
    parser.add_argument("--out", help="new run folder (default runs/bc/<task>-<algo>-seed<S>-<timestamp>)")
    dagger_arguments(parser)


def bc_hyperparams(algo: str, given: dict) -> dict:
    """The hyperparameter overrides of a `dpr bc` run: the --hyperparam values ``given``, over the default actor of an
    actor-critic, :data:`dpr.policies.model_file.SWARM_POLICY` (what cloning into PPO or A2C takes, MultiBinary
    actions from the state observation, is what it acts on); DQN keeps the yaml's policy. The library's
    behaviour_clone keeps the yaml's too: the pipeline names its actor itself."""
    from dpr.policies.model_file import SWARM_POLICY
    from dpr.policies.sb3 import FINETUNE_ALGOS

    return {"policy": SWARM_POLICY, **given} if algo in FINETUNE_ALGOS else dict(given)


def recorded_env_id(args, parser: argparse.ArgumentParser) -> str:
    """``--env``, or when it is not given the env id the first dataset's episodes were recorded on (a usage error
    naming --dataset when it names none; a dataset of another env is refused later, naming both)."""
    if args.env is not None:
        return args.env
    from dpr.datasets import LeRobotReader
    from dpr.datasets.features import ENV_ID
    from dpr.datasets.lerobot.format import DatasetError

    try:
        episodes = LeRobotReader(args.dataset[0]).episodes
    except DatasetError as error:  # a missing or damaged folder: its own message (which names it), as --dataset's
        parser.error(f"--dataset: {error}")
    if not episodes or not isinstance(episodes[0].get(ENV_ID), str):
        parser.error(f"--dataset: {args.dataset[0]} names no env id in its episodes; give --env")
    return episodes[0][ENV_ID]


def fit_settings(args) -> dict:
    """The model and fit settings (:class:`dpr.imitation.config.FitConfig` fields) that the flags say."""
    return {name: getattr(args, name) for name in ("algo", *(name for name, *_ in FIT_FLAGS))}


def dagger_config(args):
    """The :class:`dpr.imitation.config.DaggerConfig` of `dpr bc`'s DAgger flags."""
    from dpr.imitation.config import DaggerConfig

    dest = {flag: flag[2:].replace("-", "_") for _, flag, *_ in DAGGER_FLAGS}  # where argparse keeps each flag
    settings = {name: getattr(args, dest[flag]) for name, flag, *_ in DAGGER_FLAGS}
    return DaggerConfig(rounds=args.dagger_rounds, workers=args.workers, **settings)


def cmd_bc(args, parser) -> int:
    from dpr.imitation.bc import behaviour_clone
    from dpr.imitation.config import CloneConfig

    check_seed(args, parser)
    args.env = recorded_env_id(args, parser)
    if not args.lr > 0:
        parser.error(f"--lr must be > 0, got {args.lr}")
    requested = {
        name: value
        for name, value in (("n_robots", args.n_robots), ("robot_model", args.robot_model))
        if value is not None
    }
    hyperparams = bc_hyperparams(args.algo, dict(args.hyperparam or []))
    try:
        dagger_run = dagger_config(args) if args.dagger_rounds else None
        clone = CloneConfig(**fit_settings(args), env_kwargs=requested, hyperparams=hyperparams)
        if dagger_run is not None:
            from dpr.imitation.bc import default_run_dir
            from dpr.imitation.dagger import dagger

            out = args.out or default_run_dir(args.env, f"{args.algo}-dagger", args.seed)
            run = dagger(args.dataset, args.env, out, dagger_run, clone, show_progress=True)
            result, model = run.rounds[-1], run.model_path
            print(f"DAgger: {len(run.rounds) - 1} round(s), datasets {', '.join(map(str, run.datasets))}")
        else:
            result = behaviour_clone(args.dataset, args.env, clone, out=args.out, show_progress=True)
            model = result.model_path
    except (TypeError, ValueError) as error:
        parser.error(flag_message(error, BC_FLAGS))
    print(f"model: {model}" + (f" (the last round's, {result.model_path})" if model != result.model_path else ""))
    print(f"log: {result.log_path}")
    print(f"config: {result.config_path}")
    print(f"evaluate it: dpr evaluate --policy {model} --env {args.env}")
    print(
        f"best validation accuracy {result.best_val_accuracy:.3f} (epoch {result.best_epoch} of "
        f"{result.epochs_run}, validation NLL {result.best_val_nll:.4f})"
    )
    return 0


def bc_decentralised_arguments(parser: argparse.ArgumentParser) -> None:
    from dpr.imitation.config import PerRobotCloneConfig
    from dpr.policies.decentralised import MODEL_DEFAULTS
    from dpr.policies.sb3 import FINETUNE_ALGOS

    clone = defaults(PerRobotCloneConfig)
    holds = ", ".join(f"{model} {values['hold_steps']}" for model, values in MODEL_DEFAULTS.items())
    dataset_arguments(
        parser,
        "dataset folder(s) written by `dpr collect` on the same env, of any swarm sizes (e.g. one of N=9 and "
        "one of N=25); every dataset of 2 or more episodes gives validation episodes",
        "env id the datasets were recorded on",
        "the one they name",
    )
    parser.add_argument(
        "--algo",
        choices=FINETUNE_ALGOS,
        default=clone["algo"],
        help=f"model to clone into, which PPO/A2C can fine-tune on the PettingZoo env (default {clone['algo']})",
    )
    parser.add_argument("--robot-model", choices=ROBOT_MODELS, help="only checked: it must be the datasets'")
    default_argument(parser, "--max-neighbours", clone["max_neighbours"], "neighbour slots K of the local observation")
    parser.add_argument(
        "--hold-steps",
        type=positive_int,
        help=f"steps of one wave phase: the clock's period is --hold-steps x --n-phases; with the decentralised "
        f"wave as teacher, the hold it ran with (default the robot model's: {holds})",
    )
    default_argument(parser, "--n-phases", clone["n_phases"], "phases of one wave cycle (the clock's period)")
    parser.add_argument(
        "--distance-period",
        type=distance_period,
        default=clone["distance_period"],
        metavar="{wave,none,LENGTH}",
        help="what a robot senses of its distance to the goal: 'wave' (default) its phase in a band pattern of one "
        "wave length (--n-phases x 60 units), so nothing in its observation grows with the swarm and the model "
        "carries to large N; a LENGTH > 0 in world units for another period; 'none' the raw distance",
    )
    add_fit_flags(parser, clone, "robot-frames", "fraction of each dataset's episodes held out")
    parser.add_argument(
        "--out", help="new run folder (default runs/bc-decentralised/<task>-<algo>-seed<S>-<timestamp>)"
    )


def cmd_bc_decentralised(args, parser) -> int:
    from dpr.imitation.config import PerRobotCloneConfig
    from dpr.imitation.per_robot import behaviour_clone_per_robot

    check_seed(args, parser)
    args.env = recorded_env_id(args, parser)
    if not args.lr > 0:
        parser.error(f"--lr must be > 0, got {args.lr}")
    try:
        config = PerRobotCloneConfig(
            **fit_settings(args),
            max_neighbours=args.max_neighbours,
            hold_steps=args.hold_steps,
            n_phases=args.n_phases,
            distance_period=args.distance_period,
            env_kwargs={} if args.robot_model is None else {"robot_model": args.robot_model},
        )
        result = behaviour_clone_per_robot(args.dataset, args.env, config, out=args.out, show_progress=True)
    except (TypeError, ValueError) as error:
        parser.error(flag_message(error, BC_DECENTRALISED_FLAGS))
    model = result.model_path
    print(f"model: {model}")
    print(f"log: {result.log_path}")
    print(f"config: {result.config_path}")
    print(f"evaluate it at any N: dpr evaluate --policy {model} --env {args.env} --n-robots 49")
    print(
        f"best validation accuracy {result.best_val_accuracy:.4f} (epoch {result.best_epoch} of "
        f"{result.epochs_run}, validation NLL {result.best_val_nll:.4f})"
    )
    return 0


def distance_period(text: str) -> float | str | None:
    """``--distance-period``: 'wave', 'none' or a length > 0."""
    from dpr.imitation.config import WAVE_LENGTH

    if text in (WAVE_LENGTH, "none"):
        return None if text == "none" else text
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"expected 'wave', 'none' or a length > 0, got {text!r}")
    return value


# The parameters and settings fields of dpr.imitation.per_robot and .config, said as the flags that set them.
BC_DECENTRALISED_FLAGS = {"dataset_dirs": "--dataset"}

COMMANDS = (
    Command(
        "bc",
        help="behaviour-clone a recorded dataset into a PPO/A2C model",
        description="Train the policy of a new SB3 model (built as `dpr train` builds it, with the env kwargs the "
        "dataset was recorded with; a PPO or A2C model's actor is SwarmPolicy unless --hyperparam policy=... says "
        "otherwise) to maximise the likelihood of the dataset's actions; whole episodes are held "
        "out for validation, training stops early on the validation log-likelihood and the best weights are kept. "
        "Saves model.zip, bc_log.json and config.yaml into a new run folder; "
        "`dpr evaluate --policy RUN/model.zip --env ID` runs the model.",
        arguments=bc_arguments,
        run=cmd_bc,
        flags=BC_FLAGS,
    ),
    Command(
        "bc-decentralised",
        help="behaviour-clone recorded datasets into one per-robot model that runs any swarm size",
        description="Relabel every frame of the datasets (recorded by `dpr collect`, e.g. with --policy "
        "decentralised-wave, of one or several swarm sizes) into per-robot samples: each robot's local observation "
        "(its own state, its K nearest magnet neighbours with a mask, its goal direction and its distance's phase "
        "in the wave's band pattern (--distance-period), a clock of "
        "one wave cycle, its dead flag and the object where the task has them), computed from the recorded state, "
        "and the action that robot took. Train one PPO/A2C model on them whose observation is one robot's and "
        "whose action is Discrete(2), as on the PettingZoo env parallel_env(..., local_obs=True); whole episodes "
        "are held out for validation, training stops early on the validation log-likelihood and the best weights "
        "are kept. Saves model.zip (marked as a per-robot model, with its layout), bc_log.json and config.yaml "
        "into a new run folder; `dpr evaluate --policy RUN/model.zip --env ID --n-robots N` runs it at any N, "
        "as do `dpr collect` and `dpr view`.",
        arguments=bc_decentralised_arguments,
        run=cmd_bc_decentralised,
        flags=BC_DECENTRALISED_FLAGS,
    ),
)
