"""A task defined outside dpr: navigation around a square pillar that stands on the straight way to the goal.

Importing this module registers it as ``pillar_task/Pillar-v0`` (task name ``pillar``); every dpr command sees it
with ``dpr --env-package pillar_task`` when this folder is on the Python path. docs/add-a-task.md walks through it.
"""

import numpy as np

from dpr.envs import ParticleSwarmEnv, register_task
from dpr.envs.particle_env import GOAL_CLEARANCE
from dpr.sim.world import grid_centres

PILLAR_CONTACT_STEP = "pillar_contact_step"  # info key: the first physics step a robot touched the pillar, or -1


class PillarEnv(ParticleSwarmEnv):
    """
    ## Description
    Navigation (see ``dpr.envs.NavigationEnv``) with a square pillar, ``pillar_size`` wide, centred on the line
    from the swarm's start to the goal, its near face ``pillar_distance`` ahead of the expanded swarm's front.
    The swarm must move around it.

    ## Action Space, Observation Space, Rewards, Episode End
    As Navigation.

    ## Starting State
    As Navigation, farther out where the pillar needs the room: the goal lies 100 units beyond the pillar.

    ## Info
    Navigation's, plus ``pillar_contact_step``: the first physics step at which a robot touched the pillar (-1:
    none yet), also in evaluation files and reports.

    ## Arguments
    Navigation's, plus ``pillar_size`` (default 100) and ``pillar_distance`` (default 10), both > 0.

    ## Version History
    * v0: first version.
    """

    task = "pillar"
    task_description = "navigate the swarm around the pillar to the goal"
    episode_measures = (PILLAR_CONTACT_STEP,)

    def __init__(self, pillar_size: float = 100.0, pillar_distance: float = 10.0, **kwargs):
        super().__init__(**kwargs)
        if not (pillar_size > 0 and pillar_distance > 0):
            raise ValueError(f"pillar_size and pillar_distance must be > 0, got {pillar_size!r}, {pillar_distance!r}")
        self.pillar_size = float(pillar_size)
        self.pillar_distance = float(pillar_distance)
        self._contact_step = -1

    def _pillar_far_face(self, offsets: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """For each unit direction (A, 2) toward the goal: the pillar's far face, in units from the swarm's centre."""
        front = (offsets @ directions.T).max(axis=0) + self.swarm_class.expanded_radius
        return front + self.pillar_distance + self.pillar_size

    def _start_distances(self, offsets: np.ndarray, directions: np.ndarray) -> np.ndarray:
        pillar = self._pillar_far_face(offsets, directions) + GOAL_CLEARANCE
        return np.maximum(super()._start_distances(offsets, directions), pillar)

    def _walls(self, start: np.ndarray) -> list[np.ndarray]:
        along = (self.goal - start) / np.linalg.norm(self.goal - start)
        across = np.array([-along[1], along[0]])
        offsets = grid_centres(self.n_robots, (0.0, 0.0))
        half = self.pillar_size / 2
        centre = start + along * (self._pillar_far_face(offsets, along[None, :])[0] - half)
        self._contact_step = -1
        corners = [(-1, -1), (1, -1), (1, 1), (-1, 1)]
        return [np.array([centre + half * (a * along + c * across) for a, c in corners])]

    def _after_physics_step(self) -> None:
        if self._contact_step < 0 and self.world.robots_touch_walls():
            self._contact_step = self.physics_step

    def _info(self) -> dict:
        return {**super()._info(), PILLAR_CONTACT_STEP: self._contact_step}


register_task("pillar", PillarEnv, "pillar_task/Pillar-v0")
