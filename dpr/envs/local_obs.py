"""What one robot senses: a fixed-size local observation per robot, the same size for every swarm size N.

:class:`LocalObservation` says what is sensed (how many neighbour slots, whether a shared clock, a dead flag
and the object are in it) and where each part sits in the vector; :func:`local_observations` computes every
robot's row from the global state vector in vectorised numpy (neighbours from the O(N) cell grid of
:func:`dpr.sim.neighbours.pairs_within`, no loop over robots). The PettingZoo env's ``local_obs=True``
(:mod:`dpr.envs.parallel`) and the per-robot policy adapter of :mod:`dpr.policies.decentralised` both build their
rows here, so that a per-robot policy sees the same thing in either env.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from gymnasium import spaces

from dpr.checks import check_int, check_number
from dpr.envs.particle_env import LENGTH_SCALE, OBJECT_FEATURES, ROBOT_FEATURES, ParticleSwarmEnv
from dpr.sim.neighbours import pairs_within

MAX_NEIGHBOURS = 8  # neighbour slots of a local observation (a robot on the start grid has 8 within magnet range)
NEIGHBOUR_FEATURES = ROBOT_FEATURES  # x, y relative to the robot, vx, vy, angular velocity, expansion
GOAL_FEATURES = 3  # unit vector from the robot toward the goal (x, y), distance to the goal / 1000
# With distance_period: the unit vector, then sin and cos of 2 pi distance / period in place of the distance.
PERIODIC_GOAL_FEATURES = 4
CLOCK_FEATURES = 2  # sin and cos of 2 pi step / clock_period
EXPANSION = 5  # index of the expansion among a robot's features (own, and in each neighbour slot)


@dataclass(frozen=True)
class LocalObservation:
    """The layout of one robot's local observation (float32), in this order:

    * ``own`` (6): the robot's x, y (goal frame), vx, vy (all / 1000), angular velocity, expansion in [0, 1],
      as in the global state;
    * ``neighbours`` (6K, K = ``max_neighbours``): K slots of the neighbour's x, y *relative to this robot*
      (/ 1000), vx, vy, angular velocity and expansion. Neighbours are the robots whose centres lie closer than
      ``neighbour_range`` (the magnet range: the robots this one is linked to), nearest first (ties by
      index); beyond K only the K nearest are kept. Unused slots are zeros;
    * ``mask`` (K): 1.0 where the slot holds a neighbour, 0.0 where it is padding;
    * ``goal`` (3): the goal signal as the robot senses it: the unit vector from the robot toward the goal
      (zeros on the goal itself), then its distance to the goal (/ 1000). With ``distance_period`` P (world
      units), the goal part is 4 values: the unit vector, then ``sin`` and ``cos`` of ``2 pi d / P`` in place of
      the distance d, and the own x, y are zeros: the robot senses where it stands in a band pattern of period P
      around the goal, not how far the goal is, so nothing in its row grows with the swarm's size;
    * ``clock`` (2, with ``clock_period``): sin and cos of ``2 pi t / clock_period``, t the steps since the
      reset, the same for every robot;
    * ``dead`` (1, with ``dead_flag``: tasks with unresponsive robots): 1.0 if this robot ignores commands;
    * ``object`` (4, with ``has_object``: Manipulation): the object's x, y (goal frame), vx, vy, / 1000.

    ``size`` is ``6 + 7K + 3`` (``+ 4`` with ``distance_period``) plus the optional parts; it does not depend
    on the number of robots.
    """

    max_neighbours: int = MAX_NEIGHBOURS
    has_object: bool = False
    clock_period: int | None = None
    dead_flag: bool = False
    distance_period: float | None = None

    def __post_init__(self):
        check_int("max_neighbours", self.max_neighbours, 1)
        if self.clock_period is not None:
            check_int("clock_period", self.clock_period, 2)  # a period of 1 would be a constant
        if self.distance_period is not None:
            check_number("distance_period", self.distance_period, above=0)
            object.__setattr__(self, "distance_period", float(self.distance_period))

    @classmethod
    def for_env(
        cls,
        env,
        max_neighbours: int = MAX_NEIGHBOURS,
        clock_period: int | None = None,
        distance_period: float | None = None,
    ) -> LocalObservation:
        """The layout for ``env`` (a super-agent env, wrapped or not): its object, its dead robots' flag."""
        base: ParticleSwarmEnv = env.unwrapped
        return cls(max_neighbours, bool(base.has_object), clock_period, bool(base.has_dead_robots), distance_period)

    # -- where each part sits ------------------------------------------------------------------------------
    @property
    def own(self) -> slice:
        return slice(0, ROBOT_FEATURES)

    @property
    def neighbours(self) -> slice:
        return slice(ROBOT_FEATURES, ROBOT_FEATURES + NEIGHBOUR_FEATURES * self.max_neighbours)

    @property
    def mask(self) -> slice:
        start = self.neighbours.stop
        return slice(start, start + self.max_neighbours)

    @property
    def goal(self) -> slice:
        size = GOAL_FEATURES if self.distance_period is None else PERIODIC_GOAL_FEATURES
        return slice(self.mask.stop, self.mask.stop + size)

    @property
    def clock(self) -> slice:
        return slice(self.goal.stop, self.goal.stop + (CLOCK_FEATURES if self.clock_period is not None else 0))

    @property
    def dead(self) -> slice:
        return slice(self.clock.stop, self.clock.stop + (1 if self.dead_flag else 0))

    @property
    def object(self) -> slice:
        return slice(self.dead.stop, self.dead.stop + (OBJECT_FEATURES if self.has_object else 0))

    @property
    def size(self) -> int:
        return self.object.stop

    def space(self) -> spaces.Box:
        """``Box(size,)`` float32: expansions, mask, dead flag in [0, 1]; goal direction, distance phase and clock
        in [-1, 1]; distance >= 0; the rest unbounded."""
        low = np.full(self.size, -np.inf, dtype=np.float32)
        high = np.full(self.size, np.inf, dtype=np.float32)
        k = self.max_neighbours
        unit = [EXPANSION, *(self.neighbours.start + NEIGHBOUR_FEATURES * s + EXPANSION for s in range(k))]
        unit += [*range(self.mask.start, self.mask.stop), *range(self.dead.start, self.dead.stop)]
        low[unit], high[unit] = 0.0, 1.0
        signed = [self.goal.start, self.goal.start + 1, *range(self.clock.start, self.clock.stop)]
        if self.distance_period is None:
            low[self.goal.start + 2] = 0.0
        else:
            signed += [self.goal.start + 2, self.goal.start + 3]
            low[self.own.start : self.own.start + 2] = high[self.own.start : self.own.start + 2] = 0.0
        low[signed], high[signed] = -1.0, 1.0
        return spaces.Box(low, high, dtype=np.float32)

    def observe(
        self,
        state: np.ndarray,
        n_robots: int,
        neighbour_range: float,
        step: int = 0,
        dead: np.ndarray | None = None,
    ) -> np.ndarray:
        """Every robot's row (``(n_robots, size)`` float32) from the global ``state`` vector, ``step`` steps
        after the reset (for the clock) with ``dead`` (bool per robot; needed with ``dead_flag``)."""
        n, k = n_robots, self.max_neighbours
        robots = np.asarray(state[: ROBOT_FEATURES * n], dtype=np.float32).reshape(n, ROBOT_FEATURES)
        out = np.zeros((n, self.size), dtype=np.float32)
        out[:, self.own] = robots
        if self.has_object:
            out[:, self.object] = state[ROBOT_FEATURES * n : ROBOT_FEATURES * n + OBJECT_FEATURES]
        positions = robots[:, 0:2].astype(np.float64)
        distance = np.hypot(positions[:, 0], positions[:, 1])
        goal = out[:, self.goal]
        np.divide(-positions, distance[:, None], out=goal[:, 0:2], where=distance[:, None] > 0)
        if self.distance_period is None:
            goal[:, 2] = distance
        else:
            angle = (2.0 * math.pi / (self.distance_period * LENGTH_SCALE)) * distance
            goal[:, 2], goal[:, 3] = np.sin(angle), np.cos(angle)
            out[:, 0:2] = 0.0
        if self.clock_period is not None:
            angle = 2.0 * math.pi * (int(step) % self.clock_period) / self.clock_period
            out[:, self.clock] = (math.sin(angle), math.cos(angle))
        if self.dead_flag:
            if dead is None:
                raise ValueError("this layout has a dead flag: pass dead (one bool per robot)")
            out[:, self.dead.start] = np.asarray(dead, dtype=bool)

        owner, other, rank = _nearest_neighbours(positions / LENGTH_SCALE, neighbour_range, k)
        slots = out[:, self.neighbours].reshape(n, k, NEIGHBOUR_FEATURES)
        slots[owner, rank] = robots[other]
        slots[owner, rank, 0:2] -= robots[owner, 0:2]
        out[:, self.neighbours] = slots.reshape(n, k * NEIGHBOUR_FEATURES)  # a no-op where reshape gave a view
        out[owner, self.mask.start + rank] = 1.0
        return out


def _nearest_neighbours(positions: np.ndarray, neighbour_range: float, k: int):
    """(owner, neighbour, slot) of every robot's ``k`` nearest robots closer than ``neighbour_range``."""
    pairs = pairs_within(positions, neighbour_range)
    if len(pairs) == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty, empty
    # Each pair gives both robots a neighbour; sort by owner, then by distance, and rank inside each owner.
    owner = np.concatenate([pairs[:, 0], pairs[:, 1]])
    other = np.concatenate([pairs[:, 1], pairs[:, 0]])
    delta = positions[other] - positions[owner]
    distance = np.einsum("ij,ij->i", delta, delta)
    order = np.lexsort((other, distance, owner))  # ties broken by index, so the layout is deterministic
    owner, other = owner[order], other[order]
    counts = np.bincount(owner, minlength=len(positions))
    rank = np.arange(len(owner)) - np.repeat(np.cumsum(counts) - counts, counts)
    keep = rank < k
    return owner[keep], other[keep], rank[keep]


def local_observation_size(
    max_neighbours: int,
    has_object: bool,
    *,
    clock_period: int | None = None,
    dead_flag: bool = False,
    distance_period: float | None = None,
) -> int:
    """Length of one robot's local observation (see :class:`LocalObservation`)."""
    return LocalObservation(max_neighbours, has_object, clock_period, dead_flag, distance_period).size


def local_observations(
    state: np.ndarray,
    n_robots: int,
    neighbour_range: float,
    layout: LocalObservation = LocalObservation(),
    *,
    step: int = 0,
    dead: np.ndarray | None = None,
) -> np.ndarray:
    """Every robot's local observation, one row each, from a global ``state`` vector, in ``layout``; the dead flag
    is included when ``dead`` is given, whatever ``layout.dead_flag`` says."""
    layout = dataclasses.replace(layout, dead_flag=dead is not None)
    return layout.observe(state, n_robots, neighbour_range, step, dead)


__all__ = [
    "CLOCK_FEATURES",
    "GOAL_FEATURES",
    "MAX_NEIGHBOURS",
    "NEIGHBOUR_FEATURES",
    "PERIODIC_GOAL_FEATURES",
    "LocalObservation",
    "local_observation_size",
    "local_observations",
]
