"""Unresponsive: navigation with robots that ignore every command."""

import numpy as np

from dpr.checks import check_int
from dpr.envs.particle_env import ParticleSwarmEnv


class UnresponsiveEnv(ParticleSwarmEnv):
    """
    ## Description
    Navigation (see ``NavigationEnv``) where ``n_dead`` robots are unresponsive: they ignore every command,
    stay contracted and keep their magnets, so the others must drag them along.

    ## Action Space
    As Navigation; the entries of dead robots are accepted and ignored.

    ## Observation Space
    As Navigation; a dead robot's expansion stays 0. Which robots are dead is not observed (it is in
    ``info["dead_robots"]`` after reset). ``environment_state()`` (what datasets record as
    ``observation.environment_state``) ends with one flag per robot, ``dead.robot<i>``: 1 for a dead robot, else 0.

    ## Rewards
    As Navigation.

    ## Starting State
    As Navigation; the dead robots are drawn with the env's seeded generator at each reset.

    ## Episode End
    As Navigation.

    ## Arguments
    Navigation's, plus ``n_dead`` (default ``round(0.2 * n_robots)``, 2 of 9), with ``0 <= n_dead < n_robots``.

    ## Version History
    * v0: first version; dead robots come from the env's generator (they came from the unseeded global RNG).
    """

    task = "unresponsive"
    task_description = "navigate the swarm to the goal despite its unresponsive robots"
    has_dead_robots = True

    def __init__(self, n_dead: int | None = None, **kwargs):
        super().__init__(**kwargs)
        if n_dead is None:
            n_dead = int(round(0.2 * self.n_robots))
        n_dead = int(n_dead) if isinstance(n_dead, np.integer) else n_dead
        self.n_dead = check_int("n_dead", n_dead, 0, self.n_robots - 1)  # at least one robot must respond

    @property
    def environment_state_names(self) -> list[str]:
        return super().environment_state_names + [f"dead.robot{i}" for i in range(self.n_robots)]

    def environment_state(self) -> np.ndarray:
        """Navigation's, then each robot's dead flag (1 dead, 0 responsive): flags, not lengths, so not scaled."""
        return np.concatenate([super().environment_state(), self.world.dead.astype(np.float32)])

    def _dead_robots(self) -> np.ndarray:
        return np.sort(self.np_random.choice(self.n_robots, size=self.n_dead, replace=False))
