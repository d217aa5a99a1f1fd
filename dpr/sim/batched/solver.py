"""One control step's physics substeps for K swarms: chipmunk's sequential impulses, each kind of constraint solved
at once (see :mod:`dpr.sim.batched.world` for the method and the reasons).

Everything here is ``[B, K]`` body tensors (robots, then the ball), ``[P, K]`` or ``[E]`` pair tensors (one per pair
of bodies, :mod:`dpr.sim.batched.pairs`) and ``[W, B, K]`` wall tensors (one per body and wall). A substep measures
its constraints once (:func:`measure`), applies the impulses they accumulated before (:func:`warm_start`), then runs
``iterations`` rounds (:func:`solve_round`): all contacts, then ground friction, then the rods.

Constraints that do not act (pairs not touching, pairs without a rod) carry an effective mass of 0 and an impulse
of 0, so a round needs no masks: every clamp of a 0 update lands on 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from dpr.sim import constants as C
from dpr.sim.batched.walls import disk_wall_distance

ROBOT_ELASTICITY = C.BODY_ELASTICITY * C.BODY_ELASTICITY  # chipmunk multiplies the two shapes' values
BALL_ELASTICITY = C.BODY_ELASTICITY * C.OBJECT_ELASTICITY
COLLISION_SLOP = 0.1  # chipmunk's default
DISK_MOMENT = C.DISK_MASS * C.DISK_CONTRACTED_RADIUS**2 / 2  # fixed at creation, as pymunk's body keeps it


@dataclass
class Bodies:
    """Every body's state, ``[B, K]`` each: position, velocity, spin, the contacts' bias velocity (moves positions,
    never momentum), ground friction's accumulated impulses, and the radius; masses ``[B, 1]``; each swarm's
    ground friction as a multiple of the model's, ``[1, K]``."""

    px: torch.Tensor
    py: torch.Tensor
    vx: torch.Tensor
    vy: torch.Tensor
    spin: torch.Tensor
    bx: torch.Tensor
    by: torch.Tensor
    gx: torch.Tensor
    gy: torch.Tensor
    gspin: torch.Tensor
    radius: torch.Tensor
    mass: torch.Tensor
    moment: torch.Tensor
    friction_scale: torch.Tensor

    def __post_init__(self):
        self.inv_mass, self.inv_moment = 1.0 / self.mass, 1.0 / self.moment


@dataclass
class Impulses:
    """What each constraint accumulated (chipmunk's warm starts): pair contacts' normal and tangent impulses and
    the rods' ``[P, K]``; wall contacts' ``[W, B, K]``."""

    normal: torch.Tensor
    tangent: torch.Tensor
    rod: torch.Tensor
    wall_normal: torch.Tensor | None = None
    wall_tangent: torch.Tensor | None = None


@dataclass
class Rods:
    """This control step's rods, per pair: length, force limit as an impulse per substep (0 without a rod), and
    whether there is one."""

    length: torch.Tensor
    limit: torch.Tensor
    present: torch.Tensor


@dataclass
class Walls:
    """Static convex walls ``[K, W, V, 2]`` with their edges, outward normals and presence (``[K, W]``)."""

    corners: torch.Tensor
    edge: torch.Tensor
    outward: torch.Tensor
    present: torch.Tensor
    # Walls that squeeze robots (BatchedDiskWorld's wall_give): each body meets them at max(radius - give, core),
    # [B, 1] each; None: at its radius.
    give: torch.Tensor | None = None
    core: torch.Tensor | None = None


@dataclass(frozen=True)
class StepConstants:
    dt: float
    bias: float  # share of a position error corrected in one substep (chipmunk's bias coefficient)
    relaxation: float
    iterations: int
    substeps: int
    step: object  # substep(), or what torch.compile made of it


class _Rows:
    """One substep's constraint rows: geometry, effective masses, targets; plus the rounds' bias impulses."""


def physics(bodies: Bodies, pairs, elasticity, rods: Rods, walls: Walls | None, impulses: Impulses, k: StepConstants):
    """``k.substeps`` substeps of ``k.dt``, changing ``bodies`` and ``impulses`` in place; ``k.step`` is
    :func:`substep` or its compiled twin."""
    for _ in range(k.substeps):
        k.step(bodies, pairs, elasticity, rods, walls, impulses, k)


def substep(bodies: Bodies, pairs, elasticity, rods: Rods, walls, impulses: Impulses, k: StepConstants) -> None:
    """Move, measure, warm start, then ``k.iterations`` rounds."""
    bodies.px = bodies.px + (bodies.vx + bodies.bx) * k.dt
    bodies.py = bodies.py + (bodies.vy + bodies.by) * k.dt
    bodies.bx, bodies.by = torch.zeros_like(bodies.bx), torch.zeros_like(bodies.by)
    rows = measure(bodies, pairs, elasticity, rods, walls, impulses, k)
    warm_start(bodies, pairs, rows, impulses)
    for _ in range(k.iterations):
        solve_round(bodies, pairs, rows, impulses)


# -- measuring a substep's constraints ---------------------------------------------------------------------
def measure(bodies: Bodies, pairs, elasticity, rods: Rods, walls, impulses: Impulses, k: StepConstants) -> _Rows:
    """Every constraint's geometry, effective mass and target at the current positions (fixed for the substep).
    Each body's masses are split between the contacts acting on it (mass splitting), so that contacts solved at
    once sum to one body's worth."""
    rows = _Rows()
    rows.friction_limit = C.GROUND_LINEAR_FRICTION * k.dt * bodies.friction_scale
    rows.spin_friction_limit = C.GROUND_ANGULAR_FRICTION * k.dt * bodies.friction_scale
    dx, dy, dvx, dvy = pairs.difference(bodies.px, bodies.py, bodies.vx, bodies.vy)
    distance = torch.sqrt(dx * dx + dy * dy)
    inverse = 1.0 / distance.clamp(min=1e-12)
    rows.nx, rows.ny = dx * inverse, dy * inverse  # (0, 0) for coincident centres: no push
    (radius_sum,) = pairs.total(bodies.radius)
    depth = distance - radius_sum  # < 0: overlapping
    touching = (depth < 0).float()
    rows.bounce = (dvx * rows.nx + dvy * rows.ny) * elasticity
    rows.pair_bias = -k.bias * (depth + COLLISION_SLOP).clamp(max=0.0) / k.dt
    (contacts,) = pairs.scatter_total(touching)
    if walls is not None:
        wall_touching = _measure_walls(rows, bodies, walls, k)
        contacts = contacts + wall_touching.sum(0)
    share = contacts.clamp(min=1.0)
    linear, turning = share * bodies.inv_mass, share * (bodies.inv_mass + bodies.radius**2 * bodies.inv_moment)
    pair_linear, pair_turning = pairs.total(linear, turning)
    rows.normal_mass = touching * k.relaxation / pair_linear
    rows.tangent_mass = k.relaxation / pair_turning
    impulses.normal = impulses.normal * touching
    impulses.tangent = impulses.tangent * touching
    rows.pair_bias_impulse = torch.zeros_like(distance)
    if walls is not None:
        rows.wall_normal_mass = wall_touching * (k.relaxation / linear)
        rows.wall_tangent_mass = k.relaxation / turning.expand_as(wall_touching)
        impulses.wall_normal = impulses.wall_normal * wall_touching
        impulses.wall_tangent = impulses.wall_tangent * wall_touching
        rows.wall_bias_impulse = torch.zeros_like(wall_touching)
    present = rods.present
    (rod_share,) = pairs.scatter_total(present)
    (rod_linear,) = pairs.total(rod_share.clamp(min=1.0) * bodies.inv_mass)
    rows.rod_mass = present * k.relaxation / rod_linear
    rows.rod_limit = rods.limit
    rows.rod_bias = -k.bias * (distance - rods.length) / k.dt
    impulses.rod = impulses.rod * present
    return rows


def _measure_walls(rows: _Rows, bodies: Bodies, walls: Walls, k: StepConstants) -> torch.Tensor:
    """Disk-wall contacts ``[W, B, K]``: normals from each body into each wall, bias; returns which touch."""
    centre = torch.stack((bodies.px, bodies.py), dim=-1).transpose(0, 1)  # [K, B, 2]
    distance, out = disk_wall_distance(centre, walls.corners, walls.edge, walls.outward)  # [K, B, W], [.., 2]
    distance, out = distance.permute(2, 1, 0), out.permute(2, 1, 0, 3)
    rows.wall_nx, rows.wall_ny = -out[..., 0].contiguous(), -out[..., 1].contiguous()
    reach = bodies.radius if walls.give is None else torch.maximum(bodies.radius - walls.give, walls.core)
    depth = distance - reach
    rows.wall_bias = -k.bias * (depth + COLLISION_SLOP).clamp(max=0.0) / k.dt
    return ((depth < 0) & walls.present.t()[:, None, :]).float()


# -- applying impulses --------------------------------------------------------------------------------------
def _push(bodies: Bodies, vx, vy, bx=None, by=None, torque=None) -> None:
    """Impulses summed per body (``[B, K]`` each) into velocities; ``torque`` is the tangent impulses, which turn
    a disk by ``-radius * impulse / moment`` whichever side of the contact it is on."""
    bodies.vx = bodies.vx + vx * bodies.inv_mass
    bodies.vy = bodies.vy + vy * bodies.inv_mass
    if bx is not None:
        bodies.bx = bodies.bx + bx * bodies.inv_mass
        bodies.by = bodies.by + by * bodies.inv_mass
    if torque is not None:
        bodies.spin = bodies.spin - torque * bodies.radius * bodies.inv_moment


def warm_start(bodies: Bodies, pairs, rows: _Rows, impulses: Impulses) -> None:
    """Apply every accumulated impulse again, as one round with no bias."""
    normal, tangent = impulses.normal + impulses.rod, impulses.tangent
    vx, vy, torque = pairs.scatter(
        normal * rows.nx - tangent * rows.ny, normal * rows.ny + tangent * rows.nx
    ) + pairs.scatter_total(tangent)
    if impulses.wall_normal is not None:
        wall_vx, wall_vy, wall_torque = _wall_pushes(rows, impulses.wall_normal, impulses.wall_tangent)
        vx, vy, torque = vx + wall_vx, vy + wall_vy, torque + wall_torque
    _push(bodies, vx - bodies.gx, vy - bodies.gy, torque=torque)
    bodies.spin = bodies.spin - bodies.gspin * bodies.inv_moment


def _wall_pushes(rows: _Rows, normal: torch.Tensor, tangent: torch.Tensor) -> tuple:
    """What wall impulses (on the wall; the body takes the opposite) do to each body, summed over the walls."""
    nx, ny = rows.wall_nx, rows.wall_ny
    return -(normal * nx - tangent * ny).sum(0), -(normal * ny + tangent * nx).sum(0), tangent.sum(0)


# -- one round ------------------------------------------------------------------------------------------------
def _contact(old: tuple, speeds: tuple, masses: tuple, targets: tuple) -> tuple:
    """A contact group's new (normal >= 0 with restitution, tangent within the normal: friction 1, bias >= 0)
    impulses, and their changes."""
    old_normal, old_tangent, old_bias = old
    normal_speed, tangent_speed, bias_speed = speeds
    normal_mass, tangent_mass = masses
    bounce, bias_target = targets
    normal = (old_normal - (bounce + normal_speed) * normal_mass).clamp(min=0.0)
    tangent = torch.clamp(old_tangent - tangent_speed * tangent_mass, -normal, normal)
    bias = (old_bias + (bias_target - bias_speed) * normal_mass).clamp(min=0.0)
    return (normal, tangent, bias), (normal - old_normal, tangent - old_tangent, bias - old_bias)


def solve_round(bodies: Bodies, pairs, rows: _Rows, impulses: Impulses) -> None:
    """One round in chipmunk's order: all contacts at once, then ground friction, then the rods."""
    _contacts(bodies, pairs, rows, impulses)
    _ground_friction(bodies, rows)
    dvx, dvy = pairs.difference(bodies.vx, bodies.vy)
    old = impulses.rod
    impulses.rod = torch.clamp(
        old + (rows.rod_bias - (dvx * rows.nx + dvy * rows.ny)) * rows.rod_mass, -rows.rod_limit, rows.rod_limit
    )
    change = impulses.rod - old
    _push(bodies, *pairs.scatter(change * rows.nx, change * rows.ny))


def _contacts(bodies: Bodies, pairs, rows: _Rows, impulses: Impulses) -> None:
    nx, ny = rows.nx, rows.ny
    dvx, dvy, dbx, dby = pairs.difference(bodies.vx, bodies.vy, bodies.bx, bodies.by)
    (rim,) = pairs.total(bodies.spin * bodies.radius)
    (normal, tangent, bias), (d_normal, d_tangent, d_bias) = _contact(
        (impulses.normal, impulses.tangent, rows.pair_bias_impulse),
        (dvx * nx + dvy * ny, dvy * nx - dvx * ny - rim, dbx * nx + dby * ny),
        (rows.normal_mass, rows.tangent_mass),
        (rows.bounce, rows.pair_bias),
    )
    impulses.normal, impulses.tangent, rows.pair_bias_impulse = normal, tangent, bias
    vx, vy, bx, by, torque = pairs.scatter(
        d_normal * nx - d_tangent * ny, d_normal * ny + d_tangent * nx, d_bias * nx, d_bias * ny
    ) + pairs.scatter_total(d_tangent)
    if impulses.wall_normal is not None:
        wall = _wall_contacts(bodies, rows, impulses)
        vx, vy, bx, by, torque = (a + b for a, b in zip((vx, vy, bx, by, torque), wall))
    _push(bodies, vx, vy, bx, by, torque)


def _wall_contacts(bodies: Bodies, rows: _Rows, impulses: Impulses) -> tuple:
    """Body-wall contacts (the wall static): the bodies' changes, summed over the walls."""
    nx, ny = rows.wall_nx, rows.wall_ny
    normal_speed = -(bodies.vx * nx + bodies.vy * ny)
    tangent_speed = bodies.vx * ny - bodies.vy * nx - bodies.spin * bodies.radius
    bias_speed = -(bodies.bx * nx + bodies.by * ny)
    (normal, tangent, bias), (d_normal, d_tangent, d_bias) = _contact(
        (impulses.wall_normal, impulses.wall_tangent, rows.wall_bias_impulse),
        (normal_speed, tangent_speed, bias_speed),
        (rows.wall_normal_mass, rows.wall_tangent_mass),
        (0.0, rows.wall_bias),  # walls do not bounce (elasticity 0)
    )
    impulses.wall_normal, impulses.wall_tangent, rows.wall_bias_impulse = normal, tangent, bias
    vx, vy, torque = _wall_pushes(rows, d_normal, d_tangent)
    return vx, vy, -(d_bias * nx).sum(0), -(d_bias * ny).sum(0), torque


def _ground_friction(bodies: Bodies, rows: _Rows) -> None:
    """pymunk's pivot and gear joints to the static body (max_bias 0): each body's own, solved exactly, the
    accumulated impulse clamped in length to the friction's limit."""
    linear, angular = rows.friction_limit, rows.spin_friction_limit
    wanted_x, wanted_y = bodies.gx + bodies.vx * bodies.mass, bodies.gy + bodies.vy * bodies.mass
    # reciprocal, then product: what `float / tensor` computes, so swarms at scale 1 keep the bits they had when
    # the limits were Python floats
    scale = torch.reciprocal(torch.sqrt(wanted_x * wanted_x + wanted_y * wanted_y).clamp(min=linear)) * linear
    gx, gy = wanted_x * scale, wanted_y * scale
    bodies.vx = bodies.vx - (gx - bodies.gx) * bodies.inv_mass
    bodies.vy = bodies.vy - (gy - bodies.gy) * bodies.inv_mass
    bodies.gx, bodies.gy = gx, gy
    gspin = torch.clamp(bodies.gspin + bodies.spin * bodies.moment, -angular, angular)
    bodies.spin = bodies.spin - (gspin - bodies.gspin) * bodies.inv_moment
    bodies.gspin = gspin
