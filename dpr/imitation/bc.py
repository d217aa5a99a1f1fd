"""Behaviour cloning of a recorded dataset into the same stable-baselines3 model that ``dpr train`` builds.

The model is built exactly as ``dpr train`` would build it for ``algo`` on ``env_id``
(:func:`dpr.policies.sb3.build_model` from the yaml entry of :mod:`dpr.policies.hyperparams`, the env kwargs the
dataset was recorded with), then ``model.policy`` is trained in plain torch to maximise the log-likelihood of the
recorded actions under the policy's own action distribution (MultiBinary -> one Bernoulli per robot; the loss is
:mod:`dpr.imitation.loss`). What is trained, and what is not:

- the actor only: the features extractor, ``mlp_extractor.policy_net`` and ``action_net``. The value head
  (``mlp_extractor.value_net``, ``value_net``) is left at its initialisation: the dataset holds no returns worth
  regressing on for a policy other than the demonstrator, and PPO/A2C fit the critic in their first updates;
- no normalisation beyond what SB3's policy does itself (for a Box observation: none; the state observation is
  already scaled by 1/1000 in the env), so the cloned model runs unchanged in ``dpr evaluate`` and in PPO/A2C;
- the policy's own optimizer (saved with the model, used by ``learn``) is not touched: BC uses a fresh Adam.

Validation holds out whole episodes (frames of one episode are strongly correlated, so a frame-level split would
overstate generalisation). Training stops early when the validation log-likelihood has not improved for
``patience`` epochs, and the best-validation weights are restored before saving.

A run writes into a new folder: ``model.zip`` (with the env id and kwargs inside, see :mod:`dpr.policies.model_file`),
``bc_log.json`` (per-epoch metrics) and ``config.yaml`` (everything the run resolved).

DQN (``algo="dqn"``) learns over Discrete(2^N) actions: each recorded MultiBinary action becomes the integer
whose most significant bit is robot 0 (the env's own encoding), and the Q-network is trained as a classifier,
its Q-values the logits of a softmax over the 2^N actions (cross-entropy); the target network is then set to
the trained Q-network. The model runs on the same env with ``action_type="discrete"``.
"""

from __future__ import annotations

import copy
import json
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
import yaml
from torch.utils.data import DataLoader

from dpr import runs
from dpr.checks import ParameterError
from dpr.datasets import features
from dpr.datasets.frames import ConcatFrames, EpisodeBlockSampler, FrameDataset
from dpr.datasets.lerobot import LeRobotReader
from dpr.envs import MAX_EPISODE_STEPS
from dpr.imitation.config import CloneConfig, check_env_id
from dpr.imitation.loss import batch_stats, check_features
from dpr.policies.distributions import unchecked_distributions
from dpr.policies.hyperparams import Hyperparams, load_hyperparams
from dpr.policies.model_file import DQN, ModelInfo, model_architecture, write_model_info
from dpr.policies.sb3 import trained_parameters

__all__ = ["BCResult", "behaviour_clone", "dataset_env"]

RUNS_DIR = Path("runs/bc")
# Recording-only env kwargs: they change how a dataset was rendered, not what the model sees or does.
RECORDING_KWARGS = ("render_mode", "render_size")
# What a run's config.yaml says was trained, and on what loss.
_ACTOR_CRITIC_LOSS = {
    "loss": "mean per-frame NLL of the recorded action (Bernoulli per robot, summed over robots)",
    "trained": "actor only",
}
_DQN_LOSS = {
    "loss": "mean per-frame cross-entropy of the recorded action's index among the 2^N Q-values",
    "trained": "Q-network, then copied into the target network",
}
BLOCK_EPISODES = 8  # EpisodeBlockSampler block; the FrameDataset cache holds as many episodes


@dataclass(frozen=True)
class BCResult:
    """Where a BC run's files are, and how it ended."""

    run_dir: Path
    model_path: Path
    log_path: Path
    config_path: Path
    best_epoch: int
    best_val_nll: float
    best_val_accuracy: float
    epochs_run: int
    stopped_early: bool
    train_episodes: list[int] = field(default_factory=list)
    val_episodes: list[int] = field(default_factory=list)
    history: list[dict[str, Any]] = field(default_factory=list)


@dataclass
class EarlyStoppedFit:
    """What :func:`fit_with_early_stopping` did: every epoch's row (epoch 0 first), the best one, whether patience
    ran out, and the seconds spent."""

    history: list[dict[str, Any]]
    best: dict[str, Any]
    stopped_early: bool
    seconds: float


@unchecked_distributions()
def fit_with_early_stopping(
    policy, first_row: dict[str, Any], run_epoch: Callable[[int], dict[str, Any]], epochs: int, patience: int, bar
) -> EarlyStoppedFit:
    """Train up to ``epochs`` epochs (``run_epoch(epoch)`` trains one and returns its metrics, ``val_nll`` among
    them), keep the weights of the lowest validation NLL, stop after ``patience`` epochs without improving on it,
    and restore the best weights. ``first_row`` is epoch 0, the untrained policy every later epoch is compared
    with; ``bar`` (tqdm) shows the latest validation figures."""
    history = [{"epoch": 0, **first_row, "seconds": 0.0}]
    best, best_state, stale, stopped_early = history[0], copy.deepcopy(policy.state_dict()), 0, False
    started = time.perf_counter()
    for epoch in range(1, epochs + 1):
        tick = time.perf_counter()
        row = {"epoch": epoch, **run_epoch(epoch)}
        row["seconds"] = round(time.perf_counter() - tick, 3)
        history.append(row)
        bar.set_postfix(val_nll=f"{row['val_nll']:.3f}", val_acc=f"{row['val_accuracy']:.3f}", refresh=False)
        if row["val_nll"] < best["val_nll"]:
            best, stale, best_state = row, 0, copy.deepcopy(policy.state_dict())
        else:
            stale += 1
            if stale >= patience:
                stopped_early = True
                break
    policy.load_state_dict(best_state)
    policy.set_training_mode(False)
    return EarlyStoppedFit(history, best, stopped_early, time.perf_counter() - started)


def finish_bc_run(
    run_dir: Path,
    model_path: Path,
    config_path: Path,
    record: dict[str, Any],
    fit: EarlyStoppedFit,
    train_ids: list[int],
    val_ids: list[int],
    **extra: Any,
) -> BCResult:
    """Write ``bc_log.json`` (the summary and every epoch) and the finished ``config.yaml``; the run's result.
    ``extra``: further summary figures (best-epoch metrics beside NLL and accuracy)."""
    best = fit.best
    summary = {
        "best_epoch": best["epoch"],
        "best_val_nll": best["val_nll"],
        "best_val_accuracy": best["val_accuracy"],
        **extra,
        "epochs_run": len(fit.history) - 1,
        "stopped_early": fit.stopped_early,
        "train_episodes": train_ids,
        "val_episodes": val_ids,
        "seconds": round(fit.seconds, 1),
    }
    log_path = run_dir / "bc_log.json"
    log_path.write_text(json.dumps({**summary, "epochs": fit.history}, indent=2))
    record.update(summary, finished=time.strftime("%Y-%m-%dT%H:%M:%S%z"))
    config_path.write_text(yaml.safe_dump(record, sort_keys=False))
    return BCResult(
        run_dir,
        model_path,
        log_path,
        config_path,
        best["epoch"],
        best["val_nll"],
        best["val_accuracy"],
        len(fit.history) - 1,
        fit.stopped_early,
        train_ids,
        val_ids,
        fit.history,
    )


# ------------------------------------------------------------------------------------------------ dataset -> env


def dataset_env(
    reader: LeRobotReader, env_id: str, requested: dict[str, Any] | None = None
) -> tuple[dict[str, Any], int | None]:
    """The env kwargs (without recording-only kwargs and ``max_episode_steps``) and the episode length that every
    episode of the dataset was recorded with. A :class:`ParameterError` about ``dataset_dirs`` naming both values
    when an episode was recorded on another env id, when episodes disagree, or when a ``requested`` kwarg differs
    from the dataset's."""
    root = reader.root
    if reader.num_episodes == 0:
        raise ParameterError("dataset_dirs", f"{root} holds no episodes")
    recorded: dict[str, Any] | None = None
    for index, meta in enumerate(reader.episodes):
        if features.ENV_ID not in meta or not isinstance(meta.get(features.ENV_KWARGS), dict):
            raise ParameterError(
                "dataset_dirs",
                f"episode {index} of {root} has no {features.ENV_ID}/"
                f"{features.ENV_KWARGS} metadata; use a dataset recorded by `dpr collect`",
            )
        if meta[features.ENV_ID] != env_id:
            raise ParameterError(
                "dataset_dirs",
                f"{root} was recorded on {meta[features.ENV_ID]} (episode {index}), "
                f"not on {env_id}; use a dataset of {env_id}, or env {meta[features.ENV_ID]}",
            )
        if recorded is None:
            recorded = dict(meta[features.ENV_KWARGS])
        elif meta[features.ENV_KWARGS] != recorded:
            raise ParameterError(
                "dataset_dirs",
                f"{root}: episode {index} was recorded with env kwargs "
                f"{meta[features.ENV_KWARGS]}, episode 0 with {recorded}; a dataset must hold one "
                "env configuration",
            )
    assert recorded is not None
    steps = recorded.pop("max_episode_steps", None)
    for name in RECORDING_KWARGS:
        recorded.pop(name, None)
    for name, value in (requested or {}).items():
        if name in recorded and recorded[name] != value:
            raise ParameterError(
                "dataset_dirs",
                f"{root} was recorded with {name}={recorded[name]!r}; the requested "
                f"{name}={value!r} differs (leave it out to use the dataset's value)",
            )
        recorded[name] = value
    return recorded, steps


def split_episodes(num_episodes: int, val_fraction: float, seed: int) -> tuple[list[int], list[int]]:
    """Dataset episode indices for training and validation (at least one each, disjoint, chosen by ``seed``)."""
    if num_episodes < 2:
        raise ParameterError(
            "dataset_dirs", f"behaviour cloning needs at least 2 episodes (one held out), got {num_episodes}"
        )
    n_val = min(max(1, round(val_fraction * num_episodes)), num_episodes - 1)
    order = np.random.default_rng(seed).permutation(num_episodes).tolist()
    return sorted(order[n_val:]), sorted(order[:n_val])


# ------------------------------------------------------------------------------------------------ training


class AccuracyMeter:
    """Running sums of NLL and correctness over an epoch. Per-robot accuracy alone flatters a policy that never
    expands (the wave contracts most robots most of the time), so the whole-action match rate and the recall of
    recorded expansions are kept too."""

    def __init__(self, n_actions: int):
        self.frames = 0
        self.nll = 0.0
        self.correct = np.zeros(n_actions, dtype=np.float64)
        self.exact = 0
        self.expansions = 0
        self.expansions_hit = 0

    def add(self, nll: torch.Tensor, correct: torch.Tensor, action: torch.Tensor) -> None:
        correct = correct.detach()
        self.frames += len(nll)
        self.nll += float(nll.detach().sum())
        self.correct += correct.double().sum(0).numpy()
        self.exact += int(correct.all(dim=1).sum())
        expanded = action > 0.5
        self.expansions += int(expanded.sum())
        self.expansions_hit += int((correct & expanded).sum())

    def result(self, prefix: str) -> dict[str, Any]:
        frames = max(self.frames, 1)
        per_robot = self.correct / frames
        return {
            f"{prefix}_nll": self.nll / frames,
            f"{prefix}_accuracy": float(per_robot.mean()),
            f"{prefix}_exact_match": self.exact / frames,
            f"{prefix}_expand_recall": self.expansions_hit / max(self.expansions, 1),
            f"{prefix}_accuracy_per_robot": [round(float(a), 6) for a in per_robot],
        }


def _loader(dataset: FrameDataset, batch_size: int, sampler: EpisodeBlockSampler) -> DataLoader:
    return DataLoader(dataset, batch_size=batch_size, sampler=sampler, num_workers=0)


@torch.no_grad()
def measure(policy, dataset: FrameDataset, batch_size: int, prefix: str) -> dict[str, Any]:
    """NLL and accuracy of ``policy`` on every frame of ``dataset`` (eval mode, no gradients)."""
    policy.set_training_mode(False)
    meter = AccuracyMeter(dataset.action_dim)
    for batch in _loader(dataset, batch_size, EpisodeBlockSampler(dataset, shuffle=False)):
        meter.add(*batch_stats(policy, batch["observation"], batch["action"]), batch["action"])
    return meter.result(prefix)


def _train_epoch(
    policy,
    optimizer,
    loader: DataLoader,
    n_actions: int,
    bar,
    previous_action: slice | None = None,
    change_weight: float = 1.0,
) -> dict[str, Any]:
    policy.set_training_mode(True)
    meter = AccuracyMeter(n_actions)
    for batch in loader:
        nll, correct = batch_stats(policy, batch["observation"], batch["action"])
        if previous_action is not None and change_weight != 1.0:
            # frames whose action differs from the one before are the policy's decisions; the rest repeat it
            changed = (batch["observation"][:, previous_action] != batch["action"]).any(dim=1)
            weights = torch.where(changed, change_weight, 1.0)
            loss = (nll * weights).sum() / weights.sum()
        else:
            loss = nll.mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        meter.add(nll, correct, batch["action"])
        bar.update(len(nll))
    return meter.result("train")


# ------------------------------------------------------------------------------------------------ run folder


def default_run_dir(env_id: str, algo: str, seed: int) -> Path:
    """``runs/bc/<task>-<algo>-seed<S>-<timestamp>`` (a suffix when two runs start in the same second)."""
    return runs.default_run_dir(RUNS_DIR, env_id, algo, seed)


def start_run(run_dir: Path, record: dict[str, Any]) -> Path:
    """Make ``run_dir`` and write ``record`` (what the run resolved) as its ``config.yaml``; that file's path.
    :func:`finish_bc_run` completes it."""
    run_dir.mkdir(parents=True, exist_ok=True)
    config_path = run_dir / "config.yaml"
    config_path.write_text(yaml.safe_dump(record, sort_keys=False))
    return config_path


# ------------------------------------------------------------------------------------------------ behaviour_clone


def read_matching_datasets(
    dataset_dirs: str | Path | list[str | Path], env_id: str, requested: dict[str, Any]
) -> tuple[list[LeRobotReader], dict[str, Any], int | None]:
    """Readers of the datasets, and the env kwargs and episode length (:func:`dataset_env`) that all of them were
    recorded with. A DatasetError names a folder that is not a dataset; datasets that differ are a
    :class:`ParameterError` about ``dataset_dirs`` naming both."""
    dataset_dirs = [dataset_dirs] if isinstance(dataset_dirs, (str, Path)) else list(dataset_dirs)
    if not dataset_dirs:
        raise ParameterError("dataset_dirs", "give at least one dataset")
    readers = [LeRobotReader(path) for path in dataset_dirs]
    reader = readers[0]
    kwargs, steps = dataset_env(reader, env_id, requested)
    for other in readers[1:]:
        recorded = dataset_env(other, env_id, requested)
        if recorded != (kwargs, steps):
            raise ParameterError(
                "dataset_dirs",
                f"{other.root} was recorded with {recorded}, "
                f"{reader.root} with {(kwargs, steps)}; datasets cloned together must match",
            )
    return readers, kwargs, steps


def model_env_kwargs(algo: str, hyper: Hyperparams, recorded: dict[str, Any], root: Path) -> dict[str, Any]:
    """The kwargs of the env the model acts on: the ``recorded`` ones (of the dataset at ``root``) with the
    algorithm's yaml env_kwargs over them, which must not contradict them (a :class:`ParameterError` about
    ``algo``)."""
    for name, value in hyper.env_kwargs.items():  # e.g. an algorithm that needs another action type
        # DQN's Discrete(2^N) actions are the recorded MultiBinary ones, encoded as integers
        converted = algo == DQN and name == "action_type" and recorded.get(name) == "multibinary"
        if name in recorded and recorded[name] != value and not converted:
            raise ParameterError(
                "algo",
                f"{algo} needs {name}={value!r} (its yaml env_kwargs); the dataset "
                f"{root} was recorded with {name}={recorded[name]!r}",
            )
    return {**recorded, **hyper.env_kwargs}


def check_frames_fit(
    env_id: str, kwargs: dict[str, Any], readers: list[LeRobotReader], change_weight: float
) -> slice | None:
    """Check that every dataset's frames fit the spaces of ``env_id`` made with ``kwargs`` (a bad kwarg fails here,
    before the run folder exists). The slice of the observation that holds the previous action (None without
    ``obs_last_action``), which a ``change_weight`` other than 1 needs."""
    probe = gym.make(env_id, **kwargs)
    try:
        for each in readers:
            check_features(each, probe.observation_space, probe.action_space, f"{env_id} {kwargs}")
        base = probe.unwrapped
        previous_action = (
            slice(base.memory_offset, base.memory_offset + base.n_robots) if base.obs_last_action else None
        )
    finally:
        probe.close()
    if change_weight != 1.0 and previous_action is None:
        raise ValueError(
            "change_weight needs the previous action in the observation: a dataset recorded with obs_last_action=True"
        )
    return previous_action


def clone_record(
    config: CloneConfig,
    env_id: str,
    kwargs: dict[str, Any],
    steps: int,
    readers: list[LeRobotReader],
    split: tuple[list[int], list[int]],
    hyper: Hyperparams,
) -> dict[str, Any]:
    """What a ``dpr bc`` run resolved, as its config.yaml says it: the model, the env, the datasets and the
    training (``split``) and validation episodes of the first, the fit."""
    reader = readers[0]
    return {
        "algo": config.algo,
        "env_id": env_id,
        "env_kwargs": kwargs,
        "steps_per_episode": steps,
        "dataset": str(reader.root.resolve()),
        "dataset_episodes": reader.num_episodes,
        "dataset_frames": reader.num_frames,
        "train_episodes": split[0],
        "val_episodes": split[1],
        "more_datasets": [
            {"dataset": str(r.root.resolve()), "episodes": r.num_episodes, "frames": r.num_frames} for r in readers[1:]
        ],
        "bc": {
            **config.fit_record(),
            "change_weight": config.change_weight,
            "optimizer": "Adam",
            **(_DQN_LOSS if config.algo == DQN else _ACTOR_CRITIC_LOSS),
        },
        "hyperparameters": hyper.as_dict(),
        "versions": runs.package_versions(),
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


def new_model(env_id: str, kwargs: dict[str, Any], steps: int, hyper: Hyperparams, seed: int):
    """The untrained SB3 model, built as ``dpr train`` builds it (torch seeded with ``seed`` first)."""
    from dpr.policies.sb3 import build_model, make_vec_env

    torch.manual_seed(seed)
    env = make_vec_env(env_id, kwargs, steps, 1)
    try:
        return build_model(hyper, env, seed, None)
    finally:
        env.close()


def frame_sets(
    readers: list[LeRobotReader], train_ids: list[int], val_ids: list[int]
) -> tuple[FrameDataset | ConcatFrames, FrameDataset]:
    """The training frames (the first dataset's ``train_ids`` episodes, then every episode of the others) and the
    validation frames (the first dataset's ``val_ids``)."""
    root = readers[0].root
    train_set = FrameDataset(root, episodes=train_ids, cache_episodes=BLOCK_EPISODES)
    if len(readers) > 1:
        train_set = ConcatFrames(
            [train_set, *(FrameDataset(r.root, cache_episodes=BLOCK_EPISODES) for r in readers[1:])]
        )
    return train_set, FrameDataset(root, episodes=val_ids, cache_episodes=BLOCK_EPISODES)


def fit_frames(
    policy,
    train_set: FrameDataset | ConcatFrames,
    val_set: FrameDataset,
    config: CloneConfig,
    previous_action: slice | None,
    title: str,
    show_progress: bool,
) -> EarlyStoppedFit:
    """Train ``policy``'s actor on ``train_set`` with a fresh Adam, epoch after epoch, early-stopped on
    ``val_set`` (:func:`fit_with_early_stopping`); a progress bar called ``title`` counts the frames."""
    from tqdm import tqdm

    sampler = EpisodeBlockSampler(train_set, block_episodes=BLOCK_EPISODES, seed=config.seed)
    loader = _loader(train_set, config.batch_size, sampler)
    optimizer = torch.optim.Adam(trained_parameters(policy), lr=config.lr)
    n_actions, change_weight = train_set.action_dim, config.change_weight

    def run_epoch(epoch: int) -> dict[str, Any]:
        sampler.set_epoch(epoch)
        return {
            **_train_epoch(policy, optimizer, loader, n_actions, bar, previous_action, change_weight),
            **measure(policy, val_set, config.batch_size, "val"),
        }

    # Epoch 0 is the untrained policy: the baseline every later epoch is compared with.
    first = {
        **measure(policy, train_set, config.batch_size, "train"),
        **measure(policy, val_set, config.batch_size, "val"),
    }
    with tqdm(total=config.epochs * len(train_set), desc=title, unit="frame", disable=not show_progress) as bar:
        return fit_with_early_stopping(policy, first, run_epoch, config.epochs, config.patience, bar)


def behaviour_clone(
    dataset_dirs: str | Path | list[str | Path],
    env_id: str,
    config: CloneConfig | None = None,
    *,
    out: str | Path | None = None,
    show_progress: bool = False,
    log: Callable[[str], None] = lambda line: print(line, file=sys.stderr),
) -> BCResult:
    """Behaviour-clone the dataset at ``dataset_dirs`` (recorded by ``dpr collect`` on ``env_id``; or a list of
    datasets of the same env, whose first one provides the validation episodes and the rest only train) into a new
    ``config.algo`` model built as ``dpr train`` builds it, fitted as ``config`` (default :class:`CloneConfig`)
    says; save it with ``bc_log.json`` and ``config.yaml`` into ``out`` (a new or empty folder; default
    ``runs/bc/<task>-<algo>-seed<S>-<timestamp>``).

    ``config.env_kwargs`` may restate kwargs (e.g. ``{"n_robots": 9}``); any that differ from the dataset's are an
    error. Bad input raises ValueError (DatasetError for an unreadable dataset; bad settings when ``config`` is made)
    before anything is written."""
    config = CloneConfig() if config is None else config
    algo, seed = config.algo, config.seed
    check_env_id(env_id)
    runs.check_new_folder(out)
    readers, recorded, steps = read_matching_datasets(dataset_dirs, env_id, config.env_kwargs)
    hyper = load_hyperparams(algo, env_id, overrides=config.hyperparams)
    kwargs = model_env_kwargs(algo, hyper, recorded, readers[0].root)
    steps = int(steps) if steps else MAX_EPISODE_STEPS
    previous_action = check_frames_fit(env_id, kwargs, readers, config.change_weight)
    train_ids, val_ids = split_episodes(readers[0].num_episodes, config.val_fraction, seed)

    run_dir = Path(out) if out is not None else default_run_dir(env_id, algo, seed)
    record = clone_record(config, env_id, kwargs, steps, readers, (train_ids, val_ids), hyper)
    config_path = start_run(run_dir, record)
    log(
        f"dpr bc: {algo} on {env_id} {kwargs} from {readers[0].root} ({len(train_ids)} train / {len(val_ids)} "
        f"validation episodes) -> {run_dir}"
    )
    model = new_model(env_id, kwargs, steps, hyper, seed)
    train_set, val_set = frame_sets(readers, train_ids, val_ids)
    fit = fit_frames(model.policy, train_set, val_set, config, previous_action, f"bc {algo} {env_id}", show_progress)
    if hasattr(model.policy, "q_net_target"):  # DQN bootstraps from its target network: start it at the clone
        model.policy.q_net_target.load_state_dict(model.policy.q_net.state_dict())

    model_path = run_dir / "model.zip"
    model.save(model_path)
    write_model_info(model_path, ModelInfo(algo, env_id, kwargs, steps, architecture=model_architecture(hyper)))
    result = finish_bc_run(run_dir, model_path, config_path, record, fit, train_ids, val_ids)
    best = fit.best
    log(
        f"dpr bc: wrote {model_path} (best epoch {best['epoch']}: validation per-robot accuracy "
        f"{best['val_accuracy']:.3f}, whole-action match {best['val_exact_match']:.3f}, expansion recall "
        f"{best['val_expand_recall']:.3f}; {fit.seconds:.0f} s)"
    )
    return result


def result_dict(result: BCResult) -> dict[str, Any]:
    """A :class:`BCResult` as plain data (paths as strings)."""
    return {k: str(v) if isinstance(v, Path) else v for k, v in asdict(result).items()}
