"""The disk robot model (revision 2, :class:`dpr.sim.disk.DiskSwarm`) for K swarms of N robots, in torch.

One :meth:`BatchedDiskWorld.step` is one control step of every swarm: the command rule, the neighbour search,
the growth of each robot's radius into the room its neighbours leave, the rods' lengths and force limits, then
``substeps`` physics substeps. No Python loop runs over swarms or robots; the loops left run over substeps and
solver iterations, a fixed number.

The physics copies what chipmunk (pymunk's engine) does for this model, one substep at a time:

1. positions move with the velocities (plus the contacts' bias velocities) of the previous solve;
2. contacts (disk-disk, disk-wall, disk-ball, ball-wall) and rods are measured at the new positions;
3. every constraint's impulse accumulated in the previous substep is applied again (warm start);
4. ``iterations`` rounds of impulses: contacts (normal impulse >= 0 with restitution, Coulomb friction up to
   the normal impulse, overlap pushed out through separate bias velocities beyond ``collision_slop``), then
   rods (holding their length, clamped to their force limit times dt), then ground friction (each body's
   velocity and spin pulled toward zero, clamped to 500 times dt: pymunk's pivot and gear joints with no bias).

Chipmunk solves one constraint after another (Gauss-Seidel). Here all contacts are solved at once, then all
rods, then all frictions (Jacobi within each group): each constraint sees its bodies' masses multiplied by the
number of constraints of its group on them ("mass splitting", Tonge et al. 2012), so that the simultaneous
impulses sum to one body's worth and the iteration converges to the sequential solver's answer instead of
overshooting. Robots rotate (contact friction turns them) but their angle is not kept: a disk's angle changes
nothing.

Neighbour rows hold every pair twice (``i``'s row names ``j`` and ``j``'s names ``i``), so what acts on a robot is
summed over its own row, a gather without scatters: deterministic on every device.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import torch

from dpr.checks import ParameterError, check_int, check_number
from dpr.sim import constants as C
from dpr.sim.batched.neighbours import all_pairs, carry_over, cell_list
from dpr.sim.batched.solver import MUTABLE, physics, solve_round
from dpr.sim.batched.walls import disk_wall_distance, wall_geometry
from dpr.sim.swarm import REACHED_FRACTION

# Solver rounds per substep. Chipmunk does 10, one constraint after another; rounds that solve every constraint
# of a kind at once converge more slowly. Each round's impulse updates are over-relaxed (scaled up, which only
# scales the effective masses) so that 20 rounds come closest to pymunk's wave displacement over the four tasks
# (docs/research/batched-engine.md).
ITERATIONS = 20
RELAXATION = 1.3
# chipmunk's (pymunk's) defaults, which the pymunk disk model keeps
ERROR_BIAS = (1.0 - 0.1) ** 60  # both contacts' and joints' share of error left after one second
SUBSTEPS = 2  # DiskSwarm.substeps
_SANE_LIMIT = 1e6  # World.is_sane's
# what the physics reads besides MUTABLE
_READ = ("radius", "_index", "_valid", "walls", "_wall_edge", "_wall_normal", "_wall_present")
# Below this many robots, comparing every pair costs less than the cell grid's fixed work.
ALL_PAIRS_LIMIT = 32
CELL_CAP = 8  # robots per cell of the magnet range's size: disks of radius >= 32.3 fit at most ~5
MAX_NEIGHBOURS = 16  # robots within the magnet range of one robot: 4-6 in a grid, ~12 packed hard
# Bytes of working memory per robot-neighbour slot and per robot (tensors alive in a step, float32), for the
# up-front memory estimate.
_BYTES_PER_SLOT = 4 * 40
_BYTES_PER_ROBOT = 4 * 120


def _bias_coefficient(dt: float) -> float:
    """Share of a position error that chipmunk corrects in one step of ``dt`` (cpConstraint's bias_coef)."""
    return 1.0 - ERROR_BIAS**dt


def _checked_device(device) -> torch.device:
    """``device`` as a torch device that this machine has (a ParameterError naming it otherwise)."""
    try:
        checked = torch.device(device)
    except (RuntimeError, TypeError) as error:
        raise ParameterError("device", f"not a torch device: {device!r} ({error})") from None
    if checked.type == "cuda" and not torch.cuda.is_available():
        raise ParameterError("device", f"{device!r} asked for, but torch sees no CUDA device on this machine")
    return checked


def _available_memory(device: torch.device) -> int:
    if device.type == "cuda":
        return torch.cuda.get_device_properties(device).total_memory
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def estimated_memory(num_envs: int, n_robots: int) -> int:
    """Bytes a :class:`BatchedDiskWorld` of ``num_envs`` swarms of ``n_robots`` needs while stepping (estimate)."""
    slots = n_robots if n_robots <= ALL_PAIRS_LIMIT else 9 * CELL_CAP + MAX_NEIGHBOURS
    return num_envs * n_robots * (slots * _BYTES_PER_SLOT + _BYTES_PER_ROBOT)


@dataclass(frozen=True)
class SolverSettings:
    """How a :class:`BatchedDiskWorld` solves its impulses: ``iterations`` rounds per substep, ``substeps`` per
    control step, each round's updates over-relaxed by ``relaxation``, and whether one round is compiled by
    ``torch.compile`` (off: on CPU the compiled round ran slower than eager)."""

    iterations: int = ITERATIONS
    substeps: int = SUBSTEPS
    relaxation: float = RELAXATION
    compile: bool = False

    def __post_init__(self):
        check_int("iterations", self.iterations, minimum=1)
        check_int("substeps", self.substeps, minimum=1)
        check_number("relaxation", self.relaxation, above=0.0)
        if not isinstance(self.compile, bool):
            raise ParameterError("compile", f"expected True or False, got {self.compile!r}")


class BatchedDiskWorld:
    """K swarms of N disk robots, optional static walls ``[K, W, 4, 2]`` and optional ball per swarm.

    State (float32 on ``device``, read freely, written by :meth:`reset` and :meth:`step` only): ``position
    [K, N, 2]``, ``velocity [K, N, 2]``, ``angular_velocity [K, N]``, ``radius [K, N]``, ``expansion [K, N]`` in
    [0, 1], ``target [K, N]``, ``moving [K, N]``, ``alive [K, N]``; with a ball, ``object_position [K, 2]`` and
    ``object_velocity [K, 2]``; ``walls [K, W, 4, 2]``.
    """

    def __init__(
        self,
        num_envs: int,
        n_robots: int,
        *,
        device: str | torch.device = "cpu",
        n_walls: int = 0,
        object_radius: float | None = None,
        object_mass: float = 100.0,
        solver: SolverSettings = SolverSettings(),
    ):
        self.num_envs = k = check_int("num_envs", num_envs, minimum=1)
        self.n_robots = n = check_int("n_robots", n_robots, minimum=1)
        self.n_walls = check_int("n_walls", n_walls, minimum=0)
        if not isinstance(solver, SolverSettings):
            raise ParameterError("solver", f"expected SolverSettings, got {type(solver).__name__}")
        self.iterations, self.substeps, self.relaxation = solver.iterations, solver.substeps, solver.relaxation
        self.device = _checked_device(device)
        if object_radius is not None:
            object_radius = check_number("object_radius", object_radius, above=0.0)
        self.object_radius = object_radius
        self.object_mass = check_number("object_mass", object_mass, above=0.0)
        needed, available = estimated_memory(k, n), _available_memory(self.device)
        if needed > available:
            raise ParameterError(
                "num_envs",
                f"{k} swarms of {n} robots need about {needed / 2**30:.1f} GiB while stepping; "
                f"{self.device} has {available / 2**30:.1f} GiB: use fewer swarms or robots",
            )
        self.dt = C.CONTROL_PERIOD / self.substeps
        self._bias = _bias_coefficient(self.dt)
        self.use_cells = n > ALL_PAIRS_LIMIT
        self.cell_cap, self.max_neighbours = CELL_CAP, MAX_NEIGHBOURS
        self._allocate_state(k, n)
        self._allocate_solver_state(k, n)
        # compiled, one solver round is one graph (seconds to compile, once per shape and case)
        self._solve = torch.compile(solve_round, dynamic=False) if solver.compile else solve_round

    def _zeros(self, *shape, dtype=torch.float32) -> torch.Tensor:
        return torch.zeros(*shape, dtype=dtype, device=self.device)

    def _allocate_state(self, k: int, n: int) -> None:
        """The swarms', walls' and ball's state, all contracted and at rest until :meth:`reset`."""
        zeros = self._zeros
        self.position = zeros(k, n, 2)
        self.velocity = zeros(k, n, 2)
        self.angular_velocity = zeros(k, n)
        self.radius = torch.full((k, n), C.DISK_CONTRACTED_RADIUS, device=self.device)
        self.commanded_radius = self.radius.clone()  # where each actuator drives: the radius with no load
        self.expansion = zeros(k, n)
        self.target = zeros(k, n)
        self.moving = zeros(k, n, dtype=torch.bool)
        self.alive = torch.ones(k, n, dtype=torch.bool, device=self.device)
        self.walls = zeros(k, self.n_walls, 4, 2)
        self._set_wall_geometry()
        if self.object_radius is not None:
            self.object_position = zeros(k, 2)
            self.object_velocity = zeros(k, 2)
            self.object_angular_velocity = zeros(k)
            self._object_bias_velocity = zeros(k, 2)
            self._object_moment = self.object_mass * self.object_radius**2 / 2
            self._object_friction = zeros(k, 2)  # accumulated ground-friction impulses (pivot, gear)
            self._object_spin_friction = zeros(k)

    def _allocate_solver_state(self, k: int, n: int) -> None:
        """What the solver keeps between substeps and steps: the neighbour table and chipmunk's accumulated
        impulses (its warm starts)."""
        zeros = self._zeros
        self._bias_velocity = zeros(k, n, 2)
        self._ground = zeros(k, n, 2)
        self._ground_spin = zeros(k, n)
        m = n if not self.use_cells else self.max_neighbours
        self._index = torch.arange(n, device=self.device).expand(k, n, n) if not self.use_cells else None
        self._valid = zeros(k, n, m, dtype=torch.bool)
        if self.use_cells:
            self._index = torch.zeros(k, n, m, dtype=torch.long, device=self.device)
        self._config = {
            "dt": self.dt,
            "_bias": self._bias,
            "iterations": self.iterations,
            "substeps": self.substeps,
            "relaxation": self.relaxation,
            "use_cells": self.use_cells,
            "n_walls": self.n_walls,
            "object_radius": self.object_radius,
            "object_mass": self.object_mass,
            "_object_moment": getattr(self, "_object_moment", None),
        }
        self._rod_impulse = zeros(k, n, m)
        self._normal_impulse = zeros(k, n, m)
        self._tangent_impulse = zeros(k, n, m)
        self._wall_impulse = zeros(k, n, self.n_walls, 2)  # normal, tangent
        self._ball_impulse = zeros(k, n, 2)
        self._ball_wall_impulse = zeros(k, self.n_walls, 2)

    # -- state --------------------------------------------------------------------------------------------
    def reset(
        self,
        mask: torch.Tensor,
        centres: torch.Tensor,
        dead: torch.Tensor,
        walls: torch.Tensor | None = None,
        object_position: torch.Tensor | None = None,
    ) -> None:
        """Start the swarms where ``mask [K]`` is True: robots at ``centres [K, N, 2]``, contracted and at rest,
        ``dead [K, N]`` unresponsive; ``walls [K, W, 4, 2]`` and ``object_position [K, 2]`` where given. Rows of
        the other swarms are ignored."""
        k, n = self.num_envs, self.n_robots
        mask = self._checked("mask", mask, (k,), torch.bool)
        centres = self._checked("centres", centres, (k, n, 2), torch.float32)
        dead = self._checked("dead", dead, (k, n), torch.bool)
        robots = mask[:, None]

        def put(name: str, value) -> None:
            old = getattr(self, name)
            where = mask.reshape(-1, *([1] * (old.dim() - 1)))
            setattr(self, name, torch.where(where, torch.as_tensor(value, dtype=old.dtype, device=self.device), old))

        put("position", centres)
        for name in (
            "velocity",
            "angular_velocity",
            "expansion",
            "target",
            "moving",
            "_bias_velocity",
            "_ground",
            "_ground_spin",
            "_rod_impulse",
            "_normal_impulse",
            "_tangent_impulse",
            "_wall_impulse",
            "_ball_impulse",
            "_ball_wall_impulse",
            "_valid",
        ):
            put(name, 0)
        put("radius", C.DISK_CONTRACTED_RADIUS)
        put("commanded_radius", C.DISK_CONTRACTED_RADIUS)
        self.alive = torch.where(robots, ~dead, self.alive)
        if walls is not None:
            put("walls", self._checked("walls", walls, (k, self.n_walls, 4, 2), torch.float32))
            self._set_wall_geometry()
        if self.object_radius is not None:
            if object_position is not None:
                put("object_position", self._checked("object_position", object_position, (k, 2), torch.float32))
            for name in (
                "object_velocity",
                "object_angular_velocity",
                "_object_bias_velocity",
                "_object_friction",
                "_object_spin_friction",
            ):
                put(name, 0)

    def _checked(self, name: str, value, shape: tuple, dtype: torch.dtype) -> torch.Tensor:
        value = torch.as_tensor(value, device=self.device)
        if tuple(value.shape) != shape:
            raise ParameterError(name, f"expected shape {list(shape)}, got {list(value.shape)}")
        return value.to(dtype)

    def _set_wall_geometry(self) -> None:
        self._wall_edge, self._wall_normal, self._wall_present = wall_geometry(self.walls)

    def is_sane(self) -> torch.Tensor:
        """``[K]``: False where any body's state is non-finite or absurdly large (a physics blow-up)."""
        parts = [self.position.flatten(1), self.velocity.flatten(1), self.angular_velocity]
        if self.object_radius is not None:
            parts += [self.object_position, self.object_velocity, self.object_angular_velocity[:, None]]
        # NaN compares False: one comparison catches NaN, infinities and runaway values
        return (torch.cat(parts, dim=1).abs() < _SANE_LIMIT).all(dim=1)

    def max_overlap(self) -> torch.Tensor:
        """``[K]``: the deepest overlap between two robots' disks now (0 if none touch)."""
        index, valid = self._search_now() if self.use_cells else all_pairs(self.position, C.DISK_MAGNET_RANGE)
        distance = torch.linalg.vector_norm(self._gather(self.position, index) - self.position[:, :, None], dim=-1)
        overlap = self.radius[:, :, None] + self._gather(self.radius, index) - distance
        return torch.where(valid, overlap, 0.0).flatten(1).amax(dim=1).clamp(min=0.0)

    def robots_touch_walls(self) -> torch.Tensor:
        """``[K]``: whether any robot's disk touches a wall now."""
        if self.n_walls == 0:
            return torch.zeros(self.num_envs, dtype=torch.bool, device=self.device)
        distance, _ = disk_wall_distance(self.position, self.walls, self._wall_edge, self._wall_normal)
        touch = (distance < self.radius[..., None]) & self._wall_present[:, None]
        return touch.flatten(1).any(dim=1)

    # -- neighbours ---------------------------------------------------------------------------------------
    def _search_now(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The cell-list table for the current positions, searched again with larger caps until nothing
        overflows."""
        while True:
            index, valid, overflow = cell_list(self.position, C.DISK_MAGNET_RANGE, self.cell_cap, self.max_neighbours)
            if not overflow:
                return index, valid
            self.cell_cap *= 2
            self.max_neighbours *= 2

    def _update_neighbours(self) -> None:
        """This step's magnet pairs (the rods) and contact candidates: robots whose centres are closer than the
        magnet range; accumulated impulses follow their pairs to the new table's slots."""
        if not self.use_cells:
            _, self._valid = all_pairs(self.position, C.DISK_MAGNET_RANGE)
            return
        index, valid = self._search_now()
        old = (self._rod_impulse, self._normal_impulse, self._tangent_impulse)
        if index.shape[-1] != self._index.shape[-1]:  # the caps grew: widen the old table with empty slots
            pad = index.shape[-1] - self._index.shape[-1]
            grow = lambda t: torch.nn.functional.pad(t, (0, pad))  # noqa: E731
            self._index, self._valid, old = grow(self._index), grow(self._valid), [grow(t) for t in old]
        self._rod_impulse, self._normal_impulse, self._tangent_impulse = carry_over(
            self._index, self._valid, index, valid, *old
        )
        self._index, self._valid = index, valid

    def _gather(self, value: torch.Tensor, index: torch.Tensor | None = None) -> torch.Tensor:
        """Each neighbour slot's value of a per-robot tensor ``[K, N, ...]``: ``[K, N, M, ...]``."""
        index = self._index if index is None else index
        k, n = value.shape[:2]
        if not self.use_cells:  # slot m is robot m: a broadcast, no copy
            return value[:, None].expand(k, n, *value.shape[1:])
        flat = (index + torch.arange(k, device=value.device)[:, None, None] * n).reshape(-1)
        return value.reshape(k * n, *value.shape[2:])[flat].reshape(*index.shape, *value.shape[2:])

    # -- control ------------------------------------------------------------------------------------------
    def step(self, targets: torch.Tensor) -> None:
        """One control step (0.1 s) of every swarm with expansion ``targets [K, N]`` in [0, 1]."""
        targets = self._checked("targets", targets, (self.num_envs, self.n_robots), torch.float32)
        # the command rule (Swarm.command): a robot moving toward its target keeps it until within reach
        busy = self.moving & ((self.target - self.expansion).abs() >= REACHED_FRACTION)
        accept = self.alive & ~busy  # dead robots never accept: their target stays 0 (contracted)
        self.target = torch.where(accept, targets, self.target)
        self.moving = (busy | accept) & ((self.target - self.expansion).abs() >= REACHED_FRACTION)
        radius_target = C.DISK_CONTRACTED_RADIUS + self.target * (C.DISK_EXPANDED_RADIUS - C.DISK_CONTRACTED_RADIUS)

        self._update_neighbours()
        rod_length, rod_max_impulse = self._grow(radius_target)
        state = {name: getattr(self, name) for name in MUTABLE + _READ if hasattr(self, name)}
        for name, value in physics(state, self._config, rod_length, rod_max_impulse, self._solve).items():
            setattr(self, name, value)

    def _grow(self, radius_target: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """DiskSwarm.before_physics: move the commanded radii, grow the disks into the room their neighbours
        leave (at most DISK_GROWTH_OVERLAP into one), and return the rods' lengths and force limits (as impulses
        per substep)."""
        reach = C.DISK_RADIUS_SPEED * C.CONTROL_PERIOD
        commanded = torch.minimum(
            torch.maximum(radius_target, self.commanded_radius - reach), self.commanded_radius + reach
        )
        radius = self.radius
        distance = torch.linalg.vector_norm(self._gather(self.position) - self.position[:, :, None], dim=-1)
        radius_sum = radius[:, :, None] + self._gather(radius)
        commanded_sum = commanded[:, :, None] + self._gather(commanded)
        gap = distance - radius_sum  # free room between the two surfaces of each linked pair
        room = (
            torch.where(self._valid, gap, math.inf).amin(dim=-1)
            if self._valid.shape[-1]
            else torch.full_like(radius, math.inf)
        )
        new_radius = torch.minimum(commanded, radius + (room + C.DISK_GROWTH_OVERLAP).clamp(min=0.0))
        # each rod pushes (or pulls) its pair apart by what the two robots still have to grow (or shrink)
        rod_length = gap + commanded_sum
        pushing = commanded_sum > radius_sum
        rod_max_impulse = torch.where(pushing, C.DISK_PUSH_FORCE, C.MAGNET_MAX_FORCE) * self.dt
        self.commanded_radius = commanded
        self.radius = new_radius
        self.expansion = (new_radius - C.DISK_CONTRACTED_RADIUS) / (C.DISK_EXPANDED_RADIUS - C.DISK_CONTRACTED_RADIUS)
        return rod_length, rod_max_impulse
