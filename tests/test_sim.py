"""Physics layer: neighbour search, world construction, collision filtering, magnets and the command rule; the
robot-model registry and the package's import graph."""

import ast
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pymunk
import pytest
from helpers import ROBOT_MODELS, robot_of_body, shift_robot
from pymunk._chipmunk import ffi, lib

import dpr.sim
from dpr.checks import ParameterError
from dpr.sim import ROBOT_MODELS as SIM_ROBOT_MODELS
from dpr.sim import ObjectSpec, World, grid_centres, swarm_class
from dpr.sim import constants as C
from dpr.sim.disk import DiskSwarm
from dpr.sim.neighbours import pairs_within
from dpr.sim.paddle import PaddleSwarm

# ---------------------------------------------------------------------------------------------------------
# Neighbour search


def _brute_pairs(points, radius):
    out = []
    for i in range(len(points)):
        for j in range(i + 1, len(points)):
            d = points[i] - points[j]
            if d[0] * d[0] + d[1] * d[1] < radius * radius:
                out.append((i, j))
    return np.array(out, dtype=np.int64).reshape(-1, 2)


@pytest.mark.parametrize("n", [0, 1, 2, 10, 63, 64, 65, 300])
@pytest.mark.parametrize("radius", [0.5, 7.0, 30.0, 250.0])
@pytest.mark.parametrize("layout", ["uniform", "clustered", "grid"])
def test_pairs_within_matches_brute_force(n, radius, layout):
    rng = np.random.default_rng(n * 1000 + int(radius * 10))
    if layout == "uniform":
        points = rng.uniform(-100.0, 150.0, (n, 2))
    elif layout == "clustered":
        centres = rng.uniform(-1000.0, 1000.0, (3, 2))
        points = centres[rng.integers(0, 3, n)] + rng.normal(0.0, 10.0, (n, 2))
    else:  # exact grid: many distances equal to the pitch, and exact ties with the radius
        points = grid_centres(n, (0.0, 0.0), pitch=7.0) if n else np.zeros((0, 2))
    got = pairs_within(points, radius)
    want = _brute_pairs(points, radius)
    assert got.dtype == np.int64
    assert got.ndim == 2 and got.shape[1] == 2
    assert np.array_equal(got, want)


@pytest.mark.parametrize("n", [2, 65, 200])
def test_pairs_within_duplicates_and_wide_spread(n):
    rng = np.random.default_rng(n)
    points = rng.uniform(0.0, 1e4, (n, 2))
    points[1] = points[0]  # a duplicate: distance 0
    points[-1] = points[0] + (0.999, 0.0)
    got = pairs_within(points, 1.0)
    assert np.array_equal(got, _brute_pairs(points, 1.0))
    assert (0, 1) in set(map(tuple, got.tolist()))
    assert (0, n - 1) in set(map(tuple, got.tolist()))


def test_pairs_within_does_not_modify_input():
    points = np.random.default_rng(0).uniform(0, 100, (80, 2))
    copy = points.copy()
    pairs_within(points, 20.0)
    assert np.array_equal(points, copy)


# ---------------------------------------------------------------------------------------------------------
# World construction


@pytest.mark.parametrize("n", [1, 4, 9])
def test_body_counts(n):
    paddle = World(n, "paddle")
    assert len(paddle.space.bodies) == 33 * n  # 1 disk + 16 paddle1 + 16 paddle2 per robot
    assert len(paddle.swarm.bodies) == 33 * n and len(paddle.swarm.robot_bodies) == n
    disk = World(n, "disk")
    assert len(disk.space.bodies) == n
    with_object = World(n, "disk", obj=ObjectSpec("ball", (500.0, 0.0)))
    assert len(with_object.space.bodies) == n + 1


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
def test_world_centres_on_grid(robot_model):
    world = World(9, robot_model, centre=(100.0, -50.0))
    np.testing.assert_allclose(world.centre_of_mass, (100.0, -50.0), atol=1e-9)
    np.testing.assert_allclose(world.swarm.position, grid_centres(9, (100.0, -50.0)), atol=1e-9)
    assert world.robot_model == robot_model and world.n_robots == 9
    np.testing.assert_array_equal(world.swarm.expansion, 0.0)


def test_world_rejects_bad_arguments():
    for n_robots in (0, -1, 2.0, True):
        with pytest.raises(ParameterError, match="^n_robots: ") as error:
            World(n_robots, "disk")
        assert error.value.parameter == "n_robots"
    with pytest.raises(ParameterError, match=r"^robot_model: expected one of \['paddle', 'disk'\], got 'wheel'"):
        World(3, "wheel")
    with pytest.raises(ParameterError, match="^kind: expected one of"):
        World(3, "disk", obj=ObjectSpec("cone", (500.0, 0.0)))


# ---------------------------------------------------------------------------------------------------------
# Robot-model registry and import graph


def test_robot_model_registry():
    assert SIM_ROBOT_MODELS == list(ROBOT_MODELS) == ["paddle", "disk"]  # the built-in ones; a package adds more
    assert swarm_class("paddle") is PaddleSwarm and swarm_class("disk") is DiskSwarm
    for model in SIM_ROBOT_MODELS:
        assert swarm_class(model).model == model
    with pytest.raises(ValueError, match="^robot_model: "):
        swarm_class("wheel")


def package_imports(package) -> dict[str, set[str]]:
    """Module name -> the modules of ``package`` it imports (anywhere in it, function bodies included).
    ``from pkg import name`` counts as importing ``pkg.name`` where that is a module, else ``pkg`` itself."""
    root = Path(package.__file__).parent
    prefix = package.__name__
    modules = {
        prefix if path.stem == "__init__" else f"{prefix}.{path.stem}": path for path in sorted(root.glob("*.py"))
    }
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        targets = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets.update(alias.name for alias in node.names)
            elif isinstance(node, ast.ImportFrom):
                assert node.level == 0, f"{path}: relative import"
                for alias in node.names:
                    submodule = f"{node.module}.{alias.name}"
                    targets.add(submodule if submodule in modules else node.module)
        graph[name] = {target for target in targets if target in modules and target != name}
    return graph


def import_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` as a list of modules (the first repeated at the end), or None."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(module: str) -> list[str] | None:
        state[module] = 1
        path.append(module)
        for target in sorted(graph[module]):
            if state.get(target) == 1:
                return path[path.index(target) :] + [target]
            if target not in state and (cycle := visit(target)):
                return cycle
        state[module] = 2
        path.pop()
        return None

    for module in sorted(graph):
        if module not in state and (cycle := visit(module)):
            return cycle
    return None


def test_import_cycle_finder_finds_a_cycle():
    assert import_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert import_cycle({"a": {"b", "c"}, "b": {"c"}, "c": set()}) is None


def test_sim_has_no_import_cycle():
    graph = package_imports(dpr.sim)
    assert {"dpr.sim.swarm", "dpr.sim.paddle", "dpr.sim.models"} <= set(graph)
    assert "dpr.sim.swarm" in graph["dpr.sim.paddle"]  # the finder sees the edges that exist
    assert import_cycle(graph) is None, " -> ".join(import_cycle(graph))
    assert not graph["dpr.sim.swarm"] & {"dpr.sim.paddle", "dpr.sim.disk", "dpr.sim.models"}


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
def test_paper_constants(robot_model):
    world = World(2, robot_model)
    for body in world.swarm.robot_bodies:
        assert body.mass == pytest.approx(10.0 if robot_model == "paddle" else 34.0)
    # ground friction: a pivot and a gear joint to the static body per robot, max_bias 0, max_force 500
    static = world.space.static_body
    ground = [c for c in world.space.constraints if static in (c.a, c.b)]
    assert len(ground) == 2 * world.n_robots
    assert sorted(type(c).__name__ for c in ground) == ["GearJoint", "GearJoint", "PivotJoint", "PivotJoint"]
    assert all(c.max_bias == 0 and c.max_force == pytest.approx(500.0) for c in ground)


# ---------------------------------------------------------------------------------------------------------
# Collision filtering


def _all_arbiters(space):
    found = []
    for body in space.bodies:
        body.each_arbiter(lambda arbiter: found.append(arbiter.shapes))
    return found


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
def test_own_shapes_never_collide_other_robots_do(robot_model):
    world = World(4, robot_model)
    owner = robot_of_body(world.swarm)
    shapes = [s for s in world.space.shapes if s.body in owner]
    assert len(shapes) == (33 if robot_model == "paddle" else 1) * 4
    for a in shapes:
        for b in shapes:
            if a is b:
                continue
            same = owner[a.body] == owner[b.body]
            assert a.filter.rejects_collision(b.filter) == same


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
def test_overlapping_robots_are_pushed_apart_and_own_parts_are_not(robot_model):
    world = World(2, robot_model)
    owner = robot_of_body(world.swarm)
    # robot 1 starts 77.5 right of robot 0; bring it to 45 (both contracted radii are above 27.5)
    shift_robot(world.swarm, owner, 1, (45.0 - 77.5, 0.0))
    world.read_state()
    gap0 = np.linalg.norm(world.swarm.position[1] - world.swarm.position[0])
    assert gap0 == pytest.approx(45.0)
    world.step(np.zeros(2))
    pairs = _all_arbiters(world.space)
    inter = [p for p in pairs if p[0].body in owner and p[1].body in owner and owner[p[0].body] != owner[p[1].body]]
    intra = [p for p in pairs if p[0].body in owner and p[1].body in owner and owner[p[0].body] == owner[p[1].body]]
    assert inter, "overlapping robots should be in contact"
    assert not intra
    for _ in range(5):
        world.step(np.zeros(2))
    gap = np.linalg.norm(world.swarm.position[1] - world.swarm.position[0])
    assert gap > gap0 + 1.0


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
def test_no_self_collision_while_moving(robot_model):
    world = World(4, robot_model)
    owner = robot_of_body(world.swarm)
    rng = np.random.default_rng(0)
    for _ in range(15):
        world.step(rng.integers(0, 2, 4).astype(float))
        for a, b in _all_arbiters(world.space):
            if a.body in owner and b.body in owner:
                assert owner[a.body] != owner[b.body]


# ---------------------------------------------------------------------------------------------------------
# Magnets


@dataclass
class _Rod:
    a: pymunk.Body
    b: pymunk.Body
    max_force: float
    distance: float


def _paddle_rods(swarm) -> list[_Rod]:
    """The paddle model's magnets are chipmunk joints that live from update_magnets() to the end of the
    step: rebuild them from the current state and read what chipmunk holds (bodies, force, length)."""
    swarm.update_magnets()
    body = {int(ffi.cast("uintptr_t", b._body)): b for b in swarm.bodies}
    rods = []
    for rod in swarm._rods:
        a = body[int(ffi.cast("uintptr_t", lib.cpConstraintGetBodyA(rod)))]
        b = body[int(ffi.cast("uintptr_t", lib.cpConstraintGetBodyB(rod)))]
        rods.append(_Rod(a, b, lib.cpConstraintGetMaxForce(rod), lib.cpPinJointGetDist(rod)))
    swarm.after_physics()
    return rods


def _magnets(world, owner=None):
    """Inter-robot rods: joints whose two bodies belong to different robots -> list of (joint, ra, rb).
    ``owner`` (body -> robot) must be given once robots have been moved out of their start grid."""
    owner = owner if owner is not None else robot_of_body(world.swarm)
    if world.swarm.model == "paddle":
        joints = _paddle_rods(world.swarm)
    else:
        joints = [c for c in world.space.constraints if isinstance(c, pymunk.PinJoint)]
    out = [(c, owner[c.a], owner[c.b]) for c in joints if c.a in owner and c.b in owner and owner[c.a] != owner[c.b]]
    return out, owner


def _grid_neighbours(centres, distance):
    d = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    return {(i, j) for i in range(len(centres)) for j in range(i + 1, len(centres)) if d[i, j] < distance}


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
def test_magnets_join_neighbours_in_a_3x3_grid(robot_model):
    world = World(9, robot_model)
    centres = world.swarm.position.copy()
    world.step(np.zeros(9))
    magnets, owner = _magnets(world)
    linked = {tuple(sorted((a, b))) for _, a, b in magnets}
    orthogonal = _grid_neighbours(centres, 77.5 + 1e-6)  # the 12 side-by-side pairs
    assert len(orthogonal) == 12
    assert orthogonal <= linked
    in_range = _grid_neighbours(world.swarm.position, world.swarm.magnet_range)
    assert linked <= in_range
    for joint, _, _ in magnets:
        assert joint.max_force == pytest.approx(750.0)
    segments = world.swarm.magnet_segments()
    assert segments.shape == (len(magnets), 2, 2)
    # each drawn segment runs between two different robots' neighbourhoods
    for seg in segments:
        ends = [int(np.argmin(np.linalg.norm(world.swarm.position - p, axis=1))) for p in seg]
        assert ends[0] != ends[1]


def test_disk_magnets_cover_every_pair_in_range():
    world = World(9, "disk")
    world.step(np.zeros(9))
    magnets, _ = _magnets(world)
    linked = {tuple(sorted((a, b))) for _, a, b in magnets}
    assert linked == _grid_neighbours(world.swarm.position, C.DISK_MAGNET_RANGE)
    assert len(linked) == len(magnets)  # one rod per pair


def test_paddle_magnets_hold_one_per_paddle2_in_a_grid_over_time():
    world = World(9, "paddle")
    rng = np.random.default_rng(1)
    paddle2 = set(world.swarm.paddle2_bodies)
    owner = robot_of_body(world.swarm)
    for _ in range(12):
        world.step(rng.integers(0, 2, 9).astype(float))
        magnets, _ = _magnets(world, owner)
        assert magnets
        count = {}
        for joint, _, _ in magnets:
            assert joint.a in paddle2 and joint.b in paddle2  # rods between paddle2 tips
            for body in (joint.a, joint.b):
                count[body] = count.get(body, 0) + 1
        assert max(count.values()) == 1


def test_paddle_shared_tip_gets_only_one_magnet():
    """Robots 1 and 2 sit almost in the same direction from robot 0: robot 0's nearest paddle2 is the same
    for both, and must hold only one rod."""
    world = World(3, "paddle")
    owner = robot_of_body(world.swarm)
    start = world.swarm.position.copy()
    shift_robot(world.swarm, owner, 0, -start[0])
    shift_robot(world.swarm, owner, 1, np.array([70.0, 3.0]) - start[1])
    shift_robot(world.swarm, owner, 2, np.array([70.0, -3.0]) - start[2])
    world.read_state()
    world.swarm.update_magnets()
    magnets, _ = _magnets(world, owner)
    count = {}
    for joint, _, _ in magnets:
        for body in (joint.a, joint.b):
            count[body] = count.get(body, 0) + 1
    assert count and max(count.values()) == 1
    linked = {tuple(sorted((a, b))) for _, a, b in magnets}
    assert len(linked & {(0, 1), (0, 2)}) == 1  # robot 0 links to only one of them
    assert (1, 2) in linked


def test_magnets_drop_when_robots_separate():
    for model in ROBOT_MODELS:
        world = World(2, model)
        world.step(np.zeros(2))
        assert len(_magnets(world)[0]) == 1
        owner = robot_of_body(world.swarm)
        shift_robot(world.swarm, owner, 1, (300.0, 0.0))
        world.read_state()
        world.step(np.zeros(2))
        assert _magnets(world, owner)[0] == []
        assert world.swarm.magnet_segments().shape == (0, 2, 2)


# ---------------------------------------------------------------------------------------------------------
# Expansion and the command rule


def _paddle2_reach(world):
    owner = robot_of_body(world.swarm)
    reach = np.zeros(world.n_robots)
    for body in world.swarm.bodies:
        r = owner[body]
        if body is world.swarm.robot_bodies[r]:
            continue
        reach[r] = max(reach[r], np.linalg.norm(np.array(tuple(body.position)) - world.swarm.position[r]))
    return reach


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
def test_expansion_goes_from_zero_to_one(robot_model):
    world = World(1, robot_model)
    history = [world.swarm.expansion[0]]
    for _ in range(6):
        world.step(np.ones(1))
        history.append(world.swarm.expansion[0])
    history = np.array(history)
    assert history[0] == 0.0
    assert np.all(np.diff(history) >= -1e-9)
    assert 0.0 < history[1] < 0.5  # a stroke takes more than one control step
    assert history[-1] > 0.95  # and a few of them (90 degrees at 5 rad/s is 0.31 s, plus spin-up)
    if robot_model == "disk":
        (circle,) = [s for s in world.space.shapes if s.body is world.swarm.robot_bodies[0]]
        assert circle.radius == pytest.approx(C.DISK_EXPANDED_RADIUS, abs=0.5)


def test_paddles_move_outward_when_expanding():
    world = World(1, "paddle")
    contracted = _paddle2_reach(world)[0]
    for _ in range(6):
        world.step(np.ones(1))
    expanded = _paddle2_reach(world)[0]
    # paddle1 turns about its centre, pinned on the rim (radius 25); paddle2 sits on paddle1's tip, half a
    # paddle1 (12.5) away: contracted (tangent) that is hypot(25, 12.5) ~ 28 from the centre, expanded
    # (radial) 25 + 12.5
    assert contracted == pytest.approx(math.hypot(25.0, 12.5), abs=1.0)
    assert expanded == pytest.approx(37.5, abs=1.5)
    for _ in range(6):
        world.step(np.zeros(1))
    assert _paddle2_reach(world)[0] < contracted + 2.0
    assert world.swarm.expansion[0] < 0.1


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
def test_command_while_moving_is_ignored(robot_model):
    world = World(2, robot_model)
    world.step(np.ones(2))  # expand
    e1 = world.swarm.expansion.copy()
    assert np.all(e1 > 0.0) and np.all(e1 < 0.9)
    world.step(np.zeros(2))  # contract, issued while still moving: ignored
    e2 = world.swarm.expansion.copy()
    assert np.all(e2 > e1)
    peak = e2
    for _ in range(8):
        world.step(np.zeros(2))
        peak = np.maximum(peak, world.swarm.expansion)
    # it kept expanding until it reached the target (within 10 degrees), then accepted the contraction
    assert np.all(peak > 1.0 - 10.0 / 90.0)
    assert np.all(world.swarm.expansion < 0.2)


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
def test_reached_robot_accepts_new_command_at_once(robot_model):
    world = World(1, robot_model)
    for _ in range(8):
        world.step(np.ones(1))
    full = world.swarm.expansion[0]
    world.step(np.zeros(1))
    assert world.swarm.expansion[0] < full - 0.05


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
def test_dead_robot_in_world_stays_contracted(robot_model):
    world = World(4, robot_model, dead=[2])
    assert world.dead.tolist() == [False, False, True, False]
    for _ in range(6):
        world.step(np.ones(4))
    e = world.swarm.expansion
    assert e[2] < 0.05
    assert np.all(np.delete(e, 2) > 0.8)


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
def test_world_is_sane_flags_blow_up(robot_model):
    world = World(2, robot_model)
    world.step(np.ones(2))
    assert world.is_sane()
    world.swarm.robot_bodies[1].velocity = (float("nan"), 0.0)
    world.step(np.ones(2))
    assert not world.is_sane()


# -- the disk model's force-limited growth and distance-keeping magnets ------------------------------------------
def _disk_world_at(centres) -> World:
    """A disk world whose robots stand at ``centres`` (moved there from the start grid)."""
    centres = np.asarray(centres, dtype=float)
    world = World(len(centres), "disk")
    for body, centre in zip(world.swarm.robot_bodies, centres):
        body.position = tuple(centre)
    world.space.reindex_shapes_for_body  # noqa: B018  (pymunk reindexes moved static shapes only)
    world.read_state()
    return world


def _closest_overlap(swarm) -> float:
    """The deepest overlap of two robots' actual disks (radius sum minus centre distance), 0 if none touch."""
    pairs = pairs_within(swarm.position, 2 * swarm.expanded_radius)
    delta = swarm.position[pairs[:, 0]] - swarm.position[pairs[:, 1]]
    distance = np.sqrt(np.einsum("ij,ij->i", delta, delta))
    return float(max(0.0, (swarm.radius[pairs[:, 0]] + swarm.radius[pairs[:, 1]] - distance).max()))


def test_disk_constants_follow_the_paddle_robot():
    assert C.DISK_CONTRACTED_RADIUS == pytest.approx(PaddleSwarm.contracted_radius) == pytest.approx(32.26, abs=0.01)
    assert C.DISK_EXPANDED_RADIUS == PaddleSwarm.expanded_radius == C.GRID_PITCH / 2
    assert C.DISK_MAGNET_RANGE == C.MAGNET_RANGE
    # a full stroke takes as long as a paddle's: 90 degrees at 5 rad/s
    stroke_time = (C.DISK_EXPANDED_RADIUS - C.DISK_CONTRACTED_RADIUS) / C.DISK_RADIUS_SPEED
    assert stroke_time == pytest.approx(C.STROKE / C.PADDLE_SPEED)
    assert C.DISK_PUSH_FORCE == pytest.approx(400.0) and C.DISK_PUSH_FORCE < C.MAGNET_MAX_FORCE
    assert DiskSwarm.revision == 2 and PaddleSwarm.revision == 1


def test_disk_growth_held_back_by_its_neighbours_lags_and_never_digs_in():
    """The centre of a packed 3x3 block expands: its eight neighbours, each held by ground friction (500),
    are pushed with at most 400 per rod, so the centre grows only as far as they give way, and no pair of
    robots ever presses deeper than the growth allowance into each other."""
    pitch = 2 * C.DISK_CONTRACTED_RADIUS + 0.25
    world = _disk_world_at(grid_centres(9, (0.0, 0.0), pitch))
    command = np.zeros(9)
    command[4] = 1.0
    deepest = 0.0
    for _ in range(10):
        world.step(command)
        deepest = max(deepest, _closest_overlap(world.swarm))
    swarm = world.swarm
    assert swarm.commanded_radius[4] == pytest.approx(C.DISK_EXPANDED_RADIUS)
    assert swarm.expansion[4] < 0.8, "the block should hold the centre back"
    assert swarm.radius[4] < swarm.commanded_radius[4]
    assert deepest <= 2 * C.DISK_GROWTH_OVERLAP + 0.5
    # alone, the same robot reaches its full size within the same ten steps
    alone = World(1, "disk")
    for _ in range(10):
        alone.step(np.ones(1))
    assert alone.swarm.expansion[0] == pytest.approx(1.0)


def test_disk_magnets_keep_a_pair_apart_instead_of_pulling_it_into_contact():
    """Two contracted robots 90 apart (inside the magnet range, not touching) stay 90 apart: the rod holds
    their distance, as the paddle model's rods between paddle tips do."""
    world = _disk_world_at([(0.0, 0.0), (90.0, 0.0)])
    for _ in range(30):
        world.step(np.zeros(2))
    assert len(world.swarm.magnet_segments()) == 1
    distance = np.linalg.norm(world.swarm.position[1] - world.swarm.position[0])
    assert distance == pytest.approx(90.0, abs=0.5)


def test_disk_rods_push_with_less_force_than_ground_friction():
    """Two linked robots 80 apart (not touching) both expand: their rod pushes with at most 400, less than the
    500 of ground friction that holds each, so they stay put while they grow."""
    world = _disk_world_at([(0.0, 0.0), (80.0, 0.0)])
    for _ in range(8):
        world.step(np.ones(2))
    assert world.swarm.expansion == pytest.approx([1.0, 1.0])
    assert np.linalg.norm(world.swarm.position[1] - world.swarm.position[0]) == pytest.approx(80.0, abs=0.5)


def test_disk_grows_into_a_neighbour_a_bounded_step_at_a_time():
    """Two touching robots both expand: each grows at most DISK_GROWTH_OVERLAP beyond the free room per step
    (slower than alone), never presses deeper than that into the other, and both end fully expanded."""
    touching = 2 * C.DISK_CONTRACTED_RADIUS + 0.1
    world = _disk_world_at([(0.0, 0.0), (touching, 0.0)])
    free_step = C.DISK_RADIUS_SPEED * C.CONTROL_PERIOD
    previous = world.swarm.radius.copy()
    deepest = 0.0
    for step in range(30):
        world.step(np.ones(2))
        if step < 3:
            growth = world.swarm.radius - previous
            assert np.all(growth <= C.DISK_GROWTH_OVERLAP + 0.1 + 1e-9) and np.all(growth < free_step)
            previous = world.swarm.radius.copy()
        deepest = max(deepest, _closest_overlap(world.swarm))
    assert world.swarm.expansion == pytest.approx([1.0, 1.0])
    distance = np.linalg.norm(world.swarm.position[1] - world.swarm.position[0])
    assert distance == pytest.approx(2 * C.DISK_EXPANDED_RADIUS, abs=1.5)
    assert deepest <= 2 * C.DISK_GROWTH_OVERLAP + 0.5
