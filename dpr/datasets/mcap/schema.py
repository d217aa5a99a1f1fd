"""The ``dpr-mcap/1`` format's facts: topics, JSON schemas, message and metadata encoding, and :class:`McapError`.

The writer (:mod:`dpr.datasets.mcap.writer`) and the reader (:mod:`dpr.datasets.mcap.reader`) both follow what
is defined here; the layout of a file is described in :mod:`dpr.datasets.mcap`.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from dpr.sim.constants import FPS

MCAP_FORMAT = "dpr-mcap/1"
METADATA_NAME = "dpr.episode"
STEP_NS = 1_000_000_000 // FPS  # one physics step, in nanoseconds (an env step is action_repeat of them)

TOPIC_SCENE = "/scene"
TOPIC_STATE = "/swarm/state"
TOPIC_MAGNETS = "/swarm/magnets"
TOPIC_OBJECT = "/object"
TOPIC_ACTION = "/action"
TOPIC_REWARD = "/reward"
REQUIRED_TOPICS = (TOPIC_SCENE, TOPIC_STATE, TOPIC_ACTION, TOPIC_REWARD)

MAGNET_DECIMALS = 2  # magnet end points are drawing aids: stored to 0.01 units
METRIC_KEYS = ("projected_displacement", "net_displacement", "total_distance", "is_success")
ACTION_REPEAT_KEY = "action_repeat"  # the metadata record's physics steps per env step (absent before: see reader)
_RESERVED_METADATA = ("format", "json_keys", ACTION_REPEAT_KEY)


class McapError(ValueError):
    """A file that cannot be written or read as a ``dpr-mcap`` episode; the message names the file."""

    def __init__(self, path: str | os.PathLike, problem: str):
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


# -- schemas ------------------------------------------------------------------------------------------------
def _number(description: str) -> dict:
    return {"type": "number", "description": description}


def _numbers(description: str, length: int | None = None) -> dict:
    schema: dict[str, Any] = {"type": "array", "items": {"type": "number"}, "description": description}
    if length is not None:
        schema["minItems"] = schema["maxItems"] = length
    return schema


def _point() -> dict:
    return _numbers("[x, y]", 2)


def _object_schema(title: str, description: str, properties: dict) -> dict:
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "description": description,
        "type": "object",
        "properties": properties,
        "required": list(properties),
    }


_STEP = {
    "type": "integer",
    "minimum": 0,
    "description": "env step (0 = the reset state); each is action_repeat physics steps of 0.1 s",
}

SCHEMAS: dict[str, dict] = {
    TOPIC_SCENE: _object_schema(
        "dpr.Scene",
        "The static scene, logged once at time 0.",
        {
            "goal": _point(),
            "walls": {
                "type": "array",
                "description": "static wall polygons, each a list of [x, y] vertices",
                "items": {"type": "array", "items": _point()},
            },
            "object": {
                "type": ["object", "null"],
                "description": "the manipulated object's shape, or null",
                "properties": {
                    "kind": {"type": "string", "description": "ball or box"},
                    "size": _number("ball radius or half the box's side"),
                },
            },
            "robot_radii": {
                "type": ["array", "null"],
                "items": {"type": "number"},
                "description": "[contracted, expanded] outer robot radius, or null",
            },
        },
    ),
    TOPIC_STATE: _object_schema(
        "dpr.SwarmState",
        "Every robot's state after a control step (pymunk units, radians, seconds).",
        {
            "step": _STEP,
            "time": _number("simulated seconds since the reset: step * action_repeat * 0.1 s"),
            "x": _numbers("robot centre x"),
            "y": _numbers("robot centre y"),
            "angle": _numbers("robot body angle (rad)"),
            "vx": _numbers("robot velocity x"),
            "vy": _numbers("robot velocity y"),
            "omega": _numbers("robot angular velocity (rad/s)"),
            "expansion": _numbers("expansion state, 0 contracted .. 1 expanded"),
            "alive": {"type": "array", "items": {"type": "boolean"}, "description": "false for unresponsive robots"},
            "centre_of_mass": _numbers("mean of the robot centres [x, y]", 2),
        },
    ),
    TOPIC_MAGNETS: _object_schema(
        "dpr.Magnets",
        "The magnets active during a control step, as segments between their end points.",
        {
            "step": _STEP,
            "segments": {
                "type": "array",
                "description": "[[x0, y0], [x1, y1]] per magnet",
                "items": {"type": "array", "items": _point(), "minItems": 2, "maxItems": 2},
            },
        },
    ),
    TOPIC_OBJECT: _object_schema(
        "dpr.Object",
        "The manipulated object's pose and velocity after a control step.",
        {
            "step": _STEP,
            "x": _number("centre x"),
            "y": _number("centre y"),
            "angle": _number("angle (rad)"),
            "vx": _number("velocity x"),
            "vy": _number("velocity y"),
        },
    ),
    TOPIC_ACTION: _object_schema(
        "dpr.Action",
        "The action of env.step number `step` (taken in state step - 1): per-robot expansion targets.",
        {"step": _STEP, "action": _numbers("expansion target per robot, 0 contract .. 1 expand")},
    ),
    TOPIC_REWARD: _object_schema(
        "dpr.Reward",
        "Reward, episode end flags and the episode metrics so far, after env.step number `step`.",
        {
            "step": _STEP,
            "reward": _number("reward of this step"),
            "terminated": {"type": "boolean"},
            "truncated": {"type": "boolean"},
            "projected_displacement": _number("agent displacement projected on start -> goal"),
            "net_displacement": _number("|agent position - start|"),
            "total_distance": _number("agent path length"),
            "is_success": {"type": "boolean", "description": "agent came within 10 units of the goal"},
        },
    ),
}
_SCHEMA_BYTES = {topic: json.dumps(schema, indent=1).encode() for topic, schema in SCHEMAS.items()}

# One compact encoder; allow_nan=False because NaN/Infinity are not JSON (Foxglove would reject them).
# Messages are built here from lists and dicts, never cyclic, so the circular-reference check is skipped.
_ENCODER = json.JSONEncoder(separators=(",", ":"), allow_nan=False, check_circular=False)


def _finite_or_none(value: Any) -> Any:
    """``value`` with every non-finite float replaced by None (JSON null), recursively."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, list):
        return [_finite_or_none(item) for item in value]
    if isinstance(value, dict):
        return {key: _finite_or_none(item) for key, item in value.items()}
    return value


def _encode(message: dict) -> bytes:
    try:
        return _ENCODER.encode(message).encode()
    except ValueError:  # a NaN or infinity: the slow path runs only after a physics blow-up
        return _ENCODER.encode(_finite_or_none(message)).encode()


# -- metadata -----------------------------------------------------------------------------------------------
def _encode_metadata(path: Path, metadata: Mapping[str, Any], action_repeat: int = 1) -> dict[str, str]:
    if not isinstance(metadata, Mapping):
        raise McapError(path, f"metadata must be a mapping of str to values, got {type(metadata).__name__}")
    encoded = {"format": MCAP_FORMAT, ACTION_REPEAT_KEY: str(action_repeat)}
    json_keys = []
    for key, value in metadata.items():
        if not isinstance(key, str) or not key:
            raise McapError(path, f"metadata keys must be non-empty strings, got {key!r}")
        if key in _RESERVED_METADATA:
            raise McapError(path, f"metadata key {key!r} is reserved by the writer")
        if isinstance(value, str):
            encoded[key] = value
            continue
        try:
            encoded[key] = json.dumps(value, allow_nan=False)
        except (TypeError, ValueError) as exc:
            raise McapError(path, f"metadata[{key!r}] is not JSON-serialisable: {exc}") from exc
        json_keys.append(key)
    encoded["json_keys"] = ",".join(json_keys)
    return encoded


def _decode_metadata(path: Path, records: list) -> tuple[dict[str, Any], int | None]:
    """The caller's metadata, and the file's physics steps per env step (None in a file written before the
    writer recorded it)."""
    found = [record.metadata for record in records if record.name == METADATA_NAME]
    if not found:
        raise McapError(path, f"no {METADATA_NAME!r} metadata record: not a {MCAP_FORMAT} episode log")
    raw = dict(found[0])
    version = raw.pop("format", None)
    if version != MCAP_FORMAT:
        raise McapError(path, f"format is {version!r}, this reader reads {MCAP_FORMAT!r}")
    json_keys = [key for key in raw.pop("json_keys", "").split(",") if key]
    repeat = raw.pop(ACTION_REPEAT_KEY, None)
    if repeat is not None and not (repeat.isdigit() and int(repeat) >= 1):
        raise McapError(path, f"metadata {ACTION_REPEAT_KEY!r} must be a positive integer, got {repeat!r}")
    metadata: dict[str, Any] = dict(raw)
    for key in json_keys:
        if key not in raw:
            raise McapError(path, f"metadata lists {key!r} in json_keys but has no such key")
        try:
            metadata[key] = json.loads(raw[key])
        except json.JSONDecodeError as exc:
            raise McapError(path, f"metadata[{key!r}] is not valid JSON: {exc}") from exc
    return metadata, None if repeat is None else int(repeat)
