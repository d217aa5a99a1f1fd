"""`dpr train` (SB3 RL from scratch) and `dpr finetune` (RL from a cloned policy): one run folder each."""

from __future__ import annotations

import argparse
from pathlib import Path

from dpr.cli.common import (
    ENV_ID_LIST,
    EXAMPLE_ENV_ID,
    Command,
    check_rerun_output,
    check_seed,
    compile_argument,
    default_argument,
    defaults,
    engine_arguments,
    env_kwarg,
    env_kwarg_argument,
    flag_message,
    name_and_value,
    non_negative_int,
    positive_int,
    rerun_argument,
    swarm_arguments,
    workers_argument,
)
from dpr.limits import MAX_TEMPERATURE
from dpr.sim.models import ROBOT_MODELS

# --from names the model file a fine-tuning run starts from: TrainConfig.init_from, and the model file that
# dpr.policies.model_file.read_model_info reads ("policy" by default).
BATCHED_ENVS = 256  # dpr train --engine batched: envs stepped in one call, by default
FINETUNE_FLAGS = {"init_from": "--from", "policy": "--from", "anchor_datasets": "--anchor"}


def hyperparam(text: str) -> tuple[str, object]:
    """'n_steps=64' -> ('n_steps', 64); values parse as yaml (numbers, lists, 'lin_3e-4' stays a string)."""
    import yaml

    key, value = name_and_value(text, "--hyperparam")
    try:
        parsed = yaml.safe_load(value)
    except yaml.YAMLError:
        raise argparse.ArgumentTypeError(f"--hyperparam {key}: cannot parse {value!r}") from None
    if isinstance(parsed, str):  # yaml 1.1 reads 1e-4 (no dot) as text; a number is meant
        try:
            return key, float(parsed)
        except ValueError:
            pass
    return key, parsed


def _critic_warmup_argument(parser: argparse.ArgumentParser, what: str) -> None:
    """--critic-warmup, whose default (None) is dpr.rl.recipe.default_critic_warmup of the run's steps; the library's
    TrainConfig does none unless asked."""
    from dpr.rl.recipe import MAX_CRITIC_WARMUP

    parser.add_argument(
        "--critic-warmup",
        type=int,
        help=f"{what}; 0 to skip (default: a tenth of --timesteps, at most {MAX_CRITIC_WARMUP})",
    )


def _run_arguments(parser: argparse.ArgumentParser, hyperparam_example: str) -> None:
    """The flags `dpr train` and `dpr finetune` share."""
    from dpr.rl.train import EVAL_SEED_OFFSET, TrainConfig

    config = defaults(TrainConfig)
    default_argument(parser, "--seed", config["seed"], "seed of the model and the envs", type=int)
    default_argument(
        parser,
        "--eval-episodes",
        config["eval_episodes"],
        "episodes per periodic evaluation, which keeps best_model.zip (0: none)",
        type=non_negative_int,
    )
    env_kwarg_argument(parser, "reward=projected")
    parser.add_argument(
        "--training-env-kwarg",
        action="append",
        type=env_kwarg,
        metavar="NAME=VALUE",
        help="a gym.make kwarg of the envs that gather experience only, e.g. 'gate_distance=[5, 200]' (walls drawn "
        "over a spread of placements): the model records --env-kwarg's task and is evaluated on it (repeatable)",
    )
    parser.add_argument(
        "--hyperparam",
        action="append",
        type=hyperparam,
        metavar="NAME=VALUE",
        help=f"override a yaml hyperparameter, e.g. {hyperparam_example} (repeatable)",
    )
    parser.add_argument("--out", help="new run folder (default runs/train/<task>-<algo>-seed<S>-<timestamp>)")
    _resume_argument(parser)
    rerun_argument(
        parser,
        "after training, roll out every checkpoint and the final model from the evaluation "
        f"start (seed + {EVAL_SEED_OFFSET}) side by side into this new rerun file",
    )


def _log_training_to_rerun(result, env_id: str, path: str, seed: int, n_robots: int | None = None) -> None:
    """Roll out every checkpoint of a training run and its final model from one evaluation start, side by side
    in a new .rrd file (named after their step counts): how the policy changed over the run. ``n_robots``: the
    swarm size of a per-robot model's rollouts (its file names none)."""
    import re

    from tqdm import tqdm

    from dpr.envs import episode_steps
    from dpr.envs.particle_env import split_swarm_kwargs
    from dpr.policies.model_file import read_model_info
    from dpr.viz.episodes import ViewRollout, rollout_episode
    from dpr.viz.rerun_log import save_rrd

    def step_count(model: Path) -> int:
        match = re.search(r"_(\d+)_steps", model.stem)
        return int(match.group(1)) if match else -1

    checkpoints = sorted((result.run_dir / "checkpoints").glob("*.zip"), key=step_count)
    models = [(f"step_{step_count(m)}", m) for m in checkpoints] + [("final", result.model_path)]
    info = read_model_info(result.model_path)
    swarm, extra = split_swarm_kwargs(info.env_kwargs)
    if n_robots is not None:
        swarm.setdefault("n_robots", n_robots)
    # rollout_episode counts physics steps; the model's episode length counts its decisions
    decisions = info.max_episode_steps or episode_steps(info.env_kwargs)
    steps = decisions * info.env_kwargs.get("action_repeat", 1)
    episodes = [
        rollout_episode(ViewRollout(env_id, str(model), seed, steps=steps, env_kwargs=extra, **swarm), name=name)
        for name, model in tqdm(models, desc="log to rerun", unit="model")
    ]
    save_rrd(episodes, path, title=f"dpr train {result.run_dir.name} (seed {seed})")
    print(f"wrote {path}")


def _training_done(result, args, n_robots: int | None = None) -> int:
    """Say where a `dpr train`/`dpr finetune` run's files are (and log it to rerun when asked; ``n_robots``: the
    swarm size to evaluate and roll out a per-robot model at)."""
    from dpr.rl.train import EVAL_SEED_OFFSET

    print(f"model: {result.model_path}")
    if result.best_model_path:
        print(f"best model: {result.best_model_path}")
    print(f"config: {result.config_path}")
    size = f" --n-robots {n_robots}" if n_robots is not None else ""
    print(f"evaluate it: dpr evaluate --policy {result.model_path} --env {args.env}{size}")
    if args.rerun and not result.interrupted:
        _log_training_to_rerun(result, args.env, args.rerun, args.seed + EVAL_SEED_OFFSET, n_robots)
    return 130 if result.interrupted else 0


# -- train -------------------------------------------------------------------------------------------------------
def train_arguments(parser: argparse.ArgumentParser) -> None:
    from dpr.policies.hyperparams import BATCHED_PRESET, DEFAULT_PRESET, PAPER_PRESET
    from dpr.policies.model_file import ALGOS
    from dpr.rl.train import LEARNERS, TrainConfig

    config = defaults(TrainConfig)
    parser.add_argument("--algo", required=True, choices=ALGOS, help="DQN uses Discrete(2^N) actions")
    parser.add_argument("--env", required=True, help=f"env id: {ENV_ID_LIST}")
    swarm_arguments(parser, config, engine_default=True)
    parser.add_argument(
        "--timesteps",
        type=positive_int,
        help="env steps to train for (default: the preset's n_timesteps), in whole rollouts of n_steps x n-envs "
        "(DQN: train_freq x n-envs) as SB3 makes them: a larger budget is rounded up, a smaller one runs shorter "
        "rollouts, no more steps than asked; the log and config.yaml say how many",
    )
    parser.add_argument(
        "--n-envs",
        type=positive_int,
        help=f"parallel envs, subprocesses when > 1 (default {config['n_envs']}); with --engine batched, envs "
        f"stepped in one call (default {BATCHED_ENVS})",
    )
    parser.add_argument(
        "--preset",
        choices=(DEFAULT_PRESET, PAPER_PRESET, BATCHED_PRESET),
        help=f"{DEFAULT_PRESET}: laptop-sized entry of the env id; {PAPER_PRESET}: Shen et al.'s (10M steps); "
        f"{BATCHED_PRESET}: the entry for thousands of envs at once (default: {BATCHED_PRESET} with --engine "
        f"batched, else {config['preset']})",
    )
    engine_arguments(parser)
    compile_argument(parser, learner=True)
    parser.add_argument(
        "--learner",
        choices=LEARNERS,
        default=config["learner"],
        help="with --engine batched: torch (PPO with rollouts and updates on the device, dpr.rl.batched_ppo; "
        "default) or sb3 (stable-baselines3's own learn() through a VecEnv adapter, dpr.rl.sb3_batched: any --algo)",
    )
    parser.add_argument(
        "--steps-per-episode",
        type=positive_int,
        help="env steps per episode (default: a whole episode, 2500 physics steps / action_repeat)",
    )
    _run_arguments(parser, "n_steps=256 or learning_rate=lin_1e-3")


def _resume_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--resume",
        action="store_true",
        help="go on with the stopped run in --out, given the same flags: from the snapshot it writes every few "
        "minutes, to the model it would have made without the stop",
    )


def _check_resume(args, parser) -> None:
    if args.resume and args.out is None:
        parser.error("--resume: name the stopped run's folder with --out")


def resolve_engine_defaults(args) -> None:
    """--robot-model, --preset and --n-envs where not given: TrainConfig's on the pymunk engine; the disk model, the
    batched entry (for the tensor PPO) and :data:`BATCHED_ENVS` envs on the batched one."""
    from dpr.policies.hyperparams import BATCHED_PRESET
    from dpr.rl.train import TrainConfig

    batched = args.engine == "batched"
    if args.robot_model is None:
        args.robot_model = "disk" if batched else defaults(TrainConfig)["robot_model"]
    if args.preset is None:  # (the batched entry is the tensor PPO's: SB3's learner takes the env id's)
        tensor_ppo = batched and args.learner == defaults(TrainConfig)["learner"]
        args.preset = BATCHED_PRESET if tensor_ppo else defaults(TrainConfig)["preset"]
    if args.n_envs is None:
        args.n_envs = BATCHED_ENVS if batched else defaults(TrainConfig)["n_envs"]


def cmd_train(args, parser) -> int:
    from dpr.rl.train import TrainConfig, train

    _check_resume(args, parser)
    check_seed(args, parser)
    check_rerun_output(args, parser)
    resolve_engine_defaults(args)
    try:
        config = TrainConfig(
            args.algo,
            args.env,
            n_robots=args.n_robots,
            robot_model=args.robot_model,
            timesteps=args.timesteps,
            seed=args.seed,
            n_envs=args.n_envs,
            preset=args.preset,
            engine=args.engine,
            device=args.device,
            compile=args.compile,
            learner=args.learner,
            steps_per_episode=args.steps_per_episode,
            env_kwargs=dict(args.env_kwarg or []),
            training_env_kwargs=dict(args.training_env_kwarg or []),
            hyperparams=dict(args.hyperparam or []),
            eval_episodes=args.eval_episodes,
        )
        if config.engine == "batched":
            from dpr.rl.batched_train import train_batched

            result = train_batched(config, args.out, resume=args.resume)
        else:
            result = train(config, args.out, resume=args.resume)
    except (TypeError, ValueError) as error:
        parser.error(flag_message(error))
    return _training_done(result, args)


# -- finetune ----------------------------------------------------------------------------------------------------
def finetune_arguments(parser: argparse.ArgumentParser) -> None:
    from dpr.policies.sb3 import FINETUNE_ALGOS
    from dpr.rl.train import TrainConfig

    config = defaults(TrainConfig)
    parser.add_argument("--from", dest="source", required=True, metavar="MODEL.zip", help="the model to start from")
    parser.add_argument("--env", required=True, help=f"env id the model was trained on, e.g. {EXAMPLE_ENV_ID}")
    parser.add_argument(
        "--transfer",
        action="store_true",
        help="fine-tune on --env although the model was trained on another task with the same observation and "
        "action spaces (transfer learning, e.g. a Navigation model on Gate); its env kwargs apply",
    )
    parser.add_argument("--algo", choices=FINETUNE_ALGOS, help="algorithm to fine-tune with (default: the model's)")
    parser.add_argument(
        "--robot-model",
        choices=ROBOT_MODELS,
        help="the robot model to fine-tune on (default: the model's); both make the same spaces, so a model "
        "learned on the fast disk model fine-tunes on the paddle model",
    )
    parser.add_argument(
        "--timesteps",
        type=positive_int,
        help="env steps after the warm-up (default: the n_timesteps of the finetune preset of "
        "dpr/rl/hyperparams/<algo>.yml), in whole rollouts of n_steps x n-envs as SB3 makes them: a larger "
        "budget (and warm-up) is rounded up, a smaller one runs shorter rollouts, no more steps than asked; the "
        "log and config.yaml say how many",
    )
    _critic_warmup_argument(parser, "env steps that train only the value head first")
    default_argument(
        parser,
        "--exploration-temperature",
        config["exploration_temperature"],
        "divide the model's action logits by this (a Gaussian's standard deviation: multiply) before the run, so "
        "that a nearly deterministic actor explores again; its likeliest action, the one `dpr evaluate` takes, "
        f"stays the same; above 0, at most {MAX_TEMPERATURE:g}",
        type=float,
    )
    parser.add_argument(
        "--anchor",
        nargs="+",
        metavar="DATASET",
        help="demonstration datasets (from `dpr collect`) to anchor every update to: after each update, "
        "a few steps of the behaviour-cloning loss on their frames, scaled by --anchor-weight and decaying "
        "by --anchor-decay per update (DAPG's demonstration term)",
    )
    default_argument(
        parser, "--anchor-weight", config["anchor_weight"], "the anchor's scale at the first update", type=float
    )
    decay = config["anchor_decay"]
    default_argument(
        parser,
        "--anchor-decay",
        decay,
        "the anchor's scale is multiplied by this after each update; "
        f"by default {decay**100:.2f} of it is left after 100 updates",
        type=float,
    )
    workers_argument(parser, "parallel envs, subprocesses when > 1", flag="--n-envs")
    parser.add_argument(
        "--average-checkpoints",
        action="store_true",
        help="also write averaged_model.zip: the mean of the policy's weights a quarter, half and three quarters of "
        "the way and at the end (weight averaging, what `dpr pipeline`'s average_checkpoints keeps)",
    )
    _run_arguments(
        parser,
        "learning_rate=1e-5. Unless set here: the network the model was built with (its policy and "
        "policy_kwargs, when its file records them) and, for a model deciding every action_repeat = K > 1 physics "
        "steps, gamma = 0.99^K and n_steps=512 batch_size=128 n_epochs=10, the pipeline's recipe",
    )


def _as_hyperparam(value) -> str:
    """``value`` as --hyperparam reads it back (yaml flow style)."""
    import yaml

    return yaml.safe_dump(value, default_flow_style=True, width=10_000).removesuffix("...\n").strip()


def _model_defaults_line(info, source: str, defaults: dict, overrides: dict) -> str | None:
    """The log line that says which hyperparameters of a `dpr finetune` run come from the model ``info`` describes
    (None: none do): its network, and the recipe of its decision interval (dpr.rl.recipe.finetune_defaults)."""
    taken = {name: value for name, value in defaults.items() if name not in overrides}
    network = " ".join(f"{k}={_as_hyperparam(v)}" for k, v in taken.items() if k in ("policy", "policy_kwargs"))
    recipe = " ".join(f"{k}={_as_hyperparam(v)}" for k, v in taken.items() if k not in ("policy", "policy_kwargs"))
    parts = [f"{network} (its network)"] if network else []
    if recipe:
        parts.append(f"{recipe} (for its decisions every {info.env_kwargs['action_repeat']} physics steps)")
    if not parts:
        return None
    return f"dpr finetune: from {source}: {'; '.join(parts)}; a --hyperparam of the same name overrides"


def cmd_finetune(args, parser) -> int:
    import dataclasses
    import sys

    from dpr.envs import episode_steps
    from dpr.envs.particle_env import split_swarm_kwargs
    from dpr.policies.hyperparams import FINETUNE_PRESET
    from dpr.policies.model_file import model_env_kwargs, read_model_info
    from dpr.policies.sb3 import loaded_architecture, save_slim_copy
    from dpr.rl.recipe import default_critic_warmup, finetune_defaults
    from dpr.rl.train import AVERAGED_MODEL, CHECKPOINTS, TrainConfig, averaged_checkpoints, checkpoint_spacing, train

    _check_resume(args, parser)
    check_seed(args, parser)
    check_rerun_output(args, parser)
    try:
        info = read_model_info(args.source)
        if info.per_robot is not None:
            raise ValueError(
                f"--from: {args.source} is a per-robot model (one robot's local observation in, its action out); "
                f"fine-tune it with `dpr finetune-decentralised --from {args.source} --env {info.env_id} --n-robots N`"
            )
        if info.env_id != args.env and not args.transfer:
            raise ValueError(
                f"--from: {args.source} was trained on {info.env_id}, not on --env {args.env} (--transfer fine-tunes "
                "it on another task with the same spaces)"
            )
        requested = {**({"robot_model": args.robot_model} if args.robot_model else {}), **dict(args.env_kwarg or [])}
        kwargs = model_env_kwargs(args.source, args.env, requested, transfer=args.transfer)
        swarm, env_kwargs = split_swarm_kwargs(kwargs)
        overrides = dict(args.hyperparam or [])
        algo = args.algo or info.algo
        if info.architecture is None:  # a file saved before models recorded their network: read it off the model
            info = dataclasses.replace(info, architecture=loaded_architecture(args.source))
        defaults = finetune_defaults(info, algo)  # the model's network and the recipe at its decision interval
        config = TrainConfig(
            algo,
            args.env,
            **swarm,
            timesteps=args.timesteps,
            seed=args.seed,
            n_envs=args.n_envs,
            preset=FINETUNE_PRESET,
            steps_per_episode=info.max_episode_steps or episode_steps(info.env_kwargs),
            env_kwargs=env_kwargs,
            training_env_kwargs=dict(args.training_env_kwarg or []),
            hyperparams={**defaults, **overrides},
            eval_episodes=args.eval_episodes,
            init_from=args.source,
            critic_warmup=args.critic_warmup or 0,
            exploration_temperature=args.exploration_temperature,
            anchor_datasets=list(args.anchor or []),
            anchor_weight=args.anchor_weight,
            anchor_decay=args.anchor_decay,
        )
        budget = config.resolve()[2]  # the run's steps: --timesteps, else the yaml's
        if args.critic_warmup is None:  # a tenth of the run's steps
            config = dataclasses.replace(config, critic_warmup=default_critic_warmup(budget))
        if args.average_checkpoints and not checkpoint_spacing(budget // config.n_envs):
            raise ValueError(
                f"--average-checkpoints: the run must last at least {CHECKPOINTS} steps per env (--timesteps / "
                "--n-envs), so that it writes the checkpoints to average"
            )
        line = _model_defaults_line(info, args.source, defaults, overrides)
        if line:
            print(line, file=sys.stderr)
        result = train(config, args.out, resume=args.resume)
    except (TypeError, ValueError) as error:
        parser.error(flag_message(error, FINETUNE_FLAGS))
    if args.average_checkpoints and not result.interrupted:
        checkpoints = averaged_checkpoints(result.run_dir)
        print(f"averaged model: {save_slim_copy(result.model_path, result.run_dir / AVERAGED_MODEL, checkpoints)}")
    return _training_done(result, args)


# -- finetune-decentralised ----------------------------------------------------------------------------------------
FINETUNE_DECENTRALISED_FLAGS = {"init_from": "--from", "policy": "--from", "shared_reward": "--split-reward"}


def finetune_decentralised_arguments(parser: argparse.ArgumentParser) -> None:
    from dpr.policies.sb3 import FINETUNE_ALGOS
    from dpr.rl.finetune_per_robot import DEFAULT_N_ROBOTS, PerRobotFinetuneConfig

    config = defaults(PerRobotFinetuneConfig)
    parser.add_argument(
        "--from", dest="source", required=True, metavar="MODEL.zip", help="the per-robot model to start from"
    )
    parser.add_argument("--env", required=True, help=f"env id the model was trained on, e.g. {EXAMPLE_ENV_ID}")
    parser.add_argument(
        "--n-robots",
        nargs="+",
        type=positive_int,
        metavar="N",
        help="training swarm sizes, one swarm per value, stepped side by side in every rollout (e.g. 9 25; repeat a "
        "size for more swarms of it); default: the sizes the model was trained on "
        f"(its trained_n_robots, else {DEFAULT_N_ROBOTS})",
    )
    parser.add_argument("--algo", choices=FINETUNE_ALGOS, help="algorithm to fine-tune with (default: the model's)")
    parser.add_argument(
        "--timesteps",
        type=positive_int,
        help="SWARM steps after the warm-up, summed over the training swarms (one step of a 9-robot swarm counts "
        "once, not 9 times; with --n-robots 9 25, 10000 is 5000 steps of each swarm); default: the n_timesteps "
        "of the finetune preset of dpr/rl/hyperparams/<algo>.yml",
    )
    _critic_warmup_argument(
        parser, "swarm steps that train only the value head first (per-robot cloning leaves it untrained)"
    )
    parser.add_argument(
        "--split-reward",
        action="store_true",
        help="give each robot the team reward / N (default: every robot gets the whole team reward)",
    )
    default_argument(
        parser,
        "--eval-episodes",
        config["eval_episodes"],
        "validation episodes per training size at each evaluation (best_model.zip)",
    )
    default_argument(parser, "--seed", config["seed"], "seed of the model and the swarms", type=int)
    env_kwarg_argument(parser, "reward=projected")
    parser.add_argument(
        "--hyperparam",
        action="append",
        type=hyperparam,
        metavar="NAME=VALUE",
        help="override a value of the yaml's finetune preset, e.g. n_steps=256 (steps of each swarm per rollout) "
        "or learning_rate=1e-5 (repeatable)",
    )
    parser.add_argument(
        "--out", help="new run folder (default runs/finetune-decentralised/<task>-<algo>-seed<S>-<timestamp>)"
    )
    _resume_argument(parser)
    rerun_argument(
        parser,
        "after training, roll out every checkpoint and the final model at the first --n-robots size from the "
        "first validation start side by side into this new rerun file",
    )


def cmd_finetune_decentralised(args, parser) -> int:
    from dpr.rl.finetune_per_robot import PerRobotFinetuneConfig, finetune_per_robot

    _check_resume(args, parser)
    check_seed(args, parser)
    check_rerun_output(args, parser)
    try:
        config = PerRobotFinetuneConfig(
            args.source,
            args.env,
            n_robots=tuple(args.n_robots or ()),
            algo=args.algo,
            timesteps=args.timesteps,
            critic_warmup=args.critic_warmup,
            seed=args.seed,
            shared_reward=not args.split_reward,
            env_kwargs=dict(args.env_kwarg or []),
            hyperparams=dict(args.hyperparam or []),
            eval_episodes=args.eval_episodes,
        )
        result = finetune_per_robot(config, args.out, resume=args.resume)
    except (TypeError, ValueError) as error:
        parser.error(flag_message(error, FINETUNE_DECENTRALISED_FLAGS))
    return _training_done(result, args, result.n_robots[0])


COMMANDS = (
    Command(
        "train",
        help="train PPO, A2C or DQN from scratch with stable-baselines3",
        description="Train an SB3 model on a task with the hyperparameters of dpr/rl/hyperparams/<algo>.yml "
        "(the env id's entry, or --preset paper) and save model.zip, best_model.zip, checkpoints and the "
        "resolved config.yaml into a new run folder. The model carries its env id and kwargs: "
        "`dpr evaluate --policy RUN/model.zip --env ID` runs it on the env it was trained on.",
        arguments=train_arguments,
        run=cmd_train,
    ),
    Command(
        "finetune",
        help="fine-tune a behaviour-cloned model with PPO or A2C",
        description="Start PPO or A2C from the weights of a model written by `dpr bc` (or `dpr train`) and train "
        "it on the env it was made for, with the `finetune` entry of dpr/rl/hyperparams/<algo>.yml on top of the "
        "env id's entry: small, clipped updates, so the cloned behaviour is not forgotten. First, --critic-warmup "
        "steps train only the value head on rollouts of the unchanged actor. Writes a run folder as `dpr train` does.",
        arguments=finetune_arguments,
        run=cmd_finetune,
        flags=FINETUNE_FLAGS,
    ),
    Command(
        "finetune-decentralised",
        help="fine-tune a per-robot model with PPO or A2C, every robot of the swarm(s) sharing it",
        description="Start PPO or A2C from a per-robot model (written by `dpr bc-decentralised`) and train it on "
        "the PettingZoo env of its task and layout with every robot an env of one VecEnv: one policy, the same "
        "weights for every robot. --n-robots 9 25 trains a swarm of each size side by side, so every rollout holds "
        "both. Each robot gets the team reward (--split-reward: reward / N). Budgets count swarm steps, not robot "
        "steps. As `dpr finetune`: the yaml's finetune preset, a critic warm-up first, evaluations of the start "
        "and about 5 times over the run in the centralised env of each training size on fixed validation seeds "
        "(seed + 10000 ...), best_model.zip, checkpoints and config.yaml in a new run folder. The models written "
        "are per-robot models again: `dpr evaluate --policy RUN/model.zip --env ID --n-robots N` runs them at any N.",
        arguments=finetune_decentralised_arguments,
        run=cmd_finetune_decentralised,
        flags=FINETUNE_DECENTRALISED_FLAGS,
    ),
)
