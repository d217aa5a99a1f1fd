"""MCAP logs of swarm episodes: one file per episode, JSON messages described by JSON schemas.

The files open in Foxglove (every field can be plotted, since each channel carries a ``jsonschema`` schema)
and read back with the ``mcap`` library, or with :func:`read_mcap` into numpy arrays.

Layout of a file written by :class:`McapEpisodeWriter` (format ``dpr-mcap/1``)
----------------------------------------------------------------------------------
Log time of step ``t`` is ``t * 0.1 s`` in nanoseconds (10 Hz control, the env's ``render_fps``); step 0
is the state right after ``reset()``, step ``t >= 1`` the state after the ``t``-th ``env.step``.

========================  ============  ===========================================================
topic                     steps         fields
========================  ============  ===========================================================
``/scene``                once, t = 0   ``goal`` [2]; ``walls``: polygons, each a list of [x, y];
                                        ``object``: {``kind``, ``size``} or null;
                                        ``robot_radii``: [contracted, expanded] or null
``/swarm/state``          0 .. T        ``step``, ``time`` (s); per robot lists of N: ``x``, ``y``,
                                        ``angle``, ``vx``, ``vy``, ``omega``, ``expansion`` (0..1),
                                        ``alive`` (bools); ``centre_of_mass`` [2]
``/swarm/magnets``        0 .. T        ``step``, ``segments``: [[x0, y0], [x1, y1]] per active
                          (optional)    magnet, rounded to 0.01 units (a drawing aid, not state;
                                        recorded when step 0 has them, then at every step)
``/object``               0 .. T        ``step``, ``x``, ``y``, ``angle``, ``vx``, ``vy`` (tasks
                          (optional)    with an object; recorded at every step or at none)
``/action``               1 .. T        ``step``, ``action`` [N]: the per-robot expansion targets
                                        passed to ``env.step`` number ``step`` (taken in state
                                        ``step - 1``; a Discrete(2^N) action is stored as its N bits,
                                        robot 0 the most significant)
``/reward``               1 .. T        ``step``, ``reward``, ``terminated``, ``truncated``, and the
                                        episode metrics so far: ``projected_displacement``,
                                        ``net_displacement``, ``total_distance``, ``is_success``
========================  ============  ===========================================================

Episode metadata is an MCAP Metadata record named ``dpr.episode``: ``format`` (``dpr-mcap/1``) and the
caller's keys (typically ``env_id``, ``seed``, ``n_robots``, ``robot_model``, ``policy``, ``env_kwargs``; see
:func:`episode_metadata`). MCAP metadata values are strings: string values are stored as they are, any
other value as JSON text, and the key ``json_keys`` lists (comma-separated) which keys hold JSON, so
:func:`read_mcap` gives back the original values.

Floats are written with Python's ``repr`` (the shortest text that parses back to the same float64), so a
file reads back bit-exact (all but the magnet end points, which are rounded). JSON has no NaN or infinity:
a message holding one (a physics blow-up) stores ``null`` in its place, which reads back as NaN.

Crash safety: the writer writes to a ``<name>.<pid>.<random>.part`` file beside the target and renames it onto
the final name only in :meth:`McapEpisodeWriter.close` (after an fsync), so a killed run never leaves a
half-written file under the final name; an exception inside ``with McapEpisodeWriter(...)`` removes the
partial file.
"""

from __future__ import annotations

import json
import math
import os
import secrets
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from mcap.reader import make_reader
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer

MCAP_FORMAT = "dpr-mcap/1"
METADATA_NAME = "dpr.episode"
FPS = 10
STEP_NS = 1_000_000_000 // FPS  # log time of one control step, in nanoseconds

TOPIC_SCENE = "/scene"
TOPIC_STATE = "/swarm/state"
TOPIC_MAGNETS = "/swarm/magnets"
TOPIC_OBJECT = "/object"
TOPIC_ACTION = "/action"
TOPIC_REWARD = "/reward"
REQUIRED_TOPICS = (TOPIC_SCENE, TOPIC_STATE, TOPIC_ACTION, TOPIC_REWARD)

MAGNET_DECIMALS = 2  # magnet end points are drawing aids: stored to 0.01 units
METRIC_KEYS = ("projected_displacement", "net_displacement", "total_distance", "is_success")
_RESERVED_METADATA = ("format", "json_keys")
_COMPRESSIONS = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}


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


_STEP = {"type": "integer", "minimum": 0, "description": "control step (0 = the reset state)"}

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
            "time": _number("step * 0.1 s"),
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
def _encode_metadata(path: Path, metadata: Mapping[str, Any]) -> dict[str, str]:
    if not isinstance(metadata, Mapping):
        raise McapError(path, f"metadata must be a mapping of str to values, got {type(metadata).__name__}")
    encoded = {"format": MCAP_FORMAT}
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


def _decode_metadata(path: Path, records: list) -> dict[str, Any]:
    found = [record.metadata for record in records if record.name == METADATA_NAME]
    if not found:
        raise McapError(path, f"no {METADATA_NAME!r} metadata record: not a {MCAP_FORMAT} episode log")
    raw = dict(found[0])
    version = raw.pop("format", None)
    if version != MCAP_FORMAT:
        raise McapError(path, f"format is {version!r}, this reader reads {MCAP_FORMAT!r}")
    json_keys = [key for key in raw.pop("json_keys", "").split(",") if key]
    metadata: dict[str, Any] = dict(raw)
    for key in json_keys:
        if key not in raw:
            raise McapError(path, f"metadata lists {key!r} in json_keys but has no such key")
        try:
            metadata[key] = json.loads(raw[key])
        except json.JSONDecodeError as exc:
            raise McapError(path, f"metadata[{key!r}] is not valid JSON: {exc}") from exc
    return metadata


def episode_metadata(env, *, seed: int | None, policy: str, **extra: Any) -> dict[str, Any]:
    """The usual ``dpr.episode`` metadata of one episode of ``env`` (wrapped or not): env id and kwargs
    from its spec, seed, robot count and model, the policy's name, and any ``extra`` keys."""
    base = env.unwrapped
    spec = getattr(env, "spec", None)
    metadata: dict[str, Any] = {
        "env_id": spec.id if spec is not None else type(base).__name__,
        "seed": seed,
        "n_robots": int(base.n_robots),
        "robot_model": str(base.robot_model),
        "policy": policy,
        "env_kwargs": dict(spec.kwargs) if spec is not None else {},
    }
    metadata.update(extra)
    return metadata


# -- writer -------------------------------------------------------------------------------------------------
def _array(path: Path, name: str, value: Any, shape: tuple[int, ...], dtype=np.float64) -> np.ndarray:
    array = np.asarray(value, dtype=dtype)
    if array.shape != shape:
        raise McapError(path, f"{name} must have shape {shape}, got {array.shape}")
    return array


class McapEpisodeWriter:
    """Writes one episode to an MCAP file; use as a context manager.

    Call :meth:`write_scene` once and :meth:`write_step` for steps 0, 1, 2, ... in order (step 0 is the reset
    state and takes no action, reward or metrics; every later step needs them). Nothing appears under
    ``path`` until :meth:`close` succeeds: the data goes to a ``.part`` file beside it, fsynced and renamed
    onto ``path`` on close (replacing any file there). Leaving the ``with`` block by an exception, or
    :meth:`abort`, deletes the partial file.

    ``compression``: "zstd" (default), "lz4" or "none", applied per MCAP chunk of ``chunk_size`` bytes.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        metadata: Mapping[str, Any],
        compression: str = "zstd",
        chunk_size: int = 1 << 20,
    ):
        self.path = Path(path)
        if compression not in _COMPRESSIONS:
            raise McapError(self.path, f"compression must be one of {tuple(_COMPRESSIONS)}, got {compression!r}")
        if not self.path.parent.is_dir():
            raise McapError(self.path, f"directory {str(self.path.parent)!r} does not exist")
        encoded_metadata = _encode_metadata(self.path, metadata)
        self.temp_path, self._file = _create_part_file(self.path)
        self._channels: dict[str, int] = {}
        self._closed = False
        self._scene_written = False
        self._next_step = 0
        self._n_robots: int | None = None
        self._has_object = False
        self._has_magnets = False
        try:
            self._writer = Writer(self._file, chunk_size=chunk_size, compression=_COMPRESSIONS[compression])
            self._writer.start(profile="", library=f"{MCAP_FORMAT} ({LIBRARY_IDENTIFIER})")
            self._writer.add_metadata(METADATA_NAME, encoded_metadata)
            for topic in REQUIRED_TOPICS:  # registered up front so that even an empty episode lists them
                self._channel(topic)
        except BaseException:
            self.abort()
            raise

    # -- context manager ------------------------------------------------------------------------------------
    def __enter__(self) -> McapEpisodeWriter:
        return self

    def __exit__(self, exc_type, exc, traceback) -> None:
        if exc_type is not None:
            self.abort()
        else:
            self.close()

    # -- records --------------------------------------------------------------------------------------------
    def _channel(self, topic: str) -> int:
        channel = self._channels.get(topic)
        if channel is None:
            schema = self._writer.register_schema(
                name=SCHEMAS[topic]["title"], encoding=SchemaEncoding.JSONSchema, data=_SCHEMA_BYTES[topic]
            )
            channel = self._writer.register_channel(topic, MessageEncoding.JSON, schema)
            self._channels[topic] = channel
        return channel

    def _message(self, topic: str, step: int, message: dict) -> None:
        log_time = step * STEP_NS
        self._writer.add_message(self._channel(topic), log_time, _encode(message), log_time, sequence=step)

    def _check_open(self) -> None:
        if self._closed:
            raise McapError(self.path, "writer is closed")

    def write_scene(
        self,
        *,
        goal,
        walls: Iterable[np.ndarray] = (),
        object_kind: str | None = None,
        object_size: float | None = None,
        robot_radii: tuple[float, float] | None = None,
    ) -> None:
        """The static scene (goal, wall polygons, object shape, robot radii), once, logged at time 0."""
        self._check_open()
        if self._scene_written:
            raise McapError(self.path, "write_scene() was already called")
        polygons = []
        for index, wall in enumerate(walls):
            polygon = np.asarray(wall, dtype=np.float64)
            if polygon.ndim != 2 or polygon.shape[1] != 2 or len(polygon) < 3:
                raise McapError(self.path, f"walls[{index}] must be a (K >= 3, 2) polygon, got shape {polygon.shape}")
            polygons.append(polygon.tolist())
        obj = None
        if object_kind is not None:
            obj = {"kind": str(object_kind), "size": None if object_size is None else float(object_size)}
        radii = None if robot_radii is None else [float(r) for r in robot_radii]
        message = {
            "goal": _array(self.path, "goal", goal, (2,)).tolist(),
            "walls": polygons,
            "object": obj,
            "robot_radii": radii,
        }
        self._message(TOPIC_SCENE, 0, message)
        self._scene_written = True

    def write_step(
        self,
        step: int,
        *,
        positions,
        angles,
        velocities,
        angular_velocities,
        expansions,
        alive,
        action=None,
        reward: float | None = None,
        terminated: bool | None = None,
        truncated: bool | None = None,
        metrics: Mapping[str, Any] | None = None,
        object_pose=None,
        object_velocity=None,
        magnets=None,
        centre_of_mass=None,
    ) -> None:
        """One control step: the swarm's state after it and, for ``step >= 1``, the action that led to it,
        its reward, end flags and the metrics so far (keys :data:`METRIC_KEYS`; extra keys are ignored).

        Arrays are per robot: ``positions`` and ``velocities`` (N, 2), the others (N,). ``object_pose``
        (x, y, angle) with ``object_velocity`` (vx, vy), and ``magnets`` (M, 2, 2), are recorded if step 0
        has them, and then required at every step. ``centre_of_mass`` defaults to the mean of ``positions``.
        """
        self._check_open()
        path = self.path
        if isinstance(step, bool) or not isinstance(step, (int, np.integer)) or step != self._next_step:
            raise McapError(
                path, f"steps must be written in order 0, 1, 2, ...: expected {self._next_step}, got {step!r}"
            )
        step = int(step)
        positions = np.asarray(positions, dtype=np.float64)
        if positions.ndim != 2 or positions.shape[1] != 2 or len(positions) < 1:
            raise McapError(path, f"positions must have shape (N, 2), got {positions.shape}")
        n = len(positions)
        if step == 0:
            self._n_robots = n
            self._has_object = object_pose is not None
            self._has_magnets = magnets is not None
        elif n != self._n_robots:
            raise McapError(
                path, f"positions must have shape ({self._n_robots}, 2) as at step 0, got {positions.shape}"
            )
        velocities = _array(path, "velocities", velocities, (n, 2))
        if centre_of_mass is None:
            centre_of_mass = positions.mean(axis=0)
        xy = positions.T.tolist()
        vxy = velocities.T.tolist()
        state = {
            "step": step,
            "time": step / FPS,
            "x": xy[0],
            "y": xy[1],
            "angle": _array(path, "angles", angles, (n,)).tolist(),
            "vx": vxy[0],
            "vy": vxy[1],
            "omega": _array(path, "angular_velocities", angular_velocities, (n,)).tolist(),
            "expansion": _array(path, "expansions", expansions, (n,)).tolist(),
            "alive": _array(path, "alive", alive, (n,), dtype=bool).tolist(),
            "centre_of_mass": _array(path, "centre_of_mass", centre_of_mass, (2,)).tolist(),
        }
        # Validate everything before writing anything, so a bad call leaves the file consistent.
        extra = self._optional_messages(step, object_pose, object_velocity, magnets)
        outcome = self._outcome_messages(step, n, action, reward, terminated, truncated, metrics)
        self._message(TOPIC_STATE, step, state)
        for topic, message in extra + outcome:
            self._message(topic, step, message)
        self._next_step = step + 1

    def _optional_messages(self, step: int, object_pose, object_velocity, magnets) -> list[tuple[str, dict]]:
        path = self.path
        messages = []
        if (object_pose is not None) != self._has_object or (object_velocity is None) != (object_pose is None):
            raise McapError(
                path,
                f"step {step}: object_pose and object_velocity must both be given at every step or at none"
                f" (step 0 {'had' if self._has_object else 'had no'} object)",
            )
        if self._has_object:
            pose = _array(path, "object_pose", object_pose, (3,)).tolist()
            velocity = _array(path, "object_velocity", object_velocity, (2,)).tolist()
            x, y, angle = pose
            vx, vy = velocity
            messages.append((TOPIC_OBJECT, {"step": step, "x": x, "y": y, "angle": angle, "vx": vx, "vy": vy}))
        if (magnets is not None) != self._has_magnets:
            raise McapError(path, f"step {step}: magnets must be given at every step or at none (as at step 0)")
        if self._has_magnets:
            segments = np.asarray(magnets, dtype=np.float64)
            if segments.size == 0:
                segments = segments.reshape(0, 2, 2)
            if segments.ndim != 3 or segments.shape[1:] != (2, 2):
                raise McapError(path, f"magnets must have shape (M, 2, 2), got {segments.shape}")
            # Drawing data, not state: rounding halves the cost of turning these floats into text.
            messages.append((TOPIC_MAGNETS, {"step": step, "segments": segments.round(MAGNET_DECIMALS).tolist()}))
        return messages

    def _outcome_messages(
        self, step: int, n: int, action, reward, terminated, truncated, metrics
    ) -> list[tuple[str, dict]]:
        path = self.path
        given = {
            "action": action, "reward": reward, "terminated": terminated, "truncated": truncated, "metrics": metrics
        }
        if step == 0:
            extra = [name for name, value in given.items() if value is not None]
            if extra:
                raise McapError(path, f"step 0 is the reset state and takes no {', '.join(extra)}")
            return []
        missing = [name for name, value in given.items() if value is None]
        if missing:
            raise McapError(path, f"step {step}: {', '.join(missing)} required for every step after 0")
        action_array = np.asarray(action)
        if action_array.shape != (n,) or action_array.dtype.kind not in "buif":
            raise McapError(
                path, f"action must be {n} numbers, got shape {action_array.shape} dtype {action_array.dtype}"
            )
        if action_array.dtype.kind == "b":
            action_array = action_array.astype(np.int64)
        absent = [key for key in METRIC_KEYS if key not in metrics]
        if absent:
            raise McapError(path, f"step {step}: metrics lacks {', '.join(absent)}")
        outcome = {
            "step": step,
            "reward": float(reward),
            "terminated": bool(terminated),
            "truncated": bool(truncated),
            "projected_displacement": float(metrics["projected_displacement"]),
            "net_displacement": float(metrics["net_displacement"]),
            "total_distance": float(metrics["total_distance"]),
            "is_success": bool(metrics["is_success"]),
        }
        return [(TOPIC_ACTION, {"step": step, "action": action_array.tolist()}), (TOPIC_REWARD, outcome)]

    # -- finishing ------------------------------------------------------------------------------------------
    def close(self) -> None:
        """Finish the file and move it onto ``path``. Raises McapError (and removes the partial file) when no
        scene or no step 0 was written. Closing twice is a no-op."""
        if self._closed:
            return
        problems = []
        if not self._scene_written:
            problems.append("write_scene() was never called")
        if self._next_step == 0:
            problems.append("no step was written (step 0 is the reset state)")
        if problems:
            self.abort()
            raise McapError(self.path, "; ".join(problems) + "; nothing was written")
        try:
            self._writer.finish()
            self._file.flush()
            os.fsync(self._file.fileno())  # the data must be on disk before the name points at it
            self._file.close()
            os.replace(self.temp_path, self.path)
        except BaseException:
            self.abort()
            raise
        self._closed = True
        _fsync_directory(self.path.parent)

    def abort(self) -> None:
        """Drop the episode: close and delete the partial file; ``path`` is left as it was."""
        self._closed = True
        try:
            self._file.close()
        finally:
            self.temp_path.unlink(missing_ok=True)

    @property
    def steps_written(self) -> int:
        """How many steps (states) have been written so far."""
        return self._next_step

    @property
    def scene_written(self) -> bool:
        return self._scene_written


def _create_part_file(path: Path) -> tuple[Path, Any]:
    """A new, uniquely named ``<name>.<pid>.<random>.part`` file beside ``path``, open for writing. Made with
    os.open rather than tempfile.mkstemp so that the umask, not mkstemp's 0600, sets its permissions."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0)
    while True:
        temp = path.with_name(f"{path.name}.{os.getpid()}.{secrets.token_hex(4)}.part")
        try:
            fd = os.open(temp, flags, 0o666)
        except FileExistsError:
            continue
        return temp, os.fdopen(fd, "wb")


def _fsync_directory(directory: Path) -> None:
    """Persist a rename (best effort: not every platform can open a directory)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


# -- logging from a live env --------------------------------------------------------------------------------
def log_env_scene(writer: McapEpisodeWriter, env) -> None:
    """Write ``env``'s scene (goal, walls, object shape, robot radii) after its ``reset()``."""
    base = env.unwrapped
    world = base.world
    if world is None:
        raise McapError(writer.path, "the env has no world yet: call env.reset() before logging it")
    spec = world.object_spec
    writer.write_scene(
        goal=base.goal,
        walls=world.walls,
        object_kind=None if spec is None else spec.kind,
        object_size=None if spec is None else spec.size,
        robot_radii=(world.swarm.contracted_radius, world.swarm.expanded_radius),
    )


def log_env_step(
    writer: McapEpisodeWriter, env, step: int, action, reward, terminated, truncated, info, *, magnets: bool = True
) -> None:
    """Log ``env``'s state after ``reset()`` (``step`` 0: pass None for action, reward, terminated and
    truncated; the scene is written too unless it already was) or after its ``step``-th ``env.step``.

    The arrays come from ``env.unwrapped.world``; the metrics from ``info``. A Discrete(2^N) action is
    logged as its N bits (robot 0 the most significant), the targets the env applied. ``magnets=False``
    skips ``/swarm/magnets`` (about a third of the logging cost at N=9); keep it the same for a whole episode.
    """
    base = env.unwrapped
    world = base.world
    if world is None:
        raise McapError(writer.path, "the env has no world yet: call env.reset() before logging it")
    swarm = world.swarm
    if step == 0 and not writer.scene_written:
        log_env_scene(writer, env)
    if action is not None and np.ndim(action) == 0 and getattr(base, "action_type", "") == "discrete":
        action = (int(action) >> np.arange(base.n_robots - 1, -1, -1)) & 1
    has_object = world.object_body is not None
    writer.write_step(
        step,
        positions=swarm.position,
        angles=swarm.angle,
        velocities=swarm.velocity,
        angular_velocities=swarm.angular_velocity,
        expansions=swarm.expansion,
        alive=swarm.alive,
        action=action,
        reward=reward,
        terminated=terminated,
        truncated=truncated,
        metrics=None if step == 0 else info,
        object_pose=world.object_pose if has_object else None,
        object_velocity=world.object_velocity if has_object else None,
        magnets=swarm.magnet_segments() if magnets else None,
        centre_of_mass=world.centre_of_mass,
    )


# -- reader -------------------------------------------------------------------------------------------------
@dataclass
class McapEpisode:
    """One episode read back from a ``dpr-mcap/1`` file.

    ``T`` env steps give ``T + 1`` states (row 0 is the reset state) and ``T`` actions: ``actions[i]`` was
    taken in state ``i`` and produced state ``i + 1``, ``rewards[i]``, ``terminated[i]``, ``truncated[i]`` and
    ``metrics[key][i]``. ``alive`` is the step-0 mask (robots do not die or revive within an episode).
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

    @property
    def n_steps(self) -> int:
        """T, the number of env steps."""
        return len(self.rewards)

    @property
    def n_robots(self) -> int:
        return self.positions.shape[1]

    @property
    def times(self) -> np.ndarray:
        """Seconds of each state since the reset."""
        return self.steps / FPS


def _raw_messages(path: Path) -> tuple[dict[str, Any], dict[str, list[dict]]]:
    """Metadata and decoded messages per topic (all topics but foreign ones, sorted by step). Any failure of
    the mcap library (bad magic, truncation, CRC mismatch, bad compression) becomes a McapError naming
    ``path``."""
    try:
        with path.open("rb") as stream:
            reader = make_reader(stream, validate_crcs=True)
            summary = reader.get_summary()
            if summary is None:
                raise McapError(path, "no summary section: the file was not closed by its writer")
            metadata = _decode_metadata(path, list(reader.iter_metadata()))
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
    return metadata, messages


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
    metadata, messages = _raw_messages(path)
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
        return _assemble(metadata, messages)
    except (KeyError, TypeError, ValueError) as exc:
        raise McapError(path, f"malformed message ({type(exc).__name__}: {exc})") from exc


def _assemble(metadata: dict[str, Any], messages: dict[str, list[dict]]) -> McapEpisode:
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
        metrics={
            key: _column(rewards, key, bool if key == "is_success" else np.float64) for key in METRIC_KEYS
        },
        goal=np.array(scene["goal"], dtype=np.float64),
        walls=[np.array(wall, dtype=np.float64).reshape(-1, 2) for wall in scene["walls"]],
        object_poses=object_poses,
        object_velocities=object_velocities,
        magnets=magnets,
        scene=scene,
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
