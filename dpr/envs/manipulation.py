"""Manipulation: push an object to the goal."""

import math

import numpy as np

from dpr.checks import check_number
from dpr.envs.particle_env import GOAL_CLEARANCE, ParticleSwarmEnv
from dpr.sim.constants import GRID_PITCH
from dpr.sim.objects import OBJECT_TYPES, direction_angle
from dpr.sim.world import ObjectSpec

OBJECT_STARTS = ("touching", "paper")
OBJECT_MASS_RANGE = (0.01, 1e5)
OBJECT_SIZE_RANGE = (5.0, 500.0)
APPROACH_REWARD_RANGE = (0.0, 100.0)


def _square_point(direction: np.ndarray, half_side: float) -> np.ndarray:
    """Where the ray along ``direction`` leaves a square of ``half_side`` centred on its origin."""
    return direction * half_side / np.abs(direction).max()


def _distance_ahead(
    offsets: np.ndarray, direction: np.ndarray, robot_radius: float, object_type: str, size: float
) -> float:
    """The smallest distance along ``direction`` at which the object clears every robot (centres at
    ``offsets``, contracted radius ``robot_radius``): the object then touches the first robot in its path,
    not a point in empty space in front of the swarm's bounding box. A box faces the swarm with one side."""
    along = offsets @ direction
    across = np.abs(offsets @ np.array([-direction[1], direction[0]]))
    if object_type == "ball":
        reach = robot_radius + size
        in_path = across < reach
        needed = np.sqrt(reach**2 - across[in_path] ** 2)
    else:
        in_path = across < size + robot_radius
        overhang = np.clip(across[in_path] - size, 0.0, None)
        needed = size + np.sqrt(robot_radius**2 - overhang**2)
    return float(np.max(along[in_path] + needed, initial=robot_radius + size))


class ManipulationEnv(ParticleSwarmEnv):
    """
    ## Description
    The swarm must push an object (a ball by default, or a box) to the goal. The object has ground friction
    like the robots; reward, success and metrics follow the object, not the swarm.

    ## Action Space
    As Navigation.

    ## Observation Space
    Navigation's ``6N`` robot features followed by the object's x, y (goal frame), vx, vy, all / 1000:
    ``Box(6N + 4,)``; with ``obs_last_action=True`` the previous action and its held steps follow (N + 1).
    ``environment_state()`` is Navigation's followed by the object's x, y, vx, vy and distance to the goal.

    ## Rewards
    As Navigation, computed on the object's position. With ``approach_reward`` > 0, plus that weight times the
    step's decrease of the distance from the swarm's centre to the object: shaping with that distance as the
    potential (Ng et al., 1999), so over an episode it adds weight x (first gap - last gap), whatever the
    path. The first expansions kick the object ahead of the swarm, which then walks for hundreds of steps
    before it pushes again; the object's own progress rewards that walk only once contact is made, beyond a
    discount horizon of 100 steps, and the shaping rewards it as it happens. Metrics and success still follow
    the object alone.

    ## Starting State
    As Navigation; the object is placed on the goal side of the swarm, on the line from the swarm's centre
    to the goal, 1 unit clear of the first contracted robot on that line (a box turned to face the swarm
    with one side), so that the robot's first expansion reaches it.

    ## Episode End
    Terminated when the object comes within 10 units of the goal; truncated as in Navigation.

    ## Arguments
    Navigation's, plus ``object_type="ball"`` (or ``"box"``), ``object_mass=100.0``, ``object_size=30.0``
    (the ball's radius, or half the box's side), ``approach_reward=0.0`` (the shaping weight, see Rewards);
    each must be finite, with ``object_mass`` in [0.01, 1e5], ``object_size`` in [5, 500] and
    ``approach_reward`` in [0, 100]
    and ``object_start``: ``"touching"`` (default) or
    ``"paper"``, the 2021 code's placement on a square of half side ``ceil(sqrt(N)) / 2 * 77.5 + size / 4``
    around the swarm's centre, which overlaps the contracted front row (by about 16 units at N=9) so that
    the first physics step kicks the object toward the goal; use it to compare with the 2021 figures.

    ## Version History
    * v0: first version; the goal is a marker, not a solid block, so the object can reach it.
    """

    task = "manipulation"
    has_object = True

    def __init__(
        self,
        object_type: str = "ball",
        object_mass: float = 100.0,
        object_size: float = 30.0,
        object_start: str = "touching",
        approach_reward: float = 0.0,
        **kwargs,
    ):
        super().__init__(**kwargs)
        if object_start not in OBJECT_STARTS:
            raise ValueError(f"object_start must be one of {OBJECT_STARTS}, got {object_start!r}")
        self.object_start = object_start
        if object_type not in OBJECT_TYPES:
            raise ValueError(f"object_type must be one of {OBJECT_TYPES}, got {object_type!r}")
        # Finite and bounded: chipmunk aborts the interpreter on an infinite mass, and a size of 1e-300 or 1e300
        # fails mid-episode.
        check_number("object_mass", object_mass, *OBJECT_MASS_RANGE)
        check_number("object_size", object_size, *OBJECT_SIZE_RANGE)
        check_number("approach_reward", approach_reward, *APPROACH_REWARD_RANGE)
        self.approach_reward = float(approach_reward)
        self._gap = 0.0  # the swarm-object distance after the last step (for the shaping)
        self.object_type = object_type
        self.object_mass = float(object_mass)
        self.object_size = float(object_size)
        self.task_description = f"push the {object_type} to the goal"

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        observation, info = super().reset(seed=seed, options=options)
        self._gap = self._swarm_object_gap()
        return observation, info

    def _swarm_object_gap(self) -> float:
        offset = self.world.object_pose[0:2] - self.world.centre_of_mass
        return math.hypot(offset[0], offset[1])

    def _reward(self, previous: tuple[float, float]) -> float:
        reward = super()._reward(previous)
        if self.approach_reward:
            gap = self._swarm_object_gap()
            reward += self.approach_reward * (self._gap - gap)
            self._gap = gap
        return reward

    def _start_distances(self, offsets: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Besides the swarm's: the object, placed in front of the swarm, starts GOAL_CLEARANCE short of the goal."""
        ahead = np.array([self._object_offset(offsets, direction) for direction in directions])
        return np.maximum(super()._start_distances(offsets, directions), ahead + self.object_size + GOAL_CLEARANCE)

    def _object_offset(self, offsets: np.ndarray, toward_goal: np.ndarray) -> float:
        """How far ahead of the swarm's centre, along ``toward_goal``, the object starts."""
        if self.object_start == "paper":
            half_side = math.ceil(math.sqrt(self.n_robots)) / 2 * GRID_PITCH + self.object_size / 4
            return float(half_side / np.abs(toward_goal).max())  # along toward_goal to _square_point
        # 1 unit of air between the object and the nearest contracted robot
        return _distance_ahead(
            offsets, toward_goal, self.swarm_class.contracted_radius + 1.0, self.object_type, self.object_size
        )

    def _object(self, start: np.ndarray, centres: np.ndarray) -> ObjectSpec:
        toward_goal = (self.goal - start) / np.linalg.norm(self.goal - start)
        if self.object_start == "paper":
            position = start + _square_point(
                toward_goal, math.ceil(math.sqrt(self.n_robots)) / 2 * GRID_PITCH + self.object_size / 4
            )
        else:
            # 1 unit of air between the object and the nearest contracted robot
            ahead = _distance_ahead(
                centres - start,
                toward_goal,
                self.swarm_class.contracted_radius + 1.0,
                self.object_type,
                self.object_size,
            )
            position = start + toward_goal * ahead
        return ObjectSpec(
            self.object_type,
            (float(position[0]), float(position[1])),
            angle=direction_angle(toward_goal),
            mass=self.object_mass,
            size=self.object_size,
        )
