"""A fast robot model: one disk per robot whose radius grows and shrinks."""

from __future__ import annotations

import numpy as np
import pymunk

from dpr.sim import constants as C
from dpr.sim._setters import set_circle_radii, set_max_forces, set_pin_distances
from dpr.sim.neighbours import pairs_and_distances
from dpr.sim.objects import add_ground_friction
from dpr.sim.swarm import Swarm

_SET_DIFF_LIMIT = 256  # pairs (old + new) above which numpy diffs magnet sets faster than Python sets
_PER_UNIT_RADIUS = 1.0 / (C.DISK_EXPANDED_RADIUS - C.DISK_CONTRACTED_RADIUS)  # expansion per unit of radius


class DiskSwarm(Swarm):
    """One body and one circle per robot whose radius follows the paddle robot's outline: 32.3 contracted,
    38.75 expanded, moving at the speed of a full paddle stroke (90 degrees at 5 rad/s, about 0.31 s).

    Magnets are rods between the centres of robots closer than ``DISK_MAGNET_RANGE`` (100, the paddle
    model's). As the paddle model's rods between paddle tips, each step they hold the pair's current
    distance, changed by the two robots' commanded growth: expanding pushes the pair apart, contracting
    pulls it back together, and a pair that drifts apart is not pulled back into contact.

    Growth is bounded, as the paddle's is by its motors. A robot's radius grows into free room and at most
    ``DISK_GROWTH_OVERLAP`` (1 unit) per step into a neighbour (measured at the start of each step), which the
    contact then pushes out; its rods push with at most ``DISK_PUSH_FORCE`` (400, less than the ground
    friction holding a robot) and pull with at most ``MAGNET_MAX_FORCE`` (750). A robot that its neighbours
    hold back keeps pushing, as a stalled motor does, and its expansion (the observed state) lags its command.
    Same ground friction, mass, command rule and dead-robot convention as the paddle model. About 33x fewer
    bodies and 100x fewer joints than the paddle model.
    """

    model = "disk"
    # 2: the paddle robot's outline, force-limited growth, rods that keep the pair's distance (1: radii 27.5 to
    # 52.5, rods pulling each pair into contact)
    revision = 2
    contracted_radius = C.DISK_CONTRACTED_RADIUS
    expanded_radius = C.DISK_EXPANDED_RADIUS
    magnet_range = C.DISK_MAGNET_RANGE
    substeps = 2
    wave_hold_steps = 4  # tools/wave_sweep.py: the disk's stroke is quicker than the paddles'

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
        self.radius = np.full(self.n, C.DISK_CONTRACTED_RADIUS)  # of the collision shapes
        self.commanded_radius = self.radius.copy()  # where the actuator drives: the radius with no load
        self._radius_target = self.radius.copy()
        self._magnets: dict[int, pymunk.PinJoint] = {}  # every rod made so far, by pair key i * N + j
        self._active = np.empty((0, 2), dtype=np.int64)
        self._first = self._second = self._both = np.empty(0, dtype=np.int64)
        self._distance = np.empty(0)  # of each active pair, at the start of this step
        self._active_joints: list[pymunk.PinJoint] = []  # the rods of ``_active``, row by row
        self._rod_pushing: list = []  # per active rod: True while its force limit is the push limit
        # chipmunk handles of the shapes and of the active rods, made on first use (cffi pointers do not pickle)
        self._shape_handles = None
        self._rod_handles = None

    def _drive(self) -> None:
        # dead robots never accept a target, so theirs stays 0 (contracted)
        self._radius_target = C.DISK_CONTRACTED_RADIUS + self.target * (
            C.DISK_EXPANDED_RADIUS - C.DISK_CONTRACTED_RADIUS
        )

    def before_physics(self) -> None:
        """Move each robot's commanded radius by one control period's worth, grow the shapes into the room
        their neighbours leave, and set the rods' lengths and force limits (once per control step:
        per-substep updates cost more Python than the physics itself)."""
        reach = C.DISK_RADIUS_SPEED * C.CONTROL_PERIOD
        radius, commanded = self.radius, self.commanded_radius
        commanded = self.commanded_radius = np.minimum(
            np.maximum(self._radius_target, commanded - reach), commanded + reach
        )
        new_radius = commanded
        if len(self._active):
            first, second = self._first, self._second
            radius_sum = radius.take(first) + radius.take(second)
            commanded_sum = commanded.take(first) + commanded.take(second)
            gap = self._distance - radius_sum  # free room between the two surfaces of each linked pair
            if (commanded > radius).any():
                room = np.full(self.n, np.inf)  # the most a robot may grow and keep clear of every neighbour
                np.minimum.at(room, self._both, np.concatenate((gap, gap)))
                # (a robot that shrinks or holds is below its allowance anyway)
                new_radius = np.minimum(commanded, radius + np.maximum(room + C.DISK_GROWTH_OVERLAP, 0.0))
            # each rod pushes (or pulls) its pair apart by what the two robots still have to grow (or shrink):
            # length = distance + (commanded - radius) of both = gap + both commanded radii
            self._set_rods(gap + commanded_sum, commanded_sum > radius_sum)
        changing = (new_radius != radius).nonzero()[0].tolist()
        if not changing:
            return
        self.radius = new_radius
        # the radius is the expansion state: it changes here only, so expansion is set here, not per read
        self.expansion = (new_radius - C.DISK_CONTRACTED_RADIUS) * _PER_UNIT_RADIUS
        if self._shape_handles is None:
            self._shape_handles = [shape._shape for shape in self._shapes]
        radii = new_radius.tolist()
        if len(changing) == self.n:
            set_circle_radii(self._shape_handles, radii)
        else:
            set_circle_radii([self._shape_handles[r] for r in changing], [radii[r] for r in changing])

    def _set_rods(self, lengths: np.ndarray, pushing: np.ndarray) -> None:
        """Set every active rod's length, and the force limit of those that turned from pulling to pushing
        or back."""
        if self._rod_handles is None:
            self._rod_handles = [joint._constraint for joint in self._active_joints]
        set_pin_distances(self._rod_handles, lengths.tolist())
        pushing_now = pushing.tolist()
        if pushing_now != self._rod_pushing:
            flipped = [k for k, (now, before) in enumerate(zip(pushing_now, self._rod_pushing)) if now is not before]
            set_max_forces(
                [self._rod_handles[k] for k in flipped],
                [C.DISK_PUSH_FORCE if pushing_now[k] else C.MAGNET_MAX_FORCE for k in flipped],
            )
            self._rod_pushing = pushing_now

    def update_magnets(self) -> None:
        """Rods between the centres of every pair closer than the magnet range; kept between steps.

        A pair ``(i, j)`` is keyed by the integer ``i * N + j``; only the rods of pairs that appeared or went
        away are added to or removed from the space."""
        pairs, self._distance = pairs_and_distances(self.position, self.magnet_range)
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
        self._first, self._second = pairs[:, 0].copy(), pairs[:, 1].copy()  # contiguous: faster to take from
        self._both = np.concatenate((self._first, self._second))
        self._active_joints = [self._magnets[key] for key in keys.tolist()]
        self._rod_handles = None
        # a rod taken out and added again keeps its old limit: mark every limit unknown, so all are set
        self._rod_pushing = [None] * len(pairs)

    def magnet_segments(self) -> np.ndarray:
        if len(self._active) == 0:
            return np.zeros((0, 2, 2))
        return np.stack([self.position[self._active[:, 0]], self.position[self._active[:, 1]]], axis=1)

    def __getstate__(self):
        state = self.__dict__.copy()
        state.update(_shape_handles=None, _rod_handles=None)
        return state
