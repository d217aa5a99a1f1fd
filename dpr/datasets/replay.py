"""Re-run recorded episodes from their stored seed, env kwargs and actions, and compare with the recording.

A dataset is trustworthy when every replayed observation equals the recorded one bit for bit: the simulator
is deterministic, so any difference means the recording, the simulator or the env kwargs changed.
"""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from dpr.datasets.lerobot import DatasetError, LeRobotReader

COMPARED = ("observation.state", "next.reward", "next.done", "next.success")


@dataclass
class ReplayCheck:
    episode_index: int
    seed: int
    frames: int
    equal: bool
    max_abs_difference: dict[str, float]  # per compared feature (0.0 when equal)
    first_mismatch: int | None  # the first frame where anything differs

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
        raise ValueError(f"episode index must be in [0, {reader.num_episodes}), got {index}")
    meta = reader.episodes[index]
    missing = [key for key in ("seed", "env_id", "env_kwargs") if key not in meta]
    if missing:
        raise DatasetError(f"{reader.root}: episode {index} lacks {missing}; it was not recorded by dpr collect")
    import dpr  # noqa: F401  (registers the ids)

    recorded = reader.episode(index, columns=["action", *COMPARED])
    kwargs = dict(meta["env_kwargs"])
    kwargs.pop("render_mode", None)  # frames are not compared; skip rendering
    kwargs.pop("render_size", None)
    env = gym.make(meta["env_id"], **kwargs)
    action_type = env.unwrapped.action_type
    observation, _ = env.reset(seed=int(meta["seed"]))
    frames = len(recorded["action"])
    replayed = {key: np.empty_like(recorded[key]) for key in COMPARED}
    for t in range(frames):
        replayed["observation.state"][t] = observation
        observation, reward, terminated, truncated, info = env.step(_env_action(recorded["action"][t], action_type))
        replayed["next.reward"][t] = reward
        replayed["next.done"][t] = terminated or truncated
        replayed["next.success"][t] = info["is_success"]
    env.close()
    differences, first = {}, None
    for key in COMPARED:
        a, b = recorded[key].reshape(frames, -1), replayed[key].reshape(frames, -1)
        unequal = np.flatnonzero(~(a == b).all(axis=1))
        differences[key] = float(np.abs(a.astype(float) - b.astype(float)).max()) if len(unequal) else 0.0
        if len(unequal):
            first = int(unequal[0]) if first is None else min(first, int(unequal[0]))
    return ReplayCheck(index, int(meta["seed"]), frames, first is None, differences, first)


def replay_dataset(root, episodes: list[int] | None = None, progress=None) -> list[ReplayCheck]:
    """Replay ``episodes`` (default: all) of the dataset at ``root``."""
    reader = LeRobotReader(root)
    indices = list(range(reader.num_episodes)) if episodes is None else list(episodes)
    bad = [i for i in indices if not 0 <= i < reader.num_episodes]
    if bad:
        raise ValueError(f"episodes {bad} are not in the dataset {root} (it holds 0..{reader.num_episodes - 1})")
    checks = []
    for index in indices:
        checks.append(replay_episode(reader, index))
        if progress is not None:
            progress(checks[-1])
    return checks
