"""Re-run recorded episodes from their stored seed, env kwargs and actions, and compare with the recording.

A dataset is trustworthy when every replayed observation equals the recorded one bit for bit: the simulator
is deterministic, so any difference means the recording, the simulator or the env kwargs changed. The replay
is :func:`dpr.rollout.roll_out` with a policy that plays the recorded actions back. The environment state is
compared too where the dataset records it (datasets recorded before it do not).
"""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from dpr.checks import ParameterError
from dpr.datasets import features as F
from dpr.datasets.lerobot import DatasetError, LeRobotReader
from dpr.rollout import ReplayPolicy, roll_out

COMPARED = (F.OBSERVATION, F.REWARD, F.DONE, F.SUCCESS)
REPLAY_META = (F.SEED, F.ENV_ID, F.ENV_KWARGS)  # what an episode's meta must hold to be replayed


@dataclass
class ReplayCheck:
    episode_index: int
    seed: int
    frames: int
    equal: bool
    max_abs_difference: dict[str, float]  # per compared feature, over the frames both hold (0.0 when equal)
    first_mismatch: int | None  # the first frame where anything differs (or that only one of them holds)

    def as_dict(self) -> dict:
        return self.__dict__.copy()


def _env_action(action: np.ndarray, action_type: str):
    if action_type == "discrete":
        return int(action[0])
    if action_type == "multibinary":
        return action.astype(np.int8)
    return action.astype(np.float32)


def replay_episode(reader: LeRobotReader, index: int) -> ReplayCheck:
    """Replay episode ``index`` of ``reader``'s dataset and compare every frame."""
    if not 0 <= index < reader.num_episodes:
        raise ParameterError("index", f"must be in [0, {reader.num_episodes}), got {index}")
    meta = reader.episodes[index]
    missing = [key for key in REPLAY_META if key not in meta]
    if missing:
        raise DatasetError(f"{reader.root}: episode {index} lacks {missing}; it was not recorded by dpr collect")
    import dpr  # noqa: F401  (registers the ids)

    compared = (*COMPARED, F.ENVIRONMENT_STATE) if F.ENVIRONMENT_STATE in reader.features else COMPARED
    recorded = reader.episode(index, columns=[F.ACTION, *compared])
    kwargs = dict(meta[F.ENV_KWARGS])
    kwargs.pop("render_mode", None)  # frames are not compared; skip rendering
    kwargs.pop("render_size", None)
    frames = len(recorded[F.ACTION])
    recorded_by = reader.info.get("dpr")
    if isinstance(recorded_by, dict) and recorded_by.get("engine") == "batched":  # replayed on the engine it ran on
        import torch

        from dpr.datasets.collect_batched import replay_batched

        device = recorded_by.get("device", "cpu")
        if device != "cpu" and not (device == "cuda" and torch.cuda.is_available()):
            raise DatasetError(
                f"{reader.root}: recorded on the batched engine on {device!r}, where alone it replays to the bit; "
                f"torch sees no {device!r} device on this machine"
            )
        replayed = replay_batched(meta[F.ENV_ID], kwargs, int(meta[F.SEED]), recorded[F.ACTION], device)
        if F.ENVIRONMENT_STATE not in compared:
            del replayed[F.ENVIRONMENT_STATE]
    else:
        replayed = _replay_pymunk(reader, meta, kwargs, recorded[F.ACTION], compared)
    differences, first = {}, None
    for key in compared:
        width = int(np.prod(recorded[key].shape[1:], dtype=int))
        a = recorded[key].reshape(frames, width)
        b = np.array(replayed[key], dtype=recorded[key].dtype).reshape(-1, width)
        both = min(len(a), len(b))
        a_common, b_common = a[:both], b[:both]
        unequal = np.flatnonzero(~(a_common == b_common).all(axis=1))
        differences[key] = float(np.abs(a_common.astype(float) - b_common.astype(float)).max()) if len(unequal) else 0.0
        if len(b) != len(a):  # the replay ended before the recording did (or the recording holds no frame for it)
            unequal = np.append(unequal, both)
        if len(unequal):
            first = int(unequal[0]) if first is None else min(first, int(unequal[0]))
    return ReplayCheck(index, int(meta[F.SEED]), frames, first is None, differences, first)


def _replay_pymunk(reader: LeRobotReader, meta: dict, kwargs: dict, actions: np.ndarray, compared) -> dict[str, list]:
    """The episode re-run on the pymunk engine from its seed and ``actions``: each compared feature, frame by frame."""
    env = gym.make(meta[F.ENV_ID], **kwargs)
    action_type = env.unwrapped.action_type
    frames = len(actions)
    replayed = {key: [] for key in compared}
    environment_states = []  # at the reset and after every step: frame t's is the t-th
    columns = _recorded_columns(reader.features.get(F.ENVIRONMENT_STATE), env.unwrapped.environment_state_names)

    def note_environment_state(*_) -> None:
        if F.ENVIRONMENT_STATE in compared:
            environment_states.append(env.unwrapped.environment_state()[columns])

    def on_step(step) -> None:
        note_environment_state()
        replayed[F.OBSERVATION].append(step.observation)
        replayed[F.REWARD].append(step.reward)
        replayed[F.DONE].append(step.done)
        replayed[F.SUCCESS].append(step.info["is_success"])

    policy = ReplayPolicy([_env_action(action, action_type) for action in actions])
    try:
        roll_out(env, policy, int(meta[F.SEED]), frames, on_reset=note_environment_state, on_step=on_step)
    finally:
        env.close()
    if F.ENVIRONMENT_STATE in compared:
        replayed[F.ENVIRONMENT_STATE] = environment_states[: len(replayed[F.OBSERVATION])]
    return replayed


def _recorded_columns(feature: dict | None, names: list[str]) -> list[int] | slice:
    """Which of the env's environment-state values the dataset recorded: all of them, or, for a dataset recorded
    before the env's state gained values (Unresponsive's dead flags), those its names list."""
    recorded = (feature or {}).get("names")
    if isinstance(recorded, list) and recorded != names and set(recorded) <= set(names):
        return [names.index(name) for name in recorded]
    return slice(None)


def replay_dataset(root, episodes: list[int] | None = None, progress=None) -> list[ReplayCheck]:
    """Replay ``episodes`` (default: all) of the dataset at ``root``."""
    reader = LeRobotReader(root)
    indices = list(range(reader.num_episodes)) if episodes is None else list(episodes)
    bad = [i for i in indices if not 0 <= i < reader.num_episodes]
    if bad:
        raise ParameterError("episodes", f"{bad} are not in the dataset {root} (it holds 0..{reader.num_episodes - 1})")
    checks = []
    for index in indices:
        checks.append(replay_episode(reader, index))
        if progress is not None:
            progress(checks[-1])
    return checks
