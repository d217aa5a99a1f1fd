"""Manipulation: push an object to the goal."""

import numpy as np

from dpr.envs.particle_env import ParticleSwarmEnv
from dpr.sim.objects import OBJECT_TYPES, direction_angle
from dpr.sim.world import ObjectSpec


class ManipulationEnv(ParticleSwarmEnv):
    """
    ## Description
    The swarm must push an object (a ball by default, or a box) to the goal. The object has ground friction
    like the robots; reward, success and metrics follow the object, not the swarm.

    ## Action Space
    As Navigation.

    ## Observation Space
    Navigation's ``6N`` robot features followed by the object's x, y (goal frame), vx, vy, all / 1000:
    ``Box(6N + 4,)``.

    ## Rewards
    As Navigation, computed on the object's position.

    ## Starting State
    As Navigation; the object is placed touching the swarm on the goal side, on the line from the swarm's
    centre to the goal (a box turned to face the swarm with one side).

    ## Episode End
    Terminated when the object comes within 10 units of the goal; truncated as in Navigation.

    ## Arguments
    Navigation's, plus ``object_type="ball"`` (or ``"box"``), ``object_mass=100.0``, ``object_size=30.0``
    (the ball's radius, or half the box's side).

    ## Version History
    * v0: first version; the goal is a marker, not a solid block, so the object can reach it.
    """

    task = "manipulation"
    has_object = True

    def __init__(self, object_type: str = "ball", object_mass: float = 100.0, object_size: float = 30.0, **kwargs):
        super().__init__(**kwargs)
        if object_type not in OBJECT_TYPES:
            raise ValueError(f"object_type must be one of {OBJECT_TYPES}, got {object_type!r}")
        if not object_mass > 0:
            raise ValueError(f"object_mass must be > 0, got {object_mass!r}")
        if not object_size > 0:
            raise ValueError(f"object_size must be > 0, got {object_size!r}")
        self.object_type = object_type
        self.object_mass = float(object_mass)
        self.object_size = float(object_size)

    def _object(self, start: np.ndarray, centres: np.ndarray) -> ObjectSpec:
        toward_goal = (self.goal - start) / np.linalg.norm(self.goal - start)
        reach = float(((centres - start) @ toward_goal).max()) + self.swarm_class.contracted_radius
        position = start + toward_goal * (reach + self.object_size + 1.0)
        return ObjectSpec(
            self.object_type,
            (float(position[0]), float(position[1])),
            angle=direction_angle(toward_goal),
            mass=self.object_mass,
            size=self.object_size,
        )
