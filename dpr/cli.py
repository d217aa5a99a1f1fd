"""`dpr` command line: record datasets, train and evaluate policies, benchmark the simulator."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

ALL_ENVS = "all"
ROBOT_MODEL_NAMES = ("paddle", "disk")
TASK_NAMES = (
    "navigation",
    "gate",
    "unresponsive",
    "manipulation",
)  # the keys of dpr.envs.ENV_IDS (kept light: no env import for --help)


# Library parameters whose CLI flag is not "--" + the name with dashes (see dpr.checks.ParameterError).
PARAMETER_FLAGS = {
    "dataset_dirs": "--dataset",
    "datasets": "--dataset",
    "root": "--dataset",
    "init_policy": "--from",
    "anchor_dirs": "--anchor",
    "policy_name": "--policy",
    "policy_names": "--policies",
    "env_id": "--env",
    "env_ids": "--env",
}


def flag_message(error: Exception) -> str:
    """``error``'s message, with a library parameter name (dpr.checks.ParameterError) said as its CLI flag."""
    from dpr.checks import ParameterError

    if isinstance(error, ParameterError):
        flag = PARAMETER_FLAGS.get(error.parameter, "--" + error.parameter.replace("_", "-"))
        return f"{flag}: {error.problem}"
    return str(error)


def parse_seeds(text: str, flag: str = "--seeds") -> list[int]:
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
        raise argparse.ArgumentTypeError(f"{flag} must look like '0-4' or '1,3,7', got {text!r}") from None
    if not seeds or min(seeds) < 0:
        raise argparse.ArgumentTypeError(f"{flag} must be non-negative integers, got {text!r}")
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


def _check_env_kwargs(env_ids: list[str], env_kwargs: dict, parser: argparse.ArgumentParser) -> None:
    """Build each env once, so that a bad kwarg is reported before any episode runs."""
    import gymnasium as gym

    import dpr  # noqa: F401

    for env_id in env_ids:
        try:
            gym.make(env_id, **env_kwargs).close()
        except (TypeError, ValueError) as error:
            parser.error(f"{env_id} with {env_kwargs}: {error}")


def _evaluate_env_kwargs(args, env_ids: list[str], parser: argparse.ArgumentParser) -> dict:
    """The env kwargs of ``dpr evaluate``: for a scripted policy the flags (N 9 and the paddle model by
    default); for a ``.zip`` model its own kwargs, where a flag given explicitly must agree with them."""
    from dpr.policies.sb3 import is_model_path, model_env_kwargs

    given = {"n_robots": args.n_robots, "robot_model": args.robot_model}
    flags = {"n_robots": "--n-robots", "robot_model": "--robot-model"}
    explicit = {**{k: v for k, v in given.items() if v is not None}, **dict(args.env_kwarg or [])}
    if not is_model_path(args.policy):
        env_kwargs = {"n_robots": 9, "robot_model": "paddle", **explicit}
        _check_env_kwargs(env_ids, env_kwargs, parser)
        return env_kwargs
    resolved = {}
    for env_id in env_ids:
        try:
            resolved[env_id] = model_env_kwargs(args.policy, env_id, explicit)
        except ValueError as error:
            message = flag_message(error)
            for name, flag in flags.items():  # name the flag the user typed, not the kwarg
                if given[name] is not None:
                    message = message.replace(f"; {name}={given[name]!r}", f"; {flag} {given[name]}")
            parser.error(message)
    _check_env_kwargs(env_ids, resolved[env_ids[0]], parser)
    return resolved[env_ids[0]]


def cmd_evaluate(args, parser) -> int:
    from tqdm import tqdm

    from dpr.envs import ENV_IDS
    from dpr.rl.evaluation import evaluate, format_table, save_evaluation

    env_ids = list(ENV_IDS.values()) if args.env == [ALL_ENVS] else args.env
    _check_output(args.json, parser, "--json")
    _check_rerun_output(args, parser)
    env_kwargs = _evaluate_env_kwargs(args, env_ids, parser)
    try:
        with tqdm(total=len(env_ids) * len(args.seeds), desc=f"evaluate {args.policy}", unit="episode") as bar:
            results = evaluate(
                env_ids,
                args.policy,
                args.seeds,
                steps=args.steps,
                env_kwargs=env_kwargs,
                workers=args.workers,
                progress=lambda r: bar.update(1),
            )
    except ValueError as error:
        parser.error(flag_message(error))
    print(format_table(results))
    if args.json:
        save_evaluation(args.json, args.policy, env_ids, env_kwargs, args.steps, args.seeds, results)
        print(f"wrote {args.json}")
    if args.rerun:
        _log_evaluation_to_rerun(args, env_ids, env_kwargs)
    return 0


def _log_evaluation_to_rerun(args, env_ids: list[str], env_kwargs: dict) -> None:
    """Replay the evaluated episodes (the simulator is deterministic, so they are the same episodes) with
    every robot's state recorded, and save them side by side in a new .rrd file."""
    from tqdm import tqdm

    from dpr.envs.particle_env import split_swarm_kwargs
    from dpr.viz.episodes import rollout_episode
    from dpr.viz.rerun_log import save_rrd

    swarm, extra = split_swarm_kwargs(env_kwargs)
    episodes = []
    for env_id in tqdm(env_ids, desc="log to rerun", unit="env"):
        for seed in args.seeds:
            task = env_id.split("/")[-1].removesuffix("-v0").lower()
            episodes.append(
                rollout_episode(
                    env_id, args.policy, seed, steps=args.steps, env_kwargs=extra, name=f"{task}_seed{seed}", **swarm
                )
            )
    save_rrd(episodes, args.rerun, title=f"dpr evaluate {args.policy}")
    print(f"wrote {args.rerun}")


def cmd_report(args, parser) -> int:
    import warnings

    from dpr.rl.report import write_report

    if args.label is not None and len(args.label) != len(args.evaluations):
        parser.error(f"--label: give one name per file ({len(args.evaluations)} file(s), {len(args.label)} label(s))")
    with warnings.catch_warnings(record=True) as caught:  # policies left out of a figure: say so plainly
        warnings.simplefilter("always")
        try:
            written = write_report(args.evaluations, args.out, labels=args.label, seed=args.seed)
        except (ValueError, FileExistsError) as error:
            parser.error(flag_message(error))
    for warning in caught:
        print(f"dpr report: warning: {warning.message}", file=sys.stderr)
    print(written[0].read_text())
    for path in written:
        print(f"wrote {path}")
    return 0


def _name_and_value(text: str, flag: str) -> tuple[str, str]:
    """'NAME=VALUE' -> (NAME, VALUE text), NAME a Python identifier (a keyword argument)."""
    key, sep, value = text.partition("=")
    if not sep or not key.isidentifier():
        raise argparse.ArgumentTypeError(f"{flag} must look like NAME=VALUE, got {text!r}")
    return key, value


def _hyperparam(text: str) -> tuple[str, object]:
    """'n_steps=64' -> ('n_steps', 64); values parse as yaml (numbers, lists, 'lin_3e-4' stays a string)."""
    import yaml

    key, value = _name_and_value(text, "--hyperparam")
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


def _check_rerun_output(args, parser) -> None:
    """``--rerun``: a new file ending in .rrd (`dpr evaluate`, `dpr train`, `dpr finetune`)."""
    _check_output(args.rerun, parser, "--rerun")
    if args.rerun and not args.rerun.endswith(".rrd"):
        parser.error(f"--rerun: {args.rerun} must end in .rrd")


def _log_training_to_rerun(result, env_id: str, path: str, seed: int) -> None:
    """Roll out every checkpoint of a training run and its final model from one evaluation start, side by side
    in a new .rrd file (named after their step counts): how the policy changed over the run."""
    import re

    from tqdm import tqdm

    from dpr.envs.particle_env import split_swarm_kwargs
    from dpr.policies.sb3 import read_model_info
    from dpr.viz.episodes import rollout_episode
    from dpr.viz.rerun_log import save_rrd

    def step_count(model: Path) -> int:
        match = re.search(r"_(\d+)_steps", model.stem)
        return int(match.group(1)) if match else -1

    checkpoints = sorted((result.run_dir / "checkpoints").glob("*.zip"), key=step_count)
    models = [(f"step_{step_count(m)}", m) for m in checkpoints] + [("final", result.model_path)]
    info = read_model_info(result.model_path)
    swarm, extra = split_swarm_kwargs(info.env_kwargs)
    steps = info.max_episode_steps or 2500
    episodes = [
        rollout_episode(env_id, str(model), seed, steps=steps, env_kwargs=extra, name=name, **swarm)
        for name, model in tqdm(models, desc="log to rerun", unit="model")
    ]
    save_rrd(episodes, path, title=f"dpr train {result.run_dir.name} (seed {seed})")
    print(f"wrote {path}")


def _training_done(result, args) -> int:
    """Say where a `dpr train`/`dpr finetune` run's files are (and log it to rerun when asked)."""
    from dpr.rl.train import EVAL_SEED_OFFSET

    print(f"model: {result.model_path}")
    if result.best_model_path:
        print(f"best model: {result.best_model_path}")
    print(f"config: {result.config_path}")
    print(f"evaluate it: dpr evaluate --policy {result.model_path} --env {args.env}")
    if args.rerun and not result.interrupted:
        _log_training_to_rerun(result, args.env, args.rerun, args.seed + EVAL_SEED_OFFSET)
    return 130 if result.interrupted else 0


def cmd_train(args, parser) -> int:
    from dpr.rl.train import TrainConfig, train

    if args.seed < 0:
        parser.error(f"--seed must be >= 0, got {args.seed}")
    _check_rerun_output(args, parser)
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
            steps_per_episode=args.steps_per_episode,
            env_kwargs=dict(args.env_kwarg or []),
            hyperparams=dict(args.hyperparam or []),
            eval_episodes=args.eval_episodes,
        )
        result = train(config, args.out)
    except (TypeError, ValueError) as error:
        parser.error(flag_message(error))
    return _training_done(result, args)


def cmd_finetune(args, parser) -> int:
    from dpr.envs.particle_env import split_swarm_kwargs
    from dpr.policies.sb3 import model_env_kwargs, read_model_info
    from dpr.rl.train import TrainConfig, train

    if args.seed < 0:
        parser.error(f"--seed must be >= 0, got {args.seed}")
    _check_rerun_output(args, parser)
    try:
        info = read_model_info(args.source)
        if info.env_id != args.env:
            raise ValueError(f"--from: {args.source} was trained on {info.env_id}, not on --env {args.env}")
        swarm, env_kwargs = split_swarm_kwargs(model_env_kwargs(args.source, args.env, dict(args.env_kwarg or [])))
        config = TrainConfig(
            args.algo or info.algo,
            args.env,
            **swarm,
            timesteps=args.timesteps,
            seed=args.seed,
            n_envs=args.n_envs,
            preset="finetune",
            steps_per_episode=info.max_episode_steps or 2500,
            env_kwargs=env_kwargs,
            hyperparams=dict(args.hyperparam or []),
            eval_episodes=args.eval_episodes,
            init_from=args.source,
            critic_warmup=args.critic_warmup,
            anchor_datasets=list(args.anchor or []),
            anchor_weight=args.anchor_weight,
            anchor_decay=args.anchor_decay,
        )
        result = train(config, args.out)
    except (TypeError, ValueError) as error:
        parser.error(flag_message(error))
    return _training_done(result, args)


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


def cmd_bc(args, parser) -> int:
    from dpr.imitation.bc import behaviour_clone

    if args.seed < 0:
        parser.error(f"--seed must be >= 0, got {args.seed}")
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
        parser.error(flag_message(error))
    print(f"model: {model}" + (f" (the last round's, {result.model_path})" if model != result.model_path else ""))
    print(f"log: {result.log_path}")
    print(f"config: {result.config_path}")
    print(f"evaluate it: dpr evaluate --policy {model} --env {args.env}")
    print(
        f"best validation accuracy {result.best_val_accuracy:.3f} (epoch {result.best_epoch} of "
        f"{result.epochs_run}, validation NLL {result.best_val_nll:.4f})"
    )
    return 0


def cmd_bench(args, parser) -> int:
    from dpr.bench import format_table, run_benchmarks

    _check_output(args.json, parser, "--json")
    rows = run_benchmarks(
        models=args.models,
        sizes=args.sizes,
        steps=args.steps,
        repeats=args.repeats,
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


def _env_kwarg(text: str) -> tuple[str, object]:
    """'object_type=box' -> ('object_type', 'box'); values parse as JSON when they can (numbers, true, [..])."""
    key, value = _name_and_value(text, "--env-kwarg")
    try:
        return key, json.loads(value)
    except ValueError:
        return key, value


def cmd_collect(args, parser) -> int:
    from tqdm import tqdm

    _check_output(args.json, parser, "--json")
    if args.seed < 0:
        parser.error(f"--seed must be >= 0, got {args.seed}")

    from dpr.datasets.collect import CollectSpec, collect, format_summary

    try:
        spec = CollectSpec(
            args.env,
            policy=args.policy,
            n_robots=args.n_robots,
            robot_model=args.robot_model,
            steps=args.steps,
            pixels=args.pixels,
            image_size=args.image_size,
            env_kwargs=dict(args.env_kwarg or []),
            label_policy=args.label_policy,
        )
    except ValueError as error:
        parser.error(flag_message(error))
    try:
        spec.make_env().close()  # a bad --env-kwarg name or value fails here, before anything is written
    except (TypeError, ValueError) as error:
        parser.error(
            f"cannot make {spec.env_id} from --n-robots/--robot-model/--env-kwarg {spec.make_kwargs()}: {error}"
        )
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        parser.error(f"--out: {out} exists and is not a folder")
    if args.address and args.backend != "ray":
        parser.error("--address is the Ray cluster for --backend ray")
    if args.backend == "ray":
        import importlib.util

        if importlib.util.find_spec("ray") is None:
            parser.error("--backend ray needs Ray: pip install -e '.[distributed]'")
    bar = tqdm(total=args.episodes, desc=f"collect {spec.policy} {spec.env_id}", unit="episode")
    frames = [0]
    started = [None]

    def progress(record, index):
        import time

        if started[0] is None:
            started[0] = time.perf_counter() - record.seconds
        frames[0] += record.frames
        bar.update(1)
        bar.set_postfix(frames=frames[0], fps=f"{frames[0] / max(time.perf_counter() - started[0], 1e-9):.0f}")

    try:
        summary = collect(
            out,
            spec,
            episodes=args.episodes,
            seed=args.seed,
            workers=args.workers,
            mcap=args.mcap,
            progress=progress,
            backend=args.backend,
            address=args.address,
        )
    except ValueError as error:  # a DatasetError, or a policy that cannot run on this env
        bar.close()
        print(f"dpr collect: error: {flag_message(error)}", file=sys.stderr)
        return 2
    bar.close()
    print(format_summary(summary))
    if args.json:
        Path(args.json).write_text(json.dumps(summary.as_dict(), indent=2))
        print(f"wrote {args.json}")
    return 130 if summary.interrupted else 0


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


def _policy_names(text: str) -> list[str]:
    """'wave,random' -> ['wave', 'random']."""
    names = [part.strip() for part in text.split(",")]
    if not all(names):
        raise argparse.ArgumentTypeError(f"--policies must be comma-separated names like 'wave,random', got {text!r}")
    return names


def _episode_index(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"--episode takes episode indices >= 0, got {text!r}")
    return value


def _view_error(error: Exception | str) -> int:
    print(f"dpr view: error: {flag_message(error) if isinstance(error, Exception) else error}", file=sys.stderr)
    return 2


def _load_view_source(args, parser) -> list:
    """The episodes of a dataset folder or an MCAP file (argument errors exit through parser.error)."""
    from dpr.datasets.lerobot import LeRobotReader
    from dpr.viz import episode_from_dataset, episode_from_mcap

    source = Path(args.source)
    if args.policies is not None:
        parser.error("--policies rolls policies out with --env; it does not apply to a dataset or MCAP file")
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

    from dpr.viz import check_view_policy, rollout_episode

    if args.episode is not None:
        parser.error("--episode picks episodes of a dataset; with --env, policies are rolled out live")
    policies = args.policies or ["wave"]
    if len(set(policies)) != len(policies):
        parser.error(f"--policies lists a policy twice: {policies}")
    if args.seed < 0:
        parser.error(f"--seed must be >= 0, got {args.seed}")
    for name in policies:
        check_view_policy(name)
    env_kwargs = dict(args.env_kwarg or [])
    _check_env_kwargs([args.env], {"n_robots": args.n_robots, "robot_model": args.robot_model, **env_kwargs}, parser)
    episodes = []
    for name in policies:
        with tqdm(total=args.steps, desc=f"roll out {name}", unit="step", leave=False) as bar:
            episodes.append(
                rollout_episode(
                    args.env,
                    name,
                    args.seed,
                    n_robots=args.n_robots,
                    robot_model=args.robot_model,
                    steps=args.steps,
                    env_kwargs=env_kwargs,
                    on_step=lambda step: bar.update(1),
                )
            )
    return episodes


def cmd_view(args, parser) -> int:
    from dpr.datasets.lerobot import DatasetError
    from dpr.viz import ViewError

    if (args.source is None) == (args.env is None):
        parser.error("give either SOURCE (a dataset folder or a .mcap file) or --env ID to roll policies out")
    if args.save is not None:
        _check_output(args.save, parser, "--save")
        if Path(args.save).suffix != ".rrd":
            parser.error(f"--save: {args.save} must end in .rrd")
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


def _swarm_arguments(parser: argparse.ArgumentParser, *, model_default: bool = False) -> None:
    """--n-robots and --robot-model. With ``model_default`` they default to None: a saved model's own values
    apply, else 9 and paddle."""
    parser.add_argument(
        "--n-robots",
        type=positive_int,
        default=None if model_default else 9,
        help="swarm size N (default 9" + (", or a model's N)" if model_default else ")"),
    )
    parser.add_argument(
        "--robot-model",
        choices=ROBOT_MODEL_NAMES,
        default=None if model_default else "paddle",
        help="paddle: the paper's robot (default"
        + (", or a model's" if model_default else "")
        + "); disk: the fast single-body model",
    )


def _env_kwarg_argument(parser: argparse.ArgumentParser, example: str) -> None:
    parser.add_argument(
        "--env-kwarg",
        action="append",
        type=_env_kwarg,
        metavar="NAME=VALUE",
        help=f"extra gym.make kwarg, e.g. {example} (repeatable)",
    )


def _run_arguments(parser: argparse.ArgumentParser, hyperparam_example: str) -> None:
    """The flags `dpr train` and `dpr finetune` share."""
    parser.add_argument("--seed", type=int, default=0, help="seed of the model and the envs (default 0)")
    parser.add_argument(
        "--eval-episodes", type=positive_int, default=2, help="episodes per periodic evaluation (default 2)"
    )
    _env_kwarg_argument(parser, "reward=projected")
    parser.add_argument(
        "--hyperparam",
        action="append",
        type=_hyperparam,
        metavar="NAME=VALUE",
        help=f"override a yaml hyperparameter, e.g. {hyperparam_example} (repeatable)",
    )
    parser.add_argument("--out", help="new run folder (default runs/train/<task>-<algo>-seed<S>-<timestamp>)")
    parser.add_argument(
        "--rerun",
        metavar="OUT.rrd",
        help="after training, roll out every checkpoint and the final model from the evaluation "
        "start (seed + 10000) side by side into this new rerun file",
    )


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="dpr", description="Deep Particle Robot: particle-robot swarms for robot learning."
    )
    sub = parser.add_subparsers(dest="command", required=True)

    ev = sub.add_parser(
        "evaluate",
        help="score a policy with the paper's metrics over seeds",
        description="Run a policy on one or more tasks and print projected displacement, net displacement, "
        "total distance and success (median, min, max, mean ± std over seeds).",
    )
    ev.add_argument(
        "--policy",
        default="wave",
        help="'wave' (the paper's hand-crafted policy), 'wave-markov' "
        "(its phase read from the observation), 'random', or a model file MODEL.zip written by "
        "`dpr train`/`dpr bc` (run with the env kwargs it was trained with)",
    )
    ev.add_argument(
        "--env",
        nargs="+",
        default=["dpr/Navigation-v0"],
        help="env ids (dpr/Navigation-v0, dpr/Gate-v0, dpr/Unresponsive-v0, dpr/Manipulation-v0) or 'all'",
    )
    ev.add_argument("--seeds", type=parse_seeds, default=parse_seeds("0-4"), help="e.g. 0-4 or 1,3,7 (default 0-4)")
    _swarm_arguments(ev, model_default=True)
    ev.add_argument("--steps", type=positive_int, default=2500, help="steps per episode (default 2500)")
    ev.add_argument(
        "--workers",
        type=positive_int,
        default=min(2, os.cpu_count() or 1),
        help="episodes run in this many processes (default: up to 2)",
    )
    _env_kwarg_argument(ev, "object_start=paper")
    ev.add_argument("--json", help="also write episodes and summary to this new JSON file")
    ev.add_argument(
        "--rerun",
        metavar="OUT.rrd",
        help="also save every evaluated episode (replayed with full state) to this new rerun file",
    )
    ev.set_defaults(func=cmd_evaluate)

    rep = sub.add_parser(
        "report",
        help="markdown results table and the paper's figures from `dpr evaluate --json` files",
        description="Results table (markdown) and figures (bars per task and policy; trajectories from one start) "
        "from `dpr evaluate --json` files. Files are merged: one policy evaluated task by task, or several "
        'policies, give one row per (task, policy), with "% of wave" where the wave policy was evaluated on '
        "the same seeds. Writes results.md, bars.png and trajectories.png into --out (never overwritten).",
    )
    rep.add_argument("evaluations", nargs="+", metavar="EVAL.json", help="files written by `dpr evaluate --json`")
    rep.add_argument("--out", required=True, metavar="DIR", help="folder for the report (created if missing)")
    rep.add_argument(
        "--label",
        nargs="+",
        metavar="NAME",
        help="display name of each file's policy, one per file "
        "in order (default: the policy's name; a model file's stem, e.g. navigation-bc-ppo)",
    )
    rep.add_argument(
        "--seed",
        type=int,
        help="seed of the episodes drawn in trajectories.png (default: per task, the smallest seed every policy has)",
    )
    rep.set_defaults(func=cmd_report)

    tr = sub.add_parser(
        "train",
        help="train PPO, A2C or DQN from scratch with stable-baselines3",
        description="Train an SB3 model on a task with the hyperparameters of dpr/rl/hyperparams/<algo>.yml "
        "(the env id's entry, or --preset paper) and save model.zip, best_model.zip, checkpoints and the "
        "resolved config.yaml into a new run folder. The model carries its env id and kwargs: "
        "`dpr evaluate --policy RUN/model.zip --env ID` runs it on the env it was trained on.",
    )
    tr.add_argument("--algo", required=True, choices=("ppo", "a2c", "dqn"), help="DQN uses Discrete(2^N) actions")
    tr.add_argument(
        "--env", required=True, help="env id: dpr/Navigation-v0, dpr/Gate-v0, dpr/Unresponsive-v0, dpr/Manipulation-v0"
    )
    _swarm_arguments(tr)
    tr.add_argument("--timesteps", type=positive_int, help="env steps to train for (default: the preset's n_timesteps)")
    tr.add_argument("--n-envs", type=positive_int, default=1, help="parallel envs (subprocesses when > 1; default 1)")
    tr.add_argument(
        "--preset",
        choices=("default", "paper"),
        default="default",
        help="default: laptop-sized entry of the env id; paper: Shen et al.'s (10M steps)",
    )
    tr.add_argument("--steps-per-episode", type=positive_int, default=2500, help="episode length (default 2500)")
    _run_arguments(tr, "n_steps=256 or learning_rate=lin_1e-3")
    tr.set_defaults(func=cmd_train)

    ft = sub.add_parser(
        "finetune",
        help="fine-tune a behaviour-cloned model with PPO or A2C",
        description="Start PPO or A2C from the weights of a model written by `dpr bc` (or `dpr train`) and train "
        "it on the env it was made for, with the `finetune` entry of dpr/rl/hyperparams/<algo>.yml on top of the "
        "env id's entry: small, clipped updates, so the cloned behaviour is not forgotten. First, --critic-warmup "
        "steps train only the value head on rollouts of the unchanged actor. Writes a run folder as `dpr train` does.",
    )
    ft.add_argument("--from", dest="source", required=True, metavar="MODEL.zip", help="the model to start from")
    ft.add_argument("--env", required=True, help="env id the model was trained on, e.g. dpr/Navigation-v0")
    ft.add_argument("--algo", choices=("ppo", "a2c"), help="algorithm to fine-tune with (default: the model's)")
    ft.add_argument("--timesteps", type=positive_int, help="env steps after the warm-up (default: the yaml's)")
    ft.add_argument(
        "--critic-warmup",
        type=int,
        default=20_000,
        help="env steps that train only the value head first (default 20000; 0 to skip)",
    )
    ft.add_argument(
        "--anchor",
        nargs="+",
        metavar="DATASET",
        help="demonstration datasets (from `dpr collect`) to anchor every update to: after each update, "
        "a few steps of the behaviour-cloning loss on their frames, scaled by --anchor-weight and decaying "
        "by --anchor-decay per update (DAPG's demonstration term)",
    )
    ft.add_argument(
        "--anchor-weight", type=float, default=1.0, help="the anchor's scale at the first update (default 1)"
    )
    ft.add_argument(
        "--anchor-decay",
        type=float,
        default=0.99,
        help="the anchor's scale is multiplied by this after "
        "each update (default 0.99: about a third left after 100 updates)",
    )
    ft.add_argument(
        "--n-envs",
        type=positive_int,
        default=min(2, os.cpu_count() or 1),
        help="parallel envs (subprocesses when > 1; default: min(2, CPUs))",
    )
    _run_arguments(ft, "learning_rate=1e-5")
    ft.set_defaults(func=cmd_finetune)

    pi = sub.add_parser(
        "pipeline",
        help="demonstrations -> BC -> fine-tuning, beside RL from scratch, evaluated against the wave",
        description="Per task: record demonstrations of the Markov wave, clone them (BC), fine-tune the clone "
        "with PPO/A2C, train RL from scratch for the same total env steps, evaluate everything and the wave policy "
        "on unseen seeds, and write OUT/report/results.md with bars.png and trajectories.png. Every stage is "
        "skipped when its output exists: the same command resumes an interrupted run. The defaults are the "
        "small budget of `make run` (Navigation, N=9, about 10 minutes on 2 CPU cores).",
    )
    pi.add_argument("--out", default="runs/pipeline", help="run folder (default runs/pipeline; resumed if present)")
    pi.add_argument(
        "--tasks",
        nargs="+",
        default=["navigation"],
        choices=(*TASK_NAMES, ALL_ENVS),
        help="tasks to run (default navigation; 'all' for the four)",
    )
    pi.add_argument("--n-robots", type=positive_int, default=9, help="swarm size N (default 9)")
    pi.add_argument("--episodes", type=positive_int, default=40, help="demonstration episodes per task (default 40)")
    pi.add_argument("--demo-seed", type=int, default=1000, help="first demonstration seed (default 1000)")
    pi.add_argument("--bc-epochs", type=positive_int, default=15, help="behaviour-cloning epochs (default 15)")
    pi.add_argument(
        "--critic-warmup", type=int, default=10_000, help="value-only steps before fine-tuning (default 10000)"
    )
    pi.add_argument("--finetune-steps", type=positive_int, default=30_000, help="fine-tuning steps (default 30000)")
    pi.add_argument(
        "--anchor",
        action="store_true",
        help="anchor fine-tuning to the task's demonstrations "
        "(`dpr finetune --anchor` with its default weight and decay)",
    )
    pi.add_argument(
        "--approach-reward",
        type=float,
        default=1.0,
        metavar="W",
        help="Manipulation only: RL (fine-tuning and from scratch) trains with this weight of the "
        "swarm-ball approach shaping (the env's approach_reward; default 1, 0 for none)",
    )
    pi.add_argument(
        "--finetune-algos",
        nargs="+",
        default=["ppo"],
        choices=("ppo", "a2c"),
        help="algorithms that fine-tune the clone (default ppo)",
    )
    pi.add_argument(
        "--scratch-algos",
        nargs="*",
        default=["ppo"],
        choices=("ppo", "a2c", "dqn"),
        help="algorithms trained from scratch for the same total env steps (default ppo)",
    )
    pi.add_argument(
        "--eval-seeds",
        type=lambda text: parse_seeds(text, "--eval-seeds"),
        default=parse_seeds("100-104"),
        help="evaluation seeds, never used for training (default 100-104)",
    )
    pi.add_argument("--seed", type=int, default=0, help="seed of BC and RL (default 0)")
    pi.add_argument("--steps", type=positive_int, default=2500, help="steps per episode, everywhere (default 2500)")
    pi.add_argument(
        "--workers",
        type=positive_int,
        default=min(2, os.cpu_count() or 1),
        help="worker processes for collection, RL envs and evaluation (default: min(2, CPUs))",
    )
    pi.set_defaults(func=cmd_pipeline)

    bc = sub.add_parser(
        "bc",
        help="behaviour-clone a recorded dataset into a PPO/A2C model",
        description="Train the policy of a new SB3 model (built as `dpr train` builds it, with the env kwargs the "
        "dataset was recorded with) to maximise the likelihood of the dataset's actions; whole episodes are held "
        "out for validation, training stops early on the validation log-likelihood and the best weights are kept. "
        "Saves model.zip, bc_log.json and config.yaml into a new run folder; "
        "`dpr evaluate --policy RUN/model.zip --env ID` runs the model.",
    )
    bc.add_argument(
        "--dataset",
        required=True,
        nargs="+",
        help="dataset folder(s) written by `dpr collect` on the same env; validation episodes come from the first",
    )
    bc.add_argument("--env", required=True, help="env id the dataset was recorded on, e.g. dpr/Navigation-v0")
    bc.add_argument(
        "--algo",
        choices=("ppo", "a2c", "dqn"),
        default="ppo",
        help="model to clone into (default ppo; dqn: its Q-network as a classifier over 2^N actions)",
    )
    bc.add_argument("--n-robots", type=positive_int, help="swarm size N; only checked: it must be the dataset's")
    bc.add_argument("--robot-model", choices=ROBOT_MODEL_NAMES, help="only checked: it must be the dataset's")
    bc.add_argument("--epochs", type=positive_int, default=20, help="maximum epochs (default 20)")
    bc.add_argument("--batch-size", type=positive_int, default=256, help="frames per gradient step (default 256)")
    bc.add_argument("--lr", type=float, default=1e-3, help="Adam learning rate (default 1e-3)")
    bc.add_argument(
        "--val-fraction", type=float, default=0.2, help="fraction of episodes held out for validation (default 0.2)"
    )
    bc.add_argument(
        "--patience",
        type=positive_int,
        default=3,
        help="stop after this many epochs without a better validation log-likelihood (default 3)",
    )
    bc.add_argument("--seed", type=int, default=0, help="seed of the model, the split and the shuffling (default 0)")
    bc.add_argument("--out", help="new run folder (default runs/bc/<task>-<algo>-seed<S>-<timestamp>)")
    bc.add_argument(
        "--dagger-rounds",
        type=int,
        default=0,
        help="DAgger rounds after cloning: roll the clone out, label its states with --expert, clone "
        "again on everything (default 0: plain behaviour cloning)",
    )
    bc.add_argument("--dagger-episodes", type=positive_int, default=10, help="episodes per DAgger round (default 10)")
    bc.add_argument(
        "--dagger-seed",
        type=int,
        default=50_000,
        help="first seed of the DAgger episodes; must not be a demonstration seed (default 50000)",
    )
    bc.add_argument(
        "--expert",
        default="wave-markov",
        help="policy that labels the DAgger states; a function of the observation (default wave-markov)",
    )
    bc.add_argument(
        "--workers",
        type=positive_int,
        default=min(2, os.cpu_count() or 1),
        help="processes that roll out DAgger episodes (default: min(2, CPUs))",
    )
    bc.set_defaults(func=cmd_bc)

    co = sub.add_parser(
        "collect",
        help="record policy rollouts as a LeRobot v3.0 dataset (and MCAP logs)",
        description="Roll a policy out for --episodes seeds (--seed, --seed+1, ...) and append each episode to the "
        "LeRobot v3.0 dataset in --out. The dataset is valid after every episode; running the same command again "
        "resumes (seeds already recorded are skipped). An --out folder holding a dataset of another env, policy, "
        "kwargs or features is refused and left untouched.",
    )
    co.add_argument(
        "--env", required=True, help="env id: dpr/Navigation-v0, dpr/Gate-v0, dpr/Unresponsive-v0, dpr/Manipulation-v0"
    )
    co.add_argument(
        "--policy",
        default="wave",
        help="'wave' (default), 'wave-markov', 'random' or a model .zip: any policy `dpr evaluate` accepts",
    )
    co.add_argument(
        "--label-policy",
        help="record this policy's action on every observation instead of the "
        "action --policy took (DAgger data: a clone drives, an expert labels), e.g. wave-markov",
    )
    co.add_argument("--episodes", type=positive_int, default=10, help="number of episodes (seeds) to hold (default 10)")
    co.add_argument("--out", required=True, help="dataset folder (created, or resumed if it holds the same dataset)")
    co.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    _swarm_arguments(co)
    co.add_argument("--steps", type=positive_int, default=2500, help="max steps per episode (default 2500)")
    co.add_argument("--pixels", action="store_true", help="also record render() frames as observation.image (PNG)")
    co.add_argument("--image-size", type=positive_int, default=96, help="frame size for --pixels (default 96)")
    co.add_argument("--mcap", action="store_true", help="also write one MCAP log per episode into OUT/mcap/")
    co.add_argument(
        "--workers", type=positive_int, default=min(2, os.cpu_count() or 1), help="rollout processes (default: up to 2)"
    )
    _env_kwarg_argument(co, "object_type=box")
    co.add_argument(
        "--backend",
        choices=("processes", "ray"),
        default="processes",
        help="run rollouts in local worker processes (default) or as Ray tasks (pip install -e '.[distributed]')",
    )
    co.add_argument(
        "--address", help="with --backend ray: the address of a running Ray cluster (default: start a local one)"
    )
    co.add_argument("--json", help="also write the summary to this new JSON file")
    co.set_defaults(func=cmd_collect)

    rp = sub.add_parser(
        "replay",
        help="re-run recorded episodes and check they reproduce bit for bit",
        description="Re-run each episode of a dataset from its stored seed, env kwargs and actions, and compare "
        "observations, rewards and flags with the recording. Exit status 1 when any episode differs.",
    )
    rp.add_argument("dataset", help="dataset folder written by `dpr collect`")
    rp.add_argument(
        "--episodes",
        type=lambda text: parse_seeds(text, "--episodes"),
        help="episode indices, e.g. 0-4 or 1,3 (default: all)",
    )
    rp.set_defaults(func=cmd_replay)

    be = sub.add_parser(
        "bench",
        help="env steps/s vs physics-only steps/s for both robot models",
        description="Time env.step with random actions against the pymunk part of the same steps "
        "(see dpr.bench); prints a markdown table for BENCHMARKS.md.",
    )
    be.add_argument("--models", nargs="+", choices=ROBOT_MODEL_NAMES, default=list(ROBOT_MODEL_NAMES))
    be.add_argument("--sizes", nargs="+", type=positive_int, default=[9, 25, 49, 100])
    be.add_argument("--steps", type=positive_int, default=200, help="env steps per timed block at N=9 (default 200)")
    be.add_argument("--repeats", type=positive_int, default=5, help="timed blocks; medians are reported (default 5)")
    be.add_argument("--json", help="also write the rows to this new JSON file")
    be.set_defaults(func=cmd_bench)

    vi = sub.add_parser(
        "view",
        help="inspect episodes in rerun: a dataset, an MCAP log, or policies rolled out side by side",
        description="Log episodes to rerun: robots (radius following their expansion), magnets, walls, object, "
        "goal, the centre-of-mass trail, and reward, distance to goal and the paper's metrics over time, on a "
        "`step` and a `sim_time` timeline. SOURCE is a dataset folder written by `dpr collect` (pick episodes with "
        "--episode) or one of its MCAP logs; or give --env and --policies to roll policies out from the same "
        "start and see them side by side. Without --save or --serve a rerun viewer is spawned.",
    )
    vi.add_argument("source", nargs="?", help="dataset folder or .mcap file (omit with --env)")
    vi.add_argument(
        "--episode",
        nargs="+",
        type=_episode_index,
        metavar="K",
        help="dataset episode indices to show side by side (default 0)",
    )
    vi.add_argument("--env", help="env id to roll policies out on, e.g. dpr/Navigation-v0")
    vi.add_argument(
        "--policies", type=_policy_names, help="comma-separated policies for --env (default wave), e.g. wave,random"
    )
    vi.add_argument("--seed", type=int, default=0, help="reset seed of every rollout (default 0)")
    _swarm_arguments(vi)
    vi.add_argument("--steps", type=positive_int, default=2500, help="max steps per rollout (default 2500)")
    _env_kwarg_argument(vi, "object_type=box")
    vi.add_argument("--save", metavar="OUT.rrd", help="write a new .rrd file instead of starting a viewer")
    vi.add_argument("--serve", action="store_true", help="serve over gRPC (connect with `rerun URL`) until Ctrl-C")
    vi.set_defaults(func=cmd_view)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "env", None) and args.env != [ALL_ENVS]:
        from dpr.envs import ENV_IDS

        requested = [args.env] if isinstance(args.env, str) else args.env
        unknown = [e for e in requested if e not in ENV_IDS.values()]
        if unknown:
            parser.error(f"--env: unknown env id(s) {unknown}; choose from {list(ENV_IDS.values())} or 'all'")
    return args.func(args, parser)


if __name__ == "__main__":
    sys.exit(main())
