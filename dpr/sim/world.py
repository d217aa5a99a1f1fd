"""The physics world: a swarm, optional walls and object, stepped at the control rate."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pymunk
import pymunk.batch
from pymunk._chipmunk import lib

from dpr.checks import check_int
from dpr.sim import constants as C
from dpr.sim.models import swarm_class
from dpr.sim.objects import add_object, add_walls
from dpr.sim.swarm import Swarm

_FIELDS = (
    pymunk.batch.BodyFields.POSITION
    | pymunk.batch.BodyFields.ANGLE
    | pymunk.batch.BodyFields.VELOCITY
    | pymunk.batch.BodyFields.ANGULAR_VELOCITY
)
# Beyond this distance from the origin or speed, the state is treated as a physics blow-up.
_SANE_LIMIT = 1e6


@dataclass(frozen=True)
class ObjectSpec:
    """A manipulated object: ``kind`` "ball" (size = radius) or "box" (size = half side)."""

    kind: str
    position: tuple[float, float]
    angle: float = 0.0
    mass: float = 100.0
    size: float = 30.0


def grid_centres(n_robots: int, centre, pitch: float = C.GRID_PITCH) -> np.ndarray:
    """Robot centres on a square grid of ``ceil(sqrt(N))`` columns around ``centre`` (the paper's layout)."""
    columns = int(np.ceil(np.sqrt(n_robots)))
    index = np.arange(n_robots)
    offsets = np.stack([index % columns, index // columns], axis=1) - columns / 2 + 0.5
    return np.asarray(centre, dtype=float) + offsets * pitch


class World:
    """A pymunk space holding one swarm, static walls and at most one object.

    ``step(targets)`` runs one control step: the swarm applies its command rule, refreshes its magnets,
    then the space is stepped ``swarm.substeps`` times (``step_physics``); afterwards every body's state is read in one
    batch call. A new World is built for every episode: pymunk keeps contact caches in a space, so re-using
    one would break determinism.
    """

    def __init__(
        self,
        n_robots: int,
        robot_model: str = "paddle",
        centre=(0.0, 0.0),
        dead=None,
        walls: list[np.ndarray] | None = None,
        obj: ObjectSpec | None = None,
    ):
        check_int("n_robots", n_robots, minimum=1)
        self.space = pymunk.Space()
        dead_mask = np.zeros(n_robots, dtype=bool)
        if dead is not None:
            dead_mask[np.asarray(dead, dtype=np.int64)] = True
        self.swarm: Swarm = swarm_class(robot_model)(self.space, grid_centres(n_robots, centre), dead_mask)
        self.dead = dead_mask
        self.walls = [np.asarray(w, dtype=float) for w in (walls or [])]
        self.wall_shapes = add_walls(self.space, self.walls)
        self.object_spec = obj
        self.object_body = None
        self.object_shape = None
        if obj is not None:
            self.object_body, self.object_shape = add_object(
                self.space, obj.kind, obj.position, obj.angle, obj.mass, obj.size
            )
        self._n_bodies = len(self.swarm.bodies) + (obj is not None)
        self._buffer = pymunk.batch.Buffer()
        self.object_pose = np.zeros(3)
        self.object_velocity = np.zeros(2)
        self._check_body_order()
        self.read_state()

    @property
    def n_robots(self) -> int:
        return self.swarm.n

    def robots_touch_walls(self) -> bool:
        """Whether any robot's shape touches a wall now (pymunk's shape query, exact for paddles too)."""
        return any(
            hit.shape.body.body_type == pymunk.Body.DYNAMIC and hit.shape is not self.object_shape
            for wall in self.wall_shapes
            for hit in self.space.shape_query(wall)
        )

    @property
    def robot_model(self) -> str:
        return self.swarm.model

    def step(self, targets: np.ndarray) -> None:
        """One control step with expansion ``targets`` in [0, 1] (one per robot)."""
        swarm = self.swarm
        swarm.command(np.asarray(targets, dtype=float))
        swarm.update_magnets()
        swarm.before_physics()
        self.step_physics()
        swarm.after_physics()
        self.read_state()

    def step_physics(self) -> None:
        """The pymunk part of a control step: ``substeps`` calls of ``space.step`` (what benchmarks time as
        the physics-only rate)."""
        dt = C.CONTROL_PERIOD / self.swarm.substeps
        substeps = self.swarm.substeps
        if self.space._bodies_to_check:  # bodies added since the last step: pymunk's own step validates them
            self.space.step(dt)
            substeps -= 1
        # Nothing is added, removed or called back inside a step (the world has no collision handlers), so the
        # substeps call chipmunk directly, without pymunk's per-call bookkeeping.
        space_step, space = lib.cpSpaceStep, self.space._space
        for _ in range(substeps):
            space_step(space, dt)

    def read_state(self) -> None:
        """Read all bodies (robots, paddles, object) in one batch call into numpy views; also sets
        ``centre_of_mass``, the mean of the robot centres (the paper's swarm centre)."""
        if self._buffer is None:
            self._buffer = pymunk.batch.Buffer()
        self._buffer.clear()
        pymunk.batch.get_space_bodies(self.space, _FIELDS, self._buffer)
        # Dynamic bodies come first, in the order they were added; the static body follows.
        rows = np.frombuffer(self._buffer.float_buf(), dtype=np.float64).reshape(-1, 6)[: self._n_bodies].copy()
        self.swarm.update_state(rows)
        self.centre_of_mass = self.swarm.position.sum(axis=0) * (1.0 / self.swarm.n)  # np.mean costs 3x more
        if self.object_body is not None:
            self.object_pose = rows[-1, 0:3]
            self.object_velocity = rows[-1, 3:5]
        self._rows = rows

    def _check_body_order(self) -> None:
        buffer = pymunk.batch.Buffer()
        pymunk.batch.get_space_bodies(self.space, pymunk.batch.BodyFields.BODY_ID, buffer)
        ids = list(memoryview(buffer.int_buf()).cast("P"))[: self._n_bodies]
        expected = [b.id for b in self.swarm.bodies] + ([self.object_body.id] if self.object_body else [])
        if ids != expected:
            raise RuntimeError("pymunk.batch returned bodies out of insertion order")

    def is_sane(self) -> bool:
        """False when any body's state is non-finite or absurdly large (a physics blow-up)."""
        # NaN compares False, so one reduction catches NaN, infinities and runaway values alike
        return bool(np.abs(self._rows).max() < _SANE_LIMIT)

    # Batch buffers are cffi objects: rebuild them after unpickling. pymunk re-measures a PinJoint's
    # length from its bodies when unpickling it, so lengths are carried explicitly.
    def __getstate__(self):
        state = self.__dict__.copy()
        state["_buffer"] = None
        state["_pin_lengths"] = [(j, j.distance) for j in self.space.constraints if isinstance(j, pymunk.PinJoint)]
        return state

    def __setstate__(self, state):
        lengths = state.pop("_pin_lengths", [])
        self.__dict__.update(state)
        for joint, length in lengths:
            joint.distance = length
