"""A fast robot model: one disk per robot whose radius grows and shrinks."""

from __future__ import annotations

import numpy as np
import pymunk

from dpr.sim import constants as C
from dpr.sim._setters import set_circle_radii, set_pin_distances
from dpr.sim.neighbours import pairs_within
from dpr.sim.objects import add_ground_friction
from dpr.sim.swarm import Swarm

_SET_DIFF_LIMIT = 256  # pairs (old + new) above which numpy diffs magnet sets faster than Python sets


class DiskSwarm(Swarm):
    """One body and one circle per robot, radius between 27.5 (contracted) and 52.5 (expanded), moving at
    the speed of a full paddle stroke (90 degrees at 5 rad/s, about 0.31 s).

    Magnets are force-limited rods (max force 750) between the centres of robots closer than
    ``DISK_MAGNET_RANGE``, whose length follows the sum of the two radii: expanding pushes the pair apart,
    contracting pulls it back together. Same ground friction, mass, command rule and dead-robot convention
    as the paddle model. About 33x fewer bodies and 100x fewer joints than the paddle model.
    """

    model = "disk"
    contracted_radius = C.DISK_CONTRACTED_RADIUS
    expanded_radius = C.DISK_EXPANDED_RADIUS
    magnet_range = C.DISK_MAGNET_RANGE
    substeps = 2

    def __init__(self, space: pymunk.Space, centres: np.ndarray, dead: np.ndarray):
        super().__init__(space, centres, dead)
        bodies, shapes = [], []
        for r, centre in enumerate(np.asarray(centres, dtype=float)):
            body = pymunk.Body(C.DISK_MASS, pymunk.moment_for_circle(C.DISK_MASS, 0, C.DISK_CONTRACTED_RADIUS))
            body.position = tuple(centre)
            shape = pymunk.Circle(body, C.DISK_CONTRACTED_RADIUS)
            shape.elasticity, shape.friction = C.BODY_ELASTICITY, C.BODY_FRICTION
            shape.filter = pymunk.ShapeFilter(group=r + 1)
            bodies.append(body)
            shapes.append(shape)
        space.add(*bodies, *shapes)
        for body in bodies:
            add_ground_friction(space, body)
        self.robot_bodies = self.bodies = bodies
        self._shapes = shapes
        self.radius = np.full(self.n, C.DISK_CONTRACTED_RADIUS)
        self._radius_target = self.radius.copy()
        self._magnets: dict[int, pymunk.PinJoint] = {}  # every rod made so far, by pair key i * N + j
        self._active = np.empty((0, 2), dtype=np.int64)
        self._active_joints: list[pymunk.PinJoint] = []  # the rods of ``_active``, row by row
        # chipmunk handles of the shapes and of the active rods, made on first use (cffi pointers do not pickle)
        self._shape_handles = None
        self._rod_handles = None

    def _drive(self) -> None:
        # dead robots never accept a target, so theirs stays 0 (contracted)
        self._radius_target = C.DISK_CONTRACTED_RADIUS + self.target * (
            C.DISK_EXPANDED_RADIUS - C.DISK_CONTRACTED_RADIUS
        )

    def before_physics(self) -> None:
        """Grow or shrink each moving robot by one control period's worth (the shapes and the rods change
        once per control step: per-substep updates cost more Python than the physics itself)."""
        reach = C.DISK_RADIUS_SPEED * C.CONTROL_PERIOD
        step = np.minimum(np.maximum(self._radius_target - self.radius, -reach), reach)  # np.clip costs 2x
        changing = np.flatnonzero(step).tolist()
        if not changing:
            return
        self.radius += step
        # the radius is the expansion state: it changes here only, so expansion is set here, not per read
        self.expansion = (self.radius - C.DISK_CONTRACTED_RADIUS) / (C.DISK_EXPANDED_RADIUS - C.DISK_CONTRACTED_RADIUS)
        radius = self.radius.tolist()
        if self._shape_handles is None:
            self._shape_handles = [shape._shape for shape in self._shapes]
        set_circle_radii([self._shape_handles[r] for r in changing], [radius[r] for r in changing])
        self._set_magnet_lengths()

    def update_magnets(self) -> None:
        """Rods between the centres of every pair closer than the magnet range; kept between steps.

        A pair ``(i, j)`` is keyed by the integer ``i * N + j``; only the rods of pairs that appeared or went
        away are added to or removed from the space."""
        pairs = pairs_within(self.position, self.magnet_range)
        if pairs.tobytes() == self._active.tobytes():  # both (P, 2) int64: equal bytes, equal pairs
            return
        keys = pairs[:, 0] * self.n + pairs[:, 1]
        old = self._active[:, 0] * self.n + self._active[:, 1]
        if len(keys) + len(old) > _SET_DIFF_LIMIT:  # large swarms: numpy's sorted set difference
            gone = old[~np.isin(old, keys, assume_unique=True)].tolist()
            added = keys[~np.isin(keys, old, assume_unique=True)].tolist()
        else:  # small ones: Python sets cost less than numpy's fixed overhead
            old_set, new_set = set(old.tolist()), set(keys.tolist())
            gone, added = sorted(old_set - new_set), sorted(new_set - old_set)  # sorted: the numpy path's order
        if gone:
            self.space.remove(*(self._magnets[key] for key in gone))
        fresh = []
        for key in added:
            joint = self._magnets.get(key)
            if joint is None:
                a, b = divmod(key, self.n)
                joint = pymunk.PinJoint(self.bodies[a], self.bodies[b])
                joint.max_force = C.MAGNET_MAX_FORCE
                self._magnets[key] = joint
            fresh.append(joint)
        if fresh:
            self.space.add(*fresh)
        self._active = pairs
        self._active_joints = [self._magnets[key] for key in keys.tolist()]
        self._rod_handles = None
        self._set_magnet_lengths()

    def _set_magnet_lengths(self) -> None:
        """Rod length = sum of the two radii (all rods: cheaper than picking those of the robots that moved)."""
        pairs = self._active
        if len(pairs):
            if self._rod_handles is None:
                self._rod_handles = [joint._constraint for joint in self._active_joints]
            set_pin_distances(self._rod_handles, (self.radius[pairs[:, 0]] + self.radius[pairs[:, 1]]).tolist())

    def magnet_segments(self) -> np.ndarray:
        if len(self._active) == 0:
            return np.zeros((0, 2, 2))
        return np.stack([self.position[self._active[:, 0]], self.position[self._active[:, 1]]], axis=1)

    def __getstate__(self):
        state = self.__dict__.copy()
        state.update(_shape_handles=None, _rod_handles=None)
        return state
