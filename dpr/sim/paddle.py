"""The paper's particle robot: a central disk with 16 two-part paddles driven by motors."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import pymunk

from dpr.sim import constants as C
from dpr.sim._setters import add_rods, motor_handles, remove_rods, set_motor_rates
from dpr.sim.neighbours import pairs_within
from dpr.sim.objects import add_ground_friction
from dpr.sim.swarm import Swarm

_PADDLE_ANGLES = 2 * math.pi * np.arange(C.N_PADDLES) / C.N_PADDLES
_CONTRACTED_PADDLE_ANGLES = _PADDLE_ANGLES - math.pi / 2  # paddle1 angle, relative to its body, when contracted
_TIP_OFFSET = C.PADDLE_LENGTH / 2  # paddle1 turns about its centre, pinned to the rim


class _Paddle(NamedTuple):
    """One of a robot's paddles: its two bodies, their shapes, and its joints (motors included) in the order the
    space adds them."""

    paddle1: pymunk.Body
    paddle2: pymunk.Body
    shapes: list[pymunk.Shape]  # paddle1's, paddle2's
    joints: list[pymunk.Constraint]  # pin1, limit1, motor1, pin2, limit2, motor2
    motor1: pymunk.SimpleMotor
    motor2: pymunk.SimpleMotor


def _central_body(centre: np.ndarray, group: pymunk.ShapeFilter) -> tuple[pymunk.Body, pymunk.Circle]:
    body = pymunk.Body(C.BODY_MASS, pymunk.moment_for_circle(C.BODY_MASS, 0, C.BODY_RADIUS))
    body.position = tuple(centre)
    disk = pymunk.Circle(body, C.BODY_RADIUS)
    disk.elasticity, disk.friction, disk.filter = C.BODY_ELASTICITY, C.BODY_FRICTION, group
    return body, disk


def _paddle(body: pymunk.Body, centre: np.ndarray, theta: float, group: pymunk.ShapeFilter) -> _Paddle:
    """The contracted paddle at rim angle ``theta`` of the robot whose central body is ``body``."""
    radial = np.array([math.cos(theta), math.sin(theta)])
    tangent = np.array([math.sin(theta), -math.cos(theta)])  # direction of angle theta - pi/2
    rim = C.BODY_RADIUS * radial

    p1 = pymunk.Body(C.PADDLE_MASS, pymunk.moment_for_box(C.PADDLE_MASS, (C.PADDLE_LENGTH, C.PADDLE_WIDTH)))
    p1.position = tuple(centre + rim)
    p1.angle = theta - math.pi / 2
    s1 = pymunk.Poly.create_box(p1, (C.PADDLE_LENGTH, C.PADDLE_WIDTH))

    m2 = C.PADDLE_MASS / 2
    p2 = pymunk.Body(m2, pymunk.moment_for_box(m2, (C.PADDLE_LENGTH / 2, C.PADDLE_WIDTH)))
    p2.position = tuple(centre + rim + _TIP_OFFSET * tangent)
    p2.angle = theta + math.pi / 2  # parallel to the rim, as its rotary joint holds it
    s2 = pymunk.Poly.create_box(p2, (C.PADDLE_LENGTH / 2, C.PADDLE_WIDTH))
    for s in (s1, s2):
        s.elasticity, s.friction, s.filter = C.PADDLE_ELASTICITY, C.PADDLE_FRICTION, group

    # paddle1 on the rim: a zero-length pin, limited to [tangent, perpendicular], motor-driven
    pin1 = pymunk.PinJoint(body, p1, tuple(rim), (0, 0))
    limit1 = pymunk.RotaryLimitJoint(body, p1, theta - math.pi / 2, theta)
    motor1 = pymunk.SimpleMotor(body, p1, 0.0)
    # paddle2 on paddle1's tip, kept parallel to the rim
    pin2 = pymunk.PinJoint(p1, p2, (_TIP_OFFSET, 0), (0, 0))
    limit2 = pymunk.RotaryLimitJoint(body, p2, theta + math.pi / 2, theta + math.pi / 2)
    motor2 = pymunk.SimpleMotor(p1, p2, 0.0)
    for m in (motor1, motor2):
        m.max_force = C.MOTOR_MAX_FORCE
    for j in (pin1, limit1, pin2, limit2):
        j.collide_bodies = False
    return _Paddle(p1, p2, [s1, s2], [pin1, limit1, motor1, pin2, limit2, motor2], motor1, motor2)


class PaddleSwarm(Swarm):
    """Robots as built by the paper: per robot one central body and 2 x 16 paddle bodies.

    Paddle ``i`` sits at rim angle ``theta_i``. Paddle1 (25 x 2.5) is pinned at its centre to the rim and
    turns, driven by a motor, between tangent (contracted) and perpendicular to the rim (expanded); a rotary
    limit joint bounds it to that 90 degree range. Paddle2 (12.5 x 2.5) is pinned at its centre to paddle1's
    tip and held parallel to the rim by a rotary joint to the central body. A robot's own parts never
    collide (one shape-filter group per robot).

    Bodies are added to the space as all central bodies, then all paddle1s, then all paddle2s, so the
    world's batch read slices cleanly.
    """

    model = "paddle"
    contracted_radius = C.PADDLE_CONTRACTED_RADIUS
    expanded_radius = C.PADDLE_EXPANDED_RADIUS
    magnet_range = C.MAGNET_RANGE

    def __init__(self, space: pymunk.Space, centres: np.ndarray, dead: np.ndarray):
        super().__init__(space, centres, dead)
        n, k = self.n, C.N_PADDLES
        bodies, paddles1, paddles2 = [], [], []
        motors1, motors2 = [], []
        shapes, joints = [], []
        for r, centre in enumerate(np.asarray(centres, dtype=float)):
            group = pymunk.ShapeFilter(group=r + 1)
            body, disk = _central_body(centre, group)
            bodies.append(body)
            shapes.append(disk)
            for theta in _PADDLE_ANGLES:
                paddle = _paddle(body, centre, theta, group)
                paddles1.append(paddle.paddle1)
                paddles2.append(paddle.paddle2)
                shapes += paddle.shapes
                joints += paddle.joints
                motors1.append(paddle.motor1)
                motors2.append(paddle.motor2)
        space.add(*bodies, *paddles1, *paddles2, *shapes, *joints)
        for body in bodies:
            add_ground_friction(space, body)

        self.robot_bodies = bodies
        self.bodies = bodies + paddles1 + paddles2
        self.paddle2_bodies = paddles2
        self._motors1 = [motors1[r * k : (r + 1) * k] for r in range(n)]
        self._motors2 = [motors2[r * k : (r + 1) * k] for r in range(n)]
        self._rate = np.zeros(n)  # expansion rate (rad/s) applied to each robot's paddles
        self._motor_handles = None  # chipmunk handles of each robot's motors, made on first use (not pickled)
        self.paddle_angle = np.zeros((n, k))  # paddle1 angle relative to its body, 0 contracted
        self.paddle1_pose = np.zeros((n, k, 3))
        self.paddle2_pose = np.zeros((n, k, 3))
        self._active: list[tuple[int, int]] = []  # this step's magnets, as pairs of global paddle2 indices
        self._rods: list = []  # their chipmunk joints, alive from update_magnets() to after_physics()
        self._paddle2_handles = None  # chipmunk bodies of the paddle2s, made on first use (not pickled)
        self._drive()

    # -- state ------------------------------------------------------------------------------------------
    def update_state(self, rows: np.ndarray) -> None:
        super().update_state(rows)
        n, k = self.n, C.N_PADDLES
        self.paddle1_pose = rows[n : n + n * k, 0:3].reshape(n, k, 3)
        self.paddle2_pose = rows[n + n * k : n + 2 * n * k, 0:3].reshape(n, k, 3)
        relative = self.paddle1_pose[:, :, 2] - self.angle[:, None] - _CONTRACTED_PADDLE_ANGLES
        self.paddle_angle = relative
        self.expansion = np.clip(relative.sum(axis=1) * (1.0 / (k * C.STROKE)), 0.0, 1.0)

    # -- control ----------------------------------------------------------------------------------------
    def _drive(self) -> None:
        error = (self.target - self.expansion) * C.STROKE
        at_end = (self.target <= 0.0) | (self.target >= 1.0)
        # Targets at an end drive into the mechanical stop at full speed (the paper's binary robot);
        # partial targets slow down so that they arrive within one control period.
        rate = np.where(
            at_end,
            np.where(self.target >= 1.0, C.PADDLE_SPEED, -C.PADDLE_SPEED),
            np.clip(error / C.CONTROL_PERIOD, -C.PADDLE_SPEED, C.PADDLE_SPEED),
        )
        rate[~self.alive] = -C.PADDLE_SPEED
        changed = np.flatnonzero(rate != self._rate)
        if len(changed) == 0:
            return
        if self._motor_handles is None:
            self._motor_handles = [motor_handles(m1, m2) for m1, m2 in zip(self._motors1, self._motors2)]
        for r, value in zip(changed.tolist(), rate[changed].tolist()):
            # SimpleMotor drives b.w - a.w toward -rate: paddle1 turns outward at +value relative to the
            # body, and paddle2 turns back by the same amount so it stays parallel to the rim.
            set_motor_rates(self._motor_handles[r], -value, value)
        self._rate[changed] = rate[changed]

    # -- magnets ----------------------------------------------------------------------------------------
    def update_magnets(self) -> None:
        """Link each pair of robots closer than 4 radii by a rod (max force 750) between the paddle2 of
        each that is nearest to the other's centre, at the rods' current length, for this step only.

        Each paddle2 holds at most one magnet (pairs are served in index order). As in the 2021 code the
        rods are new every step (:meth:`after_physics` removes them): a rod kept from the previous step
        would carry its accumulated impulse into the next (chipmunk's warm start), which is measurably
        different physics. They are made with chipmunk's own calls, which cost less than keeping pymunk
        joints and updating them. A magnet is the pair of global paddle2 indices ``(r * 16 + i, s * 16 + j)``.
        """
        self._remove_rods()
        centres = self.position
        pairs = pairs_within(centres, self.magnet_range)
        if len(pairs) == 0:
            self._active = []
            return
        tips = self.paddle2_pose[:, :, 0:2]
        a, b = pairs[:, 0], pairs[:, 1]
        tip_a = np.einsum("pkd,pkd->pk", d := tips[a] - centres[b][:, None], d).argmin(axis=1)
        tip_b = np.einsum("pkd,pkd->pk", d := tips[b] - centres[a][:, None], d).argmin(axis=1)
        k = C.N_PADDLES
        self._active = _one_magnet_per_tip((a * k + tip_a).tolist(), (b * k + tip_b).tolist())
        if self._paddle2_handles is None:
            self._paddle2_handles = [body._body for body in self.paddle2_bodies]
        self._rods = add_rods(self.space._space, self._paddle2_handles, self._active, C.MAGNET_MAX_FORCE)

    def after_physics(self) -> None:
        self._remove_rods()

    def _remove_rods(self) -> None:
        if self._rods:
            remove_rods(self.space._space, self._rods)
            self._rods = []

    def __getstate__(self):
        state = self.__dict__.copy()
        # cffi pointers do not pickle; handles are rebuilt on first use, and rods exist only inside a step
        state.update(_motor_handles=None, _paddle2_handles=None, _rods=[])
        return state

    def magnet_segments(self) -> np.ndarray:
        if not self._active:
            return np.zeros((0, 2, 2))
        flat = self.paddle2_pose[:, :, 0:2].reshape(-1, 2)
        idx = np.array(self._active)
        return np.stack([flat[idx[:, 0]], flat[idx[:, 1]]], axis=1)


def _one_magnet_per_tip(ga: list[int], gb: list[int]) -> list[tuple[int, int]]:
    """Keep pairs in order, dropping any whose tip already holds a magnet."""
    if len(set(ga).union(gb)) == 2 * len(ga):  # the usual case: no tip is shared
        return list(zip(ga, gb))
    used: set[int] = set()
    kept = []
    for x, y in zip(ga, gb):
        if x in used or y in used:
            continue
        used.update((x, y))
        kept.append((x, y))
    return kept
