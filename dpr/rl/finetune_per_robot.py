"""Fine-tune a per-robot model with PPO or A2C, every robot of one or more swarms acting with the same weights
(``dpr finetune-decentralised``).

A per-robot model (``dpr bc-decentralised``; :mod:`dpr.policies.per_robot_model`) reads one robot's local
observation and gives that robot's action. Here every robot is one env of an SB3 VecEnv
(:class:`~dpr.envs.parallel.SwarmsAsVecEnv` of ``parallel_env(task, **spec.parallel_env_kwargs(), n_robots=N)``,
one swarm per entry of ``n_robots``), so one policy, shared by all of them, learns from every robot's transitions.
Swarms of several sizes step side by side: every rollout holds all of them. Each robot's reward is the team reward
(``shared_reward=True``) or an equal share of it.

Budgets are counted in **swarm steps**, summed over the training swarms (one step of a 9-robot swarm is one step,
not nine): with ``n_robots=(9, 25)``, 10,000 steps are 5,000 steps of each swarm. SB3's own ``num_timesteps``
counts robot steps; :class:`~dpr.rl.progress.StepUnit` converts. The yaml's ``n_steps`` (rollout length) counts the
steps of each swarm, and a rollout holds ``n_steps x sum(n_robots)`` robot transitions.

As ``dpr finetune`` does, the run starts from the model's weights in a new model with the ``finetune`` preset of
the algorithm's yaml, first trains only the value head for ``critic_warmup`` steps (per-robot cloning leaves it
untrained), evaluates the policy, and keeps the best one: the start and then about :data:`EVALUATIONS` times over
the run, the policy drives the centralised env of each training size through ``make_policy`` (as ``dpr evaluate``
runs it) from the same validation seeds (``seed + EVAL_SEED_OFFSET + i``), and ``best_model.zip`` is the one of the
highest mean team return (the start's weights when nothing beat them). A run folder holds ``model.zip``,
``best_model.zip``, ``checkpoints/model_<swarm steps>_steps.zip``, ``eval/evaluations.json``, ``config.yaml`` and
``tb/`` (with tensorboard). Every model written is a per-robot model with the layout it started with and
``trained_n_robots`` the union of the model's and this run's sizes, so it runs at any N.

Every few minutes a run writes a snapshot of its training state into ``resume/`` (:mod:`dpr.rl.resume`: the
model, each swarm's current episode, the validation results and schedule, the random states);
``finetune_per_robot(config, out, resume=True)`` goes on from it to the model the run would have made without the
stop.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from dpr import runs
from dpr.atomic import atomic_write_json, atomic_write_text
from dpr.bounded_io import load_yaml
from dpr.checks import ParameterError, check_choice, check_int
from dpr.envs import TASKS
from dpr.envs.particle_env import MAX_EPISODE_STEPS
from dpr.limits import MAX_RECORD_BYTES
from dpr.policies.distributions import unchecked_distributions
from dpr.policies.hyperparams import FINETUNE_PRESET, Hyperparams, load_hyperparams
from dpr.policies.model_file import ModelInfo, read_model_info
from dpr.policies.per_robot_spec import RobotModelSpec, check_per_robot_env
from dpr.policies.sb3 import FINETUNE_ALGOS, INIT_PARAMETER, build_model, load_initial_policy, save_model
from dpr.rl import resume as resume_state
from dpr.rl.progress import StepUnit, progress_bar, tensorboard_available
from dpr.rl.recipe import default_critic_warmup
from dpr.rl.train import EVAL_SEED_OFFSET, EVALUATIONS, TrainResult, checkpoint_spacing, warm_up_critic

__all__ = ["PerRobotFinetuneConfig", "PerRobotFinetuneResult", "finetune_per_robot", "validate_per_robot_model"]

RUNS_DIR = Path("runs/finetune-decentralised")
DEFAULT_N_ROBOTS = 9  # the training size of a model that names none
# Parallel-env kwargs the run sets itself: the swarm sizes, the model's layout, the reward sharing, the episode length.
RESERVED_ENV_KWARGS = (
    *("n_robots", "render_mode", "max_episode_steps", "local_obs", "max_neighbours", "clock_period", "distance_period"),
    "shared_reward",
)


@dataclass
class PerRobotFinetuneConfig:
    """One fine-tuning run of a per-robot model (the ``dpr finetune-decentralised`` flags)."""

    init_from: str  # the per-robot model file the run starts from
    env_id: str  # the model's own task
    n_robots: tuple[int, ...] = ()  # one training swarm per entry; () = the model's trained_n_robots (else 9)
    algo: str | None = None  # None: the model's
    timesteps: int | None = None  # swarm steps, summed over the swarms; None: the finetune preset's n_timesteps
    # swarm steps training the value head only, before the actor moves; None: dpr.rl.recipe.default_critic_warmup
    # of the run's timesteps (a tenth, at most 10,000)
    critic_warmup: int | None = 0
    seed: int = 0
    shared_reward: bool = True  # every robot gets the team reward; False: reward / N
    env_kwargs: dict[str, Any] = field(default_factory=dict)  # task kwargs beside the model's own
    hyperparams: dict[str, Any] = field(default_factory=dict)  # overrides of the yaml's finetune preset
    eval_episodes: int = 2  # validation episodes per training size at each evaluation

    def __post_init__(self):
        self.n_robots = (self.n_robots,) if isinstance(self.n_robots, int) else tuple(self.n_robots)


@dataclass(frozen=True)
class PerRobotFinetuneResult(TrainResult):
    """Where a run's files are (``timesteps`` in swarm steps) and the swarm sizes it trained on."""

    n_robots: tuple[int, ...] = ()


@dataclass(frozen=True)
class _Resolved:
    """What a config resolves to, all checked before any folder is made."""

    info: ModelInfo  # the starting model's
    spec: RobotModelSpec  # the saved models' (trained_n_robots updated)
    algo: str
    hyper: Hyperparams
    env_kwargs: dict[str, Any]  # task kwargs of the centralised env and the parallel env (no N, no layout)
    sizes: tuple[int, ...]
    timesteps: int
    steps_per_episode: int
    critic_warmup: int  # swarm steps

    @property
    def eval_sizes(self) -> list[int]:
        return sorted(set(self.sizes))

    def model_info(self) -> ModelInfo:
        return ModelInfo(
            self.algo, self.info.env_id, self.env_kwargs, self.steps_per_episode, per_robot=self.spec.as_dict()
        )


def _resolve(config: PerRobotFinetuneConfig) -> _Resolved:
    check_int("seed", config.seed, 0)
    if config.critic_warmup is not None:
        check_int("critic_warmup", config.critic_warmup, 0)
    check_int("eval_episodes", config.eval_episodes, 1)
    if config.timesteps is not None:
        check_int("timesteps", config.timesteps, 1)
    if not isinstance(config.shared_reward, bool):
        raise ParameterError("shared_reward", f"expected True or False, got {config.shared_reward!r}")
    for n in config.n_robots:
        check_int("n_robots", n, 1)
    check_choice("env_id", config.env_id, TASKS)
    path = config.init_from
    info = read_model_info(path, INIT_PARAMETER)  # a missing file, or one that is no dpr model
    spec = RobotModelSpec.from_info(info, path, INIT_PARAMETER)  # a centralised model
    if config.env_id != info.env_id:
        raise ParameterError(
            "env_id",
            f"per-robot model {path} was trained on {info.env_id}; it fine-tunes on its own task's PettingZoo env",
        )
    algo = config.algo or info.algo
    if algo not in FINETUNE_ALGOS:
        raise ParameterError("algo", f"a per-robot model fine-tunes with one of {FINETUNE_ALGOS}, got {algo!r}")
    reserved = sorted(set(RESERVED_ENV_KWARGS) & set(config.env_kwargs))
    if reserved:
        raise ParameterError(
            "env_kwargs",
            f"must not set {reserved}: the swarm sizes, the model's layout ({spec.parallel_env_kwargs()}), the reward "
            "sharing and the episode length are the run's own",
        )
    env_kwargs = dict(info.env_kwargs)
    for name, value in config.env_kwargs.items():
        if name in env_kwargs and env_kwargs[name] != value:
            raise ParameterError(
                "env_kwargs", f"{path} was trained with {name}={env_kwargs[name]!r}, not {value!r} (leave it out)"
            )
        env_kwargs[name] = value
    hyper = load_hyperparams(algo, config.env_id, FINETUNE_PRESET, config.hyperparams)
    if hyper.env_kwargs:
        raise ParameterError("hyperparams", f"a per-robot model takes no yaml env_kwargs, got {hyper.env_kwargs}")
    if (hyper.algo_kwargs.get("policy_kwargs") or {}).get("features_extractor", "flatten") != "flatten":
        raise ParameterError("hyperparams", "a per-robot model reads one robot's vector: features_extractor flatten")
    sizes = config.n_robots or spec.trained_n_robots or (DEFAULT_N_ROBOTS,)
    trained = tuple(sorted({*spec.trained_n_robots, *sizes}))
    timesteps = config.timesteps or hyper.n_timesteps
    return _Resolved(
        info,
        RobotModelSpec(**{**asdict(spec), "trained_n_robots": trained}),
        algo,
        hyper,
        env_kwargs,
        sizes,
        timesteps,
        info.max_episode_steps or MAX_EPISODE_STEPS,
        default_critic_warmup(timesteps) if config.critic_warmup is None else config.critic_warmup,
    )


def _swarms(config: PerRobotFinetuneConfig, resolved: _Resolved, episodes: list | None = None):
    """The training VecEnv (every robot of every swarm an entry, episode returns monitored), each swarm checked
    against the model's layout: a ValueError naming what differs. With ``episodes`` (a snapshot's, one per swarm),
    each swarm is rebuilt where it stood."""
    from stable_baselines3.common.vec_env import VecMonitor

    from dpr.envs.parallel import SwarmsAsVecEnv, parallel_env
    from dpr.envs.replay import ParallelReplayLog, replay_parallel

    kwargs = {
        **resolved.spec.parallel_env_kwargs(),
        **resolved.env_kwargs,
        "max_episode_steps": resolved.steps_per_episode,
        "shared_reward": config.shared_reward,
    }
    envs = []
    try:
        for index, n in enumerate(resolved.sizes):
            envs.append(ParallelReplayLog(parallel_env(TASKS[config.env_id], n_robots=n, **kwargs)))
            check_per_robot_env(config.init_from, resolved.info, envs[-1].env, centralised=False)
            if episodes:
                replay_parallel(lambda: envs[-1], episodes[index])  # brought to where it stood
        return VecMonitor(SwarmsAsVecEnv(envs))
    except BaseException:
        for env in envs:
            env.close()
        raise


def validate_per_robot_model(
    path: str | Path, env_id: str, sizes: list[int], seeds: list[int], steps: int, env_kwargs: dict[str, Any]
) -> dict[str, Any]:
    """Score the per-robot model file at ``path`` in the centralised env ``env_id`` (``env_kwargs``, at most
    ``steps`` steps an episode) of each swarm size in ``sizes``, from each of ``seeds``, as ``dpr evaluate`` runs
    it (:func:`dpr.policies.registry.make_policy`): the mean team return over every episode, and per size each
    episode's return and projected displacement."""
    import gymnasium as gym

    from dpr.policies.registry import make_policy
    from dpr.rollout import roll_out

    by_n, returns = {}, []
    for n in sizes:
        env = gym.make(env_id, n_robots=n, max_episode_steps=steps, **env_kwargs)
        try:
            policy = make_policy(str(path), env)
            results = [roll_out(env, policy, seed) for seed in seeds]
        finally:
            env.close()
        episode_returns = [float(np.sum(r.rewards)) for r in results]
        returns.extend(episode_returns)
        by_n[n] = {
            "returns": episode_returns,
            "projected_displacement": [float(r.metrics.projected_displacement) for r in results],
        }
    return {"mean_return": float(np.mean(returns)), "by_n": by_n}


class _Validation:
    """Evaluations on the validation seeds, ``best_model.zip`` and ``eval/evaluations.json``."""

    def __init__(
        self,
        run_dir: Path,
        config: PerRobotFinetuneConfig,
        resolved: _Resolved,
        log: Callable,
        resumed: dict[str, Any] | None = None,
    ):
        self.best_path = run_dir / "best_model.zip"
        self.log_path = run_dir / "eval" / "evaluations.json"
        self.log_path.parent.mkdir(exist_ok=resumed is not None)
        self.candidate = run_dir / "eval" / "candidate.zip"
        self.config, self.resolved, self.log = config, resolved, log
        self.seeds = [config.seed + EVAL_SEED_OFFSET + i for i in range(config.eval_episodes)]
        self.rows: list[dict[str, Any]] = [] if resumed is None else resumed["rows"]
        self.best: dict[str, Any] | None = None if resumed is None else resumed["best"]

    def state(self) -> dict[str, Any]:
        """What a snapshot keeps of it (``resumed`` gives it back)."""
        return {"rows": self.rows, "best": self.best}

    def __call__(self, model, steps: int, label: str) -> None:
        save_model(model, self.candidate, self.resolved.model_info())
        resolved = self.resolved
        row = {"swarm_steps": steps, "model": label}
        row.update(
            validate_per_robot_model(
                self.candidate,
                self.config.env_id,
                resolved.eval_sizes,
                self.seeds,
                resolved.steps_per_episode,
                resolved.env_kwargs,
            )
        )
        row["best"] = self.best is None or row["mean_return"] > self.best["mean_return"]
        if row["best"]:
            self.best = row
            os.replace(self.candidate, self.best_path)
        else:
            self.candidate.unlink()
        self.rows.append(row)
        atomic_write_json(
            self.log_path,
            {
                "seeds": self.seeds,
                "n_robots": resolved.eval_sizes,
                "steps": resolved.steps_per_episode,
                "evaluations": self.rows,
            },
            indent=2,
        )
        self.log(
            f"dpr finetune-decentralised: validation of the {label} model ({steps} swarm steps): mean return "
            f"{row['mean_return']:.4g}" + (" (best so far)" if row["best"] else "")
        )


def _periodic(
    validation: _Validation,
    run_dir: Path,
    resolved: _Resolved,
    unit: StepUnit,
    resumed: resume_state.Snapshot | None = None,
):
    """An SB3 callback that, at the start of each rollout (after an update), writes a checkpoint every
    ``timesteps / CHECKPOINTS`` swarm steps and evaluates every ``timesteps / EVALUATIONS``, counted from the end of
    the warm-up; checkpoints are named by swarm steps, warm-up included. Its ``state()`` is its schedule, which a
    ``resumed`` run's snapshot gives back."""
    from stable_baselines3.common.callbacks import BaseCallback

    every_eval = max(resolved.timesteps // EVALUATIONS, 1)
    every_checkpoint = max(checkpoint_spacing(resolved.timesteps), 1)
    folder = run_dir / "checkpoints"

    class Periodic(BaseCallback):
        def _on_training_start(self) -> None:
            if resumed is None:
                self.first = self.model.num_timesteps
                self.next_eval, self.next_checkpoint = every_eval, every_checkpoint
            else:  # the run's learn() call started at the snapshot's origin
                schedule = resumed.extra["schedule"]
                self.first, self.next_eval, self.next_checkpoint = (
                    resumed.origin,
                    schedule["next_eval"],
                    schedule["next_checkpoint"],
                )

        def state(self) -> dict[str, int]:
            return {"next_eval": self.next_eval, "next_checkpoint": self.next_checkpoint}

        def _on_rollout_start(self) -> None:
            done = unit.from_sb3(self.model.num_timesteps - self.first)
            total = unit.from_sb3(self.model.num_timesteps)  # the warm-up's steps too
            if done >= self.next_checkpoint:
                folder.mkdir(exist_ok=True)
                save_model(self.model, folder / f"model_{total}_steps.zip", resolved.model_info())
                self.next_checkpoint = (done // every_checkpoint + 1) * every_checkpoint
            if done >= self.next_eval and done < resolved.timesteps:  # the final model is evaluated after learn
                validation(self.model, total, "training")
                self.next_eval = (done // every_eval + 1) * every_eval

        def _on_step(self) -> bool:
            return True

    return Periodic()


def default_run_dir(env_id: str, algo: str, seed: int) -> Path:
    """``runs/finetune-decentralised/<task>-<algo>-seed<S>-<timestamp>``."""
    return runs.default_run_dir(RUNS_DIR, env_id, algo, seed)


MONITOR = ("episode_returns", "episode_lengths", "episode_count")  # VecMonitor's sums of the episodes under way


def check_resumable(out: str | Path | None, config: PerRobotFinetuneConfig) -> None:
    """A :class:`ParameterError` about ``out`` unless it is a stopped run of ``config`` with a snapshot to resume
    from."""
    resume_state.check_resumable(out, _config_record(config))


def _config_record(config: PerRobotFinetuneConfig) -> dict[str, Any]:
    return {**asdict(config), "n_robots": list(config.n_robots)}


def _model_for(config: PerRobotFinetuneConfig, resolved, venv, snapshot):
    """The model to fine-tune: built for the swarms with the initial policy's weights, or the stopped run's."""
    try:
        model = build_model(resolved.hyper, venv, config.seed, None)
    except (AssertionError, ValueError, TypeError) as error:
        raise ParameterError("hyperparams", f"{resolved.algo} refuses them: {error}") from None
    if snapshot is None:
        load_initial_policy(model, config.init_from)  # another network than the finetune preset's
    else:
        snapshot.restore_model(model)
        snapshot.restore_vec_env(venv.venv, "train")  # building the model seeded the swarms anew
        for name in MONITOR:
            setattr(venv, name, snapshot.extra["monitor"][name])
    return model


def _run_record(config: PerRobotFinetuneConfig, resolved, unit, validation, tensorboard_log) -> dict[str, Any]:
    """What the run's config.yaml says at its start."""
    return {
        "algo": resolved.algo,
        "env_id": config.env_id,
        "env_kwargs": resolved.env_kwargs,
        "per_robot": resolved.spec.as_dict(),
        "parallel_env_kwargs": resolved.spec.parallel_env_kwargs(),
        "n_robots": list(resolved.sizes),
        "shared_reward": config.shared_reward,
        "steps_per_episode": resolved.steps_per_episode,
        "hyperparameters": resolved.hyper.as_dict(),
        "hyperparameter_overrides": dict(config.hyperparams),
        "seed": config.seed,
        "timesteps": resolved.timesteps,
        "critic_warmup": resolved.critic_warmup,
        "step_unit": "swarm steps, summed over the training swarms (SB3's num_timesteps counts robot steps)",
        "sb3_timesteps": unit.to_sb3(resolved.timesteps),
        "eval_episodes": config.eval_episodes,
        "validation_seeds": validation.seeds,
        "init_from": str(Path(config.init_from).resolve()),
        "tensorboard_log": tensorboard_log,
        "versions": runs.package_versions(),
        "config": _config_record(config),
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


def _resumed_record(config_path: Path, tensorboard_log: str | None, from_swarm_steps: int) -> dict[str, Any]:
    record = {**load_yaml(config_path, "out", MAX_RECORD_BYTES), "tensorboard_log": tensorboard_log}
    resumed = {"at": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "from_swarm_steps": from_swarm_steps}
    record["resumed"] = [*record.get("resumed", []), resumed]
    return record


def _start_line(config: PerRobotFinetuneConfig, resolved, unit, snapshot, run_dir: Path) -> str:
    sizes = " + ".join(str(n) for n in resolved.sizes)
    again = ""
    if snapshot is not None:  # counted as the checkpoints' names count (warm-up included) and as the bar does
        after_warmup = unit.from_sb3(snapshot.reached - snapshot.origin)
        again = (
            f", resumed at swarm step {unit.from_sb3(snapshot.reached)} "
            f"({after_warmup} of {resolved.timesteps} after the warm-up)"
        )
    return (
        f"dpr finetune-decentralised: per-robot {resolved.algo} on {config.env_id} swarms of {sizes} robots "
        f"{resolved.env_kwargs}, from {config.init_from} ({resolved.critic_warmup} critic warm-up steps first), "
        f"{resolved.timesteps} swarm steps, seed {config.seed}{again} -> {run_dir}"
    )


def finetune_per_robot(
    config: PerRobotFinetuneConfig,
    out: str | Path | None = None,
    *,
    show_progress: bool = True,
    resume: bool = False,
    log: Callable[[str], None] = lambda line: print(line, file=sys.stderr),
) -> PerRobotFinetuneResult:
    """Fine-tune the per-robot model ``config.init_from`` (module docstring) and save the run into ``out`` (a new or
    empty folder; default ``runs/finetune-decentralised/<task>-<algo>-seed<S>-<timestamp>``). Bad input (no such
    file, a centralised model, another task, robot model or layout, values SB3 refuses) raises ValueError before
    anything is written. ``TrainResult.timesteps`` counts swarm steps. ``resume=True`` goes on from the snapshot of
    the stopped run in ``out``, made with the same ``config`` (a ParameterError otherwise)."""
    from stable_baselines3.common.callbacks import CallbackList

    if resume:
        check_resumable(out, config)
    else:
        runs.check_new_folder(out)
    resolved = _resolve(config)
    try:
        snapshot = resume_state.load_snapshot(out) if resume else None
    except ValueError as error:  # another version, or files that are not a snapshot: nothing was written yet
        raise ParameterError("out", str(error)) from None
    venv = _swarms(config, resolved, snapshot and snapshot.train_episodes)
    try:
        swarms = venv.venv
        unit = StepUnit(swarms.num_envs, len(swarms.swarms))
        model = _model_for(config, resolved, venv, snapshot)
        run_dir = Path(out) if out is not None else default_run_dir(config.env_id, resolved.algo, config.seed)
        run_dir.mkdir(parents=True, exist_ok=True)
        tensorboard_log = str(run_dir / "tb") if tensorboard_available() else None
        model.tensorboard_log = tensorboard_log  # read by learn(); the folder did not exist when the model was built
        if tensorboard_log is None:
            log("dpr finetune-decentralised: tensorboard is not installed; no TensorBoard logs")
        validation = _Validation(run_dir, config, resolved, log, snapshot and snapshot.extra["validation"])
        record = _run_record(config, resolved, unit, validation, tensorboard_log)
        config_path = run_dir / "config.yaml"
        if snapshot is not None:  # the stopped run's record, with this resume added
            record = _resumed_record(config_path, tensorboard_log, unit.from_sb3(snapshot.reached))
        atomic_write_text(config_path, yaml.safe_dump(record, sort_keys=False))
        log(_start_line(config, resolved, unit, snapshot, run_dir))
        started = time.perf_counter()
        if snapshot is None:
            validation(model, 0, "start")
        desc = f"finetune-decentralised {resolved.algo} {config.env_id}"
        periodic = _periodic(validation, run_dir, resolved, unit, snapshot)
        callbacks = CallbackList(
            [progress_bar(desc, resolved.timesteps, show_progress, unit, snapshot and snapshot.origin), periodic]
        )
        try:
            if snapshot is None:
                if resolved.critic_warmup:
                    warm_up_critic(model, resolved.critic_warmup, show_progress, unit)
                origin = model.num_timesteps  # where the progress bar, the schedule and the snapshots count from
                total, reset = unit.to_sb3(resolved.timesteps), not resolved.critic_warmup
            else:
                origin, total, reset = snapshot.origin, snapshot.total_timesteps - model.num_timesteps, False
            if resolved.algo in resume_state.SNAPSHOT_ALGOS:

                def extra() -> dict[str, Any]:
                    monitor = {name: getattr(venv, name) for name in MONITOR}
                    return {"validation": validation.state(), "schedule": periodic.state(), "monitor": monitor}

                callbacks.callbacks.append(
                    resume_state.snapshots(run_dir, swarms, None, callbacks, origin, extra=extra)
                )
            if snapshot is not None:
                snapshot.restore_callbacks(callbacks)
                snapshot.restore_random_states()
            with unchecked_distributions():
                model.learn(total_timesteps=total, callback=callbacks, reset_num_timesteps=reset)
            interrupted = False
        except KeyboardInterrupt:  # Ctrl-C: keep what was learned so far
            interrupted = True
            log("dpr finetune-decentralised: interrupted; saving the model as it is")
        model_path = save_model(model, run_dir / "model.zip", resolved.model_info())
        done = unit.from_sb3(model.num_timesteps)
        if not interrupted:
            validation(model, done, "final")
    finally:
        venv.close()
    seconds = time.perf_counter() - started
    record.update(finished=time.strftime("%Y-%m-%dT%H:%M:%S%z"), seconds=round(seconds, 1), timesteps_done=done)
    record.update(interrupted=interrupted, best_evaluation=validation.best)
    atomic_write_text(config_path, yaml.safe_dump(record, sort_keys=False))
    if not interrupted:
        resume_state.drop_snapshot(run_dir)
    log(f"dpr finetune-decentralised: wrote {model_path} ({done} swarm steps in {seconds:.0f} s)")
    best = validation.best_path
    return PerRobotFinetuneResult(
        run_dir,
        model_path,
        config_path,
        best if best.is_file() else None,
        resolved.timesteps,
        seconds,
        interrupted,
        resolved.sizes,
    )
