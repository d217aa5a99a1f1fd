"""`dpr pipeline`: per task, demonstrations -> BC -> fine-tuning, beside RL from scratch, evaluated against the
wave (dpr.pipeline.campaign)."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Callable

from dpr.cli.common import (
    ALL_ENVS,
    Command,
    flag_message,
    non_negative_int,
    parse_seeds,
    positive_int,
    seeds_text,
    shown,
    workers_argument,
)
from dpr.envs import ENV_IDS

PIPELINE_OUT = "runs/pipeline"
PIPELINE_FLAGS = {
    "finetune_hyperparams": "--finetune-hyperparam",
    "scratch_hyperparams": "--scratch-hyperparam",
    "env_ids": "--env-id",
    "training_env_kwargs": "--training-env-kwarg",
}
HYPERPARAM_FLAGS = {"finetune_hyperparams": "--finetune-hyperparam", "scratch_hyperparams": "--scratch-hyperparam"}


def _task_kwargs(mapping: dict) -> str:
    return " ".join(f"{task}:{_pairs(kwargs)}" for task, kwargs in mapping.items()) or "none"


def _pairs(mapping: dict) -> str:
    return " ".join(f"{key}={value}" for key, value in mapping.items()) or "none"


def earlier_env_id(text: str) -> str:
    """An ``--env-id`` value: one of the tasks' earlier registered ids."""
    from dpr.envs import EARLIER_ENV_IDS

    if text not in EARLIER_ENV_IDS:
        raise argparse.ArgumentTypeError(f"expected one of {list(EARLIER_ENV_IDS)}, got {text!r}")
    return text


def task_env_kwarg(text: str) -> tuple[str, str, object]:
    """A ``--training-env-kwarg`` value: ``TASK:NAME=VALUE``."""
    from dpr.cli.common import env_kwarg

    task, colon, rest = text.partition(":")
    if not colon or not task:
        raise argparse.ArgumentTypeError(f"expected TASK:NAME=VALUE (e.g. 'gate:gate_distance=[5, 200]'), got {text!r}")
    return (task, *env_kwarg(rest, "--training-env-kwarg"))


class _SettingFlag:
    """Adds to ``parser`` a flag that overrides one setting of the config (None when not given), its help ending
    with every shipped preset's value of it."""

    def __init__(self, parser: argparse.ArgumentParser, presets: dict[str, dict]):
        self.parser, self.presets = parser, presets

    def __call__(self, flag: str, what: str, type: Callable = positive_int, show: Callable = shown, **kwargs) -> None:
        name = flag[2:].replace("-", "_")
        values = ", ".join(f"{preset} {show(config[name])}" for preset, config in self.presets.items())
        self.parser.add_argument(flag, dest=name, type=type, default=None, help=f"{what} (preset: {values})", **kwargs)


def pipeline_arguments(parser: argparse.ArgumentParser) -> None:
    """`dpr pipeline`'s flags, in the order --help lists them: where the settings come from and the tasks, the
    budgets and seeds, the learners, then where the stages run."""
    from dpr.pipeline.config import PRESETS, preset_path, read_settings

    presets = {name: read_settings(preset_path(name)) for name in PRESETS}
    preset_argument = _SettingFlag(parser, presets)
    _source_arguments(parser, preset_argument, presets)
    _budget_arguments(preset_argument)
    _learner_arguments(parser, preset_argument, presets)
    _run_arguments(parser)


def _source_arguments(parser: argparse.ArgumentParser, preset_argument: _SettingFlag, presets: dict) -> None:
    from dpr.envs import EARLIER_ENV_IDS
    from dpr.pipeline.config import DEFAULT_PRESET, PRESETS

    parser.add_argument("--out", default=PIPELINE_OUT, help=f"run folder (default {PIPELINE_OUT}; resumed if present)")
    source = parser.add_mutually_exclusive_group()
    source.add_argument(
        "--preset",
        choices=PRESETS,
        default=None,
        help=f"the shipped settings to start from (default {DEFAULT_PRESET}: `make run`'s minutes; tiny: the tests' "
        "seconds per stage; full: the headline, hours per task); the flags below override single values",
    )
    source.add_argument(
        "--config",
        metavar="FILE.yaml",
        help="settings from this yaml file (any of the settings below, by their names with underscores; the rest "
        "keep the small preset's values), or a run folder's pipeline.yaml, whose stored stages are then reused",
    )
    tasks = (*ENV_IDS, ALL_ENVS)  # the registered ones: an --env-package's too
    preset_argument("--tasks", f"tasks to run, or '{ALL_ENVS}'", type=str, nargs="+", choices=tasks)
    parser.add_argument(
        "--env-id",
        dest="env_ids",
        action="append",
        type=earlier_env_id,
        metavar="ID",
        default=None,
        help="run a task on this earlier registered id of it instead of its current one (repeatable; "
        f"{', '.join(EARLIER_ENV_IDS)})",
    )
    training_kwargs = ", ".join(
        f"{name} {_task_kwargs(config.get('training_env_kwargs', {}))}" for name, config in presets.items()
    )
    parser.add_argument(
        "--training-env-kwarg",
        dest="training_env_kwargs",
        action="append",
        type=task_env_kwarg,
        metavar="TASK:NAME=VALUE",
        default=None,
        help="a kwarg of the envs that TASK's RL runs (fine-tuning, from scratch) gather experience on, over the "
        "config's, e.g. 'gate:gate_distance=[5, 200]'; the models stay the task's and are evaluated on it "
        f"(repeatable; preset: {training_kwargs})",
    )
    preset_argument(
        "--average-checkpoints",
        "tasks whose fine-tuned models average the policy's weights at four evenly spaced points of fine-tuning "
        "(a quarter, half, three quarters of the way and the end) instead of keeping the last ones",
        type=str,
        nargs="*",
        choices=ENV_IDS,
        show=lambda tasks: shown(tasks) or "none",
    )


def _budget_arguments(preset_argument: _SettingFlag) -> None:
    from dpr.pipeline.config import SCRATCH_ALGOS
    from dpr.policies.sb3 import FINETUNE_ALGOS

    preset_argument("--n-robots", "swarm size N")
    preset_argument("--episodes", "demonstration episodes per task")
    preset_argument("--demo-seed", "first demonstration seed", type=non_negative_int)
    preset_argument("--bc-epochs", "behaviour-cloning epochs")
    preset_argument("--critic-warmup", "value-only physics steps before fine-tuning", type=non_negative_int)
    preset_argument("--finetune-steps", "fine-tuning physics steps")
    preset_argument("--n-envs", "envs each RL run trains on, in its one process (a setting of the recipe)")
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
        "algorithms trained from scratch for the same total physics steps",
        type=str,
        nargs="*",
        choices=SCRATCH_ALGOS,
    )
    preset_argument(
        "--train-seeds",
        "seeds of BC and RL: one training run of every method per seed",
        type=lambda text: parse_seeds(text, "--train-seeds"),
        show=seeds_text,
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
    )


def _learner_arguments(parser: argparse.ArgumentParser, preset_argument: _SettingFlag, presets: dict) -> None:
    from dpr.cli.learn import hyperparam
    from dpr.pipeline.config import ACTORS

    for name, flag in HYPERPARAM_FLAGS.items():
        what = "fine-tuning" if name.startswith("finetune") else "from-scratch"
        entry = "the yaml's `finetune` entry" if name.startswith("finetune") else "the yaml's entry of the env id"
        parser.add_argument(
            flag,
            dest=name,
            action="append",
            type=hyperparam,
            metavar="NAME=VALUE",
            help=f"a {what} hyperparameter over the config's (preset: "
            + ", ".join(f"{preset} {_pairs(config[name])}" for preset, config in presets.items())
            + f") and {entry}, e.g. learning_rate=1e-4; NAME=null drops the config's value (repeatable)",
        )
    preset_argument(
        "--actor",
        "every learner's actor: swarm (one network shared by the robots, seeing the whole swarm: "
        "dpr.policies.swarm_policy) or mlp (one MLP from the whole state to every robot's action)",
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


def _run_arguments(parser: argparse.ArgumentParser) -> None:
    from dpr.pipeline.stages import BACKENDS

    parser.add_argument(
        "--reuse",
        action="append",
        default=[],
        metavar="RUN",
        help="another run folder whose stored stages this run takes where they match (read, never written; "
        "repeatable): a candidate recipe trains only what differs from the record",
    )
    parser.add_argument(
        "--shipped",
        metavar="CARD",
        help="also evaluate the shipped models that this model card lists (e.g. models/card.yaml, what `make run` "
        "passes) on the test seeds, beside the wave on their tasks: the headline checked on your machine",
    )
    parser.add_argument(
        "--backend",
        choices=BACKENDS,
        default="local",
        help="where the stages run: local (this machine's processes) or ray (a new local Ray cluster, or the one "
        "at --address). Either gives the same report (default local)",
    )
    parser.add_argument("--address", help="with --backend ray: host:port of a running Ray cluster to join")
    parser.add_argument(
        "--engine",
        choices=("pymunk", "batched"),
        default=None,
        help="pymunk (the reference engine; default) or batched: the disk robot model throughout, its "
        "demonstrations, evaluations and RL from scratch stepped together on the batched engine (dpr.sim.batched), "
        "cloning and fine-tuning on pymunk's disk model; part of every such stage's key",
    )
    parser.add_argument("--device", default=None, help="with --engine batched: its torch device, cpu or cuda (cpu)")
    workers_argument(
        parser, "stages run at once, each a process on one CPU with one torch thread; never changes a result"
    )


def pipeline_config(args):
    """The :class:`dpr.pipeline.config.PipelineConfig` the parsed flags say: the config file or preset, and every
    flag given over it (checked: a ParameterError names the setting)."""
    from dpr.envs import ENV_IDS, TASKS
    from dpr.pipeline.config import PipelineConfig, load_config, preset_path, read_settings

    overrides = {
        field.name: getattr(args, field.name)
        for field in dataclasses.fields(PipelineConfig)
        if getattr(args, field.name, None) is not None
    }
    if overrides.get("tasks") == [ALL_ENVS]:
        overrides["tasks"] = list(ENV_IDS)
    if "env_ids" in overrides:  # --env-id dpr/Gate-v0 -> {"gate": "dpr/Gate-v0"}
        overrides["env_ids"] = {TASKS[env_id]: env_id for env_id in overrides["env_ids"]}
    base = read_settings(args.config) if args.config else read_settings(preset_path(args.preset or "small"))
    if "training_env_kwargs" in overrides:  # TASK:NAME=VALUE triples over the config's, per task
        merged = {task: dict(kwargs) for task, kwargs in base.get("training_env_kwargs", {}).items()}
        for task, name, value in overrides["training_env_kwargs"]:
            merged.setdefault(task, {})[name] = value
        overrides["training_env_kwargs"] = merged
    for name in HYPERPARAM_FLAGS:  # NAME=VALUE pairs over the config's; NAME=null drops the config's value
        if name in overrides:
            merged = {**base.get(name, {}), **dict(overrides[name])}
            overrides[name] = {key: value for key, value in merged.items() if value is not None}
    if args.config:
        return load_config(args.config, **overrides)
    return load_config(preset=args.preset, **overrides)


def cmd_pipeline(args, parser) -> int:
    from pathlib import Path

    from dpr.evaluation.model_card import load_model_card
    from dpr.pipeline.campaign import run_pipeline
    from dpr.pipeline.stages import Backend

    try:
        config = pipeline_config(args)
        shipped = load_model_card(args.shipped) if args.shipped else []
        reuse = list(args.reuse)
        if args.config and Path(args.config).name == "pipeline.yaml":  # a run folder's settings: reuse its stages
            folder = Path(args.config).parent
            if (folder / "stages").is_dir() and folder.resolve() != Path(args.out).resolve():
                reuse.append(folder)
        report = run_pipeline(
            config,
            args.out,
            shipped=shipped,
            backend=Backend(args.backend, args.workers, args.address),
            reuse=reuse,
        )
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
        "Every stage is stored in OUT/stages by a key of what it depends on, and never made twice: the same "
        "command resumes an interrupted run, another task may run into the same folder meanwhile, and --reuse (or "
        "--config RUN/pipeline.yaml) takes a record's stages that a new recipe shares. Settings come from a "
        "preset or a yaml file (--config), flags override single values. --preset small (the default) is `make "
        "run` (Navigation, N=9, minutes on 2 CPU cores); --preset full is the headline.",
        arguments=pipeline_arguments,
        flags=PIPELINE_FLAGS,
        run=cmd_pipeline,
    ),
)
