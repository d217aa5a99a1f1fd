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
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
import yaml

from dpr import runs
from dpr.checks import ParameterError, check_int, check_number
from dpr.datasets.features import ACTION, OBSERVATION, SEED
from dpr.datasets.lerobot import LeRobotReader
from dpr.envs import MAX_EPISODE_STEPS, TASKS
from dpr.envs.local_obs import MAX_NEIGHBOURS, LocalObservation
from dpr.envs.particle_env import joint_action_bits
from dpr.imitation.bc import (
    AccuracyMeter,
    BCResult,
    check_bc_arguments,
    dataset_env,
    finish_bc_run,
    fit_with_early_stopping,
    split_episodes,
)
from dpr.imitation.loss import batch_stats, check_features
from dpr.policies.decentralised import DEFAULT_N_PHASES, MODEL_DEFAULTS, wave_env_kwargs
from dpr.policies.hyperparams import load_hyperparams
from dpr.policies.per_robot_spec import RobotModelSpec
from dpr.policies.sb3 import DEFAULT_ALGO, FINETUNE_ALGOS, ModelInfo, trained_parameters, write_model_info
from dpr.policies.wave import BIN_WIDTH
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
WAVE_LENGTH = "wave"  # distance_period: one wave length, n_phases x the wave's bin width
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


def behaviour_clone_per_robot(
    dataset_dirs: str | Path | list[str | Path],
    env_id: str,
    *,
    algo: str = DEFAULT_ALGO,
    max_neighbours: int = MAX_NEIGHBOURS,
    hold_steps: int | None = None,
    n_phases: int = DEFAULT_N_PHASES,
    distance_period: float | str | None = WAVE_LENGTH,
    epochs: int = 20,
    batch_size: int = 512,
    lr: float = 1e-3,
    val_fraction: float = 0.2,
    patience: int = 3,
    seed: int = 0,
    out: str | Path | None = None,
    env_kwargs: dict[str, Any] | None = None,
    hyperparams: dict[str, Any] | None = None,
    show_progress: bool = False,
    log: Callable[[str], None] = lambda line: print(line, file=sys.stderr),
) -> BCResult:
    """Clone the robots' actions in ``dataset_dirs`` (one or more datasets recorded by ``dpr collect`` on
    ``env_id``, possibly of different swarm sizes and start radii, otherwise with the same env kwargs) into a new
    per-robot ``algo`` model (module docstring); save ``model.zip``, ``bc_log.json`` and ``config.yaml`` into
    ``out`` (a new or empty folder; default ``runs/bc-decentralised/<task>-<algo>-seed<S>-<timestamp>``).

    The local observation has ``max_neighbours`` neighbour slots and a clock whose period is one wave cycle of the
    robot model: ``hold_steps`` (the robot model's wave hold by default, as the decentralised wave) x ``n_phases``;
    with the decentralised wave as the teacher, they must be the values it ran with. ``distance_period`` replaces
    the raw distance to the goal by its phase (:class:`~dpr.envs.local_obs.LocalObservation`): ``"wave"`` (the
    default) one wave length, ``n_phases`` x the wave's bin width, so that a robot senses its band of the wave and
    nothing that grows with the swarm; a length in world units; or None for the raw distance. ``hyperparams``
    override the algorithm's yaml entry for ``env_id`` (the network). Bad input raises ValueError before anything is
    written."""
    from dpr.envs.parallel import AgentsAsVecEnv, parallel_env
    from dpr.policies.sb3 import build_model

    if algo not in FINETUNE_ALGOS:
        raise ParameterError("algo", f"a per-robot model is an actor-critic: one of {FINETUNE_ALGOS}, got {algo!r}")
    check_bc_arguments(env_id, algo, epochs, batch_size, lr, val_fraction, patience, seed)
    check_int("max_neighbours", max_neighbours, 1)
    runs.check_new_folder(out)
    if "n_robots" in (env_kwargs or {}):
        raise ParameterError("env_kwargs", "n_robots is each dataset's own; a per-robot model runs any N")
    readers, kwargs_list, steps_list = _read_datasets(dataset_dirs, env_id, env_kwargs)
    kwargs = kwargs_list[0]
    robot_model = kwargs.get("robot_model", "paddle")
    clock_period = wave_env_kwargs(robot_model, hold_steps, n_phases)["clock_period"]
    if distance_period == WAVE_LENGTH:
        distance_period = n_phases * BIN_WIDTH
    elif distance_period is not None:
        distance_period = check_number("distance_period", distance_period, above=0)
    hold = MODEL_DEFAULTS[robot_model]["hold_steps"] if hold_steps is None else hold_steps
    hyper = load_hyperparams(algo, env_id, overrides=hyperparams)
    if hyper.env_kwargs:
        raise ParameterError("hyperparams", f"a per-robot model takes no yaml env_kwargs, got {hyper.env_kwargs}")
    if (hyper.algo_kwargs.get("policy_kwargs") or {}).get("features_extractor", "flatten") != "flatten":
        raise ParameterError("hyperparams", "a per-robot model reads one robot's vector: features_extractor flatten")
    for reader, recorded in zip(readers, kwargs_list):  # the frames must be the recorded env's
        probe = gym.make(env_id, **recorded)
        try:
            check_features(reader, probe.observation_space, probe.action_space, f"{env_id} {recorded}")
        finally:
            probe.close()
    task_kwargs = {k: v for k, v in kwargs.items() if k not in (*CENTRALISED_ONLY_KWARGS, *EPISODE_ONLY_KWARGS)}
    n_values = [int(k["n_robots"]) for k in kwargs_list]
    swarm_env = parallel_env(
        TASKS[env_id],
        n_robots=n_values[0],
        local_obs=True,
        max_neighbours=max_neighbours,
        clock_period=clock_period,
        distance_period=distance_period,
        **task_kwargs,
    )
    layout = swarm_env.local_layout
    spec = RobotModelSpec(
        robot_model,
        max_neighbours,
        clock_period,
        layout.dead_flag,
        layout.has_object,
        hold,
        n_phases,
        tuple(sorted(set(n_values))),
        layout.distance_period,
    )
    splits = []
    for reader in readers:  # whole episodes of every dataset with two or more are held out
        if reader.num_episodes >= 2:
            splits.append(split_episodes(reader.num_episodes, val_fraction, seed))
        else:
            splits.append((list(range(reader.num_episodes)), []))
    if not any(val for _, val in splits):
        raise ParameterError("dataset_dirs", "behaviour cloning needs a dataset of at least 2 episodes (one held out)")

    run_dir = Path(out) if out is not None else default_run_dir(env_id, algo, seed)
    run_dir.mkdir(parents=True, exist_ok=True)
    steps = int(steps_list[0]) if steps_list[0] else MAX_EPISODE_STEPS
    record: dict[str, Any] = {
        "algo": algo,
        "env_id": env_id,
        "env_kwargs": task_kwargs,
        "per_robot": spec.as_dict(),
        "steps_per_episode": steps,
        "datasets": [
            {
                "dataset": str(r.root.resolve()),
                "n_robots": n,
                "episodes": r.num_episodes,
                "frames": r.num_frames,
                "train_episodes": train,
                "val_episodes": val,
            }
            for r, n, (train, val) in zip(readers, n_values, splits)
        ],
        "bc": {
            "epochs": epochs,
            "batch_size": batch_size,
            "lr": lr,
            "val_fraction": val_fraction,
            "patience": patience,
            "seed": seed,
            "optimizer": "Adam",
            **_LOSS,
        },
        "hyperparameters": hyper.as_dict(),
        "versions": runs.package_versions(),
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    config_path = run_dir / "config.yaml"
    config_path.write_text(yaml.safe_dump(record, sort_keys=False))
    datasets_text = ", ".join(f"{r.root} (N={n})" for r, n in zip(readers, n_values))
    log(f"dpr bc-decentralised: per-robot {algo} on {env_id} {task_kwargs} from {datasets_text} -> {run_dir}")

    started = time.perf_counter()
    train_parts = [relabel_dataset(r, env_id, layout, train) for r, (train, _) in zip(readers, splits)]
    val_parts = {n: relabel_dataset(r, env_id, layout, val) for r, n, (_, val) in zip(readers, n_values, splits) if val}
    train_rows = torch.from_numpy(np.concatenate([rows for rows, _ in train_parts]))
    train_labels = torch.from_numpy(np.concatenate([labels for _, labels in train_parts]))
    val_rows = torch.from_numpy(np.concatenate([rows for rows, _ in val_parts.values()]))
    val_labels = torch.from_numpy(np.concatenate([labels for _, labels in val_parts.values()]))
    log(
        f"dpr bc-decentralised: {len(train_rows)} training / {len(val_rows)} validation robot-frames "
        f"(relabelled in {time.perf_counter() - started:.0f} s)"
    )

    torch.manual_seed(seed)
    venv = AgentsAsVecEnv(swarm_env)
    try:
        model = build_model(hyper, venv, seed, None)
    finally:
        venv.close()
    policy = model.policy
    optimizer = torch.optim.Adam(trained_parameters(policy), lr=lr)
    generator = torch.Generator().manual_seed(seed)

    def validation() -> dict[str, Any]:
        row = _measure(policy, val_rows, val_labels, 4 * batch_size, "val")
        if len(val_parts) > 1:
            row["val_accuracy_by_n"] = {
                n: _measure(policy, torch.from_numpy(r), torch.from_numpy(y), 4 * batch_size, "val")["val_accuracy"]
                for n, (r, y) in val_parts.items()
            }
        return row

    from tqdm import tqdm

    def run_epoch(epoch: int) -> dict[str, Any]:
        row = {**_train_epoch(policy, optimizer, train_rows, train_labels, batch_size, generator), **validation()}
        bar.update(1)
        return row

    first = {**_measure(policy, train_rows, train_labels, 4 * batch_size, "train"), **validation()}
    with tqdm(total=epochs, desc=f"bc-decentralised {algo} {env_id}", unit="epoch", disable=not show_progress) as bar:
        fit = fit_with_early_stopping(policy, first, run_epoch, epochs, patience, bar)

    model_path = run_dir / "model.zip"
    model.save(model_path)
    write_model_info(model_path, ModelInfo(algo, env_id, task_kwargs, steps, per_robot=spec.as_dict()))
    train_ids = [i for train, _ in splits for i in train]
    val_ids = [i for _, val in splits for i in val]
    best = fit.best
    result = finish_bc_run(
        run_dir,
        model_path,
        config_path,
        record,
        fit,
        train_ids,
        val_ids,
        best_val_expand_recall=best["val_expand_recall"],
    )
    log(
        f"dpr bc-decentralised: wrote {model_path} (best epoch {best['epoch']}: validation accuracy "
        f"{best['val_accuracy']:.4f}, expansion recall {best['val_expand_recall']:.4f}; {fit.seconds:.0f} s)"
    )
    return result
