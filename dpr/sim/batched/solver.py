"""One control step's physics substeps for K swarms: chipmunk's sequential impulses as Jacobi rounds.

Each substep measures its constraints once (:class:`_Bodies`: normals, effective masses, biases, all fixed
within the substep), then runs ``iterations`` rounds of :func:`solve_round`, a pure function of two dicts of
plain tensors (what the rounds change, what they only read). That one round is what ``torch.compile`` fuses:
small enough to compile in seconds, called 60 times a control step. See :mod:`dpr.sim.batched.world` for the
method and the reasons.

Constraints that do not act (pairs not touching, slots without a rod) carry an effective mass of 0 and an
impulse of 0, so a round needs no masks: every clamp of a 0 update lands on 0.
"""

from __future__ import annotations

import torch

from dpr.sim import constants as C
from dpr.sim.batched.walls import disk_wall_distance

ROBOT_ELASTICITY = C.BODY_ELASTICITY * C.BODY_ELASTICITY  # chipmunk multiplies the two shapes' values
COLLISION_SLOP = 0.1  # chipmunk's default
DISK_MOMENT = C.DISK_MASS * C.DISK_CONTRACTED_RADIUS**2 / 2  # fixed at creation, as pymunk's body keeps it
INV_MASS, INV_MOMENT = 1.0 / C.DISK_MASS, 1.0 / DISK_MOMENT

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
# (normal, tangent) accumulated impulses kept stacked in the world's state and split for the rounds
_STACKED = {"_wall_impulse": "wall", "_ball_impulse": "ball", "_ball_wall_impulse": "ball_wall"}


def _perp(v: torch.Tensor) -> torch.Tensor:
    return torch.stack([-v[..., 1], v[..., 0]], dim=-1)


def _dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return (a * b).sum(-1)


def _neighbours(value: torch.Tensor, fixed: dict) -> torch.Tensor:
    """Each neighbour slot's value of a per-robot tensor ``[K, N, ...]``: ``[K, N, M, ...]``."""
    k, n = value.shape[:2]
    flat = fixed.get("flat")
    if flat is None:  # all pairs: slot m is robot m, a broadcast without a copy
        return value[:, None].expand(k, n, *value.shape[1:])
    return value.reshape(k * n, *value.shape[2:])[flat].reshape(k, n, -1, *value.shape[2:])


def physics(state: dict, config: dict, rod_length: torch.Tensor, rod_max_impulse: torch.Tensor, solve=None) -> dict:
    """``config["substeps"]`` substeps from ``state`` (tensors by attribute name) with constant ``config``
    (python numbers and flags); ``solve`` is :func:`solve_round` or its compiled twin. Returns the changed
    tensors."""
    solve = solve_round if solve is None else solve
    bodies = _Bodies(state, config)
    for _ in range(config["substeps"]):
        bodies.move()
        fixed = bodies.measure(rod_length, rod_max_impulse)
        live = bodies.warm_start(fixed)
        for _ in range(config["iterations"]):
            live = solve(live, fixed)
        bodies.keep(live)
    return {name: getattr(bodies, name) for name in MUTABLE if name in state}


# -- one solver round -------------------------------------------------------------------------------------
def solve_round(live: dict, fixed: dict) -> dict:
    """One round in chipmunk's order: all contacts at once, then ground friction, then the rods. ``live`` holds
    the velocities and accumulated impulses (returned updated, a new dict), ``fixed`` this substep's constants."""
    live = dict(live)
    velocity, spin, bias = live["velocity"], live["angular_velocity"], live["_bias_velocity"]
    changes = [_pair_contacts(live, fixed, velocity, spin, bias)]
    if "wall_normal" in fixed:
        changes.append(_wall_contacts(live, fixed, velocity, spin, bias))
    if "ball_normal" in fixed:
        ball = _ball_contacts(live, fixed, velocity, spin, bias)
        changes.append(ball[:3])
        ball_changes = [ball[3:]]
        if "ball_wall_normal" in fixed:
            ball_changes.append(_ball_wall_contacts(live, fixed))
        for name, total in zip(
            ("object_velocity", "object_angular_velocity", "_object_bias_velocity"), zip(*ball_changes)
        ):
            live[name] = live[name] + sum(total)
    for name, total in zip(("velocity", "angular_velocity", "_bias_velocity"), zip(*changes)):
        live[name] = live[name] + sum(total)
    _ground_friction(live, fixed)
    _rods(live, fixed)
    return live


def _contact(normal_speed, tangent_speed, bias_speed, old: tuple, fixed: dict, name: str):
    """One contact group's new impulses (normal >= 0 with restitution; friction within the normal impulse; the
    separate bias impulse >= 0) and their changes: ``(new normal, tangent, bias), (changes)``."""
    old_normal, old_tangent, old_bias = old
    mass = fixed[name + "_normal_mass"]  # 0 where not touching: the impulses stay 0
    normal = (old_normal - (fixed[name + "_bounce"] + normal_speed) * mass).clamp(min=0.0)
    tangent = torch.clamp(old_tangent - tangent_speed * fixed[name + "_tangent_mass"], -normal, normal)
    bias = (old_bias + (fixed[name + "_bias"] - bias_speed) * mass).clamp(min=0.0)
    return (normal, tangent, bias), (normal - old_normal, tangent - old_tangent, bias - old_bias)


def _pair_contacts(live: dict, fixed: dict, velocity, spin, bias) -> tuple:
    """Robot-robot contacts; returns the robots' velocity, spin and bias velocity changes."""
    normal, tangent = fixed["normal"], fixed["tangent"]
    relative = _neighbours(velocity, fixed) - velocity[:, :, None]
    rim_speed = _neighbours(spin, fixed) * fixed["other_radius"] + (spin * fixed["radius"])[:, :, None]
    bias_speed = _dot(_neighbours(bias, fixed) - bias[:, :, None], normal)
    old = (live["_normal_impulse"], live["_tangent_impulse"], live["pair_bias_impulse"])
    new, (d_normal, d_tangent, d_bias) = _contact(
        _dot(relative, normal), _dot(relative, tangent) - rim_speed, bias_speed, old, fixed, "pair"
    )
    live["_normal_impulse"], live["_tangent_impulse"], live["pair_bias_impulse"] = new
    # slot values are the impulse on the neighbour; the robot gets the opposite
    return _pushed(normal, tangent, d_normal, d_tangent, d_bias, fixed["radius"], 2)


def _pushed(normal, tangent, d_normal, d_tangent, d_bias, radius, dim: int) -> tuple:
    """A robot's velocity, spin and bias velocity changes from impulses ``-(normal, tangent)`` summed over
    ``dim`` (the slots; None: one contact per robot)."""
    impulse = normal * d_normal[..., None] + tangent * d_tangent[..., None]
    bias_impulse = normal * d_bias[..., None]
    if dim is not None:
        impulse, d_tangent, bias_impulse = impulse.sum(dim), d_tangent.sum(dim), bias_impulse.sum(dim)
    return -impulse * INV_MASS, -radius * d_tangent * INV_MOMENT, -bias_impulse * INV_MASS


def _wall_contacts(live: dict, fixed: dict, velocity, spin, bias) -> tuple:
    normal, tangent = fixed["wall_normal"], fixed["wall_tangent"]  # from the robot into the wall
    normal_speed = -_dot(velocity[:, :, None], normal)
    tangent_speed = -_dot(velocity[:, :, None], tangent) - (spin * fixed["radius"])[..., None]
    bias_speed = -_dot(bias[:, :, None], normal)
    old = (live["wall_normal_impulse"], live["wall_tangent_impulse"], live["wall_bias_impulse"])
    new, (d_normal, d_tangent, d_bias) = _contact(normal_speed, tangent_speed, bias_speed, old, fixed, "wall")
    live["wall_normal_impulse"], live["wall_tangent_impulse"], live["wall_bias_impulse"] = new
    return _pushed(normal, tangent, d_normal, d_tangent, d_bias, fixed["radius"], 2)


def _ball_contacts(live: dict, fixed: dict, velocity, spin, bias) -> tuple:
    """Robot-ball contacts: the robots' changes, then the ball's (velocity, spin, bias velocity)."""
    normal, tangent = fixed["ball_normal"], fixed["ball_tangent"]  # from the robot to the ball
    relative = live["object_velocity"][:, None] - velocity
    ball_spin = live["object_angular_velocity"][:, None] * fixed["object_radius"]
    tangent_speed = _dot(relative, tangent) - ball_spin - spin * fixed["radius"]
    bias_speed = _dot(live["_object_bias_velocity"][:, None] - bias, normal)
    old = (live["ball_normal_impulse"], live["ball_tangent_impulse"], live["ball_bias_impulse"])
    new, (d_normal, d_tangent, d_bias) = _contact(_dot(relative, normal), tangent_speed, bias_speed, old, fixed, "ball")
    live["ball_normal_impulse"], live["ball_tangent_impulse"], live["ball_bias_impulse"] = new
    robots = _pushed(normal, tangent, d_normal, d_tangent, d_bias, fixed["radius"], None)
    on_ball = _pushed(normal, tangent, d_normal, d_tangent, d_bias, fixed["object_radius"], 1)
    return robots + _ball_share(on_ball, fixed, -1.0)


def _ball_wall_contacts(live: dict, fixed: dict) -> tuple:
    normal, tangent = fixed["ball_wall_normal"], fixed["ball_wall_tangent"]
    velocity, spin = live["object_velocity"][:, None], live["object_angular_velocity"][:, None]
    normal_speed = -_dot(velocity, normal)
    tangent_speed = -_dot(velocity, tangent) - spin * fixed["object_radius"]
    bias_speed = -_dot(live["_object_bias_velocity"][:, None], normal)
    old = (live["ball_wall_normal_impulse"], live["ball_wall_tangent_impulse"], live["ball_wall_bias_impulse"])
    new, (d_normal, d_tangent, d_bias) = _contact(normal_speed, tangent_speed, bias_speed, old, fixed, "ball_wall")
    live["ball_wall_normal_impulse"], live["ball_wall_tangent_impulse"], live["ball_wall_bias_impulse"] = new
    return _ball_share(_pushed(normal, tangent, d_normal, d_tangent, d_bias, fixed["object_radius"], 1), fixed, 1.0)


def _ball_share(disk_changes: tuple, fixed: dict, sign: float) -> tuple:
    """Changes computed with a disk's mass and moment rescaled to the ball's (``sign`` -1: the ball's velocity
    takes the opposite of what the robots' takes; friction turns both the same way)."""
    velocity, spin, bias = disk_changes
    mass_scale = sign * C.DISK_MASS * fixed["object_inv_mass"]
    moment_scale = DISK_MOMENT * fixed["object_inv_moment"]
    return velocity * mass_scale, spin * moment_scale, bias * mass_scale


def _ground_friction(live: dict, fixed: dict) -> None:
    """pymunk's pivot and gear joints to the static body (max_bias 0): each body's own, solved exactly."""
    linear_max, angular_max = fixed["linear_friction"], fixed["angular_friction"]
    live["_ground"], live["velocity"] = _stop(live["_ground"], live["velocity"], C.DISK_MASS, linear_max)
    live["_ground_spin"], live["angular_velocity"] = _stop_spin(
        live["_ground_spin"], live["angular_velocity"], DISK_MOMENT, angular_max
    )
    if "object_inv_mass" in fixed:
        mass, moment = 1.0 / fixed["object_inv_mass"], 1.0 / fixed["object_inv_moment"]
        live["_object_friction"], live["object_velocity"] = _stop(
            live["_object_friction"], live["object_velocity"], mass, linear_max
        )
        live["_object_spin_friction"], live["object_angular_velocity"] = _stop_spin(
            live["_object_spin_friction"], live["object_angular_velocity"], moment, angular_max
        )


def _rods(live: dict, fixed: dict) -> None:
    """Rods hold their length, pushing or pulling with at most their force limit (0 in slots without a rod)."""
    velocity, normal = live["velocity"], fixed["normal"]
    normal_speed = _dot(_neighbours(velocity, fixed) - velocity[:, :, None], normal)
    old, limit = live["_rod_impulse"], fixed["rod_max_impulse"]
    new = torch.clamp(old + (fixed["rod_bias"] - normal_speed) * fixed["rod_mass"], -limit, limit)
    live["_rod_impulse"] = new
    live["velocity"] = velocity - (normal * (new - old)[..., None]).sum(2) * INV_MASS


def _stop(accumulated: torch.Tensor, velocity: torch.Tensor, mass, max_impulse):
    """One pivot-joint round: the accumulated impulse (opposing the velocity) that stops the body, clamped in
    length to ``max_impulse``; returns it and the new velocity."""
    wanted = accumulated + velocity * mass
    length = torch.linalg.vector_norm(wanted, dim=-1, keepdim=True)
    clamped = wanted * (max_impulse / torch.maximum(length, max_impulse))
    return clamped, velocity - (clamped - accumulated) / mass


def _stop_spin(accumulated: torch.Tensor, spin: torch.Tensor, moment, max_impulse):
    clamped = torch.clamp(accumulated + spin * moment, -max_impulse, max_impulse)
    return clamped, spin - (clamped - accumulated) / moment


# -- a substep's constraints ------------------------------------------------------------------------------
class _Bodies:
    """The tensors and constants of one physics call, as attributes (the names :class:`BatchedDiskWorld` uses)."""

    def __init__(self, state: dict, config: dict):
        self.__dict__.update(state)
        self.__dict__.update(config)
        self.has_ball, self.has_walls = self.object_radius is not None, self.n_walls > 0
        self.flat = None
        if self.use_cells:  # the neighbour table is fixed for the whole control step
            k, n = self.position.shape[:2]
            self.flat = (self._index + torch.arange(k, device=self.position.device)[:, None, None] * n).reshape(-1)

    def move(self) -> None:
        """Positions move with the last solve's velocities and bias velocities."""
        self.position = self.position + (self.velocity + self._bias_velocity) * self.dt
        self._bias_velocity = torch.zeros_like(self._bias_velocity)
        if self.has_ball:
            self.object_position = self.object_position + (self.object_velocity + self._object_bias_velocity) * self.dt
            self._object_bias_velocity = torch.zeros_like(self._object_bias_velocity)

    def measure(self, rod_length: torch.Tensor, rod_max_impulse: torch.Tensor) -> dict:
        """Every constraint's geometry and effective mass at the current positions: the rounds' ``fixed``."""
        fixed = {"radius": self.radius, "flat": self.flat} if self.flat is not None else {"radius": self.radius}
        fixed["linear_friction"] = torch.tensor(C.GROUND_LINEAR_FRICTION * self.dt, device=self.position.device)
        fixed["angular_friction"] = torch.tensor(C.GROUND_ANGULAR_FRICTION * self.dt, device=self.position.device)
        touching = {"pair": self._pair_geometry(fixed)}
        if self.has_walls:
            touching["wall"] = self._wall_geometry(fixed, "wall", self.position, self.radius[..., None])
        contacts = sum(t.sum(-1) for t in touching.values()).float()
        if self.has_ball:
            touching["ball"], touching["ball_wall"] = self._ball_geometry(fixed)
            contacts = contacts + touching["ball"]
            ball_contacts = touching["ball"].sum(-1).float()
            if self.has_walls:
                ball_contacts = ball_contacts + touching["ball_wall"].sum(-1)
            self._ball_masses(fixed, touching, contacts.clamp(min=1.0), ball_contacts.clamp(min=1.0))
        share = contacts.clamp(min=1.0)  # mass splitting: the contacts acting on each robot
        self._pair_masses(fixed, touching["pair"], share)
        if self.has_walls:
            fixed["wall_normal_mass"] = (C.DISK_MASS / share[..., None]) * touching["wall"]
            fixed["wall_tangent_mass"] = 1.0 / (
                share[..., None] * (INV_MASS + self.radius[..., None] ** 2 * INV_MOMENT)
            )
            fixed["wall_bounce"] = torch.zeros_like(fixed["wall_normal_mass"])
            self._wall_impulse = self._wall_impulse * touching["wall"][..., None]
        self._rod_constants(fixed, rod_length, rod_max_impulse)
        for name in [name for name in fixed if name.endswith("_mass") and name != "object_inv_mass"]:
            fixed[name] = fixed[name] * self.relaxation
        return fixed

    def _pair_geometry(self, fixed: dict) -> torch.Tensor:
        delta = _neighbours(self.position, fixed) - self.position[:, :, None]
        distance = torch.linalg.vector_norm(delta, dim=-1)
        fixed["distance"] = distance
        fixed["normal"] = delta / distance.clamp(min=1e-12)[..., None]  # (0, 0) for coincident centres: no push
        fixed["tangent"] = _perp(fixed["normal"])
        fixed["other_radius"] = _neighbours(self.radius, fixed)
        depth = distance - self.radius[:, :, None] - fixed["other_radius"]  # < 0: overlapping
        fixed["pair_bias"] = -self._bias * (depth + COLLISION_SLOP).clamp(max=0.0) / self.dt
        return self._valid & (depth < 0)

    def _wall_geometry(self, fixed: dict, name: str, centre: torch.Tensor, radius) -> torch.Tensor:
        """Disks ``centre [K, P, 2]`` of ``radius`` against the walls: normals into the wall, bias; touching."""
        distance, out = disk_wall_distance(centre, self.walls, self._wall_edge, self._wall_normal)
        depth = distance - radius
        fixed[name + "_normal"] = -out
        fixed[name + "_tangent"] = _perp(-out)
        fixed[name + "_bias"] = -self._bias * (depth + COLLISION_SLOP).clamp(max=0.0) / self.dt
        return (depth < 0) & self._wall_present[:, None]

    def _ball_geometry(self, fixed: dict) -> tuple:
        fixed["object_radius"] = torch.tensor(self.object_radius, device=self.position.device)
        fixed["object_inv_mass"] = torch.tensor(1.0 / self.object_mass, device=self.position.device)
        fixed["object_inv_moment"] = torch.tensor(1.0 / self._object_moment, device=self.position.device)
        delta = self.object_position[:, None] - self.position
        distance = torch.linalg.vector_norm(delta, dim=-1)
        fixed["ball_normal"] = delta / distance.clamp(min=1e-12)[..., None]
        fixed["ball_tangent"] = _perp(fixed["ball_normal"])
        depth = distance - self.radius - self.object_radius
        fixed["ball_bias"] = -self._bias * (depth + COLLISION_SLOP).clamp(max=0.0) / self.dt
        fixed["ball_bounce"] = torch.zeros_like(depth)
        if not self.has_walls:
            return depth < 0, None
        touching = self._wall_geometry(fixed, "ball_wall", self.object_position[:, None], self.object_radius)
        for name in ("ball_wall_normal", "ball_wall_tangent"):
            fixed[name] = fixed[name][:, 0]
        fixed["ball_wall_bias"] = fixed["ball_wall_bias"][:, 0]
        return depth < 0, touching[:, 0]

    def _pair_masses(self, fixed: dict, touching: torch.Tensor, share: torch.Tensor) -> None:
        other_share, radius = _neighbours(share, fixed), self.radius[:, :, None]
        fixed["pair_normal_mass"] = touching / ((share[:, :, None] + other_share) * INV_MASS)
        fixed["pair_tangent_mass"] = 1.0 / (
            (share[:, :, None] + other_share) * INV_MASS
            + (share[:, :, None] * radius**2 + other_share * fixed["other_radius"] ** 2) * INV_MOMENT
        )
        relative = _neighbours(self.velocity, fixed) - self.velocity[:, :, None]
        fixed["pair_bounce"] = _dot(relative, fixed["normal"]) * ROBOT_ELASTICITY
        # persistent contacts keep their impulses (chipmunk's warm start); the rest start from 0
        self._normal_impulse = self._normal_impulse * touching
        self._tangent_impulse = self._tangent_impulse * touching

    def _ball_masses(self, fixed: dict, touching: dict, share: torch.Tensor, ball_share: torch.Tensor) -> None:
        inv_mass, inv_moment, radius = 1.0 / self.object_mass, 1.0 / self._object_moment, self.object_radius
        fixed["ball_normal_mass"] = touching["ball"] / (share * INV_MASS + ball_share[:, None] * inv_mass)
        fixed["ball_tangent_mass"] = 1.0 / (
            share * (INV_MASS + self.radius**2 * INV_MOMENT) + ball_share[:, None] * (inv_mass + radius**2 * inv_moment)
        )
        self._ball_impulse = self._ball_impulse * touching["ball"][..., None]
        if self.has_walls:
            fixed["ball_wall_normal_mass"] = touching["ball_wall"] * self.object_mass / ball_share[:, None]
            fixed["ball_wall_tangent_mass"] = 1.0 / (ball_share[:, None] * (inv_mass + radius**2 * inv_moment))
            fixed["ball_wall_bounce"] = torch.zeros_like(fixed["ball_wall_normal_mass"])
            self._ball_wall_impulse = self._ball_wall_impulse * touching["ball_wall"][..., None]

    def _rod_constants(self, fixed: dict, rod_length: torch.Tensor, rod_max_impulse: torch.Tensor) -> None:
        rods = self._valid
        rod_share = rods.sum(-1).float().clamp(min=1.0)
        fixed["rod_mass"] = rods / ((rod_share[:, :, None] + _neighbours(rod_share, fixed)) * INV_MASS)
        fixed["rod_max_impulse"] = rod_max_impulse * rods  # 0 without a rod: its impulse stays 0
        fixed["rod_bias"] = -self._bias * (fixed.pop("distance") - rod_length) / self.dt
        self._rod_impulse = self._rod_impulse * rods

    def warm_start(self, fixed: dict) -> dict:
        """Apply every accumulated impulse again (chipmunk's warm start); returns the rounds' ``live`` state."""
        live = {name: getattr(self, name) for name in MUTABLE if hasattr(self, name) and "position" not in name}
        live["pair_bias_impulse"] = torch.zeros_like(self._normal_impulse)
        for stacked, name in _STACKED.items():
            if name + "_normal_mass" in fixed:
                live[name + "_normal_impulse"], live[name + "_tangent_impulse"] = live.pop(stacked).unbind(-1)
                live[name + "_bias_impulse"] = torch.zeros_like(live[name + "_normal_impulse"])
            else:
                live.pop(stacked, None)
        zero = torch.zeros_like(self._normal_impulse)
        # the warm start is one round's application of the whole accumulated impulses, with no bias
        impulses = {"pair": (live["_normal_impulse"] + live["_rod_impulse"], live["_tangent_impulse"], zero)}
        changes = [_pushed(fixed["normal"], fixed["tangent"], *impulses["pair"], self.radius, 2)]
        if "wall_normal" in fixed:
            n, t = live["wall_normal_impulse"], live["wall_tangent_impulse"]
            changes.append(
                _pushed(fixed["wall_normal"], fixed["wall_tangent"], n, t, torch.zeros_like(n), self.radius, 2)
            )
        ball_changes = []
        if "ball_normal" in fixed:
            n, t = live["ball_normal_impulse"], live["ball_tangent_impulse"]
            args = (fixed["ball_normal"], fixed["ball_tangent"], n, t, torch.zeros_like(n))
            changes.append(_pushed(*args, self.radius, None))
            ball_changes.append(_ball_share(_pushed(*args, fixed["object_radius"], 1), fixed, -1.0))
            if "ball_wall_normal" in fixed:
                n, t = live["ball_wall_normal_impulse"], live["ball_wall_tangent_impulse"]
                args = (fixed["ball_wall_normal"], fixed["ball_wall_tangent"], n, t, torch.zeros_like(n))
                ball_changes.append(_ball_share(_pushed(*args, fixed["object_radius"], 1), fixed, 1.0))
        for name, total in zip(("velocity", "angular_velocity"), zip(*changes)):
            live[name] = live[name] + sum(total)
        live["velocity"] = live["velocity"] - live["_ground"] * INV_MASS
        live["angular_velocity"] = live["angular_velocity"] - live["_ground_spin"] * INV_MOMENT
        if ball_changes:
            for name, total in zip(("object_velocity", "object_angular_velocity"), zip(*ball_changes)):
                live[name] = live[name] + sum(total)
            live["object_velocity"] = live["object_velocity"] - live["_object_friction"] * fixed["object_inv_mass"]
            live["object_angular_velocity"] = (
                live["object_angular_velocity"] - live["_object_spin_friction"] * fixed["object_inv_moment"]
            )
        return live

    def keep(self, live: dict) -> None:
        """The rounds' results back into the bodies; the stacked impulses stacked again."""
        for stacked, name in _STACKED.items():
            if name + "_normal_impulse" in live:
                impulses = [live[name + "_normal_impulse"], live[name + "_tangent_impulse"]]
                setattr(self, stacked, torch.stack(impulses, dim=-1))
        for name in MUTABLE:
            if name in live:
                setattr(self, name, live[name])
