"""Gate: navigate the swarm through an opening narrower than itself."""

from __future__ import annotations

import numpy as np

from dpr.checks import ParameterError, check_number_range
from dpr.envs.particle_env import GOAL_CLEARANCE, MAX_DISTANCE, ParticleSwarmEnv
from dpr.sim.objects import gate_polygons
from dpr.sim.world import grid_centres

WALL_THICKNESS = 100.0
WALL_CLEARANCE = 10.0  # Gate-v0: the least gap between the walls and a contracted robot they block, at the start
# Gate-v1's gap between the walls' near face and the robots they block: clear at rest, met by the first
# expansion of a front robot (docs/envs.md gives the wave's contact steps and distances)
GATE_DISTANCE = 5.0
# info keys of the passage measure (ParticleSwarmEnv.episode_measures)
GATE_PASSAGE = "gate_passage"
GATE_CONTACT_STEP = "gate_contact_step"
OPENING = "opening"  # the opening's centre, a landmark of the state observation with observe_opening


class GateEnv(ParticleSwarmEnv):
    """
    ## Description
    Navigation (see ``NavigationEnv``) with two static walls, 100 thick and 500 long, across the line from the
    swarm's start to the goal, leaving an opening of ``gate_width`` (150 by default) on that line: wider than
    one expanded robot, narrower than the swarm, which must deform to squeeze through. From ``dpr/Gate-v1`` on the
    walls' near face stands ``gate_distance`` (5) ahead of the robots they block, so that the swarm meets them
    as soon as its front robots expand. ``dpr/Gate-v0`` keeps the paper's placement, the walls halfway
    between start and goal, 175-275 units ahead of the swarm: farther than the wave carries a swarm of 9 in
    2500 steps, so its episodes are Navigation's.

    ## Action Space
    As Navigation.

    ## Observation Space
    Navigation's ``6N`` robot features followed by the opening's centre, x and y in the goal frame, / 1000
    (``opening.x``, ``opening.y``): ``Box(6N + 2,)``; with ``obs_last_action=True`` the previous action and its held
    steps follow (N + 1). With ``observe_opening=False`` (v0, v1) the state is Navigation's: the walls are not in
    it, and once the swarm has moved, how far ahead they stand cannot be read from it (the distance from the
    start to the goal varies by 100 units).
    ``environment_state()`` ends with ``gate.dx``, ``gate.dy``: the opening's centre relative to the swarm's
    centre, / 1000.

    ## Rewards
    As Navigation.

    ## Starting State
    As Navigation; the walls are placed once the start is drawn. From v1 on, the front is the farthest point toward
    the goal of the contracted robots that the opening does not hold (of the whole swarm if it holds them all);
    robots it holds may start inside the opening. No robot starts in a wall, at any size.

    ## Episode End
    As Navigation.

    ## Info
    Navigation's, plus the passage measure: ``gate_passage``, the fraction of robots whose centre is past the
    walls' near face, and ``gate_contact_step``, the physics step at which a robot first touched a wall (-1
    until then). Evaluations report both at the episode's end.

    ## Arguments
    Navigation's, plus ``gate_width=150.0``, which must exceed one expanded robot's diameter (77.5) and be
    finite and <= 1e5 (``[low, high]``: drawn uniformly each episode, to train on a spread of openings, every
    start then drawn as for ``low``), ``gate_distance`` (v1, v2: 5.0; None: halfway, v0's placement;
    ``[low, high]``: drawn uniformly each episode, to train on a spread of placements, every start then drawn as
    for ``high``), finite, >= 0 and at most the near end of ``start_radius``, and ``observe_opening`` (v2: True;
    see Observation Space).

    ## Version History
    * v2: the opening's centre in the state observation (``observe_opening``).
    * v1: the walls stand ``gate_distance`` ahead of the front of the robots they block, where the swarm meets
      them; the passage measure in ``info``.
    * v0: the paper's placement, halfway to the goal; walls collide with every robot (robot 0 used to pass
      through them).
    """

    task = "gate"
    task_description = "navigate the swarm through the gate to the goal"
    episode_measures = (GATE_PASSAGE, GATE_CONTACT_STEP)
    environment_extra_names = ("gate.dx", "gate.dy")  # the opening's centre relative to the swarm's centre

    def __init__(
        self,
        gate_width: float = 150.0,
        gate_distance: float | None = GATE_DISTANCE,
        observe_opening: bool = True,
        **kwargs,
    ):
        if not isinstance(observe_opening, (bool, np.bool_)):
            raise ParameterError("observe_opening", f"expected True or False, got {observe_opening!r}")
        self.observe_opening = bool(observe_opening)
        self.landmark_names = (OPENING,) if self.observe_opening else ()  # before the spaces are built
        super().__init__(**kwargs)
        diameter = 2 * self.swarm_class.expanded_radius
        self._gate_widths = check_number_range("gate_width", gate_width, maximum=MAX_DISTANCE)
        if not self._gate_widths[0] > diameter:
            raise ValueError(
                f"gate_width must be wider than one expanded robot ({diameter:g} for robot_model="
                f"{self.robot_model!r}), got {gate_width!r}"
            )
        self.gate_width = _checked(gate_width, self._gate_widths)
        self._width = self._gate_widths[0]  # this episode's opening
        self._gate_distances = None if gate_distance is None else self._distance_range(gate_distance)
        if self._gate_distances is not None:
            gate_distance = _checked(gate_distance, self._gate_distances)
        self.gate_distance = gate_distance
        self._gate_along = np.zeros(2)  # unit vector from the start toward the goal
        self._gate_near = 0.0  # the walls' near face, in units from the start along it
        self._gate_centre = np.zeros(2)  # the opening's centre, on the line from the start to the goal
        self._contact_step = -1

    def _blocked_front(
        self, offsets: np.ndarray, directions: np.ndarray, radius: float, width: float, corners: bool = False
    ) -> np.ndarray:
        """For each unit direction (A, 2) toward the goal: the farthest point along it of the robots (offsets
        (N, 2) from the swarm's centre, disks of ``radius``) that an opening ``width`` wide does not hold (-inf if
        it holds them all). With ``corners``, a robot that overlaps the opening's edge reaches only as far as it
        meets the wall's corner: the walls placed there touch it and every robot it holds beside them."""
        along = offsets @ directions.T
        across = np.abs(offsets @ np.stack([-directions[:, 1], directions[:, 0]], axis=1).T)
        half = width / 2
        reach = radius
        if corners:
            reach = np.where(across >= half, radius, np.sqrt(np.maximum(radius**2 - (half - across) ** 2, 0.0)))
        return np.where(across + radius > half, along + reach, -np.inf).max(axis=0)

    def _distance_range(self, gate_distance) -> tuple[float, float]:
        """``gate_distance`` as the (low, high) it is drawn from (one number: both)."""
        low, high = check_number_range("gate_distance", gate_distance, minimum=0.0)
        nearest_goal = self.start_radius[0]
        if high > nearest_goal:
            raise ParameterError(
                "gate_distance",
                f"must be <= {nearest_goal:g} (the near end of start_radius) so that the walls stand between "
                f"the swarm and the goal; got {high:g}",
            )
        return low, high

    def _near_face(self, offsets: np.ndarray, directions: np.ndarray, gate_distance: float, width: float) -> np.ndarray:
        """Gate-v1: the walls' near face for each direction, in units from the swarm's centre: ``gate_distance``
        beyond the front of the contracted robots that an opening ``width`` wide does not hold, where they meet
        the walls (of every robot if it holds them all)."""
        contracted = self.swarm_class.contracted_radius
        front = self._blocked_front(offsets, directions, contracted, width, corners=True)
        whole = (offsets @ directions.T).max(axis=0) + contracted
        return np.where(np.isfinite(front), front, whole) + gate_distance

    def _start_distances(self, offsets: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Besides the goal's clearance, v0: every contracted robot that the opening does not hold stays
        WALL_CLEARANCE in front of the walls, which stand halfway to the goal; v1: the goal lies GOAL_CLEARANCE
        beyond the walls' far face. The narrowest opening holds the fewest robots: its walls stand farthest."""
        narrowest = self._gate_widths[0]
        if self.gate_distance is None:
            front = self._blocked_front(offsets, directions, self.swarm_class.contracted_radius, narrowest)
            walls = 2 * (front + WALL_CLEARANCE + WALL_THICKNESS / 2)
        else:
            farthest = self._gate_distances[1]
            walls = self._near_face(offsets, directions, farthest, narrowest) + WALL_THICKNESS + GOAL_CLEARANCE
        return np.maximum(super()._start_distances(offsets, directions), walls)

    def _walls(self, start: np.ndarray) -> list[np.ndarray]:
        """This episode's walls, and the passage measure's geometry and state."""
        distance = np.linalg.norm(self.goal - start)
        self._gate_along = (self.goal - start) / distance
        self._contact_step = -1
        self._width = self._draw(self._gate_widths)
        if self.gate_distance is None:
            self._gate_near = distance / 2 - WALL_THICKNESS / 2
        else:
            gate_distance = self._draw(self._gate_distances)
            offsets = grid_centres(self.n_robots, (0.0, 0.0))
            self._gate_near = float(self._near_face(offsets, self._gate_along[None, :], gate_distance, self._width)[0])
        at = None if self.gate_distance is None else self._gate_near  # v0's walls as they always were, to the bit
        walls = gate_polygons(start, self.goal, self._width, thickness=WALL_THICKNESS, at=at)
        self._gate_centre = (walls[0][0] + walls[0][3] + walls[1][0] + walls[1][3]) / 4  # the walls' inner corners
        return walls

    def _draw(self, bounds: tuple[float, float]) -> float:
        """This episode's value from ``bounds`` (low, high): uniform, or the one number, which draws nothing."""
        low, high = bounds
        return low if low == high else float(self.np_random.uniform(low, high))

    def _environment_extra(self) -> list[float]:
        """The opening's centre relative to the swarm's centre (``gate.dx``, ``gate.dy``)."""
        return (self._gate_centre - self.world.centre_of_mass).tolist()

    def _landmark_positions(self) -> np.ndarray:
        """With ``observe_opening``: the opening's centre."""
        return self._gate_centre[None, :]

    def _after_physics_step(self) -> None:
        if self._contact_step < 0 and self.world.robots_touch_walls():
            self._contact_step = self.physics_step

    def _info(self) -> dict:
        info = super()._info()
        past = (self.world.swarm.position - self.start) @ self._gate_along > self._gate_near
        info[GATE_PASSAGE] = float(past.mean())
        info[GATE_CONTACT_STEP] = self._contact_step
        return info


def _checked(value, bounds: tuple[float, float]):
    """What the env keeps of a number-or-range argument: the checked float, or [low, high]."""
    return list(bounds) if isinstance(value, (list, tuple)) else bounds[0]
