"""Ground friction, manipulated objects and static walls."""

from __future__ import annotations

import math

import numpy as np
import pymunk

from dpr.checks import ParameterError
from dpr.sim import constants as C


def add_ground_friction(space: pymunk.Space, body: pymunk.Body) -> tuple[pymunk.Constraint, pymunk.Constraint]:
    """Emulate top-down ground friction: a pivot and a gear joint to the static body with no position
    correction (max_bias 0), whose force limits are the friction forces."""
    pivot = pymunk.PivotJoint(space.static_body, body, (0, 0), (0, 0))
    pivot.max_bias = 0
    pivot.max_force = C.GROUND_LINEAR_FRICTION
    gear = pymunk.GearJoint(space.static_body, body, 0.0, 1.0)
    gear.max_bias = 0
    gear.max_force = C.GROUND_ANGULAR_FRICTION
    space.add(pivot, gear)
    return pivot, gear


OBJECT_TYPES = ("ball", "box")


def add_object(
    space: pymunk.Space, kind: str, position, angle: float, mass: float, size: float
) -> tuple[pymunk.Body, pymunk.Shape]:
    """Add a ball (``size`` = radius) or a box (``size`` = half side) with ground friction."""
    if kind == "ball":
        body = pymunk.Body(mass, pymunk.moment_for_circle(mass, 0, size))
        shape: pymunk.Shape = pymunk.Circle(body, size)
    elif kind == "box":
        body = pymunk.Body(mass, pymunk.moment_for_box(mass, (2 * size, 2 * size)))
        shape = pymunk.Poly.create_box(body, (2 * size, 2 * size))
    else:
        raise ParameterError("kind", f"expected one of {list(OBJECT_TYPES)}, got {kind!r}")
    body.position = tuple(position)
    body.angle = angle
    shape.elasticity = C.OBJECT_ELASTICITY
    shape.friction = C.OBJECT_FRICTION
    space.add(body, shape)
    add_ground_friction(space, body)
    return body, shape


def add_walls(space: pymunk.Space, polygons: list[np.ndarray]) -> list[pymunk.Poly]:
    """Add static convex polygons (each an array of vertices) to the space's static body."""
    shapes = []
    for vertices in polygons:
        shape = pymunk.Poly(space.static_body, [tuple(v) for v in np.asarray(vertices, dtype=float)])
        shape.elasticity = C.WALL_ELASTICITY
        shape.friction = C.WALL_FRICTION
        shapes.append(shape)
    space.add(*shapes)
    return shapes


def gate_polygons(
    start, goal, opening: float, thickness: float = 100.0, length: float = 500.0, at: float | None = None
) -> list[np.ndarray]:
    """Two walls across the line from ``start`` to ``goal``, leaving an ``opening`` centred on that line, their
    near face ``at`` units from ``start`` toward the goal (None: the walls' middle halfway between the two, the
    paper's placement). Returns two (4, 2) vertex arrays."""
    start, goal = np.asarray(start, float), np.asarray(goal, float)
    along = goal - start
    along /= np.linalg.norm(along)
    middle = (start + goal) / 2 if at is None else start + along * (at + thickness / 2)
    across = np.array([-along[1], along[0]])
    walls = []
    for side in (1.0, -1.0):
        near = middle + side * across * opening / 2
        far = middle + side * across * (opening / 2 + length)
        half = along * thickness / 2
        walls.append(np.array([near - half, far - half, far + half, near + half]))
    return walls


def direction_angle(vector) -> float:
    return math.atan2(vector[1], vector[0])
