"""Training runs that survive being stopped: a run folder's ``resume/`` snapshot, and resuming from it to the same
model an uninterrupted run makes.

Every :data:`SNAPSHOT_SECONDS` (at the start of a rollout, when no step is in flight) a run writes its whole
training state into ``<run>/resume/``: the SB3 model's weights and optimizer state, its step counters and last
observation, each env's current episode as a :class:`dpr.envs.replay.ReplayLog` record (its random state at reset
and the actions since: the training envs' and the evaluation env's), the pending seeds of both vector envs, the
counters and results of the callbacks, and the torch, numpy and Python random states. :func:`dpr.rl.train.train`
with ``resume=True`` builds the run's model again, puts all of it back and goes on (as does
:func:`dpr.rl.finetune_per_robot.finetune_per_robot`, whose swarms are recorded by
:class:`dpr.envs.replay.ParallelReplayLog` and whose own state is the snapshot's ``extra``); the test
``tests/test_resume.py`` checks that the model it ends with is the one an uninterrupted run ends with, weight for
weight. A stopped run loses at most the last :data:`SNAPSHOT_SECONDS`. Runs of :data:`SNAPSHOT_ALGOS` keep
snapshots; DQN's (whose replay buffer a snapshot would have to hold) and runs anchored to demonstrations (whose
anchor has its own state) do not, and start again when stopped.

Nothing in a snapshot can run code when it is read: the weights are read by torch with ``weights_only=True``
(:data:`WEIGHTS_FILE`), everything else is JSON with its arrays in a numpy ``.npz`` read with
``allow_pickle=False`` (:mod:`dpr.rl.plain_state`). A snapshot of the pickled layout that dpr wrote before
(``state.pkl``) is never read: :func:`old_snapshot_error` says so, and the run starts again in a new folder.
"""

from __future__ import annotations

import dataclasses
import random
import shutil
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from dpr.bounded_io import load_yaml
from dpr.checks import ParameterError
from dpr.limits import MAX_RECORD_BYTES
from dpr.rl.plain_state import read_state, write_state

SNAPSHOT_ALGOS = ("ppo", "a2c")  # on-policy: nothing but the model and the envs carries over between rollouts
SNAPSHOT_DIR = "resume"
NEW_DIR, OLD_DIR = SNAPSHOT_DIR + ".new", SNAPSHOT_DIR + ".old"  # beside it while a snapshot replaces another
SNAPSHOT_SECONDS = 300.0
WEIGHTS_FILE = "weights.pt"  # the policy's and its optimizer's state dicts (torch.save; read weights_only)
STATE_FILE, ARRAYS_FILE = "state.json", "arrays.npz"  # everything else (dpr.rl.plain_state)
STATE_VERSION = 2
OLD_STATE_FILE = "state.pkl"  # version 1's pickled state, beside an SB3 model.zip: never read
# The model's attributes that training changes (beside its weights); the others follow from its hyperparameters.
MODEL_PROGRESS = (
    "num_timesteps",
    "_total_timesteps",
    "_num_timesteps_at_start",
    "_episode_num",
    "_n_updates",
    "_current_progress_remaining",
    "_last_obs",
    "_last_original_obs",
    "_last_episode_starts",
    "ep_info_buffer",
    "ep_success_buffer",
)
EVAL_ATTRIBUTES = (
    "best_mean_reward",
    "last_mean_reward",
    "evaluations_results",
    "evaluations_timesteps",
    "evaluations_length",
    "evaluations_successes",
    "_is_success_buffer",
)


def snapshot_path(run_dir: str | Path) -> Path:
    """Where a run folder keeps its snapshot."""
    return Path(run_dir) / SNAPSHOT_DIR


def _whole(folder: Path) -> bool:
    return all((folder / name).is_file() for name in (WEIGHTS_FILE, STATE_FILE, ARRAYS_FILE))


def old_snapshot_error(run_dir: str | Path) -> str | None:
    """Why ``run_dir``'s snapshot cannot be resumed from, when it is one of the pickled layout dpr wrote before
    (``resume/state.pkl``); None otherwise. The file is not opened."""
    for name in (SNAPSHOT_DIR, NEW_DIR, OLD_DIR):
        path = Path(run_dir) / name / OLD_STATE_FILE
        if path.exists():
            return (
                f"{path} is a snapshot of an earlier dpr, stored with pickle: it cannot be read safely (unpickling a "
                "file can run any code in it), so it is not read. Start the run again in a new folder"
            )
    return None


def snapshot_folder(run_dir: str | Path) -> Path | None:
    """The folder holding ``run_dir``'s complete snapshot: ``resume/``, or where a stop between
    :func:`save_snapshot`'s two renames left it (``.new`` is renamed into place only once whole); None if none."""
    folder = snapshot_path(run_dir)
    candidates = [folder] if folder.exists() else [folder.with_name(NEW_DIR), folder.with_name(OLD_DIR)]
    return next((candidate for candidate in candidates if _whole(candidate)), None)


def has_snapshot(run_dir: str | Path) -> bool:
    """Whether ``run_dir`` holds a complete snapshot to resume from (changes nothing)."""
    return snapshot_folder(run_dir) is not None


# TrainConfig's settings that came after runs were recorded: a run recorded before one ran at its default
SETTINGS_ADDED_LATER = ("engine", "device", "learner", "compile", "exploration_temperature")


def added_later(config) -> dict[str, Any]:
    """The defaults of ``config``'s (a TrainConfig's) :data:`SETTINGS_ADDED_LATER`."""
    return {f.name: f.default for f in dataclasses.fields(config) if f.name in SETTINGS_ADDED_LATER}


def check_resumable(out: str | Path | None, config: dict[str, Any], later: dict[str, Any] | None = None) -> None:
    """A :class:`ParameterError` about ``out`` unless it is a stopped run with a snapshot to resume from whose
    ``config.yaml`` records ``config`` (:func:`check_recorded_settings`)."""
    old = None if out is None else old_snapshot_error(out)
    if old is not None:
        raise ParameterError("out", f"{old} (another --out)")
    if out is None or not has_snapshot(out):
        raise ParameterError("out", f"{out} holds no snapshot of a stopped run to resume from")
    check_recorded_settings(out, config, later)


def check_recorded_settings(out: str | Path, config: dict[str, Any], later: dict[str, Any] | None = None) -> None:
    """A :class:`ParameterError` about ``out`` unless its ``config.yaml`` records ``config`` (the run's settings,
    as it records them under ``config``); ``later``: settings that came after some runs were recorded, with the
    value such a run had."""
    import yaml

    config_path = Path(out) / "config.yaml"
    recorded = load_yaml(config_path, "out", MAX_RECORD_BYTES).get("config") if config_path.is_file() else None
    wanted = yaml.safe_load(yaml.safe_dump(config))
    if recorded is not None and later:
        recorded = {**{k: v for k, v in later.items() if k in wanted}, **recorded}
    if recorded != wanted:
        differ = sorted(k for k in wanted if (recorded or {}).get(k) != wanted[k]) if recorded else "all"
        raise ParameterError("out", f"{out} is a run of other settings (differing: {differ}); it cannot be resumed")


def _all_callbacks(callback) -> list:
    """``callback`` and every callback inside it (lists, and the children of event callbacks), in a fixed order."""
    from stable_baselines3.common.callbacks import CallbackList, EventCallback

    found = [callback]
    if isinstance(callback, CallbackList):
        for child in callback.callbacks:
            found += _all_callbacks(child)
    elif isinstance(callback, EventCallback) and callback.callback is not None:
        found += _all_callbacks(callback.callback)
    return found


def _callback_state(callback) -> list[dict[str, Any]]:
    from stable_baselines3.common.callbacks import EvalCallback

    rows = []
    for each in _all_callbacks(callback):
        row = {"n_calls": each.n_calls}
        if isinstance(each, EvalCallback):
            row |= {name: getattr(each, name) for name in EVAL_ATTRIBUTES}  # copied to disk at once
        rows.append(row)
    return rows


def _episodes(vec_env) -> list[dict[str, Any] | None]:
    """Each env's current episode: one per env of a VecEnv, one per swarm of a per-robot run's
    :class:`~dpr.envs.parallel.SwarmsAsVecEnv` (whose every robot is an env); none without a VecEnv."""
    if vec_env is None:
        return []
    if hasattr(vec_env, "parallel_envs"):
        return [env.episode() for env in vec_env.parallel_envs]
    return list(vec_env.env_method("episode"))


@dataclass
class Snapshot:
    """A run's training state as read back from its folder (see the module's docstring)."""

    weights: dict[str, Any]  # the policy's and its optimizer's state dicts
    progress: dict[str, Any]  # the model's MODEL_PROGRESS attributes
    reached: int  # the model's step count when the snapshot was taken
    total_timesteps: int  # the model's _total_timesteps: where the run's learn() call ends
    origin: int  # the model's step count when that learn() call started (after any critic warm-up)
    train_episodes: list
    eval_episodes: list
    pending: dict[str, Any]  # the vector envs' seeds and options for their next reset
    callbacks: list[dict[str, Any]]
    random_states: dict[str, Any]
    extra: dict[str, Any] = field(default_factory=dict)  # the run's own state beyond SB3's (a per-robot run's)

    def restore_model(self, model) -> None:
        """Put the weights, optimizer state and progress of the snapshot's model into ``model``, built again as the
        run built it (same hyperparameters, env and seed)."""
        try:
            model.policy.load_state_dict(self.weights["policy"])
            model.policy.optimizer.load_state_dict(self.weights["optimizer"])
        except (RuntimeError, KeyError, TypeError, ValueError) as error:
            raise ValueError(f"the snapshot's weights are not those of this run's model ({error})") from None
        for name, value in self.progress.items():
            if name in ("ep_info_buffer", "ep_success_buffer") and value is not None:
                value = deque(value, maxlen=model._stats_window_size)
            setattr(model, name, value)

    def restore_vec_env(self, vec_env, which: str) -> None:
        """Give ``vec_env`` (rebuilt from this snapshot's episodes) the seeds and options it had pending."""
        vec_env._seeds, vec_env._options = self.pending[which]

    def restore_callbacks(self, callback) -> None:
        """Put the callbacks' counters and evaluation results back (``callback`` built as the run built it)."""
        found = _all_callbacks(callback)
        if len(found) != len(self.callbacks):
            raise ValueError(f"the snapshot has {len(self.callbacks)} callbacks, the run {len(found)}")
        for each, row in zip(found, self.callbacks, strict=True):
            for name, value in row.items():
                setattr(each, name, value)

    def restore_random_states(self) -> None:
        """The global torch, numpy and Python random states, as they were: the last thing before learning goes on
        (loading the model reseeds them)."""
        import numpy as np
        import torch

        torch.set_rng_state(self.random_states["torch"])
        np.random.set_state(self.random_states["numpy"])
        random.setstate(self.random_states["python"])


def load_snapshot(run_dir: str | Path) -> Snapshot:
    """The snapshot in ``run_dir`` (a ValueError naming the folder if it is missing, of another version, or of the
    pickled layout dpr wrote before: :func:`old_snapshot_error`)."""
    old = old_snapshot_error(run_dir)
    if old is not None:
        raise ValueError(old)
    folder, found = snapshot_path(run_dir), snapshot_folder(run_dir)
    if found is None:
        raise ValueError(f"{folder} holds no snapshot to resume from")
    if found != folder:  # put back the snapshot that a stop between save_snapshot's renames left aside
        found.rename(folder)
    state = read_state(folder / STATE_FILE, folder / ARRAYS_FILE)
    version = state.get("version") if isinstance(state, dict) else None
    if version != STATE_VERSION:
        raise ValueError(f"{folder / STATE_FILE} is snapshot version {version}, expected {STATE_VERSION}")
    names = {each.name for each in fields(Snapshot) if each.name != "weights"}
    if not names - {"extra"} <= set(state) - {"version"} <= names:  # (snapshots of runs that keep no extra lack it)
        raise ValueError(f"{folder / STATE_FILE}: not a snapshot dpr can read (its entries: {sorted(state)})")
    del state["version"]
    return Snapshot(weights=_read_weights(folder / WEIGHTS_FILE), **state)


def _read_weights(path: Path) -> dict[str, Any]:
    """The state dicts in ``path``, read by torch with ``weights_only=True``: tensors and plain values only."""
    import pickle

    import torch

    from dpr.policies.torch_files import is_refused_pickle, refused_pickle

    try:
        weights = torch.load(path, map_location="cpu", weights_only=True)
    except (pickle.UnpicklingError, RuntimeError, EOFError, ValueError) as error:
        if is_refused_pickle(error):  # (torch's message advises weights_only=False: never passed on)
            raise ValueError(f"{path}: not the weights of a snapshot (it holds {refused_pickle(error)})") from None
        first = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise ValueError(f"{path}: not the weights of a snapshot ({first})") from None
    if not isinstance(weights, dict) or not {"policy", "optimizer"} <= set(weights):
        raise ValueError(f"{path}: not the weights of a snapshot (no policy and optimizer state)")
    return weights


def save_snapshot(
    run_dir: Path, model, train_env, eval_env, callback, origin: int, extra: dict[str, Any] | None = None
) -> None:
    """Write the run's state into ``run_dir/resume/``, replacing the last snapshot only once the new one is whole
    (``eval_env`` None: a run evaluating without one; ``extra``: the run's own state, read back as
    :attr:`Snapshot.extra`)."""
    import numpy as np
    import torch

    folder = snapshot_path(run_dir)
    fresh = folder.with_name(NEW_DIR)
    if fresh.exists():
        shutil.rmtree(fresh)
    fresh.mkdir()
    weights = {"policy": model.policy.state_dict(), "optimizer": model.policy.optimizer.state_dict()}
    torch.save(weights, fresh / WEIGHTS_FILE)
    progress = {name: getattr(model, name) for name in MODEL_PROGRESS}
    for name in ("ep_info_buffer", "ep_success_buffer"):
        progress[name] = None if progress[name] is None else list(progress[name])
    state = {
        "version": STATE_VERSION,
        "progress": progress,
        "reached": int(model.num_timesteps),
        "total_timesteps": int(model._total_timesteps),
        "origin": int(origin),
        "train_episodes": _episodes(train_env),
        "eval_episodes": _episodes(eval_env),
        "pending": {
            name: (env._seeds, env._options)
            for name, env in (("train", train_env), ("eval", eval_env))
            if env is not None
        },
        "callbacks": _callback_state(callback),
        "random_states": {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate()},
        "extra": extra or {},
    }
    write_state(state, fresh / STATE_FILE, fresh / ARRAYS_FILE)
    old = folder.with_name(OLD_DIR)
    if folder.exists():
        folder.rename(old)
    fresh.rename(folder)
    if old.exists():
        shutil.rmtree(old)


def snapshots(
    run_dir: Path,
    train_env,
    eval_env,
    callback,
    origin: int,
    every: float | None = None,
    extra: Callable[[], dict[str, Any]] | None = None,
):
    """An SB3 callback writing a snapshot at the start of a rollout once ``every`` seconds (default
    :data:`SNAPSHOT_SECONDS`, read when it runs) have passed since the last one; ``callback`` is the run's whole
    callback list, this one included; ``extra()`` gives the run's own state to keep with it."""
    from stable_baselines3.common.callbacks import BaseCallback

    class Snapshots(BaseCallback):
        def _on_training_start(self) -> None:
            self.last = time.monotonic()

        def _on_rollout_start(self) -> None:
            if time.monotonic() - self.last >= (SNAPSHOT_SECONDS if every is None else every):
                save_snapshot(
                    run_dir, self.model, train_env, eval_env, callback, origin, None if extra is None else extra()
                )
                self.last = time.monotonic()

        def _on_step(self) -> bool:
            return True

    return Snapshots()


def drop_snapshot(run_dir: str | Path) -> None:
    """Remove a finished run's snapshot (its model.zip is then the run's result)."""
    for name in (SNAPSHOT_DIR, NEW_DIR, OLD_DIR):
        path = Path(run_dir) / name
        if path.exists():
            shutil.rmtree(path)
