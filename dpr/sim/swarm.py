"""The command rule shared by both robot models (the registry of models is :mod:`dpr.sim.models`).

A swarm owns its pymunk bodies, shapes and joints inside a :class:`pymunk.Space`. The world reads every
body's state in one batch call and hands each swarm its slice; the swarm turns commanded expansion targets
into motor rates (paddle model) or radius velocities (disk model) and keeps the magnets up to date.
"""

from __future__ import annotations

import numpy as np
import pymunk

from dpr.sim import constants as C

# A robot within this fraction of a full stroke of its target has reached it (10 degrees of 90).
REACHED_FRACTION = C.REACHED_TOLERANCE / C.STROKE


class Swarm:
    """Base class: N robots, their expansion targets and the paper's command rule.

    Command rule (the paper's robot): a robot accepts a new target only once it has reached its previous
    one (within 10 degrees of stroke); until then it keeps moving toward the old target. Unresponsive
    ("dead") robots ignore commands and stay contracted.
    """

    model: str = ""
    contracted_radius: float = 0.0  # outer radius of a contracted robot
    expanded_radius: float = 0.0  # outer radius of an expanded robot
    magnet_range: float = C.MAGNET_RANGE
    substeps: int = C.SUBSTEPS  # pymunk steps per control step, of CONTROL_PERIOD / substeps each
    revision: int = 1  # raised whenever the model's physics change: datasets record it
    # The wave that moves this model toward the goal (dpr.policies.wave): steps each phase is held, and whether the
    # band nearest the goal expands first ("near") or last ("far")
    wave_hold_steps: int = 10
    wave_start_side: str = "near"

    def __init__(self, space: pymunk.Space, centres: np.ndarray, dead: np.ndarray):
        self.space = space
        self.n = len(centres)
        self.alive = ~np.asarray(dead, dtype=bool)
        self.target = np.zeros(self.n)  # in [0, 1]: 0 contracted, 1 expanded
        self.moving = np.zeros(self.n, dtype=bool)
        self.bodies: list[pymunk.Body] = []  # in the order they were added to the space
        self.robot_bodies: list[pymunk.Body] = []
        # views filled by update_state()
        self.position = np.zeros((self.n, 2))
        self.angle = np.zeros(self.n)
        self.velocity = np.zeros((self.n, 2))
        self.angular_velocity = np.zeros(self.n)
        self.expansion = np.zeros(self.n)

    # -- state ------------------------------------------------------------------------------------------
    def update_state(self, rows: np.ndarray) -> None:
        """``rows``: (len(self.bodies), 6) array of x, y, angle, vx, vy, angular velocity."""
        robots = rows[: self.n]
        self.position = robots[:, 0:2]
        self.angle = robots[:, 2]
        self.velocity = robots[:, 3:5]
        self.angular_velocity = robots[:, 5]

    # -- control ----------------------------------------------------------------------------------------
    def command(self, targets: np.ndarray) -> None:
        """Apply the command rule to ``targets`` (N values in [0, 1]) and drive the actuators."""
        # A robot is busy while it is moving and has not reached its target; the others (alive) accept
        # the new target, and are moving afterwards unless they are already there.
        busy = self.moving & (np.abs(self.target - self.expansion) >= REACHED_FRACTION)
        accept = self.alive & ~busy
        np.copyto(self.target, targets, where=accept)
        self.moving = (busy | accept) & (np.abs(self.target - self.expansion) >= REACHED_FRACTION)
        self._drive()

    def _drive(self) -> None:
        raise NotImplementedError

    # -- per step hooks ---------------------------------------------------------------------------------
    def update_magnets(self) -> None:
        raise NotImplementedError

    def before_physics(self) -> None:
        """Called once per control step before the pymunk steps (the disk model resizes its shapes here)."""

    def after_physics(self) -> None:
        """Called once per control step after the pymunk steps (the paddle model removes its rods here)."""

    def magnet_segments(self) -> np.ndarray:
        """(M, 2, 2) end points of the magnets active in this step, for drawing."""
        raise NotImplementedError
