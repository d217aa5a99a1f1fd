"""`dpr pipeline`: per task, demonstrations -> BC -> fine-tuning, beside RL from scratch, evaluated against the
wave (dpr.rl.pipeline)."""

from __future__ import annotations

import argparse
import sys

from dpr.cli.common import (
    ALL_ENVS,
    TASK_NAMES,
    Command,
    default_argument,
    defaults,
    flag_message,
    parse_seeds,
    seeds_text,
    shown,
    workers_argument,
)

PIPELINE_OUT = "runs/pipeline"


def pipeline_arguments(parser: argparse.ArgumentParser) -> None:
    from dpr.policies.sb3 import FINETUNE_ALGOS
    from dpr.rl.pipeline import SCRATCH_ALGOS, PipelineConfig

    config = defaults(PipelineConfig)
    parser.add_argument("--out", default=PIPELINE_OUT, help=f"run folder (default {PIPELINE_OUT}; resumed if present)")
    parser.add_argument(
        "--tasks",
        nargs="+",
        default=config["tasks"],
        choices=(*TASK_NAMES, ALL_ENVS),
        help=f"tasks to run (default {shown(config['tasks'])}; '{ALL_ENVS}' for the four)",
    )
    default_argument(parser, "--n-robots", config["n_robots"], "swarm size N")
    default_argument(parser, "--episodes", config["episodes"], "demonstration episodes per task")
    default_argument(parser, "--demo-seed", config["demo_seed"], "first demonstration seed", type=int)
    default_argument(parser, "--bc-epochs", config["bc_epochs"], "behaviour-cloning epochs")
    default_argument(
        parser, "--critic-warmup", config["critic_warmup"], "value-only steps before fine-tuning", type=int
    )
    default_argument(parser, "--finetune-steps", config["finetune_steps"], "fine-tuning steps")
    parser.add_argument(
        "--anchor",
        action="store_true",
        help="anchor fine-tuning to the task's demonstrations "
        "(`dpr finetune --anchor` with its default weight and decay)",
    )
    parser.add_argument(
        "--approach-reward",
        type=float,
        default=config["approach_reward"],
        metavar="W",
        help="Manipulation only: RL (fine-tuning and from scratch) trains with this weight of the "
        f"swarm-ball approach shaping (the env's approach_reward; default {shown(config['approach_reward'])}, "
        "0 for none)",
    )
    parser.add_argument(
        "--finetune-algos",
        nargs="+",
        default=config["finetune_algos"],
        choices=FINETUNE_ALGOS,
        help=f"algorithms that fine-tune the clone (default {shown(config['finetune_algos'])})",
    )
    parser.add_argument(
        "--scratch-algos",
        nargs="*",
        default=config["scratch_algos"],
        choices=SCRATCH_ALGOS,
        help=f"algorithms trained from scratch for the same total env steps (default {shown(config['scratch_algos'])})",
    )
    parser.add_argument(
        "--eval-seeds",
        type=lambda text: parse_seeds(text, "--eval-seeds"),
        default=config["eval_seeds"],
        help=f"evaluation seeds, never used for training (default {seeds_text(config['eval_seeds'])})",
    )
    default_argument(parser, "--seed", config["seed"], "seed of BC and RL", type=int)
    default_argument(parser, "--steps", config["steps"], "steps per episode, everywhere")
    workers_argument(parser, "worker processes for collection, RL envs and evaluation")


def cmd_pipeline(args, parser) -> int:
    from dpr.envs import ENV_IDS
    from dpr.rl.pipeline import PipelineConfig, run_pipeline

    tasks = list(ENV_IDS) if args.tasks == [ALL_ENVS] else args.tasks
    try:
        config = PipelineConfig(
            tasks=tasks,
            n_robots=args.n_robots,
            episodes=args.episodes,
            demo_seed=args.demo_seed,
            bc_epochs=args.bc_epochs,
            critic_warmup=args.critic_warmup,
            finetune_steps=args.finetune_steps,
            finetune_algos=args.finetune_algos,
            scratch_algos=args.scratch_algos,
            eval_seeds=args.eval_seeds,
            anchor=args.anchor,
            approach_reward=args.approach_reward,
            seed=args.seed,
            workers=args.workers,
            steps=args.steps,
        )
        report = run_pipeline(config, args.out)
    except (TypeError, ValueError) as error:
        parser.error(flag_message(error))
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
        "on unseen seeds, and write OUT/report/results.md with bars.png and trajectories.png. Every stage is "
        "skipped when its output exists: the same command resumes an interrupted run. The defaults are the "
        "small budget of `make run` (Navigation, N=9, about 10 minutes on 2 CPU cores).",
        arguments=pipeline_arguments,
        run=cmd_pipeline,
    ),
)
