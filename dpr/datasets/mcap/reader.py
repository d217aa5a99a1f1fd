"""Reading ``dpr-mcap/1`` episode logs back into numpy arrays: :func:`read_mcap` gives a :class:`McapEpisode`."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from mcap.reader import make_reader
from mcap.well_known import MessageEncoding

from dpr.datasets import features as F
from dpr.datasets.mcap.schema import (
    METRIC_KEYS,
    REQUIRED_TOPICS,
    SCHEMAS,
    TOPIC_ACTION,
    TOPIC_MAGNETS,
    TOPIC_OBJECT,
    TOPIC_REWARD,
    TOPIC_SCENE,
    TOPIC_STATE,
    McapError,
    _decode_metadata,
)
from dpr.sim.constants import FPS


@dataclass
class McapEpisode:
    """One episode read back from a ``dpr-mcap/1`` file.

    ``T`` env steps give ``T + 1`` states (row 0 is the reset state) and ``T`` actions: ``actions[i]`` was
    taken in state ``i`` and produced state ``i + 1``, ``rewards[i]``, ``terminated[i]``, ``truncated[i]`` and
    ``metrics[key][i]``. ``alive`` is the step-0 mask (robots do not die or revive within an episode).
    ``action_repeat``: physics steps of 0.1 s per env step, as the metadata record says (a file written before
    it did: its ``env_kwargs``' value, whose log times count 0.1 s per env step, else 1).
    """

    metadata: dict[str, Any]
    steps: np.ndarray  # [T+1] int64
    positions: np.ndarray  # [T+1, N, 2]
    angles: np.ndarray  # [T+1, N]
    velocities: np.ndarray  # [T+1, N, 2]
    angular_velocities: np.ndarray  # [T+1, N]
    expansions: np.ndarray  # [T+1, N]
    centres_of_mass: np.ndarray  # [T+1, 2]
    alive: np.ndarray  # [N] bool
    actions: np.ndarray  # [T, N] int64 for binary actions, float64 for continuous ones
    rewards: np.ndarray  # [T]
    terminated: np.ndarray  # [T] bool
    truncated: np.ndarray  # [T] bool
    metrics: dict[str, np.ndarray]  # METRIC_KEYS -> [T]
    goal: np.ndarray  # [2]
    walls: list[np.ndarray]  # each [K, 2]
    object_poses: np.ndarray | None  # [T+1, 3] (x, y, angle)
    object_velocities: np.ndarray | None  # [T+1, 2]
    magnets: list[np.ndarray] | None  # per state, [M_t, 2, 2], rounded to MAGNET_DECIMALS
    scene: dict[str, Any]  # the raw /scene message (object shape, robot radii)
    action_repeat: int = 1

    @property
    def n_steps(self) -> int:
        """T, the number of env steps."""
        return len(self.rewards)

    @property
    def n_robots(self) -> int:
        return self.positions.shape[1]

    @property
    def physics_steps(self) -> np.ndarray:
        """Physics step of each state since the reset: ``steps * action_repeat``."""
        return self.steps * self.action_repeat

    @property
    def times(self) -> np.ndarray:
        """Simulated seconds of each state since the reset."""
        return self.physics_steps / FPS


def _raw_messages(path: Path) -> tuple[tuple[dict[str, Any], int | None], dict[str, list[dict]]]:
    """(Metadata, recorded action_repeat) and decoded messages per topic (all topics but foreign ones, sorted by
    step). Any failure of the mcap library (bad magic, truncation, CRC mismatch, bad compression) becomes a
    McapError naming ``path``."""
    try:
        with path.open("rb") as stream:
            reader = make_reader(stream, validate_crcs=True)
            summary = reader.get_summary()
            if summary is None:
                raise McapError(path, "no summary section: the file was not closed by its writer")
            metadata, repeat = _decode_metadata(path, list(reader.iter_metadata()))
            topics = {channel.topic for channel in summary.channels.values()}
            encodings = {channel.topic: channel.message_encoding for channel in summary.channels.values()}
            raw: dict[str, list[bytes]] = {topic: [] for topic in topics}
            for _schema, channel, message in reader.iter_messages(log_time_order=False):
                raw[channel.topic].append(message.data)
    except McapError:
        raise
    except Exception as exc:  # the mcap library raises many types on damaged input
        raise McapError(path, f"not a readable MCAP file ({type(exc).__name__}: {exc})") from exc
    missing = [topic for topic in REQUIRED_TOPICS if topic not in topics]
    if missing:
        raise McapError(path, f"missing channel(s) {', '.join(missing)}")
    messages: dict[str, list[dict]] = {}
    for topic, items in raw.items():
        if topic not in SCHEMAS:
            continue  # a channel added by someone else: not ours to read
        if encodings[topic] != MessageEncoding.JSON:
            raise McapError(path, f"channel {topic} has message encoding {encodings[topic]!r}, expected 'json'")
        try:
            decoded = [json.loads(item) for item in items]
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise McapError(path, f"a message on {topic} is not valid JSON: {exc}") from exc
        if topic != TOPIC_SCENE:
            try:
                decoded.sort(key=lambda message: message["step"])
            except (KeyError, TypeError) as exc:
                raise McapError(path, f"a message on {topic} has no integer 'step'") from exc
        messages[topic] = decoded
    return (metadata, repeat), messages


def _check_steps(path: Path, topic: str, messages: list[dict], first: int, count: int) -> None:
    steps = [message["step"] for message in messages]
    if steps != list(range(first, first + count)):
        raise McapError(
            path, f"{topic} has messages for {len(steps)} steps, expected steps {first}..{first + count - 1} once each"
        )


def _column(messages: list[dict], key: str, dtype=np.float64) -> np.ndarray:
    return np.array([message[key] for message in messages], dtype=dtype)


def read_mcap(path: str | os.PathLike) -> McapEpisode:
    """Read an episode written by :class:`McapEpisodeWriter`. Raises McapError naming the file when it is
    missing, damaged or truncated, of another format version, or lacks channels or steps."""
    path = Path(path)
    if not path.is_file():
        raise McapError(path, "no such file")
    (metadata, repeat), messages = _raw_messages(path)
    states = messages[TOPIC_STATE]
    if not states:
        raise McapError(path, f"no messages on {TOPIC_STATE}")
    if len(messages[TOPIC_SCENE]) != 1:
        raise McapError(path, f"{TOPIC_SCENE} must hold exactly one message, found {len(messages[TOPIC_SCENE])}")
    n_states = len(states)
    _check_steps(path, TOPIC_STATE, states, 0, n_states)
    for topic in (TOPIC_ACTION, TOPIC_REWARD):
        _check_steps(path, topic, messages[topic], 1, n_states - 1)
    for topic in (TOPIC_OBJECT, TOPIC_MAGNETS):
        if messages.get(topic):
            _check_steps(path, topic, messages[topic], 0, n_states)
    try:
        return _assemble(metadata, messages, _action_repeat(path, metadata, repeat))
    except (KeyError, TypeError, ValueError) as exc:
        raise McapError(path, f"malformed message ({type(exc).__name__}: {exc})") from exc


def _action_repeat(path: Path, metadata: dict[str, Any], recorded: int | None) -> int:
    """The file's physics steps per env step: as recorded, or in a file written before they were, the episode's
    ``env_kwargs`` value (its log times and ``time`` fields count 0.1 s per env step: too short where it is > 1)."""
    if recorded is not None:
        return recorded
    kwargs = metadata.get(F.ENV_KWARGS)
    repeat = kwargs.get("action_repeat", 1) if isinstance(kwargs, dict) else 1
    if isinstance(repeat, bool) or not isinstance(repeat, int) or repeat < 1:
        raise McapError(path, f"metadata env_kwargs hold action_repeat={repeat!r}, not a positive integer")
    return repeat


def _assemble(metadata: dict[str, Any], messages: dict[str, list[dict]], action_repeat: int = 1) -> McapEpisode:
    states = messages[TOPIC_STATE]
    actions = messages[TOPIC_ACTION]
    rewards = messages[TOPIC_REWARD]
    scene = messages[TOPIC_SCENE][0]
    n = len(states[0]["x"])
    positions = np.stack([_column(states, "x"), _column(states, "y")], axis=-1)
    velocities = np.stack([_column(states, "vx"), _column(states, "vy")], axis=-1)
    action_array = np.array([message["action"] for message in actions])
    if len(actions) == 0:
        action_array = np.zeros((0, n), dtype=np.int64)
    elif action_array.dtype.kind not in "if":
        raise ValueError(f"actions must be numbers, got dtype {action_array.dtype}")
    object_poses = object_velocities = None
    if messages.get(TOPIC_OBJECT):
        objects = messages[TOPIC_OBJECT]
        object_poses = np.stack([_column(objects, key) for key in ("x", "y", "angle")], axis=-1)
        object_velocities = np.stack([_column(objects, key) for key in ("vx", "vy")], axis=-1)
    magnets = None
    if messages.get(TOPIC_MAGNETS):
        magnets = [np.array(m["segments"], dtype=np.float64).reshape(-1, 2, 2) for m in messages[TOPIC_MAGNETS]]
    episode = McapEpisode(
        metadata=metadata,
        steps=_column(states, "step", np.int64),
        positions=positions,
        angles=_column(states, "angle"),
        velocities=velocities,
        angular_velocities=_column(states, "omega"),
        expansions=_column(states, "expansion"),
        centres_of_mass=_column(states, "centre_of_mass").reshape(-1, 2),
        alive=np.array(states[0]["alive"], dtype=bool),
        actions=action_array,
        rewards=_column(rewards, "reward"),
        terminated=_column(rewards, "terminated", bool),
        truncated=_column(rewards, "truncated", bool),
        metrics={key: _column(rewards, key, bool if key == "is_success" else np.float64) for key in METRIC_KEYS},
        goal=np.array(scene["goal"], dtype=np.float64),
        walls=[np.array(wall, dtype=np.float64).reshape(-1, 2) for wall in scene["walls"]],
        object_poses=object_poses,
        object_velocities=object_velocities,
        magnets=magnets,
        scene=scene,
        action_repeat=action_repeat,
    )
    _check_shapes(episode)
    return episode


def _check_shapes(episode: McapEpisode) -> None:
    """Ragged or mis-sized per-robot lists would otherwise surface later as confusing numpy errors."""
    states, n = episode.positions.shape[0], episode.positions.shape[1]
    expected = {
        "positions": (episode.positions.shape, (states, n, 2)),
        "angles": (episode.angles.shape, (states, n)),
        "velocities": (episode.velocities.shape, (states, n, 2)),
        "angular_velocities": (episode.angular_velocities.shape, (states, n)),
        "expansions": (episode.expansions.shape, (states, n)),
        "alive": (episode.alive.shape, (n,)),
        "actions": (episode.actions.shape, (states - 1, n)),
        "goal": (episode.goal.shape, (2,)),
    }
    for name, (got, want) in expected.items():
        if got != want:
            raise ValueError(f"{name} has shape {got}, expected {want}")
