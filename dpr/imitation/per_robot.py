"""Per-robot behaviour cloning: one policy, shared by every robot, learned from recorded centralised datasets, that
runs any swarm size.

A dataset of the centralised env (``dpr collect``: the global state and every robot's action at each frame) is
relabelled into per-robot samples ``(robot i's local observation, robot i's action)``
(:func:`relabel_episode`): each frame's local observations are computed from its state with
:meth:`LocalObservation.observe <dpr.envs.local_obs.LocalObservation.observe>`, exactly as
:class:`~dpr.policies.decentralised.PerRobotPolicyAdapter` computes them live: neighbours within the robot model's
magnet range, the clock at the frame's index in its episode (the adapter counts steps from the reset), and on tasks
with unresponsive robots the dead flags. Which robots were dead is not in the frames; it is recovered by resetting
the env with the episode's recorded seed and env kwargs (the env draws them from its seeded generator), see
:func:`episode_dead_robots`.

Any recorded policy can be the teacher; the relabelling is the same. The decentralised wave (``dpr collect
--policy decentralised-wave``) decides from the local observation alone (its goal distance and the clock), so a
per-robot model can match it; the centralised wave's actions depend on the whole swarm and can only be approximated.

:func:`behaviour_clone_per_robot` trains an SB3 PPO (or A2C) model whose spaces are one robot's: observation
``LocalObservation.space()``, action ``Discrete(2)``, built by :func:`dpr.policies.sb3.build_model` on
``AgentsAsVecEnv(parallel_env(task, local_obs=True, clock_period=T, ...))``, so that PPO can fine-tune it there
unchanged. The loss is :func:`dpr.imitation.loss.batch_stats`'s (the NLL of the recorded action under the policy's
own distribution); only the actor is trained, as in :mod:`dpr.imitation.bc`. Validation holds out whole episodes of
every dataset that has two or more. The model file records that it is a per-robot model and its layout
(:class:`~dpr.policies.per_robot_model.RobotModelSpec`), so ``make_policy`` runs it in a centralised env of any N.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from dpr import runs
from dpr.checks import ParameterError
from dpr.datasets.features import ACTION, OBSERVATION, SEED
from dpr.datasets.lerobot import LeRobotReader
from dpr.envs import MAX_EPISODE_STEPS, TASKS
from dpr.envs.local_obs import LocalObservation
from dpr.envs.particle_env import joint_action_bits
from dpr.imitation.bc import (
    AccuracyMeter,
    BCResult,
    EarlyStoppedFit,
    dataset_env,
    finish_bc_run,
    fit_with_early_stopping,
    split_episodes,
    start_run,
)
from dpr.imitation.config import WAVE_LENGTH, PerRobotCloneConfig, check_env_id
from dpr.imitation.loss import batch_stats, check_features
from dpr.policies.decentralised import MODEL_DEFAULTS, wave_env_kwargs
from dpr.policies.hyperparams import Hyperparams, load_hyperparams
from dpr.policies.model_file import ModelInfo, write_model_info
from dpr.policies.per_robot_spec import RobotModelSpec
from dpr.policies.sb3 import trained_parameters
from dpr.sim.models import swarm_class

__all__ = [
    "WAVE_LENGTH",
    "behaviour_clone_per_robot",
    "episode_dead_robots",
    "relabel_dataset",
    "relabel_episode",
    "robot_actions",
]

RUNS_DIR = Path("runs/bc-decentralised")
FRAME_INDEX = "frame_index"  # LeRobot's default column: the frame's step within its episode
# Centralised-env kwargs a per-robot model does not depend on: the adapter encodes its 0/1 actions into any action
# type and reads the robots' states whatever else the observation holds. A model file leaves them (and N) out.
CENTRALISED_ONLY_KWARGS = ("n_robots", "action_type", "obs_type", "obs_last_action", "image_size")
# Kwargs of the recorded episodes, not of the model: datasets cloned together may differ in them, and a model file
# leaves them out. Where the swarm starts changes which distances to the goal the robots see, not what a robot
# observes or does, so demonstrations from wider starts teach the distances that larger swarms span.
EPISODE_ONLY_KWARGS = ("n_robots", "start_radius")
_LOSS = {
    "loss": "mean per-sample NLL of the recorded action (one sample = one robot at one frame, Categorical(2))",
    "trained": "actor only",
}


# ------------------------------------------------------------------------------------------------ relabelling


def robot_actions(actions: np.ndarray, n_robots: int) -> np.ndarray:
    """Each robot's recorded 0/1 action, ``[T, N]`` int64, from a dataset's ``action`` column: ``[T, N]`` floats
    (MultiBinary, or a continuous action that only took 0 and 1) or ``[T, 1]`` int64 (``action_type="discrete"``,
    robot 0 the most significant bit). A ValueError for a continuous action between 0 and 1."""
    actions = np.asarray(actions)
    if actions.dtype.kind in "iu" and actions.shape[1:] == (1,):
        return ((actions.reshape(-1, 1) & joint_action_bits(n_robots)) > 0).astype(np.int64)
    if actions.shape[1:] != (n_robots,):
        raise ValueError(f"expected actions of shape [T, {n_robots}] (one per robot), got {actions.shape}")
    binary = (actions == 0) | (actions == 1)
    if not binary.all():
        value = actions[~binary].flat[0]
        raise ValueError(f"per-robot BC clones 0/1 actions (contract/expand); the dataset holds {value!r}")
    return actions.astype(np.int64)


def relabel_episode(
    states: np.ndarray,
    actions: np.ndarray,
    layout: LocalObservation,
    n_robots: int,
    neighbour_range: float,
    frame_index: np.ndarray | None = None,
    dead: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """One recorded episode as per-robot samples: ``(rows [T*N, layout.size] float32, labels [T*N] int64)``, frame
    by frame, robot 0 first. ``states`` ``[T, D]`` are the observations the actions were taken on, ``actions``
    ``[T, N]`` 0/1 (see :func:`robot_actions`), ``frame_index`` each frame's step in its episode (the clock; 0, 1,
    ... by default), ``dead`` one bool per robot (needed with ``layout.dead_flag``)."""
    states = np.asarray(states)
    frames = len(states)
    if len(actions) != frames:
        raise ValueError(f"{frames} states but {len(actions)} actions")
    steps = np.arange(frames) if frame_index is None else np.asarray(frame_index).reshape(frames)
    rows = np.empty((frames, n_robots, layout.size), dtype=np.float32)
    for t in range(frames):
        rows[t] = layout.observe(states[t], n_robots, neighbour_range, int(steps[t]), dead)
    return rows.reshape(frames * n_robots, layout.size), np.asarray(actions, dtype=np.int64).reshape(-1)


def episode_dead_robots(env_id: str, env_kwargs: dict[str, Any], seed: int) -> np.ndarray:
    """Which robots were dead in the episode recorded from ``reset(seed=seed)`` with ``env_kwargs`` (bool per
    robot): the env draws them at the reset from its seeded generator, so resetting it again gives them back."""
    import dpr  # noqa: F401  (registers the ids)

    kwargs = {k: v for k, v in env_kwargs.items() if k not in ("render_mode", "render_size", "max_episode_steps")}
    env = gym.make(env_id, **kwargs)
    try:
        env.reset(seed=int(seed))
        return env.unwrapped.world.dead.copy()
    finally:
        env.close()


def relabel_dataset(
    reader: LeRobotReader,
    env_id: str,
    layout: LocalObservation,
    episodes: list[int] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-robot samples (rows, labels) of ``episodes`` (all by default) of the dataset read by ``reader``,
    recorded on ``env_id``; its swarm size and robot model come from the episodes' env kwargs."""
    kwargs, _ = dataset_env(reader, env_id)
    n_robots = int(kwargs["n_robots"])
    neighbour_range = float(swarm_class(kwargs.get("robot_model", "paddle")).magnet_range)
    columns = [OBSERVATION, ACTION] + ([FRAME_INDEX] if FRAME_INDEX in reader.features else [])
    parts_rows, parts_labels = [], []
    for index in range(reader.num_episodes) if episodes is None else episodes:
        data = reader.episode(index, columns)
        dead = episode_dead_robots(env_id, kwargs, reader.episodes[index][SEED]) if layout.dead_flag else None
        rows, labels = relabel_episode(
            data[OBSERVATION],
            robot_actions(data[ACTION], n_robots),
            layout,
            n_robots,
            neighbour_range,
            data.get(FRAME_INDEX),
            dead,
        )
        parts_rows.append(rows)
        parts_labels.append(labels)
    if not parts_rows:
        return np.zeros((0, layout.size), np.float32), np.zeros(0, np.int64)
    return np.concatenate(parts_rows), np.concatenate(parts_labels)


# ------------------------------------------------------------------------------------------------ training


def _measure(policy, rows: torch.Tensor, labels: torch.Tensor, batch_size: int, prefix: str) -> dict[str, Any]:
    policy.set_training_mode(False)
    meter = AccuracyMeter(1)
    with torch.no_grad():
        for start in range(0, len(rows), batch_size):
            observation, action = rows[start : start + batch_size], labels[start : start + batch_size]
            nll, correct = batch_stats(policy, observation, action)
            meter.add(nll, correct[:, None], action[:, None])
    result = meter.result(prefix)
    del result[f"{prefix}_accuracy_per_robot"], result[f"{prefix}_exact_match"]  # one action: both are accuracy
    return result


def _train_epoch(policy, optimizer, rows, labels, batch_size: int, generator: torch.Generator) -> dict[str, Any]:
    policy.set_training_mode(True)
    meter = AccuracyMeter(1)
    for batch in torch.randperm(len(rows), generator=generator).split(batch_size):
        observation, action = rows[batch], labels[batch]
        nll, correct = batch_stats(policy, observation, action)
        loss = nll.mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        meter.add(nll, correct[:, None], action[:, None])
    result = meter.result("train")
    del result["train_accuracy_per_robot"], result["train_exact_match"]
    return result


def _read_datasets(
    dataset_dirs, env_id: str, requested: dict[str, Any] | None
) -> tuple[list[LeRobotReader], list[dict], list[int | None]]:
    """Readers, env kwargs and episode lengths of the datasets; they may differ in EPISODE_ONLY_KWARGS only, and
    must have the ``requested`` kwargs' values."""
    dataset_dirs = [dataset_dirs] if isinstance(dataset_dirs, (str, Path)) else list(dataset_dirs)
    if not dataset_dirs:
        raise ParameterError("dataset_dirs", "give at least one dataset")
    readers = [LeRobotReader(path) for path in dataset_dirs]  # DatasetError naming a folder that is not a dataset
    recorded = [dataset_env(reader, env_id, requested) for reader in readers]
    kwargs = [k for k, _ in recorded]

    def shared(k: dict) -> dict:
        return {name: value for name, value in k.items() if name not in EPISODE_ONLY_KWARGS}

    for reader, other in zip(readers[1:], kwargs[1:]):
        if shared(other) != shared(kwargs[0]):
            raise ParameterError(
                "dataset_dirs",
                f"{reader.root} was recorded with {shared(other)}, {readers[0].root} with {shared(kwargs[0])}; "
                f"datasets cloned together may differ in {' and '.join(EPISODE_ONLY_KWARGS)} only",
            )
    return readers, kwargs, [steps for _, steps in recorded]


def default_run_dir(env_id: str, algo: str, seed: int) -> Path:
    """``runs/bc-decentralised/<task>-<algo>-seed<S>-<timestamp>`` (a suffix when two runs start together)."""
    return runs.default_run_dir(RUNS_DIR, env_id, algo, seed)


def check_per_robot_hyperparams(hyper: Hyperparams) -> None:
    """A :class:`ParameterError` about ``hyperparams`` unless the yaml entry builds a model of one robot's vector."""
    if hyper.env_kwargs:
        raise ParameterError("hyperparams", f"a per-robot model takes no yaml env_kwargs, got {hyper.env_kwargs}")
    if (hyper.algo_kwargs.get("policy_kwargs") or {}).get("features_extractor", "flatten") != "flatten":
        raise ParameterError("hyperparams", "a per-robot model reads one robot's vector: features_extractor flatten")


def check_recorded_frames(env_id: str, readers: list[LeRobotReader], kwargs_list: list[dict[str, Any]]) -> None:
    """Check that each dataset's frames fit the spaces of the centralised env it was recorded on."""
    for reader, recorded in zip(readers, kwargs_list):
        probe = gym.make(env_id, **recorded)
        try:
            check_features(reader, probe.observation_space, probe.action_space, f"{env_id} {recorded}")
        finally:
            probe.close()


def swarm_env_and_spec(
    env_id: str, kwargs: dict[str, Any], n_values: list[int], clock_period: int, config: PerRobotCloneConfig
):
    """The PettingZoo env whose agents' spaces the model gets (local observations of ``config``'s layout, on the
    task's kwargs), and the model's :class:`RobotModelSpec` (it learned on swarms of ``n_values`` robots)."""
    from dpr.envs.parallel import parallel_env

    robot_model = kwargs.get("robot_model", "paddle")
    swarm_env = parallel_env(
        TASKS[env_id],
        n_robots=n_values[0],
        local_obs=True,
        max_neighbours=config.max_neighbours,
        clock_period=clock_period,
        distance_period=config.distance_length,
        **task_kwargs(kwargs),
    )
    layout = swarm_env.local_layout
    spec = RobotModelSpec(
        robot_model,
        config.max_neighbours,
        clock_period,
        layout.dead_flag,
        layout.has_object,
        MODEL_DEFAULTS[robot_model]["hold_steps"] if config.hold_steps is None else config.hold_steps,
        config.n_phases,
        tuple(sorted(set(n_values))),
        layout.distance_period,
    )
    return swarm_env, spec


def task_kwargs(kwargs: dict[str, Any]) -> dict[str, Any]:
    """The recorded env kwargs a per-robot model depends on: those of neither the centralised env nor the
    episodes."""
    return {k: v for k, v in kwargs.items() if k not in (*CENTRALISED_ONLY_KWARGS, *EPISODE_ONLY_KWARGS)}


def split_datasets(readers: list[LeRobotReader], val_fraction: float, seed: int) -> list[tuple[list[int], list[int]]]:
    """The training and validation episodes of each dataset: whole episodes of every dataset with two or more are
    held out; a :class:`ParameterError` about ``dataset_dirs`` when none has two."""
    splits = []
    for reader in readers:
        if reader.num_episodes >= 2:
            splits.append(split_episodes(reader.num_episodes, val_fraction, seed))
        else:
            splits.append((list(range(reader.num_episodes)), []))
    if not any(val for _, val in splits):
        raise ParameterError("dataset_dirs", "behaviour cloning needs a dataset of at least 2 episodes (one held out)")
    return splits


@dataclass
class PerRobotInputs:
    """What a per-robot cloning run learns from and builds, checked before anything is written: the datasets
    (``readers``, each one's swarm size in ``n_values`` and its training and validation episodes in ``splits``),
    the env kwargs the model depends on (:func:`task_kwargs`) and its episode length, the yaml entry of the model,
    the PettingZoo env whose agents' spaces it gets, and its :class:`RobotModelSpec`."""

    readers: list[LeRobotReader]
    n_values: list[int]
    splits: list[tuple[list[int], list[int]]]
    model_kwargs: dict[str, Any]
    steps: int
    hyper: Hyperparams
    swarm_env: Any
    spec: RobotModelSpec

    @property
    def episode_ids(self) -> tuple[list[int], list[int]]:
        """Every dataset's training episodes, one after the other, and its validation ones."""
        return [i for train, _ in self.splits for i in train], [i for _, val in self.splits for i in val]

    def new_model(self, seed: int):
        """The untrained model on the swarm env's agents, built as PPO fine-tunes it (torch seeded first)."""
        from dpr.envs.parallel import AgentsAsVecEnv
        from dpr.policies.sb3 import build_model

        torch.manual_seed(seed)
        venv = AgentsAsVecEnv(self.swarm_env)
        try:
            return build_model(self.hyper, venv, seed, None)
        finally:
            venv.close()

    def record(self, config: PerRobotCloneConfig, env_id: str) -> dict[str, Any]:
        """What the run resolved, as its config.yaml says it."""
        datasets = [
            {
                "dataset": str(r.root.resolve()),
                "n_robots": n,
                "episodes": r.num_episodes,
                "frames": r.num_frames,
                "train_episodes": train,
                "val_episodes": val,
            }
            for r, n, (train, val) in zip(self.readers, self.n_values, self.splits)
        ]
        return {
            "algo": config.algo,
            "env_id": env_id,
            "env_kwargs": self.model_kwargs,
            "per_robot": self.spec.as_dict(),
            "steps_per_episode": self.steps,
            "datasets": datasets,
            "bc": {**config.fit_record(), "optimizer": "Adam", **_LOSS},
            "hyperparameters": self.hyper.as_dict(),
            "versions": runs.package_versions(),
            "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        }


def check_inputs(
    dataset_dirs: str | Path | list[str | Path], env_id: str, config: PerRobotCloneConfig
) -> PerRobotInputs:
    """Read and check the datasets and the model's settings (module docstring): a ValueError naming what is wrong,
    before anything is written."""
    readers, kwargs_list, steps_list = _read_datasets(dataset_dirs, env_id, config.env_kwargs)
    robot_model = kwargs_list[0].get("robot_model", "paddle")
    clock_period = wave_env_kwargs(robot_model, config.hold_steps, config.n_phases)["clock_period"]
    hyper = load_hyperparams(config.algo, env_id, overrides=config.hyperparams)
    check_per_robot_hyperparams(hyper)
    check_recorded_frames(env_id, readers, kwargs_list)
    n_values = [int(k["n_robots"]) for k in kwargs_list]
    swarm_env, spec = swarm_env_and_spec(env_id, kwargs_list[0], n_values, clock_period, config)
    splits = split_datasets(readers, config.val_fraction, config.seed)
    steps = int(steps_list[0]) if steps_list[0] else MAX_EPISODE_STEPS
    return PerRobotInputs(readers, n_values, splits, task_kwargs(kwargs_list[0]), steps, hyper, swarm_env, spec)


@dataclass(frozen=True)
class RobotSamples:
    """The per-robot samples of a run: training rows and labels, and validation ones, all of them and by swarm
    size (numpy)."""

    train_rows: torch.Tensor
    train_labels: torch.Tensor
    val_rows: torch.Tensor
    val_labels: torch.Tensor
    val_by_n: dict[int, tuple[np.ndarray, np.ndarray]]


def relabel_splits(inputs: PerRobotInputs, env_id: str) -> RobotSamples:
    """Every dataset's training and validation episodes relabelled into per-robot samples (:func:`relabel_dataset`)
    of the swarm env's local layout."""
    readers, n_values, splits, layout = inputs.readers, inputs.n_values, inputs.splits, inputs.swarm_env.local_layout
    train_parts = [relabel_dataset(r, env_id, layout, train) for r, (train, _) in zip(readers, splits)]
    val_parts = {n: relabel_dataset(r, env_id, layout, val) for r, n, (_, val) in zip(readers, n_values, splits) if val}
    return RobotSamples(
        torch.from_numpy(np.concatenate([rows for rows, _ in train_parts])),
        torch.from_numpy(np.concatenate([labels for _, labels in train_parts])),
        torch.from_numpy(np.concatenate([rows for rows, _ in val_parts.values()])),
        torch.from_numpy(np.concatenate([labels for _, labels in val_parts.values()])),
        val_parts,
    )


def fit_samples(
    policy, samples: RobotSamples, config: PerRobotCloneConfig, title: str, show_progress: bool
) -> EarlyStoppedFit:
    """Train ``policy``'s actor on the training samples with a fresh Adam, epoch after epoch, early-stopped on the
    validation samples (:func:`fit_with_early_stopping`); validation rows also give the accuracy at each swarm size
    when there are several. A progress bar called ``title`` counts the epochs."""
    from tqdm import tqdm

    optimizer = torch.optim.Adam(trained_parameters(policy), lr=config.lr)
    generator = torch.Generator().manual_seed(config.seed)
    batch_size, measured = config.batch_size, 4 * config.batch_size

    def validation() -> dict[str, Any]:
        row = _measure(policy, samples.val_rows, samples.val_labels, measured, "val")
        if len(samples.val_by_n) > 1:
            row["val_accuracy_by_n"] = {
                n: _measure(policy, torch.from_numpy(r), torch.from_numpy(y), measured, "val")["val_accuracy"]
                for n, (r, y) in samples.val_by_n.items()
            }
        return row

    def run_epoch(epoch: int) -> dict[str, Any]:
        trained = _train_epoch(policy, optimizer, samples.train_rows, samples.train_labels, batch_size, generator)
        row = {**trained, **validation()}
        bar.update(1)
        return row

    first = {**_measure(policy, samples.train_rows, samples.train_labels, measured, "train"), **validation()}
    with tqdm(total=config.epochs, desc=title, unit="epoch", disable=not show_progress) as bar:
        return fit_with_early_stopping(policy, first, run_epoch, config.epochs, config.patience, bar)


def behaviour_clone_per_robot(
    dataset_dirs: str | Path | list[str | Path],
    env_id: str,
    config: PerRobotCloneConfig | None = None,
    *,
    out: str | Path | None = None,
    show_progress: bool = False,
    log: Callable[[str], None] = lambda line: print(line, file=sys.stderr),
) -> BCResult:
    """Clone the robots' actions in ``dataset_dirs`` (one or more datasets recorded by ``dpr collect`` on
    ``env_id``, possibly of different swarm sizes and start radii, otherwise with the same env kwargs) into a new
    per-robot ``config.algo`` model (module docstring) with the local observation and fit ``config`` says (default
    :class:`PerRobotCloneConfig`); save ``model.zip``, ``bc_log.json`` and ``config.yaml`` into ``out`` (a new or
    empty folder; default ``runs/bc-decentralised/<task>-<algo>-seed<S>-<timestamp>``).

    The clock's period is one wave cycle of the robot model: ``config.hold_steps`` (the robot model's wave hold by
    default, as the decentralised wave) x ``config.n_phases``; with the decentralised wave as the teacher, they must
    be the values it ran with. Bad input raises ValueError (bad settings when ``config`` is made) before anything
    is written."""
    config = PerRobotCloneConfig() if config is None else config
    algo, seed = config.algo, config.seed
    check_env_id(env_id)
    runs.check_new_folder(out)
    inputs = check_inputs(dataset_dirs, env_id, config)

    run_dir = Path(out) if out is not None else default_run_dir(env_id, algo, seed)
    record = inputs.record(config, env_id)
    config_path = start_run(run_dir, record)
    datasets_text = ", ".join(f"{r.root} (N={n})" for r, n in zip(inputs.readers, inputs.n_values))
    log(f"dpr bc-decentralised: per-robot {algo} on {env_id} {inputs.model_kwargs} from {datasets_text} -> {run_dir}")
    started = time.perf_counter()
    samples = relabel_splits(inputs, env_id)
    log(
        f"dpr bc-decentralised: {len(samples.train_rows)} training / {len(samples.val_rows)} validation robot-frames "
        f"(relabelled in {time.perf_counter() - started:.0f} s)"
    )

    model = inputs.new_model(seed)
    fit = fit_samples(model.policy, samples, config, f"bc-decentralised {algo} {env_id}", show_progress)

    model_path = run_dir / "model.zip"
    model.save(model_path)
    info = ModelInfo(algo, env_id, inputs.model_kwargs, inputs.steps, per_robot=inputs.spec.as_dict())
    write_model_info(model_path, info)
    best = fit.best
    extra = {"best_val_expand_recall": best["val_expand_recall"]}
    result = finish_bc_run(run_dir, model_path, config_path, record, fit, *inputs.episode_ids, **extra)
    log(
        f"dpr bc-decentralised: wrote {model_path} (best epoch {best['epoch']}: validation accuracy "
        f"{best['val_accuracy']:.4f}, expansion recall {best['val_expand_recall']:.4f}; {fit.seconds:.0f} s)"
    )
    return result
