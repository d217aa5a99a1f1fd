"""Bulk setters that call chipmunk directly.

They do exactly what pymunk's public property setters do (``SimpleMotor.rate``, ``PinJoint.distance``,
``Circle.unsafe_set_radius``) without pymunk's per-attribute Python wrapper, which for a small swarm costs
more than the physics step itself. pymunk is pinned below 8 for these private handles.
"""

from pymunk._chipmunk import lib


def set_motor_rates(motors, rate: float) -> None:
    for motor in motors:
        lib.cpSimpleMotorSetRate(motor._constraint, rate)


def set_pin_distances(joints, distances) -> None:
    for joint, distance in zip(joints, distances):
        lib.cpPinJointSetDist(joint._constraint, distance)


def set_circle_radii(shapes, radii) -> None:
    for shape, radius in zip(shapes, radii):
        lib.cpCircleShapeSetRadius(shape._shape, radius)
