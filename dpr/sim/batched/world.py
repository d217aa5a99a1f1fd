"""The disk robot model (revision 2, :class:`dpr.sim.disk.DiskSwarm`) for K swarms of N robots, in torch.

One :meth:`BatchedDiskWorld.step` is one control step of every swarm: the command rule, the pairs within the
magnet range, the growth of each robot's radius into the room its neighbours leave, the rods' lengths and force
limits, then ``substeps`` physics substeps. No Python loop runs over swarms or robots; the loops left run over
substeps and solver rounds, a fixed number.

The physics copies what chipmunk (pymunk's engine) does for this model, one substep at a time:

1. positions move with the velocities (plus the contacts' bias velocities) of the previous solve;
2. contacts (disk-disk, disk-ball, disk-wall, ball-wall) and rods are measured at the new positions;
3. every constraint's impulse accumulated in the previous substep is applied again (warm start);
4. ``iterations`` rounds of impulses: contacts (normal impulse >= 0 with restitution, Coulomb friction up to
   the normal impulse, overlap pushed out through separate bias velocities beyond ``collision_slop``), then
   ground friction (each body's velocity and spin pulled toward zero, clamped to 500 times dt: pymunk's pivot
   and gear joints with no bias), then rods (holding their length, clamped to their force limit times dt).

Chipmunk solves one constraint after another (Gauss-Seidel). Here all contacts are solved at once, then all
rods, then all frictions (Jacobi within each group): each constraint sees its bodies' masses multiplied by the
number of constraints of its group on them ("mass splitting", Tonge et al. 2012), so that the simultaneous
impulses sum to one body's worth and the iteration converges to the sequential solver's answer instead of
overshooting. Robots rotate (contact friction turns them) but their angle is not kept: a disk's angle changes
nothing.

The state is body-major: ``[B, K]`` tensors, one row per body (the robots, then the ball), the swarms along the
fast axis, and every pair of bodies kept once (:mod:`dpr.sim.batched.pairs`). Up to ``ALL_PAIRS_LIMIT`` robots,
every pair is a column of one fixed incidence matrix and reading or summing over pairs is a matrix product; above
it, a cell list finds the pairs within the magnet range each control step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from dpr.checks import ParameterError, check_int, check_number
from dpr.limits import check_memory, physical_memory
from dpr.sim import constants as C
from dpr.sim.batched.neighbours import cell_pairs
from dpr.sim.batched.pairs import DensePairs, SparsePairs
from dpr.sim.batched.solver import (
    BALL_ELASTICITY,
    DISK_MOMENT,
    ROBOT_ELASTICITY,
    Bodies,
    Impulses,
    Rods,
    StepConstants,
    Walls,
    physics,
    substep,
)
from dpr.sim.batched.walls import disk_wall_distance, wall_geometry
from dpr.sim.swarm import REACHED_FRACTION

# What BatchedDiskWorld.reset's ``dynamics [K, 3]`` multiplies, per swarm, in this order: the rods' push limit
# (C.DISK_PUSH_FORCE), their pull limit (C.MAGNET_MAX_FORCE) and the ground friction's limits (linear and angular).
DYNAMICS = ("push_force", "magnet_force", "ground_friction")
# Solver rounds per substep. Chipmunk does 10, one constraint after another; rounds that solve every constraint
# of a kind at once converge more slowly, so each round's impulse updates are over-relaxed (scaled up, which only
# scales the effective masses): 10 rounds over-relaxed by 1.5 come as close to pymunk's wave displacement on the
# four tasks as 20 by 1.3, in half the time (chosen on starts no agreement line reports; the research log's
# batched-engine.md).
ITERATIONS = 10
RELAXATION = 1.5
# How far a robot's outline may yield to a wall (wall_give): a paddle robot's paddles fold back to its central disk.
MAX_WALL_GIVE = C.DISK_EXPANDED_RADIUS - C.BODY_RADIUS
# chipmunk's (pymunk's) defaults, which the pymunk disk model keeps
ERROR_BIAS = (1.0 - 0.1) ** 60  # both contacts' and joints' share of error left after one second
SUBSTEPS = 2  # DiskSwarm.substeps
_SANE_LIMIT = 1e6  # World.is_sane's
# Up to this many robots every pair is kept (a matrix product per read); above, a cell list finds the pairs.
ALL_PAIRS_LIMIT = 32
# Bytes of working memory per pair and per body (tensors alive in a step, float32), for the up-front estimate;
# a cell-list swarm keeps about PAIRS_PER_ROBOT pairs per robot (within the magnet range, each once).
_BYTES_PER_PAIR = 4 * 48
_BYTES_PER_BODY = 4 * 64
_PAIRS_PER_ROBOT = 8


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
    if checked.type == "cuda" and checked.index is not None and checked.index >= torch.cuda.device_count():
        count = torch.cuda.device_count()
        raise ParameterError(
            "device", f"{device!r} asked for, but torch sees {count} CUDA device(s): cuda:0 to cuda:{count - 1}"
        )
    return checked


def _body_major(swarm_major: torch.Tensor) -> torch.Tensor:
    """``[K, X]`` as ``[X, K]``, laid out row by row: a transposed view would hand its layout on through every
    operation that reads it, and the state would be read across its rows, a stride apart, in every substep."""
    return swarm_major.t().contiguous()


def compiled_if(function, compile: bool):
    """``function``, through ``torch.compile`` (static shapes) when ``compile``."""
    return torch.compile(function, dynamic=False) if compile else function


def _sane(*state: torch.Tensor) -> torch.Tensor:
    # NaN compares False: one comparison catches NaN, infinities and runaway values
    return (torch.stack(state).abs() < _SANE_LIMIT).flatten(0, 1).all(dim=0)


def _available_memory(device: torch.device) -> int:
    if device.type == "cuda":
        return torch.cuda.get_device_properties(device).total_memory
    return physical_memory()


def checked_size(
    num_envs: int, n_robots: int, device: str | torch.device = "cpu", name: str = "num_envs"
) -> torch.device:
    """The torch device of a world of ``num_envs`` swarms of ``n_robots``, once this machine has that device and its
    memory holds the world's estimate (:func:`estimated_memory`): ParameterErrors naming ``device`` or ``name`` (the
    caller's word for the count) otherwise, before anything is built."""
    checked = _checked_device(device)
    what = f"{num_envs} swarms of {n_robots} robots on {checked}"
    check_memory(name, what, estimated_memory(num_envs, n_robots), _available_memory(checked))
    return checked


def estimated_memory(num_envs: int, n_robots: int) -> int:
    """Bytes a :class:`BatchedDiskWorld` of ``num_envs`` swarms of ``n_robots`` needs while stepping (estimate)."""
    bodies = n_robots + 1
    pairs = bodies * (bodies - 1) // 2 if n_robots <= ALL_PAIRS_LIMIT else _PAIRS_PER_ROBOT * bodies
    return num_envs * (pairs * _BYTES_PER_PAIR + bodies * _BYTES_PER_BODY)


@dataclass(frozen=True)
class SolverSettings:
    """How a :class:`BatchedDiskWorld` solves its impulses: ``iterations`` rounds per substep, ``substeps`` per
    control step, each round's updates over-relaxed by ``relaxation``, and whether ``torch.compile`` fuses each
    substep, and the command rule with the growth, into a few loops (swarms of up to ``ALL_PAIRS_LIMIT`` robots;
    the first step of each shape then takes seconds to compile, every later one runs about 3 times faster on a
    CPU)."""

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
    ``object_velocity [K, 2]``; ``walls [K, W, 4, 2]``; ``dynamics [K, 3]``, each swarm's multiples of the model's
    constants named in :data:`DYNAMICS` (1 unless :meth:`reset` sets them).

    ``wall_give`` (default 0, at most :data:`MAX_WALL_GIVE`) lets walls squeeze the robots as they squeeze the
    paddle robot, whose paddles fold back against a wall: walls meet each robot's disk at its radius less this,
    never inside the central body (``BODY_RADIUS``). Robots and the ball still meet each other at full radius.

    ``compiled`` says whether this world's steps run through ``torch.compile`` (``solver.compile``, all pairs).
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
        wall_give: float = 0.0,
        solver: SolverSettings = SolverSettings(),
    ):
        self.num_envs = k = check_int("num_envs", num_envs, minimum=1)
        self.n_robots = n = check_int("n_robots", n_robots, minimum=1)
        self.n_walls = check_int("n_walls", n_walls, minimum=0)
        if not isinstance(solver, SolverSettings):
            raise ParameterError("solver", f"expected SolverSettings, got {type(solver).__name__}")
        self.device = checked_size(k, n, device)
        if object_radius is not None:
            object_radius = check_number("object_radius", object_radius, above=0.0)
        self.object_radius = object_radius
        self.object_mass = check_number("object_mass", object_mass, above=0.0)
        self.wall_give = check_number("wall_give", wall_give, 0.0, MAX_WALL_GIVE)
        self.n_bodies = n + (object_radius is not None)
        self.use_cells = n > ALL_PAIRS_LIMIT
        self.compiled = compiled = solver.compile and not self.use_cells
        # Eager, pairs are read and summed through matrix products. Compiled on a CPU, their ends are read as rows
        # picked by index, loads that inductor fuses into what uses them, and summed through the products: about
        # twice as fast a substep as slices, compiled in a fifth of the time (the same sums, in the same order).
        # Compiled on a GPU, slices fuse into a few kernels where each product is a launch.
        pair_mode = "matrix" if not compiled else "gather" if self.device.type == "cpu" else "slices"
        dt = C.CONTROL_PERIOD / solver.substeps
        self.constants = StepConstants(
            dt,
            _bias_coefficient(dt),
            solver.relaxation,
            solver.iterations,
            solver.substeps,
            compiled_if(substep, compiled),
        )
        # Compiled, the command rule and the growth are one graph too (a few loops where eager runs some forty ops).
        self._before_physics = compiled_if(BatchedDiskWorld._command_and_grow, compiled)
        self._sane = compiled_if(_sane, compiled)
        self._allocate_state(k, n)
        self._pairs = None if self.use_cells else DensePairs(self.n_bodies, k, self.device, pair_mode)
        self._impulses = self._no_impulses(0 if self.use_cells else self._pairs.size)
        if not self.use_cells:
            self._pair_constants(self._pairs)

    def _zeros(self, *shape, dtype=torch.float32) -> torch.Tensor:
        return torch.zeros(*shape, dtype=dtype, device=self.device)

    def _allocate_state(self, k: int, n: int) -> None:
        """The swarms', walls' and ball's state, all contracted and at rest until :meth:`reset`."""
        b = self.n_bodies
        masses = [C.DISK_MASS] * n + ([self.object_mass] if self.object_radius is not None else [])
        moments = [DISK_MOMENT] * n + ([self.object_mass * self.object_radius**2 / 2] if b > n else [])
        radius = torch.full((b, k), C.DISK_CONTRACTED_RADIUS, device=self.device)
        if b > n:
            radius[n] = self.object_radius
        zeros = [self._zeros(b, k) for _ in range(10)]
        self.bodies = Bodies(
            *zeros,
            radius=radius,
            mass=torch.tensor(masses, device=self.device)[:, None],
            moment=torch.tensor(moments, device=self.device)[:, None],
            friction_scale=torch.ones(1, k, device=self.device),
        )
        self._rod_scales = torch.ones(2, k, device=self.device)  # DYNAMICS' first two; the friction's is in bodies
        self._commanded = torch.full((n, k), C.DISK_CONTRACTED_RADIUS, device=self.device)  # radius with no load
        self._expansion, self._target = self._zeros(n, k), self._zeros(n, k)
        self._moving = self._zeros(n, k, dtype=torch.bool)
        self._alive = torch.ones(n, k, dtype=torch.bool, device=self.device)
        self.walls = self._zeros(k, self.n_walls, 4, 2)
        self._set_wall_geometry()

    def _no_impulses(self, n_pairs: int) -> Impulses:
        k, walls = self.num_envs, self.n_walls
        pair = [self._zeros(n_pairs, k) if not self.use_cells else self._zeros(n_pairs) for _ in range(3)]
        wall = [self._zeros(walls, self.n_bodies, k) for _ in range(2)] if walls else [None, None]
        return Impulses(*pair, *wall)

    def _pair_constants(self, pairs) -> None:
        """Per pair: which are two robots (rods and the magnet range apply) and the contact's restitution."""
        self._robot_pair = pairs.second < self.n_robots
        self._elasticity = torch.where(self._robot_pair, ROBOT_ELASTICITY, BALL_ELASTICITY)
        if not self.use_cells:
            self._robot_pair, self._elasticity = self._robot_pair[:, None], self._elasticity[:, None]

    # -- the public state, [K, N, ...] ----------------------------------------------------------------------
    def _robots_xy(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return torch.stack((x[: self.n_robots], y[: self.n_robots]), dim=-1).transpose(0, 1)

    @property
    def position(self) -> torch.Tensor:
        return self._robots_xy(self.bodies.px, self.bodies.py)

    @property
    def velocity(self) -> torch.Tensor:
        return self._robots_xy(self.bodies.vx, self.bodies.vy)

    @property
    def angular_velocity(self) -> torch.Tensor:
        return self.bodies.spin[: self.n_robots].t()

    @property
    def radius(self) -> torch.Tensor:
        return self.bodies.radius[: self.n_robots].t()

    @property
    def commanded_radius(self) -> torch.Tensor:
        return self._commanded.t()

    expansion = property(lambda self: self._expansion.t())
    target = property(lambda self: self._target.t())
    moving = property(lambda self: self._moving.t())
    alive = property(lambda self: self._alive.t())
    dynamics = property(lambda self: torch.cat((self._rod_scales, self.bodies.friction_scale)).t())
    # the swarm's centre, [K, 2]: the mean of the robots' centres, dead ones too (World.centre_of_mass)
    centre_of_mass = property(lambda self: self.position.mean(dim=1))

    def _ball(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        if self.object_radius is None:
            raise AttributeError("this world has no ball")
        return torch.stack((x[self.n_robots], y[self.n_robots]), dim=-1)

    object_position = property(lambda self: self._ball(self.bodies.px, self.bodies.py))
    object_velocity = property(lambda self: self._ball(self.bodies.vx, self.bodies.vy))
    object_angular_velocity = property(lambda self: self._ball(self.bodies.spin, self.bodies.spin)[:, 0])

    # -- state --------------------------------------------------------------------------------------------
    def reset(
        self,
        mask: torch.Tensor,
        centres: torch.Tensor,
        dead: torch.Tensor,
        walls: torch.Tensor | None = None,
        object_position: torch.Tensor | None = None,
        dynamics: torch.Tensor | None = None,
    ) -> None:
        """Start the swarms where ``mask [K]`` is True: robots at ``centres [K, N, 2]``, contracted and at rest,
        ``dead [K, N]`` unresponsive; ``walls [K, W, 4, 2]``, ``object_position [K, 2]`` and ``dynamics [K, 3]``
        (multiples of the constants named in :data:`DYNAMICS`, > 0) where given. Rows of the other swarms are
        ignored."""
        k, n = self.num_envs, self.n_robots
        mask = self._checked("mask", mask, (k,), torch.bool)
        centres = self._checked("centres", centres, (k, n, 2), torch.float32)
        dead = self._checked("dead", dead, (k, n), torch.bool)
        bodies = self.bodies
        px, py = _body_major(centres[..., 0]), _body_major(centres[..., 1])
        if self.object_radius is not None and object_position is not None:
            ball = self._checked("object_position", object_position, (k, 2), torch.float32)
            px, py = torch.cat((px, ball[None, :, 0])), torch.cat((py, ball[None, :, 1]))
        elif self.object_radius is not None:
            px, py = torch.cat((px, bodies.px[n:])), torch.cat((py, bodies.py[n:]))
        bodies.px, bodies.py = torch.where(mask, px, bodies.px), torch.where(mask, py, bodies.py)
        for name in ("vx", "vy", "spin", "bx", "by", "gx", "gy", "gspin"):
            setattr(bodies, name, torch.where(mask, 0.0, getattr(bodies, name)))
        bodies.radius = torch.where(mask, self._contracted_radii(), bodies.radius)
        self._commanded = torch.where(mask, C.DISK_CONTRACTED_RADIUS, self._commanded)
        self._expansion = torch.where(mask, 0.0, self._expansion)
        self._target = torch.where(mask, 0.0, self._target)
        self._moving = self._moving & ~mask
        self._alive = torch.where(mask, ~_body_major(dead), self._alive)
        self._clear_impulses(mask)
        if walls is not None:
            walls = self._checked("walls", walls, (k, self.n_walls, 4, 2), torch.float32)
            self.walls = torch.where(mask[:, None, None, None], walls, self.walls)
            self._set_wall_geometry()
        if dynamics is not None:
            dynamics = self._checked("dynamics", dynamics, (k, len(DYNAMICS)), torch.float32)
            if not bool((dynamics[mask] > 0).all()):
                raise ParameterError("dynamics", f"expected multiples > 0 of {', '.join(DYNAMICS)}")
            self._rod_scales = torch.where(mask, _body_major(dynamics[:, :2]), self._rod_scales)
            self.bodies.friction_scale = torch.where(mask, _body_major(dynamics[:, 2:]), self.bodies.friction_scale)

    # -- snapshots ----------------------------------------------------------------------------------------
    _STATE = ("_commanded", "_expansion", "_target", "_moving", "_alive", "walls", "_rod_scales")

    def state_dict(self) -> dict[str, torch.Tensor]:
        """Every tensor that stepping changes (bodies, accumulated impulses, this step's pairs, the robots'
        commands): what :meth:`load_state_dict` needs to go on exactly where this world stands."""
        state = {f"bodies.{name}": value.clone() for name, value in vars(self.bodies).items()}
        state.update({f"impulses.{name}": v.clone() for name, v in vars(self._impulses).items() if v is not None})
        state.update({name: getattr(self, name).clone() for name in self._STATE})
        if self.use_cells and self._pairs is not None:
            state.update({f"pairs.{name}": getattr(self._pairs, name).clone() for name in ("first", "second", "env")})
        return state

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        """Go on from ``state`` (:meth:`state_dict` of a world of the same settings)."""
        mine = self.state_dict()
        if set(state) - set(mine) - {"pairs.first", "pairs.second", "pairs.env"}:
            raise ValueError(f"the state holds what this world does not: {sorted(set(state) - set(mine))}")
        for name, value in state.items():
            if name in mine and not name.startswith(("pairs.", "impulses.")) and value.shape != mine[name].shape:
                raise ValueError(f"the state's {name} is {list(value.shape)}, this world's {list(mine[name].shape)}")
            owner, _, attribute = name.rpartition(".")
            if owner in ("bodies", "impulses"):
                setattr(self.bodies if owner == "bodies" else self._impulses, attribute, value.to(self.device))
            elif not owner:
                setattr(self, name, value.to(self.device))
        if self.use_cells and "pairs.first" in state:
            self._pairs = SparsePairs(
                *(state[f"pairs.{name}"].to(self.device) for name in ("first", "second", "env")),
                self.n_bodies,
                self.num_envs,
            )
            self._pair_constants(self._pairs)
        self._set_wall_geometry()

    def _contracted_radii(self) -> torch.Tensor:
        radius = torch.full((self.n_bodies, 1), C.DISK_CONTRACTED_RADIUS, device=self.device)
        if self.object_radius is not None:
            radius[self.n_robots] = self.object_radius
        return radius

    def _clear_impulses(self, mask: torch.Tensor) -> None:
        impulses = self._impulses
        if self._pairs is not None:
            pair_mask = mask[self._pairs.env] if self.use_cells else mask
            for name in ("normal", "tangent", "rod"):
                setattr(impulses, name, torch.where(pair_mask, 0.0, getattr(impulses, name)))
        if self.n_walls:
            impulses.wall_normal = torch.where(mask, 0.0, impulses.wall_normal)
            impulses.wall_tangent = torch.where(mask, 0.0, impulses.wall_tangent)

    def _checked(self, name: str, value, shape: tuple, dtype: torch.dtype) -> torch.Tensor:
        value = torch.as_tensor(value, device=self.device)
        if tuple(value.shape) != shape:
            raise ParameterError(name, f"expected shape {list(shape)}, got {list(value.shape)}")
        return value.to(dtype)

    def _set_wall_geometry(self) -> None:
        edge, outward, present = wall_geometry(self.walls)
        self._walls = Walls(self.walls, edge, outward, present, *self._wall_reach()) if self.n_walls else None

    def _wall_reach(self) -> tuple[torch.Tensor | None, torch.Tensor | None]:
        """Walls' ``give`` and ``core`` ``[B, 1]``: robots yield ``wall_give`` down to the central body; a ball
        does not yield."""
        if self.wall_give == 0:
            return None, None
        robot = torch.arange(self.n_bodies, device=self.device)[:, None] < self.n_robots
        zero = torch.zeros((), device=self.device)
        return torch.where(robot, self.wall_give, zero), torch.where(robot, C.BODY_RADIUS, zero)

    def is_sane(self) -> torch.Tensor:
        """``[K]``: False where any body's state is non-finite or absurdly large (a physics blow-up)."""
        b = self.bodies
        return self._sane(b.px, b.py, b.vx, b.vy, b.spin)

    def max_overlap(self) -> torch.Tensor:
        """``[K]``: the deepest overlap between two robots' disks now (0 if none touch)."""
        pairs = self._search() if self.use_cells else self._pairs
        robot_pair = pairs.second < self.n_robots
        dx, dy = pairs.difference(self.bodies.px, self.bodies.py)
        (radius_sum,) = pairs.total(self.bodies.radius)
        overlap = torch.where(robot_pair if self.use_cells else robot_pair[:, None], radius_sum - dx.hypot(dy), 0.0)
        if not self.use_cells:
            return overlap.amax(dim=0).clamp(min=0.0)
        deepest = torch.zeros(self.num_envs, device=self.device)
        return deepest.scatter_reduce(0, pairs.env, overlap, reduce="amax")

    def robots_touch_walls(self) -> torch.Tensor:
        """``[K]``: whether any robot's disk touches a wall now."""
        if self.n_walls == 0:
            return torch.zeros(self.num_envs, dtype=torch.bool, device=self.device)
        distance, _ = disk_wall_distance(self.position, self.walls, self._walls.edge, self._walls.outward)
        touch = (distance < self.radius[..., None]) & self._walls.present[:, None]
        return touch.flatten(1).any(dim=1)

    # -- neighbours ---------------------------------------------------------------------------------------
    def _search(self) -> SparsePairs:
        """Every pair of robots closer than the magnet range (and every robot with the ball), from a cell list."""
        n, b, device = self.n_robots, self.n_bodies, self.device
        env, first, second = cell_pairs(self.position, C.DISK_MAGNET_RANGE)
        if b > n:  # every robot with the ball
            env_grid, robot_grid = torch.meshgrid(
                torch.arange(self.num_envs, device=device), torch.arange(n, device=device), indexing="ij"
            )
            env, first = torch.cat((env, env_grid.reshape(-1))), torch.cat((first, robot_grid.reshape(-1)))
            second = torch.cat((second, torch.full_like(robot_grid.reshape(-1), n)))
        order = torch.argsort((env * b + first) * b + second)
        return SparsePairs(first[order], second[order], env[order], b, self.num_envs)

    def _update_pairs(self) -> None:
        """This step's pairs; accumulated impulses follow their pairs into the new list (0 for new pairs)."""
        old, impulses = self._pairs, self._impulses
        self._pairs = pairs = self._search()
        self._pair_constants(pairs)
        if old is None or old.size == 0:
            impulses.normal, impulses.tangent, impulses.rod = (self._zeros(pairs.size) for _ in range(3))
            return
        old_key, new_key = old.key(), pairs.key()
        at = torch.searchsorted(old_key, new_key).clamp(max=old.size - 1)
        found = old_key[at] == new_key
        for name in ("normal", "tangent", "rod"):
            setattr(impulses, name, torch.where(found, getattr(impulses, name)[at], 0.0))

    # -- control ------------------------------------------------------------------------------------------
    def step(self, targets: torch.Tensor) -> None:
        """One control step (0.1 s) of every swarm with expansion ``targets [K, N]`` in [0, 1]."""
        targets = _body_major(self._checked("targets", targets, (self.num_envs, self.n_robots), torch.float32))
        rods = self._before_physics(self, targets)
        physics(self.bodies, self._pairs, self._elasticity, rods, self._walls, self._impulses, self.constants)

    def _command_and_grow(self, targets: torch.Tensor) -> Rods:
        """The command rule, this step's pairs (large swarms) and the growth, for ``targets [N, K]``: the rods."""
        # the command rule (Swarm.command): a robot moving toward its target keeps it until within reach
        busy = self._moving & ((self._target - self._expansion).abs() >= REACHED_FRACTION)
        accept = self._alive & ~busy  # dead robots never accept: their target stays 0 (contracted)
        self._target = torch.where(accept, targets, self._target)
        self._moving = (busy | accept) & ((self._target - self._expansion).abs() >= REACHED_FRACTION)
        radius_target = C.DISK_CONTRACTED_RADIUS + self._target * (C.DISK_EXPANDED_RADIUS - C.DISK_CONTRACTED_RADIUS)
        if self.use_cells:
            self._update_pairs()
        return self._grow(radius_target)

    def _grow(self, radius_target: torch.Tensor) -> Rods:
        """DiskSwarm.before_physics: move the commanded radii, grow the disks into the room their neighbours
        leave (at most DISK_GROWTH_OVERLAP into one), and return the rods: pairs of robots within the magnet
        range, their lengths and force limits (as impulses per substep)."""
        n, pairs, bodies = self.n_robots, self._pairs, self.bodies
        reach = C.DISK_RADIUS_SPEED * C.CONTROL_PERIOD
        commanded = torch.minimum(torch.maximum(radius_target, self._commanded - reach), self._commanded + reach)
        commanded_bodies = torch.cat((commanded, bodies.radius[n:]))
        dx, dy = pairs.difference(bodies.px, bodies.py)
        distance = torch.sqrt(dx * dx + dy * dy)
        radius_sum, commanded_sum = pairs.total(bodies.radius, commanded_bodies)
        rod = (distance < C.DISK_MAGNET_RANGE) & self._robot_pair
        gap = distance - radius_sum  # free room between the two surfaces of each linked pair
        room = pairs.nearest(torch.where(rod, gap, math.inf))[:n]
        new_radius = torch.minimum(commanded, bodies.radius[:n] + (room + C.DISK_GROWTH_OVERLAP).clamp(min=0.0))
        # each rod pushes (or pulls) its pair apart by what the two robots still have to grow (or shrink)
        pushing = commanded_sum > radius_sum
        push, pull = self._rod_scales[:, pairs.env] if self.use_cells else self._rod_scales[:, None]
        limit = torch.where(pushing, C.DISK_PUSH_FORCE * push, C.MAGNET_MAX_FORCE * pull) * self.constants.dt * rod
        self._commanded = commanded
        bodies.radius = torch.cat((new_radius, bodies.radius[n:]))
        self._expansion = (new_radius - C.DISK_CONTRACTED_RADIUS) / (C.DISK_EXPANDED_RADIUS - C.DISK_CONTRACTED_RADIUS)
        return Rods(gap + commanded_sum, limit, rod.float())
