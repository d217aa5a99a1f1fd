"""Gate: navigate the swarm through an opening narrower than itself."""

import numpy as np

from dpr.checks import check_number
from dpr.envs.particle_env import MAX_DISTANCE, ParticleSwarmEnv
from dpr.sim.objects import gate_polygons

WALL_THICKNESS = 100.0
WALL_CLEARANCE = 10.0  # the least gap between the walls and a contracted robot they block, at the start


class GateEnv(ParticleSwarmEnv):
    """
    ## Description
    Navigation (see ``NavigationEnv``) with two static walls, 100 thick and 500 long, halfway between the
    swarm's start and the goal, across the line joining them, leaving an opening of ``gate_width`` (150 by
    default): wider than one expanded robot, narrower than the swarm, which must squeeze through.

    ## Action Space
    As Navigation.

    ## Observation Space
    As Navigation (the walls are fixed relative to the start and goal and not part of the state).

    ## Rewards
    As Navigation.

    ## Starting State
    As Navigation; the walls are placed once the start is drawn.

    ## Episode End
    As Navigation.

    ## Arguments
    Navigation's, plus ``gate_width=150.0``, which must exceed one expanded robot's diameter
    (77.5 for the paddle model, 105 for the disk model), and be finite and <= 1e5.

    ## Version History
    * v0: first version; walls collide with every robot (robot 0 used to pass through them).
    """

    task = "gate"
    task_description = "navigate the swarm through the gate to the goal"

    def __init__(self, gate_width: float = 150.0, **kwargs):
        super().__init__(**kwargs)
        diameter = 2 * self.swarm_class.expanded_radius
        check_number("gate_width", gate_width, maximum=MAX_DISTANCE)
        if not gate_width > diameter:
            raise ValueError(
                f"gate_width must be wider than one expanded robot ({diameter:g} for robot_model="
                f"{self.robot_model!r}), got {gate_width!r}"
            )
        self.gate_width = float(gate_width)

    def _start_distances(self, offsets: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Besides the goal's clearance: every contracted robot that the opening does not hold stays
        WALL_CLEARANCE in front of the walls, which stand halfway to the goal."""
        radius = self.swarm_class.contracted_radius
        along = offsets @ directions.T
        across = np.abs(offsets @ np.stack([-directions[:, 1], directions[:, 0]], axis=1).T)
        blocked = across + radius > self.gate_width / 2
        front = np.where(blocked, along + radius, -np.inf).max(axis=0)
        walls = 2 * (front + WALL_CLEARANCE + WALL_THICKNESS / 2)
        return np.maximum(super()._start_distances(offsets, directions), walls)

    def _walls(self, start: np.ndarray) -> list[np.ndarray]:
        return gate_polygons(start, self.goal, self.gate_width, thickness=WALL_THICKNESS)
