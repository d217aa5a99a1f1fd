"""`dpr bc`: behaviour cloning of recorded demonstrations into an SB3 model, optionally followed by DAgger rounds."""

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

# dpr.imitation.bc and dpr.imitation.dagger parameters, said as the flags that set them.
BC_FLAGS = {
    "dataset_dirs": "--dataset",
    "rounds": "--dagger-rounds",
    "episodes_per_round": "--dagger-episodes",
    "first_seed": "--dagger-seed",
}


def bc_arguments(parser: argparse.ArgumentParser) -> None:
    from dpr.imitation.bc import behaviour_clone
    from dpr.imitation.dagger import dagger
    from dpr.policies.sb3 import BC_ALGOS

    clone = defaults(behaviour_clone)
    dagger_run = defaults(dagger)

    parser.add_argument(
        "--dataset",
        required=True,
        nargs="+",
        help="dataset folder(s) written by `dpr collect` on the same env; validation episodes come from the first",
    )
    parser.add_argument("--env", required=True, help=f"env id the dataset was recorded on, e.g. {EXAMPLE_ENV_ID}")
    parser.add_argument(
        "--algo",
        choices=BC_ALGOS,
        default=clone["algo"],
        help=f"model to clone into (default {clone['algo']}; dqn: its Q-network as a classifier over 2^N actions)",
    )
    parser.add_argument("--n-robots", type=positive_int, help="swarm size N; only checked: it must be the dataset's")
    parser.add_argument("--robot-model", choices=ROBOT_MODELS, help="only checked: it must be the dataset's")
    default_argument(parser, "--epochs", clone["epochs"], "maximum epochs")
    default_argument(parser, "--batch-size", clone["batch_size"], "frames per gradient step")
    default_argument(parser, "--lr", clone["lr"], "Adam learning rate", type=float)
    default_argument(
        parser, "--val-fraction", clone["val_fraction"], "fraction of episodes held out for validation", type=float
    )
    default_argument(
        parser,
        "--patience",
        clone["patience"],
        "stop after this many epochs without a better validation log-likelihood",
    )
    default_argument(parser, "--seed", clone["seed"], "seed of the model, the split and the shuffling", type=int)
    parser.add_argument("--out", help="new run folder (default runs/bc/<task>-<algo>-seed<S>-<timestamp>)")
    parser.add_argument(
        "--dagger-rounds",
        type=int,
        default=0,
        help="DAgger rounds after cloning: roll the clone out, label its states with --expert, clone "
        "again on everything (default 0: plain behaviour cloning)",
    )
    default_argument(parser, "--dagger-episodes", dagger_run["episodes_per_round"], "episodes per DAgger round")
    default_argument(
        parser,
        "--dagger-seed",
        dagger_run["first_seed"],
        "first seed of the DAgger episodes; must not be a demonstration seed",
        type=int,
    )
    default_argument(
        parser,
        "--expert",
        dagger_run["expert"],
        "policy that labels the DAgger states; a function of the observation",
        type=str,
    )
    workers_argument(parser, "processes that roll out DAgger episodes")


def cmd_bc(args, parser) -> int:
    from dpr.imitation.bc import behaviour_clone

    check_seed(args, parser)
    if not args.lr > 0:
        parser.error(f"--lr must be > 0, got {args.lr}")
    requested = {
        name: value
        for name, value in (("n_robots", args.n_robots), ("robot_model", args.robot_model))
        if value is not None
    }
    bc_kwargs = dict(
        algo=args.algo,
        epochs=args.epochs,
        batch_size=args.batch_size,
        lr=args.lr,
        val_fraction=args.val_fraction,
        patience=args.patience,
        seed=args.seed,
        env_kwargs=requested,
        show_progress=True,
    )
    try:
        if args.dagger_rounds:
            from dpr.imitation.bc import default_run_dir
            from dpr.imitation.dagger import dagger

            out = args.out or default_run_dir(args.env, f"{args.algo}-dagger", args.seed)
            run = dagger(
                args.dataset,
                args.env,
                out,
                expert=args.expert,
                rounds=args.dagger_rounds,
                episodes_per_round=args.dagger_episodes,
                first_seed=args.dagger_seed,
                workers=args.workers,
                **bc_kwargs,
            )
            result, model = run.rounds[-1], run.model_path
            print(f"DAgger: {len(run.rounds) - 1} round(s), datasets {', '.join(map(str, run.datasets))}")
        else:
            result = behaviour_clone(args.dataset, args.env, out=args.out, **bc_kwargs)
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


COMMANDS = (
    Command(
        "bc",
        help="behaviour-clone a recorded dataset into a PPO/A2C model",
        description="Train the policy of a new SB3 model (built as `dpr train` builds it, with the env kwargs the "
        "dataset was recorded with) to maximise the likelihood of the dataset's actions; whole episodes are held "
        "out for validation, training stops early on the validation log-likelihood and the best weights are kept. "
        "Saves model.zip, bc_log.json and config.yaml into a new run folder; "
        "`dpr evaluate --policy RUN/model.zip --env ID` runs the model.",
        arguments=bc_arguments,
        run=cmd_bc,
        flags=BC_FLAGS,
    ),
)
