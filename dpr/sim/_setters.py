"""Bulk setters (and the transient magnet rods) that call chipmunk directly.

They do exactly what pymunk's public property setters do (``SimpleMotor.rate``, ``PinJoint.distance``,
``Constraint.max_force``, ``Circle.unsafe_set_radius``) without pymunk's per-attribute Python wrapper, which
for a small swarm costs more than the physics step itself. pymunk is pinned below 8 for these private handles.
"""

from pymunk._chipmunk import lib


def motor_handles(*groups) -> tuple[list, ...]:
    """The chipmunk handles of each group of SimpleMotors (cffi pointers: valid while the motors live)."""
    return tuple([motor._constraint for motor in group] for group in groups)


def set_motor_rates(handles: tuple[list, ...], *rates: float) -> None:
    """Set every motor of ``handles[g]`` to ``rates[g]``."""
    set_rate = lib.cpSimpleMotorSetRate
    for group, rate in zip(handles, rates):
        for handle in group:
            set_rate(handle, rate)


def set_pin_distances(handles, distances) -> None:
    """``handles``: chipmunk handles of PinJoints (``joint._constraint``)."""
    set_distance = lib.cpPinJointSetDist
    for handle, distance in zip(handles, distances):
        set_distance(handle, distance)


def set_max_forces(handles, forces) -> None:
    """``handles``: chipmunk handles of constraints (``joint._constraint``)."""
    set_force = lib.cpConstraintSetMaxForce
    for handle, force in zip(handles, forces):
        set_force(handle, force)


def set_circle_radii(handles, radii) -> None:
    """``handles``: chipmunk handles of Circle shapes (``shape._shape``)."""
    set_radius = lib.cpCircleShapeSetRadius
    for handle, radius in zip(handles, radii):
        set_radius(handle, radius)


def add_rods(space, bodies, pairs, max_force: float) -> list:
    """Join ``bodies[i]`` and ``bodies[j]`` (chipmunk body handles) for each ``(i, j)`` in ``pairs`` by a
    PinJoint between their centres at their current distance, force-limited, and add it to ``space``
    (a chipmunk space handle). pymunk does not know these joints: remove them with :func:`remove_rods`
    before anything else (pickling, freeing the bodies) touches the space."""
    new, set_force, add = lib.cpPinJointNew, lib.cpConstraintSetMaxForce, lib.cpSpaceAddConstraint
    rods = []
    for i, j in pairs:
        rod = new(bodies[i], bodies[j], (0.0, 0.0), (0.0, 0.0))
        set_force(rod, max_force)
        add(space, rod)
        rods.append(rod)
    return rods


def remove_rods(space, rods) -> None:
    """Take the joints made by :func:`add_rods` out of ``space`` and free them."""
    remove, free = lib.cpSpaceRemoveConstraint, lib.cpConstraintFree
    for rod in rods:
        remove(space, rod)
        free(rod)
