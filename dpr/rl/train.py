"""Train PPO, A2C or DQN on a particle-robot task: from scratch (``dpr train``) or from a model (``dpr finetune``).

Fine-tuning loads the cloned actor-critic's weights into a new model built with the ``finetune`` preset
(small, clipped updates: see the yaml), then, for ``critic_warmup`` steps, trains only the value head on
rollouts of the unchanged cloned actor (its parameters are frozen), so that the first actor updates follow
advantages from a fitted critic rather than from a random one. Then all parameters train.

A run writes into a new folder: ``model.zip`` (the final model, with its env id and kwargs inside),
``config.yaml`` (everything the run resolved: algorithm, env, hyperparameters, seed, budget, versions),
``best_model.zip`` (best deterministic evaluation, when there was one), ``checkpoints/``, ``eval/``
(EvalCallback's evaluations.npz) and ``tb/`` (TensorBoard logs, when ``tensorboard`` is installed).
"""

from __future__ import annotations

import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import yaml

from dpr import runs
from dpr.bounded_io import load_yaml
from dpr.checks import ParameterError, check_choice, check_int, check_number
from dpr.envs import TASKS, episode_steps
from dpr.limits import MAX_RECORD_BYTES, MAX_TEMPERATURE
from dpr.policies.distributions import unchecked_distributions
from dpr.policies.exploration import soften_actions
from dpr.policies.hyperparams import DEFAULT_PRESET, PRESETS, Hyperparams, load_hyperparams
from dpr.policies.model_file import ALGOS, PPO, ModelInfo, model_architecture, write_model_info
from dpr.policies.sb3 import (
    FINETUNE_ALGOS,
    INIT_PARAMETER,
    actor_parameters,
    build_model,
    check_hyperparameters,
    check_initial_spaces,
    load_initial_policy,
    load_model,
    make_vec_env,
    save_model,
)
from dpr.rl import resume as resume_state
from dpr.rl.budget import TRAIN_COUNT_BOUNDS, check_training_memory, fit_budget
from dpr.rl.progress import SB3_STEPS, StepUnit, progress_bar, tensorboard_available

if TYPE_CHECKING:  # the anchor imports torch and the BC loss: only runs that anchor load it
    from dpr.rl.anchor import Demonstrations

RUNS_DIR = Path("runs/train")
EVALUATIONS = 5  # EvalCallback runs about this many times over a run
CHECKPOINTS = 4  # evenly spaced: a quarter, half and three quarters of the way, and the end
AVERAGED_MODEL = "averaged_model.zip"  # `dpr finetune --average-checkpoints`
ENGINES = ("pymunk", "batched")  # the reference engine, and the disk model for many envs at once in torch
LEARNERS = ("torch", "sb3")  # the batched engine's: dpr.rl.batched_ppo, or SB3's learn() on dpr.rl.sb3_batched
EVAL_SEED_OFFSET = 10_000  # EvalCallback's env is seeded with seed + this: its starts differ from training's
# Kwargs the trainer owns: they come from TrainConfig fields, not from env_kwargs.
RESERVED_ENV_KWARGS = ("n_robots", "robot_model", "render_mode", "max_episode_steps")


@dataclass
class TrainConfig:
    """One training run (the ``dpr train`` flags)."""

    algo: str
    env_id: str
    n_robots: int = 9
    robot_model: str = "paddle"
    timesteps: int | None = None  # None: the preset's n_timesteps
    seed: int = 0
    n_envs: int = 1
    env_processes: bool = True  # each of several envs in a process of its own (False: all in this one)
    preset: str = DEFAULT_PRESET
    steps_per_episode: int | None = None  # env steps; None: a whole episode (dpr.envs.episode_steps)
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    # on top of env_kwargs in the envs that gather experience only (e.g. a spread of Gate's wall placements): the
    # model records env_kwargs, the task it is for, and is evaluated there
    training_env_kwargs: dict[str, Any] = field(default_factory=dict)
    hyperparams: dict[str, Any] = field(default_factory=dict)  # overrides of the yaml entry
    eval_episodes: int = 2  # per evaluation during training (best_model.zip); 0: none
    init_from: str | None = None  # a model file whose policy weights the run starts from (dpr finetune)
    critic_warmup: int = 0  # with init_from: steps that train the value head only, before the actor moves
    exploration_temperature: float = 1.0  # with init_from: its logits divided by this first (dpr.policies.exploration)
    anchor_datasets: list[str] = field(default_factory=list)  # demonstrations the updates are anchored to
    anchor_weight: float = 1.0  # the anchor's loss scale at the first update ...
    anchor_decay: float = 0.99  # ... times this per update
    engine: str = "pymunk"  # or "batched": PPO on n_envs envs of the batched disk engine (dpr.rl.batched_train)
    device: str = "cpu"  # the batched engine's torch device
    compile: bool = False  # the batched engine's: torch.compile its physics substeps
    learner: str = "torch"  # the batched engine's: PPO on the device (dpr.rl.batched_ppo), or "sb3" (SB3's learn())

    def __post_init__(self):
        if self.algo not in ALGOS:
            raise ValueError(f"algo must be one of {ALGOS}, got {self.algo!r}")
        if self.preset not in PRESETS:
            raise ValueError(f"preset must be one of {PRESETS}, got {self.preset!r}")
        if self.env_id not in TASKS:  # a task's current id, or an earlier one kept for the runs made on it
            raise ValueError(f"env must be one of {tuple(TASKS)}, got {self.env_id!r}")
        if self.steps_per_episode is None:
            self.steps_per_episode = episode_steps(self.env_kwargs)
        self._check_counts()
        if self.critic_warmup and self.init_from is None:
            raise ValueError("critic_warmup needs init_from: a critic warm-up keeps a trained actor unchanged")
        check_number("exploration_temperature", self.exploration_temperature, maximum=MAX_TEMPERATURE, above=0.0)
        if self.exploration_temperature != 1.0 and self.init_from is None:
            raise ParameterError("exploration_temperature", "needs init_from: it widens a trained actor's actions")
        if self.init_from is not None and self.algo not in FINETUNE_ALGOS:
            raise ValueError(f"algo {self.algo!r} cannot start from a cloned policy; choose one of {FINETUNE_ALGOS}")
        if self.anchor_datasets and self.algo not in FINETUNE_ALGOS:
            raise ValueError(f"algo {self.algo!r} cannot be anchored to demonstrations; choose one of {FINETUNE_ALGOS}")
        check_number("anchor_weight", self.anchor_weight, above=0.0)
        check_number("anchor_decay", self.anchor_decay, maximum=1.0, above=0.0)
        self._check_engine()
        for name in ("env_kwargs", "training_env_kwargs"):
            reserved = sorted(set(RESERVED_ENV_KWARGS) & set(getattr(self, name)))
            if reserved:
                raise ValueError(f"{name} must not set {reserved}: use n_robots, robot_model and steps_per_episode")

    def _check_counts(self) -> None:
        """Every count within its bound (dpr.limits), and the envs within this machine's memory."""
        for name, (minimum, maximum) in TRAIN_COUNT_BOUNDS.items():
            if name != "timesteps" or self.timesteps is not None:
                check_int(name, getattr(self, name), minimum, maximum)
        check_training_memory(self.n_envs, self.n_robots, self.robot_model, self.engine, self.device)

    def _check_engine(self) -> None:
        check_choice("engine", self.engine, ENGINES)
        check_choice("learner", self.learner, LEARNERS)
        if self.engine == ENGINES[0]:
            for name, asked in (("compile", self.compile), ("learner", self.learner != LEARNERS[0])):
                if asked:
                    raise ParameterError(name, "is a setting of the batched engine: it needs engine='batched'")
            return
        if self.algo != PPO and self.learner != "sb3":
            raise ParameterError("algo", f"the batched engine's torch learner trains {PPO} only (sb3: any)")
        if self.robot_model != "disk":
            raise ParameterError("robot_model", f"the batched engine has the disk model only: {self.robot_model!r}")
        if self.init_from is not None or self.anchor_datasets:
            raise ParameterError("engine", "the batched engine trains from scratch: fine-tune on the pymunk engine")

    @property
    def command(self) -> str:
        """The command that makes this run: ``finetune`` from a model, else ``train``."""
        return "finetune" if self.init_from else "train"

    def resolve(self) -> tuple[Hyperparams, dict[str, Any], int]:
        """The hyperparameters, the env kwargs (the algorithm's, then n_robots, robot_model and env_kwargs)
        and the step budget of this run."""
        hyper = load_hyperparams(self.algo, self.env_id, self.preset, self.hyperparams)
        env_kwargs = {**hyper.env_kwargs, "n_robots": self.n_robots, "robot_model": self.robot_model}
        for name, value in self.env_kwargs.items():
            needed = hyper.env_kwargs.get(name, value)
            if needed != value:
                raise ValueError(f"{self.algo} needs {name}={needed!r} (its yaml env_kwargs); got {value!r}")
            env_kwargs[name] = value
        return hyper, env_kwargs, self.timesteps or hyper.n_timesteps

    def training_kwargs(self, env_kwargs: dict[str, Any]) -> dict[str, Any]:
        """The kwargs of the envs that gather experience: ``env_kwargs`` (from :meth:`resolve`) with
        ``training_env_kwargs`` over them."""
        return {**env_kwargs, **self.training_env_kwargs}


@dataclass(frozen=True)
class TrainResult:
    """Where a run's files are."""

    run_dir: Path
    model_path: Path
    config_path: Path
    best_model_path: Path | None
    timesteps: int
    seconds: float
    interrupted: bool = False


def prepare_run_dir(out: str | Path | None, config: TrainConfig) -> Path:
    """A new, empty run folder: ``out`` (refused when it exists and is not an empty folder) or
    ``runs/train/<task>-<algo>-seed<S>-<timestamp>``."""
    runs.check_new_folder(out)
    path = Path(out) if out is not None else runs.default_run_dir(RUNS_DIR, config.env_id, config.algo, config.seed)
    path.mkdir(parents=True, exist_ok=True)
    return path


def check_resumable(out: str | Path | None, config: TrainConfig) -> None:
    """A :class:`ParameterError` about ``out`` unless it is a stopped run of ``config`` with a snapshot to resume."""
    resume_state.check_resumable(out, asdict(config), resume_state.added_later(config))


def checkpoint_spacing(steps: int) -> int:
    """Steps between a run's :data:`CHECKPOINTS` evenly spaced checkpoints over its ``steps`` (per env for SB3's
    callbacks; swarm steps for a per-robot run); 0 for a run too short to space them (it then writes one at every
    step)."""
    return steps // CHECKPOINTS


def averaged_checkpoints(run_dir: str | Path) -> list[Path]:
    """The checkpoints a quarter, half and three quarters of the way through the finished run in ``run_dir``: with
    its final weights (``model.zip``), the four evenly spaced points of training whose mean weight averaging keeps.
    The last checkpoint falls within the final rollout, so it is left out."""
    checkpoints = Path(run_dir) / "checkpoints"
    found = sorted(checkpoints.glob("model_*_steps.zip"), key=lambda path: int(path.stem.split("_")[1]))
    if len(found) < CHECKPOINTS - 1:
        raise ValueError(f"{checkpoints}: expected {CHECKPOINTS - 1} checkpoints to average, found {len(found)}")
    return found[: CHECKPOINTS - 1]


def resumable(out: str | Path, config: TrainConfig) -> bool:
    """Whether ``out`` is a stopped run of ``config`` that ``train(config, out, resume=True)`` goes on with."""
    try:
        check_resumable(out, config)
    except ParameterError:
        return False
    return True


def resume_model(snapshot: resume_state.Snapshot, hyper: Hyperparams, env, seed: int, tensorboard_log: str | None):
    """The model of ``snapshot`` on ``env`` (rebuilt from the snapshot's episodes): built as the run built it, then
    given the snapshot's weights, optimizer state and progress, its last observation kept."""
    model = build_model(hyper, env, seed, tensorboard_log)
    snapshot.restore_model(model)
    snapshot.restore_vec_env(env, "train")  # building the model seeded the env anew
    return model


def _callbacks(
    config: TrainConfig,
    run_dir: Path,
    info: ModelInfo,
    env_kwargs: dict,
    timesteps: int,
    show_progress: bool,
    snapshot: resume_state.Snapshot | None = None,
):
    """Progress bar, evaluation (best_model.zip) and checkpoints, each stamping its zips with ``info``; resuming
    from ``snapshot``, the evaluation env is rebuilt where it stood and the bar starts where the run was."""
    from stable_baselines3.common.callbacks import BaseCallback, CallbackList, CheckpointCallback, EvalCallback

    class StampBest(BaseCallback):
        """Runs right after EvalCallback saved a new best_model.zip: writes the env metadata into it."""

        def _on_step(self) -> bool:
            write_model_info(run_dir / "best_model.zip", info)
            return True

    class StampingCheckpoints(CheckpointCallback):
        """SB3's checkpoints, each made loadable by ``dpr evaluate`` as soon as it is written."""

        def _on_step(self) -> bool:
            result = super()._on_step()
            if self.n_calls % self.save_freq == 0:  # SB3 has just saved (or, resumed, saved again) this file
                write_model_info(Path(self._checkpoint_path(extension="zip")), info)
            return result

    per_env = max(timesteps // config.n_envs, 1)  # callbacks count vec-env steps, not env steps
    if snapshot is None:
        eval_env = make_vec_env(config.env_id, env_kwargs, config.steps_per_episode, 1)
        eval_env.seed(config.seed + EVAL_SEED_OFFSET)
    else:
        eval_env = make_vec_env(config.env_id, env_kwargs, config.steps_per_episode, 1, snapshot.eval_episodes)
        snapshot.restore_vec_env(eval_env, "eval")
    evaluation = EvalCallback(
        eval_env,
        n_eval_episodes=config.eval_episodes,
        eval_freq=max(per_env // EVALUATIONS, 1),
        best_model_save_path=str(run_dir),
        log_path=str(run_dir / "eval"),
        deterministic=True,
        verbose=0,
        callback_on_new_best=StampBest(),
    )
    checkpoints = StampingCheckpoints(
        save_freq=max(checkpoint_spacing(per_env), 1),
        save_path=str(run_dir / "checkpoints"),
        name_prefix="model",
        verbose=0,
    )
    desc = f"{config.command} {config.algo} {config.env_id}"
    bar = progress_bar(desc, timesteps, show_progress, origin=snapshot and snapshot.origin)
    return CallbackList([bar, evaluation, checkpoints] if config.eval_episodes else [bar, checkpoints]), eval_env


def _close_quietly(vec_env) -> None:
    """Close a VecEnv whose worker processes may already be gone (Ctrl-C reaches them too)."""
    if vec_env is None:
        return
    try:
        vec_env.close()
    except (EOFError, BrokenPipeError, ConnectionResetError):
        pass


def check_training_env_kwargs(
    env_id: str, env_kwargs: dict[str, Any], training_env_kwargs: dict[str, Any], task_env: gym.Env | None = None
) -> None:
    """A :class:`ParameterError` about ``training_env_kwargs`` unless ``env_id`` made with them over ``env_kwargs``
    takes the observations and actions it takes with ``env_kwargs`` alone (a kwarg the env refuses: its own
    ValueError or TypeError). ``task_env``: the env already made with ``env_kwargs``, if the caller has one."""
    made = task_env is None
    if made:
        task_env = gym.make(env_id, **env_kwargs)
    try:
        training_env = gym.make(env_id, **{**env_kwargs, **training_env_kwargs})
        spaces = (task_env.observation_space, task_env.action_space)
        same = spaces == (training_env.observation_space, training_env.action_space)
        training_env.close()
    finally:
        if made:
            task_env.close()
    if not same:
        raise ParameterError(
            "training_env_kwargs",
            f"{training_env_kwargs} change the observation or action space of {env_id}; they may change only what "
            "the training envs draw",
        )


def _demonstrations(config: TrainConfig, env: gym.Env, env_kwargs: dict[str, Any]) -> Demonstrations | None:
    """The anchor's demonstration frames, checked against the spaces of ``env`` (made with ``env_kwargs``);
    None without ``anchor_datasets``."""
    if not config.anchor_datasets:
        return None
    from dpr.rl.anchor import load_demonstrations

    return load_demonstrations(
        config.anchor_datasets, env.observation_space, env.action_space, f"{config.env_id} {env_kwargs}"
    )


@unchecked_distributions()
def warm_up_critic(model, steps: int, show_progress: bool, unit: StepUnit = SB3_STEPS) -> None:
    """``steps`` steps (counted in ``unit``) of ``model.learn``, every actor parameter frozen: the value head learns."""
    actor = actor_parameters(model.policy)
    for parameter in actor:
        parameter.requires_grad_(False)
    try:
        model.learn(
            total_timesteps=unit.to_sb3(steps),
            callback=progress_bar("critic warm-up", steps, show_progress, unit),
            tb_log_name="critic_warmup",
        )
    finally:
        for parameter in actor:
            parameter.requires_grad_(True)


def _check_inputs(config: TrainConfig, hyper: Hyperparams, env_kwargs: dict[str, Any]) -> Demonstrations | None:
    """Every input checked on one env of the task before the run folder exists: the env kwargs, the training env
    kwargs, the model to start from, the demonstrations to anchor to and the values SB3 refuses; the
    demonstrations, loaded."""
    probe = gym.make(config.env_id, **env_kwargs)  # a bad env kwarg fails here, before the run folder exists
    try:
        if config.training_env_kwargs:
            check_training_env_kwargs(config.env_id, env_kwargs, config.training_env_kwargs, task_env=probe)
        if config.init_from is not None:  # so does a missing, foreign, corrupt or crafted model file
            initial, source = load_model(config.init_from, parameter=INIT_PARAMETER)
            if source.per_robot is not None:
                raise ParameterError(
                    INIT_PARAMETER,
                    f"{config.init_from} is a per-robot model (one robot's local observation in, its action out); "
                    "it trains on every robot of a PettingZoo swarm, not on the centralised env: fine-tune it with "
                    "`dpr finetune-decentralised` (dpr.rl.finetune_per_robot)",
                )
            check_initial_spaces(config.init_from, initial, source, probe)  # e.g. a model of another task
        demonstrations = _demonstrations(config, probe, env_kwargs)  # and a dataset that does not fit the env
        check_hyperparameters(hyper, probe, config.seed)  # and values SB3 refuses
    finally:
        probe.close()
    return demonstrations


def _run_record(config, hyper, env_kwargs, timesteps, budget, demonstrations, tensorboard_log) -> dict[str, Any]:
    """What a run's config.yaml says at its start: the settings it resolved and the software it ran on."""
    return {
        "algo": config.algo,
        "env_id": config.env_id,
        "env_kwargs": env_kwargs,
        "training_env_kwargs": dict(config.training_env_kwargs),
        "steps_per_episode": config.steps_per_episode,
        "hyperparameters": hyper.as_dict(),
        "hyperparameter_overrides": dict(config.hyperparams),
        "seed": config.seed,
        "n_envs": config.n_envs,
        "timesteps": timesteps,
        "steps": budget.record(),  # what the run makes: SB3 collects whole rollouts (dpr.rl.budget)
        "eval_episodes": config.eval_episodes,
        "init_from": None if config.init_from is None else str(Path(config.init_from).resolve()),
        "critic_warmup": config.critic_warmup,
        "exploration_temperature": config.exploration_temperature,
        "anchor": None if demonstrations is None else demonstrations.record(config.anchor_weight, config.anchor_decay),
        "tensorboard_log": tensorboard_log,
        "versions": runs.package_versions(),
        "config": asdict(config),
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


def _resumed_record(config_path: Path, tensorboard_log: str | None, snapshot) -> dict[str, Any]:
    """The stopped run's record, with this resume added."""
    record = {**load_yaml(config_path, "out", MAX_RECORD_BYTES), "tensorboard_log": tensorboard_log}
    resumed = {"at": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "from_timesteps": snapshot.reached}
    record["resumed"] = [*record.get("resumed", []), resumed]
    return record


def _finish_record(record: dict, config_path: Path, seconds: float, timesteps_done: int, interrupted: bool) -> None:
    record.update(
        finished=time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        seconds=round(seconds, 1),
        timesteps_done=timesteps_done,
        interrupted=interrupted,
    )
    config_path.write_text(yaml.safe_dump(record, sort_keys=False))


def _start_line(config: TrainConfig, env_kwargs: dict[str, Any], timesteps: int, snapshot, run_dir: Path) -> str:
    start = f" from {config.init_from} ({config.critic_warmup} critic warm-up steps first)" if config.init_from else ""
    again = f", resumed at step {snapshot.reached}" if snapshot is not None else ""
    return (
        f"dpr {config.command}: {config.algo} on {config.env_id} {env_kwargs}{start}, {timesteps} steps, "
        f"seed {config.seed}{again} -> {run_dir}"
    )


def _new_or_resumed_model(config: TrainConfig, hyper: Hyperparams, env, tensorboard_log: str | None, snapshot):
    """A new model (with the initial policy of ``config.init_from``), or the stopped run's from its snapshot."""
    if snapshot is not None:
        return resume_model(snapshot, hyper, env, config.seed, tensorboard_log)
    model = build_model(hyper, env, config.seed, tensorboard_log)
    if config.init_from is not None:
        load_initial_policy(model, config.init_from)
        soften_actions(model.policy, config.exploration_temperature)
    return model


def train(
    config: TrainConfig,
    out: str | Path | None = None,
    *,
    show_progress: bool = True,
    resume: bool = False,
    log: Callable[[str], None] = lambda line: print(line, file=sys.stderr),
) -> TrainResult:
    """Train ``config.algo`` from scratch and save the run into ``out`` (a new or empty folder; default
    ``runs/train/<task>-<algo>-seed<S>-<timestamp>``). Bad input raises ValueError before anything is written.

    A PPO or A2C run writes a snapshot of its training state into ``out/resume/`` every few minutes
    (:mod:`dpr.rl.resume`; not when anchored to demonstrations). ``resume=True`` goes on from the snapshot of the
    stopped run in ``out``, made with the same ``config`` (a ParameterError otherwise), to the model the run would
    have made had it never stopped."""
    if config.engine != ENGINES[0]:
        raise ParameterError("engine", "train() runs the pymunk engine; dpr.rl.batched_train.train_batched the batched")
    hyper, env_kwargs, timesteps = config.resolve()
    hyper, budget = fit_budget(hyper, config.n_envs, timesteps, config.critic_warmup, config.command)
    if resume:
        check_resumable(out, config)
    training_kwargs = config.training_kwargs(env_kwargs)
    demonstrations = _check_inputs(config, hyper, env_kwargs)
    run_dir = Path(out) if resume else prepare_run_dir(out, config)
    try:
        snapshot = resume_state.load_snapshot(run_dir) if resume else None
    except ValueError as error:  # another version, or files that are not a snapshot: nothing was written yet
        raise ParameterError("out", str(error)) from None
    info = ModelInfo(
        config.algo, config.env_id, env_kwargs, config.steps_per_episode, architecture=model_architecture(hyper)
    )
    tensorboard_log = str(run_dir / "tb") if tensorboard_available() else None
    if tensorboard_log is None:
        log(f"dpr {config.command}: tensorboard is not installed; no TensorBoard logs (pip install tensorboard)")
    record = _run_record(config, hyper, env_kwargs, timesteps, budget, demonstrations, tensorboard_log)
    config_path = run_dir / "config.yaml"
    if snapshot is not None:  # the stopped run's record, with this resume added
        record = _resumed_record(config_path, tensorboard_log, snapshot)
    config_path.write_text(yaml.safe_dump(record, sort_keys=False))
    log(_start_line(config, env_kwargs, timesteps, snapshot, run_dir))
    if budget.note:
        log(budget.note)

    env = make_vec_env(
        config.env_id,
        training_kwargs,
        config.steps_per_episode,
        config.n_envs,
        snapshot and snapshot.train_episodes,
        processes=config.env_processes,
    )
    eval_env = None
    started = time.perf_counter()
    try:
        model = _new_or_resumed_model(config, hyper, env, tensorboard_log, snapshot)
        training = budget.training_learn
        callbacks, eval_env = _callbacks(config, run_dir, info, env_kwargs, training, show_progress, snapshot)
        if demonstrations is not None:
            from dpr.rl.anchor import demonstration_anchor

            callbacks.callbacks.append(
                demonstration_anchor(demonstrations, config.anchor_weight, config.anchor_decay, config.seed)
            )
        with warnings.catch_warnings(), unchecked_distributions():
            # EvalCallback warns when the eval env is a DummyVecEnv and training runs in a SubprocVecEnv: harmless
            # (both are Monitor-wrapped), and one env does not need a process of its own.
            warnings.filterwarnings("ignore", message="Training and eval env are not of the same type")
            try:
                if snapshot is None:
                    if config.critic_warmup:
                        warm_up_critic(model, budget.warmup_learn, show_progress)
                    origin = model.num_timesteps  # where the progress bar and the snapshots count from
                    total, reset = training, not config.critic_warmup
                else:
                    origin, total, reset = snapshot.origin, snapshot.total_timesteps - model.num_timesteps, False
                # no snapshots of an anchor's own state, or of DQN's replay buffer: such runs keep none
                if demonstrations is None and hyper.algo in resume_state.SNAPSHOT_ALGOS:
                    callbacks.callbacks.append(resume_state.snapshots(run_dir, env, eval_env, callbacks, origin))
                if snapshot is not None:
                    snapshot.restore_callbacks(callbacks)
                    snapshot.restore_random_states()
                model.learn(total_timesteps=total, callback=callbacks, reset_num_timesteps=reset)
                interrupted = False
            except KeyboardInterrupt:  # Ctrl-C: keep what was learned so far
                interrupted = True
                log(f"dpr {config.command}: interrupted; saving the model as it is")
        model_path = save_model(model, run_dir / "model.zip", info)
    finally:
        for vec_env in (env, eval_env):
            _close_quietly(vec_env)
    seconds = time.perf_counter() - started
    _finish_record(record, config_path, seconds, int(model.num_timesteps), interrupted)
    if not interrupted:
        resume_state.drop_snapshot(run_dir)
    best = run_dir / "best_model.zip"
    log(f"dpr {config.command}: wrote {model_path} ({model.num_timesteps} steps in {seconds:.0f} s)")
    return TrainResult(
        run_dir, model_path, config_path, best if best.is_file() else None, timesteps, seconds, interrupted
    )
