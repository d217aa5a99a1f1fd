"""`dpr pipeline`: per task, demonstrations -> BC -> fine-tuning, beside RL from scratch, evaluated against the
wave (dpr.rl.pipeline)."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Callable

from dpr.cli.common import (
    ALL_ENVS,
    TASK_NAMES,
    Command,
    flag_message,
    non_negative_int,
    parse_seeds,
    positive_int,
    seeds_text,
    shown,
    workers_argument,
)

PIPELINE_OUT = "runs/pipeline"
PIPELINE_FLAGS = {"finetune_hyperparams": "--finetune-hyperparam", "env_ids": "--env-id"}


def _pairs(mapping: dict) -> str:
    return " ".join(f"{key}={value}" for key, value in mapping.items()) or "none"


def earlier_env_id(text: str) -> str:
    """An ``--env-id`` value: one of the tasks' earlier registered ids."""
    from dpr.envs import EARLIER_ENV_IDS

    if text not in EARLIER_ENV_IDS:
        raise argparse.ArgumentTypeError(f"expected one of {list(EARLIER_ENV_IDS)}, got {text!r}")
    return text


def pipeline_arguments(parser: argparse.ArgumentParser) -> None:
    from dpr.cli.learn import hyperparam
    from dpr.envs import EARLIER_ENV_IDS
    from dpr.policies.sb3 import FINETUNE_ALGOS
    from dpr.rl.pipeline_config import ACTORS, DEFAULT_PRESET, PRESETS, SCRATCH_ALGOS

    presets = {name: dataclasses.asdict(config) for name, config in PRESETS.items()}

    def preset_argument(
        flag: str, what: str, type: Callable = positive_int, show: Callable = shown, aliases=(), **kwargs
    ) -> None:
        """A flag that overrides the preset's value (None when not given); its help lists every preset's."""
        name = flag[2:].replace("-", "_")
        values = ", ".join(f"{preset} {show(config[name])}" for preset, config in presets.items())
        parser.add_argument(
            flag, *aliases, dest=name, type=type, default=None, help=f"{what} (preset: {values})", **kwargs
        )

    parser.add_argument("--out", default=PIPELINE_OUT, help=f"run folder (default {PIPELINE_OUT}; resumed if present)")
    parser.add_argument(
        "--preset",
        choices=list(PRESETS),
        default=DEFAULT_PRESET,
        help=f"the budgets and seed sets to start from (default {DEFAULT_PRESET}: `make run`'s minutes; full: the "
        "headline, hours per task); the flags below override single values",
    )
    preset_argument("--tasks", f"tasks to run, or '{ALL_ENVS}'", type=str, nargs="+", choices=(*TASK_NAMES, ALL_ENVS))
    parser.add_argument(
        "--env-id",
        dest="env_ids",
        action="append",
        type=earlier_env_id,
        metavar="ID",
        default=None,
        help="run a task on this earlier registered id of it instead of its current one, as the records made before "
        f"it do (repeatable; {', '.join(EARLIER_ENV_IDS)})",
    )
    preset_argument("--n-robots", "swarm size N")
    preset_argument("--episodes", "demonstration episodes per task")
    preset_argument("--demo-seed", "first demonstration seed", type=non_negative_int)
    preset_argument("--bc-epochs", "behaviour-cloning epochs")
    preset_argument("--critic-warmup", "value-only steps before fine-tuning", type=non_negative_int)
    preset_argument("--finetune-steps", "fine-tuning steps")
    parser.add_argument(
        "--anchor",
        action="store_true",
        default=None,
        help="anchor fine-tuning to the task's demonstrations "
        "(`dpr finetune --anchor` with its default weight and decay)",
    )
    parser.add_argument(
        "--scratch-physics-discount",
        action="store_true",
        default=None,
        help="the runs from scratch discount 0.99 per physics step (0.99^K per decision of K steps), as the "
        "fine-tuning does, instead of the yaml's gamma per decision",
    )
    preset_argument(
        "--approach-reward",
        "Manipulation only: RL (fine-tuning and from scratch) trains with this weight of the swarm-ball approach "
        "shaping (the env's approach_reward; 0 for none)",
        type=float,
        metavar="W",
    )
    preset_argument(
        "--finetune-algos", "algorithms that fine-tune the clone", type=str, nargs="+", choices=FINETUNE_ALGOS
    )
    preset_argument(
        "--scratch-algos",
        "algorithms trained from scratch for the same total env steps",
        type=str,
        nargs="*",
        choices=SCRATCH_ALGOS,
    )
    preset_argument(
        "--train-seeds",
        "seeds of BC and RL: one training run of every method per seed",
        type=lambda text: parse_seeds(text, "--train-seeds"),
        show=seeds_text,
        aliases=("--seed",),
    )
    preset_argument(
        "--validation-seeds",
        "seeds that make every choice (each method's canonical model is its median run there); needed with "
        "several training seeds",
        type=lambda text: parse_seeds(text, "--validation-seeds"),
        show=lambda seeds: seeds_text(seeds) or "none",
    )
    preset_argument(
        "--test-seeds",
        "seeds that score every run and the wave for the report, and nothing else",
        type=lambda text: parse_seeds(text, "--test-seeds"),
        show=seeds_text,
        aliases=("--eval-seeds",),
    )
    parser.add_argument(
        "--finetune-hyperparam",
        dest="finetune_hyperparams",
        action="append",
        type=hyperparam,
        metavar="NAME=VALUE",
        help="a fine-tuning hyperparameter over the preset's (preset: "
        + ", ".join(f"{name} {_pairs(config['finetune_hyperparams'])}" for name, config in presets.items())
        + ") and the yaml's `finetune` entry, e.g. learning_rate=1e-4; NAME=null drops the preset's value, so the "
        "yaml's stands (repeatable)",
    )
    preset_argument(
        "--actor",
        "every learner's actor: mlp (one MLP from the whole state to every robot's action) or swarm (one network "
        "shared by the robots, seeing the whole swarm: dpr.policies.swarm_policy)",
        type=str,
        choices=list(ACTORS),
    )
    preset_argument("--steps", "physics steps per episode, everywhere")
    preset_argument(
        "--teacher-holds",
        "holds (physics steps per phase) of the Markov wave among which each task's teacher, the policy its "
        "demonstrations come from, is chosen by its median on the teacher seeds (the paper's wave, which "
        "every result is a percentage of, holds 10)",
        nargs="+",
        metavar="HOLD",
    )
    preset_argument(
        "--teacher-bin-widths",
        "bin widths (units along the goal direction; the wave's is 60) of the Markov wave: each task's teacher is "
        "chosen among every pair of a teacher hold and a bin width",
        type=float,
        nargs="+",
        metavar="WIDTH",
    )
    preset_argument(
        "--teacher-seeds",
        "seeds that choose each task's teacher ('none': the validation seeds); never test seeds",
        type=lambda text: [] if text == "none" else parse_seeds(text, "--teacher-seeds"),
        show=lambda seeds: seeds_text(seeds) or "none",
    )
    preset_argument(
        "--action-repeat",
        "the learners (demonstrations, BC, RL) decide every K physics steps (env kwarg action_repeat; K divides "
        "every teacher hold), or 0: once per phase of the task's teacher (K = its hold); budgets stay physics "
        "steps. Fine-tuning discounts 0.99 per physics step (gamma = 0.99^K per decision) unless "
        "--finetune-hyperparam sets gamma",
        type=non_negative_int,
        metavar="K",
    )
    parser.add_argument(
        "--shipped",
        metavar="CARD",
        help="also evaluate the shipped models that this model card lists (e.g. models/card.yaml, what `make run` "
        "passes) on the test seeds, beside the wave on their tasks: the headline checked on your machine",
    )
    workers_argument(parser, "worker processes for collection, RL envs and evaluation")


def pipeline_config(args):
    """The :class:`dpr.rl.pipeline_config.PipelineConfig` the parsed flags say: the preset, and every flag given
    over it (checked: a ValueError names the setting)."""
    from dpr.envs import ENV_IDS, TASKS
    from dpr.rl.pipeline_config import PRESETS, PipelineConfig, preset_config

    overrides = {
        field.name: getattr(args, field.name)
        for field in dataclasses.fields(PipelineConfig)
        if getattr(args, field.name, None) is not None
    }
    if overrides.get("tasks") == [ALL_ENVS]:
        overrides["tasks"] = list(ENV_IDS)
    if "env_ids" in overrides:  # --env-id dpr/Gate-v0 -> {"gate": "dpr/Gate-v0"}
        overrides["env_ids"] = {TASKS[env_id]: env_id for env_id in overrides["env_ids"]}
    if "finetune_hyperparams" in overrides:  # NAME=VALUE pairs over the preset's; NAME=null drops the preset's
        preset = PRESETS[args.preset].finetune_hyperparams  # (argparse allows only known presets)
        merged = {**preset, **dict(overrides["finetune_hyperparams"])}
        overrides["finetune_hyperparams"] = {name: value for name, value in merged.items() if value is not None}
    return preset_config(args.preset, **overrides)


def cmd_pipeline(args, parser) -> int:
    from dpr.rl.model_card import load_model_card
    from dpr.rl.pipeline import run_pipeline

    try:
        config = pipeline_config(args)
        shipped = load_model_card(args.shipped) if args.shipped else []
        report = run_pipeline(config, args.out, shipped=shipped)
    except (TypeError, ValueError) as error:
        parser.error(flag_message(error, PIPELINE_FLAGS))
    except KeyboardInterrupt:
        print(f"dpr pipeline: interrupted; run the same command again to resume {args.out}", file=sys.stderr)
        return 130
    print((report / "results.md").read_text())
    return 0


COMMANDS = (
    Command(
        "pipeline",
        help="demonstrations -> BC -> fine-tuning, beside RL from scratch, evaluated against the wave",
        description="Per task: record demonstrations of the Markov wave, clone them (BC), fine-tune the clone "
        "with PPO/A2C, train RL from scratch for the same total env steps, evaluate everything and the wave policy "
        "on seeds no choice saw, and write OUT/report/results.md (with interval estimates over training runs) and "
        "its figures. Training seeds, validation seeds (every choice) and test seeds (the report) never overlap. "
        "Every stage is skipped when its output exists: the same command resumes an interrupted run. --preset "
        "small (the default) is `make run` (Navigation, N=9, about 5 minutes on 2 CPU cores); --preset full "
        "--tasks all is the headline.",
        arguments=pipeline_arguments,
        flags=PIPELINE_FLAGS,
        run=cmd_pipeline,
    ),
)
