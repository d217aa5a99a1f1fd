"""Writing ``dpr-mcap/1`` episode logs: :class:`McapEpisodeWriter`, and logging a live env into one with
:func:`log_env_scene` and :func:`log_env_step`.

Crash safety: while an episode runs, its log lives in an anonymous spool (memory, spilling past
``SPOOL_MEMORY`` bytes to an unlinked file in the system's temporary folder), so a killed run leaves nothing of an
unfinished episode on disk. :meth:`McapEpisodeWriter.close` copies the finished log into a
:class:`dpr.atomic.AtomicFile` beside the target, fsyncs it and renames it onto the final name; an exception inside
``with McapEpisodeWriter(...)`` drops the spool.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import tempfile
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer

from dpr.atomic import AtomicFile
from dpr.checks import check_choice, check_int
from dpr.datasets import features as F
from dpr.datasets.mcap.schema import (
    _SCHEMA_BYTES,
    MAGNET_DECIMALS,
    MCAP_FORMAT,
    METADATA_NAME,
    METRIC_KEYS,
    REQUIRED_TOPICS,
    SCHEMAS,
    STEP_NS,
    TOPIC_ACTION,
    TOPIC_MAGNETS,
    TOPIC_OBJECT,
    TOPIC_REWARD,
    TOPIC_SCENE,
    TOPIC_STATE,
    McapError,
    _encode,
    _encode_metadata,
)
from dpr.envs.particle_env import MAX_EPISODE_STEPS
from dpr.sim.constants import FPS

_COMPRESSIONS = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}


def episode_metadata(env, *, seed: int | None, policy: str, **extra: Any) -> dict[str, Any]:
    """The usual ``dpr.episode`` metadata of one episode of ``env`` (wrapped or not): env id and kwargs
    from its spec, seed, robot count and model, the policy's name, and any ``extra`` keys."""
    base = env.unwrapped
    spec = getattr(env, "spec", None)
    metadata: dict[str, Any] = {
        F.ENV_ID: spec.id if spec is not None else type(base).__name__,
        F.SEED: seed,
        F.N_ROBOTS: int(base.n_robots),
        F.ROBOT_MODEL: str(base.robot_model),
        F.POLICY: policy,
        F.ENV_KWARGS: dict(spec.kwargs) if spec is not None else {},
    }
    metadata.update(extra)
    return metadata


# -- what one step logs -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SwarmState:
    """The swarm after a reset or a step, as :meth:`McapEpisodeWriter.write_step` logs it. Arrays are per robot:
    ``positions`` and ``velocities`` (N, 2), the others (N,). ``object_pose`` (x, y, angle) with
    ``object_velocity`` (vx, vy), and ``magnets`` (M, 2, 2), are recorded if step 0 has them, and then required at
    every step. ``centre_of_mass`` defaults to the mean of ``positions``."""

    positions: Any
    angles: Any
    velocities: Any
    angular_velocities: Any
    expansions: Any
    alive: Any
    object_pose: Any = None
    object_velocity: Any = None
    magnets: Any = None
    centre_of_mass: Any = None


@dataclass(frozen=True)
class StepOutcome:
    """What a step after the reset did: the action it was given, its reward and end flags, and the metrics so
    far (keys :data:`METRIC_KEYS`; extra keys, as in an env's ``info``, are ignored). Every field is needed; one
    left out is named by :meth:`McapEpisodeWriter.write_step`."""

    action: Any = None
    reward: float | None = None
    terminated: bool | None = None
    truncated: bool | None = None
    metrics: Mapping[str, Any] | None = None


# -- writer -------------------------------------------------------------------------------------------------
def _array(path: Path, name: str, value: Any, shape: tuple[int, ...], dtype=np.float64) -> np.ndarray:
    array = np.asarray(value, dtype=dtype)
    if array.shape != shape:
        raise McapError(path, f"{name} must have shape {shape}, got {array.shape}")
    return array


# An episode log stays in memory up to this size (a 2500-step episode of 9 robots takes about 2 MB), then
# spills to an unlinked temporary file that the operating system reclaims however the process ends.
SPOOL_MEMORY = 64 << 20


class McapEpisodeWriter:
    """Writes one episode to an MCAP file; use as a context manager.

    Call :meth:`write_scene` once and :meth:`write_step` for steps 0, 1, 2, ... in order (step 0 is the reset
    state and takes no :class:`StepOutcome`; every later step needs one). Nothing appears under
    ``path`` until :meth:`close` succeeds, and nothing of the episode is on disk under any name before it: the
    data goes to an anonymous spool, copied on close into a temporary file beside ``path`` (see
    :class:`dpr.atomic.AtomicFile`), fsynced and renamed onto ``path`` (replacing any file there). Leaving the
    ``with`` block by an exception, or :meth:`abort`, drops the spool.

    ``action_repeat``: physics steps (0.1 s each) per env step, as the env was made with: step ``t`` is logged at
    ``t * action_repeat * 0.1 s``, and the number is kept in the metadata record (see :mod:`dpr.datasets.mcap`).

    ``compression``: "zstd" (default), "lz4" or "none", applied per MCAP chunk of ``chunk_size`` bytes. A bad
    ``action_repeat``, ``compression`` or ``chunk_size`` raises :class:`dpr.checks.ParameterError` naming it.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        metadata: Mapping[str, Any],
        action_repeat: int = 1,
        compression: str = "zstd",
        chunk_size: int = 1 << 20,
    ):
        self.path = Path(path)
        check_choice("compression", compression, _COMPRESSIONS)
        check_int("chunk_size", chunk_size, minimum=1)
        self.action_repeat = check_int("action_repeat", action_repeat, 1, MAX_EPISODE_STEPS)
        if not self.path.parent.is_dir():
            raise McapError(self.path, f"directory {str(self.path.parent)!r} does not exist")
        encoded_metadata = _encode_metadata(self.path, metadata, self.action_repeat)
        self._file = tempfile.SpooledTemporaryFile(max_size=SPOOL_MEMORY)
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
        log_time = step * self.action_repeat * STEP_NS  # simulated time, in integer nanoseconds
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

    def write_step(self, step: int, state: SwarmState, outcome: StepOutcome | None = None) -> None:
        """One control step: the swarm's ``state`` after it and, for ``step >= 1``, the ``outcome`` that led to it
        (step 0, the reset state, takes none). Everything is checked before anything is written, so a bad call
        leaves the file consistent."""
        self._check_open()
        if isinstance(step, bool) or not isinstance(step, (int, np.integer)) or step != self._next_step:
            raise McapError(
                self.path, f"steps must be written in order 0, 1, 2, ...: expected {self._next_step}, got {step!r}"
            )
        step = int(step)
        n, message = self._state_message(step, state)
        extra = self._optional_messages(step, state.object_pose, state.object_velocity, state.magnets)
        outcome_messages = self._outcome_messages(step, n, StepOutcome() if outcome is None else outcome)
        self._message(TOPIC_STATE, step, message)
        for topic, extra_message in extra + outcome_messages:
            self._message(topic, step, extra_message)
        self._next_step = step + 1

    def _state_message(self, step: int, state: SwarmState) -> tuple[int, dict]:
        """The robot count N and the ``/swarm/state`` message; step 0 fixes N and which optional parts follow."""
        path = self.path
        positions = np.asarray(state.positions, dtype=np.float64)
        if positions.ndim != 2 or positions.shape[1] != 2 or len(positions) < 1:
            raise McapError(path, f"positions must have shape (N, 2), got {positions.shape}")
        n = len(positions)
        if step == 0:
            self._n_robots = n
            self._has_object = state.object_pose is not None
            self._has_magnets = state.magnets is not None
        elif n != self._n_robots:
            raise McapError(
                path, f"positions must have shape ({self._n_robots}, 2) as at step 0, got {positions.shape}"
            )
        velocities = _array(path, "velocities", state.velocities, (n, 2))
        centre_of_mass = positions.mean(axis=0) if state.centre_of_mass is None else state.centre_of_mass
        xy = positions.T.tolist()
        vxy = velocities.T.tolist()
        message = {
            "step": step,
            "time": step * self.action_repeat / FPS,
            "x": xy[0],
            "y": xy[1],
            "angle": _array(path, "angles", state.angles, (n,)).tolist(),
            "vx": vxy[0],
            "vy": vxy[1],
            "omega": _array(path, "angular_velocities", state.angular_velocities, (n,)).tolist(),
            "expansion": _array(path, "expansions", state.expansions, (n,)).tolist(),
            "alive": _array(path, "alive", state.alive, (n,), dtype=bool).tolist(),
            "centre_of_mass": _array(path, "centre_of_mass", centre_of_mass, (2,)).tolist(),
        }
        return n, message

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

    def _outcome_messages(self, step: int, n: int, outcome: StepOutcome) -> list[tuple[str, dict]]:
        path = self.path
        given = {field.name: getattr(outcome, field.name) for field in dataclasses.fields(outcome)}
        if step == 0:
            extra = [name for name, value in given.items() if value is not None]
            if extra:
                raise McapError(path, f"step 0 is the reset state and takes no {', '.join(extra)}")
            return []
        missing = [name for name, value in given.items() if value is None]
        if missing:
            raise McapError(path, f"step {step}: {', '.join(missing)} required for every step after 0")
        action_array = np.asarray(outcome.action)
        if action_array.shape != (n,) or action_array.dtype.kind not in "buif":
            raise McapError(
                path, f"action must be {n} numbers, got shape {action_array.shape} dtype {action_array.dtype}"
            )
        if action_array.dtype.kind == "b":
            action_array = action_array.astype(np.int64)
        metrics = outcome.metrics
        absent = [key for key in METRIC_KEYS if key not in metrics]
        if absent:
            raise McapError(path, f"step {step}: metrics lacks {', '.join(absent)}")
        outcome = {
            "step": step,
            "reward": float(outcome.reward),
            "terminated": bool(outcome.terminated),
            "truncated": bool(outcome.truncated),
            "projected_displacement": float(metrics["projected_displacement"]),
            "net_displacement": float(metrics["net_displacement"]),
            "total_distance": float(metrics["total_distance"]),
            "is_success": bool(metrics["is_success"]),
        }
        return [(TOPIC_ACTION, {"step": step, "action": action_array.tolist()}), (TOPIC_REWARD, outcome)]

    # -- finishing ------------------------------------------------------------------------------------------
    def close(self) -> None:
        """Finish the file and move it onto ``path``. Raises McapError (and removes the temporary file) when no
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
            self._file.seek(0)
            with AtomicFile(self.path) as target:  # fsynced before the rename: the name never points at missing data
                shutil.copyfileobj(self._file, target.file, 1 << 20)
        finally:
            self.abort()
        self._closed = True

    def abort(self) -> None:
        """Drop the episode's spool; ``path`` is left as it was."""
        self._closed = True
        self._file.close()

    @property
    def steps_written(self) -> int:
        """How many steps (states) have been written so far."""
        return self._next_step

    @property
    def scene_written(self) -> bool:
        return self._scene_written


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
    writer: McapEpisodeWriter, env, step: int, outcome: StepOutcome | None = None, *, magnets: bool = True
) -> None:
    """Log ``env``'s state after ``reset()`` (``step`` 0, no ``outcome``; the scene is written too unless it
    already was) or after its ``step``-th ``env.step``, whose ``outcome`` carries the ``info`` it returned as
    its metrics.

    The arrays come from ``env.unwrapped.world``. A Discrete(2^N) action is logged as its N bits (robot 0 the
    most significant), the targets the env applied. ``magnets=False`` skips ``/swarm/magnets`` (about a third of
    the logging cost at N=9); keep it the same for a whole episode.
    """
    base = env.unwrapped
    world = base.world
    if world is None:
        raise McapError(writer.path, "the env has no world yet: call env.reset() before logging it")
    repeat = getattr(base, "action_repeat", 1)
    if repeat != writer.action_repeat:
        raise McapError(
            writer.path,
            f"the env takes {repeat} physics steps per step and the writer logs {writer.action_repeat}: make the "
            f"writer with action_repeat={repeat}, so that its log times are the simulated time",
        )
    swarm = world.swarm
    if step == 0 and not writer.scene_written:
        log_env_scene(writer, env)
    action = None if outcome is None else outcome.action
    if action is not None and np.ndim(action) == 0 and getattr(base, "action_type", "") == "discrete":
        outcome = dataclasses.replace(outcome, action=(int(action) >> np.arange(base.n_robots - 1, -1, -1)) & 1)
    has_object = world.object_body is not None
    state = SwarmState(
        positions=swarm.position,
        angles=swarm.angle,
        velocities=swarm.velocity,
        angular_velocities=swarm.angular_velocity,
        expansions=swarm.expansion,
        alive=swarm.alive,
        object_pose=world.object_pose if has_object else None,
        object_velocity=world.object_velocity if has_object else None,
        magnets=swarm.magnet_segments() if magnets else None,
        centre_of_mass=world.centre_of_mass,
    )
    writer.write_step(step, state, outcome)
