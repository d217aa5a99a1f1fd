"""One control step's physics substeps for K swarms: chipmunk's sequential impulses as Jacobi rounds.

:func:`physics` is a pure function of tensors (``state`` in, ``state`` out) so that it can be handed to
``torch.compile`` whole; :class:`_Bodies` is the namespace it works on. See :mod:`dpr.sim.batched.world` for the
method and the reasons.
"""

from __future__ import annotations

import torch

from dpr.sim import constants as C
from dpr.sim.batched.walls import disk_wall_distance

ROBOT_ELASTICITY = C.BODY_ELASTICITY * C.BODY_ELASTICITY  # chipmunk multiplies the two shapes' values
COLLISION_SLOP = 0.1  # chipmunk's default
DISK_MOMENT = C.DISK_MASS * C.DISK_CONTRACTED_RADIUS**2 / 2  # fixed at creation, as pymunk's body keeps it

# what the physics changes; the rest of ``state`` (radii, neighbour table, walls) it only reads
MUTABLE = (
    "position",
    "velocity",
    "angular_velocity",
    "_bias_velocity",
    "_normal_impulse",
    "_tangent_impulse",
    "_rod_impulse",
    "_wall_impulse",
    "_ball_impulse",
    "_ball_wall_impulse",
    "_ground",
    "_ground_spin",
    "object_position",
    "object_velocity",
    "object_angular_velocity",
    "_object_bias_velocity",
    "_object_friction",
    "_object_spin_friction",
)


def _perp(v: torch.Tensor) -> torch.Tensor:
    return torch.stack([-v[..., 1], v[..., 0]], dim=-1)


def _dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return (a * b).sum(-1)


def physics(state: dict, config: dict, rod_length: torch.Tensor, rod_max_impulse: torch.Tensor) -> dict:
    """``config["substeps"]`` substeps from ``state`` (tensors by attribute name) with constant ``config``
    (python numbers and flags); returns the changed tensors."""
    bodies = _Bodies(state, config)
    for _ in range(config["substeps"]):
        bodies._substep(rod_length, rod_max_impulse)
    return {name: getattr(bodies, name) for name in MUTABLE if name in state}


class _Bodies:
    """The tensors and constants of one physics call, as attributes (the names :class:`BatchedDiskWorld` uses)."""

    def __init__(self, state: dict, config: dict):
        self.__dict__.update(state)
        self.__dict__.update(config)

    def _gather(self, value: torch.Tensor, index: torch.Tensor | None = None) -> torch.Tensor:
        """Each neighbour slot's value of a per-robot tensor ``[K, N, ...]``: ``[K, N, M, ...]``."""
        index = self._index if index is None else index
        k, n = value.shape[:2]
        if not self.use_cells:  # slot m is robot m: a broadcast, no copy
            return value[:, None].expand(k, n, *value.shape[1:])
        flat = (index + torch.arange(k, device=value.device)[:, None, None] * n).reshape(-1)
        return value.reshape(k * n, *value.shape[2:])[flat].reshape(*index.shape, *value.shape[2:])

    # -- physics ------------------------------------------------------------------------------------------
    def _substep(self, rod_length: torch.Tensor, rod_max_impulse: torch.Tensor) -> None:
        dt, bias, mass = self.dt, self._bias, C.DISK_MASS
        has_ball, has_walls = self.object_radius is not None, self.n_walls > 0
        # 1. positions move with the last solve's velocities and bias velocities
        self.position = self.position + (self.velocity + self._bias_velocity) * dt
        self._bias_velocity = torch.zeros_like(self._bias_velocity)
        if has_ball:
            self.object_position = self.object_position + (self.object_velocity + self._object_bias_velocity) * dt
            self._object_bias_velocity = torch.zeros_like(self._object_bias_velocity)

        # 2. geometry at the new positions
        radius = self.radius
        delta = self._gather(self.position) - self.position[:, :, None]  # [K, N, M, 2] from robot to neighbour
        distance = torch.linalg.vector_norm(delta, dim=-1)
        normal = delta / distance.clamp(min=1e-12)[..., None]  # (0, 0) for coincident centres: no push
        tangent = _perp(normal)
        other_radius = self._gather(radius)
        depth = distance - radius[:, :, None] - other_radius  # < 0: overlapping
        touching = self._valid & (depth < 0)
        rods = self._valid
        rod_bias = -bias * (distance - rod_length) / dt

        if has_walls:
            wall_distance, wall_out = disk_wall_distance(self.position, self.walls, self._wall_edge, self._wall_normal)
            wall_touching = (wall_distance < radius[..., None]) & self._wall_present[:, None]
            wall_depth = wall_distance - radius[..., None]
            wall_normal = -wall_out  # from the robot into the wall
        if has_ball:
            ball_delta = self.object_position[:, None] - self.position
            ball_distance = torch.linalg.vector_norm(ball_delta, dim=-1)
            ball_normal = ball_delta / ball_distance.clamp(min=1e-12)[..., None]
            ball_depth = ball_distance - radius - self.object_radius
            ball_touching = ball_depth < 0
            if has_walls:
                bw_distance, bw_out = disk_wall_distance(
                    self.object_position[:, None], self.walls, self._wall_edge, self._wall_normal
                )
                bw_distance, bw_out = bw_distance[:, 0], bw_out[:, 0]
                ball_wall_touching = (bw_distance < self.object_radius) & self._wall_present
                ball_wall_depth = bw_distance - self.object_radius
                ball_wall_normal = -bw_out

        # mass splitting: how many contacts, and how many rods, act on each body
        contacts = touching.sum(-1).float()
        if has_walls:
            contacts = contacts + wall_touching.sum(-1)
        if has_ball:
            contacts = contacts + ball_touching
            ball_contacts = ball_touching.sum(-1).float()
            if has_walls:
                ball_contacts = ball_contacts + ball_wall_touching.sum(-1)
            ball_share = ball_contacts.clamp(min=1.0)
        share = contacts.clamp(min=1.0)
        rod_share = rods.sum(-1).float().clamp(min=1.0)
        inv_mass, inv_moment = 1.0 / mass, 1.0 / DISK_MOMENT

        # robot-robot contacts
        other_share = self._gather(share)
        normal_mass = 1.0 / ((share[:, :, None] + other_share) * inv_mass)
        tangent_mass = 1.0 / (
            (share[:, :, None] + other_share) * inv_mass
            + (share[:, :, None] * radius[:, :, None] ** 2 + other_share * other_radius**2) * inv_moment
        )
        contact_bias = -bias * (depth + COLLISION_SLOP).clamp(max=0.0) / dt
        relative = self._gather(self.velocity) - self.velocity[:, :, None]
        bounce = _dot(relative, normal) * ROBOT_ELASTICITY
        rod_mass = 1.0 / ((rod_share[:, :, None] + self._gather(rod_share)) * inv_mass)

        # persistent contacts and rods keep their impulses (chipmunk's warm start); the rest start from 0
        self._normal_impulse = torch.where(touching, self._normal_impulse, 0.0)
        self._tangent_impulse = torch.where(touching, self._tangent_impulse, 0.0)
        self._rod_impulse = torch.where(rods, self._rod_impulse, 0.0)
        normal_bias_impulse = torch.zeros_like(depth)
        if has_walls:
            wall_tangent = _perp(wall_normal)
            wall_normal_mass = mass / share[..., None]
            wall_tangent_mass = 1.0 / (share[..., None] * (inv_mass + radius[..., None] ** 2 * inv_moment))
            wall_bias = -bias * (wall_depth + COLLISION_SLOP).clamp(max=0.0) / dt
            self._wall_impulse = torch.where(wall_touching[..., None], self._wall_impulse, 0.0)
            wall_bias_impulse = torch.zeros_like(wall_depth)
        if has_ball:
            ball_tangent = _perp(ball_normal)
            ball_inv_moment = 1.0 / self._object_moment
            ball_normal_mass = 1.0 / (share * inv_mass + ball_share[:, None] / self.object_mass)
            ball_tangent_mass = 1.0 / (
                share * (inv_mass + radius**2 * inv_moment)
                + ball_share[:, None] * (1.0 / self.object_mass + self.object_radius**2 * ball_inv_moment)
            )
            ball_bias = -bias * (ball_depth + COLLISION_SLOP).clamp(max=0.0) / dt
            self._ball_impulse = torch.where(ball_touching[..., None], self._ball_impulse, 0.0)
            ball_bias_impulse = torch.zeros_like(ball_depth)
            if has_walls:
                bw_tangent = _perp(ball_wall_normal)
                bw_normal_mass = self.object_mass / ball_share[:, None]
                bw_tangent_mass = 1.0 / (
                    ball_share[:, None] * (1.0 / self.object_mass + self.object_radius**2 * ball_inv_moment)
                )
                bw_bias = -bias * (ball_wall_depth + COLLISION_SLOP).clamp(max=0.0) / dt
                self._ball_wall_impulse = torch.where(ball_wall_touching[..., None], self._ball_wall_impulse, 0.0)
                bw_bias_impulse = torch.zeros_like(ball_wall_depth)

        # 3. warm start: each accumulated impulse applied again
        self._apply_pairs(
            normal, tangent, self._normal_impulse + self._rod_impulse, self._tangent_impulse, radius, other_radius
        )
        if has_walls:
            self._apply_walls(wall_normal, wall_tangent, self._wall_impulse[..., 0], self._wall_impulse[..., 1], radius)
        if has_ball:
            self._apply_ball(ball_normal, ball_tangent, self._ball_impulse[..., 0], self._ball_impulse[..., 1], radius)
            if has_walls:
                self._apply_ball_walls(
                    ball_wall_normal, bw_tangent, self._ball_wall_impulse[..., 0], self._ball_wall_impulse[..., 1]
                )
        self.velocity = self.velocity - self._ground / mass
        self.angular_velocity = self.angular_velocity - self._ground_spin / DISK_MOMENT
        if has_ball:
            self.object_velocity = self.object_velocity - self._object_friction / self.object_mass
            self.object_angular_velocity = (
                self.object_angular_velocity - self._object_spin_friction / self._object_moment
            )

        # 4. iterations in chipmunk's order: contacts, then the joints as they were added: ground friction, then rods
        for _ in range(self.iterations):
            # robot-robot contacts
            v, w = self.velocity, self.angular_velocity
            relative = self._gather(v) - v[:, :, None]
            normal_speed = _dot(relative, normal)
            tangent_speed = (
                _dot(relative, tangent) - self._gather(w) * other_radius - w[:, :, None] * radius[:, :, None]
            )
            new_normal = (self._normal_impulse - (bounce + normal_speed) * normal_mass).clamp(min=0.0)
            new_normal = torch.where(touching, new_normal, 0.0)
            limit = new_normal  # friction coefficient 1 * 1
            new_tangent = torch.minimum(
                torch.maximum(self._tangent_impulse - tangent_speed * tangent_mass, -limit), limit
            )
            bias_speed = _dot(self._gather(self._bias_velocity) - self._bias_velocity[:, :, None], normal)
            new_bias = torch.where(
                touching, (normal_bias_impulse + (contact_bias - bias_speed) * normal_mass).clamp(min=0.0), 0.0
            )
            d_normal, d_tangent = new_normal - self._normal_impulse, new_tangent - self._tangent_impulse
            d_bias = new_bias - normal_bias_impulse
            self._normal_impulse, self._tangent_impulse, normal_bias_impulse = new_normal, new_tangent, new_bias
            if has_walls:
                normal_speed = -_dot(v[:, :, None], wall_normal)
                tangent_speed = -_dot(v[:, :, None], wall_tangent) - w[..., None] * radius[..., None]
                old = self._wall_impulse
                new_n = torch.where(wall_touching, (old[..., 0] - normal_speed * wall_normal_mass).clamp(min=0.0), 0.0)
                new_t = torch.minimum(torch.maximum(old[..., 1] - tangent_speed * wall_tangent_mass, -new_n), new_n)
                bias_speed = -_dot(self._bias_velocity[:, :, None], wall_normal)
                new_wb = torch.where(
                    wall_touching, (wall_bias_impulse + (wall_bias - bias_speed) * wall_normal_mass).clamp(min=0.0), 0.0
                )
                wall_dn, wall_dt, wall_db = new_n - old[..., 0], new_t - old[..., 1], new_wb - wall_bias_impulse
                self._wall_impulse, wall_bias_impulse = torch.stack([new_n, new_t], dim=-1), new_wb
            if has_ball:
                bv, bw = self.object_velocity, self.object_angular_velocity
                relative = bv[:, None] - v
                normal_speed = _dot(relative, ball_normal)
                tangent_speed = _dot(relative, ball_tangent) - bw[:, None] * self.object_radius - w * radius
                old = self._ball_impulse
                new_n = torch.where(ball_touching, (old[..., 0] - normal_speed * ball_normal_mass).clamp(min=0.0), 0.0)
                new_t = torch.minimum(torch.maximum(old[..., 1] - tangent_speed * ball_tangent_mass, -new_n), new_n)
                bias_speed = _dot(self._object_bias_velocity[:, None] - self._bias_velocity, ball_normal)
                new_bb = torch.where(
                    ball_touching, (ball_bias_impulse + (ball_bias - bias_speed) * ball_normal_mass).clamp(min=0.0), 0.0
                )
                ball_dn, ball_dt, ball_db = new_n - old[..., 0], new_t - old[..., 1], new_bb - ball_bias_impulse
                self._ball_impulse, ball_bias_impulse = torch.stack([new_n, new_t], dim=-1), new_bb
                if has_walls:
                    normal_speed = -_dot(bv[:, None], ball_wall_normal)
                    tangent_speed = -_dot(bv[:, None], bw_tangent) - bw[:, None] * self.object_radius
                    old = self._ball_wall_impulse
                    new_n = torch.where(
                        ball_wall_touching, (old[..., 0] - normal_speed * bw_normal_mass).clamp(min=0.0), 0.0
                    )
                    new_t = torch.minimum(torch.maximum(old[..., 1] - tangent_speed * bw_tangent_mass, -new_n), new_n)
                    bias_speed = -_dot(self._object_bias_velocity[:, None], ball_wall_normal)
                    new_bwb = torch.where(
                        ball_wall_touching,
                        (bw_bias_impulse + (bw_bias - bias_speed) * bw_normal_mass).clamp(min=0.0),
                        0.0,
                    )
                    bw_dn, bw_dt, bw_db = new_n - old[..., 0], new_t - old[..., 1], new_bwb - bw_bias_impulse
                    self._ball_wall_impulse, bw_bias_impulse = torch.stack([new_n, new_t], dim=-1), new_bwb
            # apply all contact impulses of this round at once
            self._apply_pairs(normal, tangent, d_normal, d_tangent, radius, other_radius, d_bias)
            if has_walls:
                self._apply_walls(wall_normal, wall_tangent, wall_dn, wall_dt, radius, wall_db)
            if has_ball:
                self._apply_ball(ball_normal, ball_tangent, ball_dn, ball_dt, radius, ball_db)
                if has_walls:
                    self._apply_ball_walls(ball_wall_normal, bw_tangent, bw_dn, bw_dt, bw_db)

            # ground friction: each body's own pivot and gear, solved exactly
            self._ground_friction()

            # rods: hold their length, pushing or pulling with at most their force limit
            v = self.velocity
            normal_speed = _dot(self._gather(v) - v[:, :, None], normal)
            new_rod = torch.minimum(
                torch.maximum(self._rod_impulse + (rod_bias - normal_speed) * rod_mass, -rod_max_impulse),
                rod_max_impulse,
            )
            new_rod = torch.where(rods, new_rod, 0.0)
            d_rod = new_rod - self._rod_impulse
            self._rod_impulse = new_rod
            self.velocity = self.velocity - (normal * d_rod[..., None]).sum(2) * inv_mass

    def _apply_pairs(self, normal, tangent, d_normal, d_tangent, radius, other_radius, d_bias=None) -> None:
        """Robot-robot impulses (slot values are the impulse on the neighbour; the robot gets the opposite)."""
        impulse = normal * d_normal[..., None] + tangent * d_tangent[..., None]
        self.velocity = self.velocity - impulse.sum(2) / C.DISK_MASS
        self.angular_velocity = self.angular_velocity - radius * d_tangent.sum(2) / DISK_MOMENT
        if d_bias is not None:
            self._bias_velocity = self._bias_velocity - (normal * d_bias[..., None]).sum(2) / C.DISK_MASS

    def _apply_walls(self, normal, tangent, d_normal, d_tangent, radius, d_bias=None) -> None:
        impulse = normal * d_normal[..., None] + tangent * d_tangent[..., None]
        self.velocity = self.velocity - impulse.sum(2) / C.DISK_MASS
        self.angular_velocity = self.angular_velocity - radius * d_tangent.sum(2) / DISK_MOMENT
        if d_bias is not None:
            self._bias_velocity = self._bias_velocity - (normal * d_bias[..., None]).sum(2) / C.DISK_MASS

    def _apply_ball(self, normal, tangent, d_normal, d_tangent, radius, d_bias=None) -> None:
        impulse = normal * d_normal[..., None] + tangent * d_tangent[..., None]  # on the ball; robots get -
        self.velocity = self.velocity - impulse / C.DISK_MASS
        self.angular_velocity = self.angular_velocity - radius * d_tangent / DISK_MOMENT
        self.object_velocity = self.object_velocity + impulse.sum(1) / self.object_mass
        self.object_angular_velocity = (
            self.object_angular_velocity - self.object_radius * d_tangent.sum(1) / self._object_moment
        )
        if d_bias is not None:
            bias_impulse = normal * d_bias[..., None]
            self._bias_velocity = self._bias_velocity - bias_impulse / C.DISK_MASS
            self._object_bias_velocity = self._object_bias_velocity + bias_impulse.sum(1) / self.object_mass

    def _apply_ball_walls(self, normal, tangent, d_normal, d_tangent, d_bias=None) -> None:
        impulse = normal * d_normal[..., None] + tangent * d_tangent[..., None]
        self.object_velocity = self.object_velocity - impulse.sum(1) / self.object_mass
        self.object_angular_velocity = (
            self.object_angular_velocity - self.object_radius * d_tangent.sum(1) / self._object_moment
        )
        if d_bias is not None:
            self._object_bias_velocity = (
                self._object_bias_velocity - (normal * d_bias[..., None]).sum(1) / self.object_mass
            )

    def _ground_friction(self) -> None:
        """pymunk's pivot and gear joints to the static body (max_bias 0): each body's accumulated friction
        impulse moves toward stopping it, clamped to the friction force times dt (a disk, not a cone)."""
        linear_max = C.GROUND_LINEAR_FRICTION * self.dt
        angular_max = C.GROUND_ANGULAR_FRICTION * self.dt
        self._ground, self.velocity = _stop(self._ground, self.velocity, C.DISK_MASS, linear_max)
        self._ground_spin, self.angular_velocity = _stop_spin(
            self._ground_spin, self.angular_velocity, DISK_MOMENT, angular_max
        )
        if self.object_radius is not None:
            self._object_friction, self.object_velocity = _stop(
                self._object_friction, self.object_velocity, self.object_mass, linear_max
            )
            self._object_spin_friction, self.object_angular_velocity = _stop_spin(
                self._object_spin_friction, self.object_angular_velocity, self._object_moment, angular_max
            )


def _stop(accumulated: torch.Tensor, velocity: torch.Tensor, mass: float, max_impulse: float):
    """One pivot-joint round: the accumulated impulse (opposing the velocity) that stops the body, clamped in
    length to ``max_impulse``; returns it and the new velocity."""
    wanted = accumulated + velocity * mass
    length = torch.linalg.vector_norm(wanted, dim=-1, keepdim=True)
    clamped = wanted * (max_impulse / length.clamp(min=max_impulse))
    return clamped, velocity - (clamped - accumulated) / mass


def _stop_spin(accumulated: torch.Tensor, spin: torch.Tensor, moment: float, max_impulse: float):
    clamped = (accumulated + spin * moment).clamp(-max_impulse, max_impulse)
    return clamped, spin - (clamped - accumulated) / moment
