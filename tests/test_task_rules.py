"""The task rules: unresponsive robots, the gate's walls, the manipulated object, the goal and termination."""

import math

import gymnasium as gym
import numpy as np
import pymunk
import pytest
from helpers import ENV_IDS, ROBOT_MODELS, expansions, move_bodies

# ---------------------------------------------------------------------------------------------------------
# Unresponsive


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
def test_dead_robots_never_expand(make_env, robot_model):
    n = 9
    env = make_env("dpr/Unresponsive-v0", robot_model=robot_model, n_robots=n)
    obs, info = env.reset(seed=1)
    dead = np.asarray(info["dead_robots"])
    assert len(dead) == 2
    alive = np.setdiff1d(np.arange(n), dead)
    for _ in range(8):
        obs, *_ = env.step(np.ones(n, dtype=np.int8))
        assert np.all(expansions(obs, n)[dead] < 0.05)
    assert np.all(expansions(obs, n)[alive] > 0.8)


@pytest.mark.parametrize("action_type", ["continuous", "discrete"])
def test_dead_robots_ignore_every_action_type(make_env, action_type):
    n = 5
    env = make_env("dpr/Unresponsive-v0", n_robots=n, n_dead=2, action_type=action_type)
    obs, info = env.reset(seed=0)
    dead = np.asarray(info["dead_robots"])
    action = 2**n - 1 if action_type == "discrete" else np.ones(n, dtype=np.float32)
    for _ in range(4):
        obs, *_ = env.step(action)
    e = expansions(obs, n)
    assert np.all(e[dead] == 0.0)
    assert np.all(np.delete(e, dead) > 0.8)


def test_dead_robots_come_from_the_seed(make_env):
    env = make_env("dpr/Unresponsive-v0", n_robots=9)
    drawn = []
    for seed in range(10):
        _, info = env.reset(seed=seed)
        dead = np.asarray(info["dead_robots"])
        assert len(dead) == 2 and len(np.unique(dead)) == 2
        assert np.all((0 <= dead) & (dead < 9))
        drawn.append(tuple(sorted(dead.tolist())))
    assert len(set(drawn)) > 1
    # same seed, same dead robots (also from a fresh env)
    other = make_env("dpr/Unresponsive-v0", n_robots=9)
    for seed in (0, 4, 9):
        _, info = other.reset(seed=seed)
        assert tuple(sorted(np.asarray(info["dead_robots"]).tolist())) == drawn[seed]
        assert np.array_equal(np.flatnonzero(other.unwrapped.world.dead), np.sort(info["dead_robots"]))


@pytest.mark.parametrize("n_robots", range(1, 13))
def test_default_n_dead(n_robots):
    env = gym.make("dpr/Unresponsive-v0", robot_model="disk", n_robots=n_robots)
    assert env.unwrapped.n_dead == round(0.2 * n_robots)
    _, info = env.reset(seed=0)
    assert len(info["dead_robots"]) == round(0.2 * n_robots)
    env.close()


@pytest.mark.parametrize("env_id", ["dpr/Navigation-v0", "dpr/Gate-v0", "dpr/Manipulation-v0"])
def test_other_tasks_have_no_dead_robots(make_env, env_id):
    _, info = make_env(env_id).reset(seed=0)
    assert len(info["dead_robots"]) == 0


# ---------------------------------------------------------------------------------------------------------
# Gate


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
def test_gate_walls_collide_with_every_robot(make_env, robot_model):
    env = make_env("dpr/Gate-v0", robot_model=robot_model, n_robots=4)
    env.reset(seed=0)
    space = env.unwrapped.world.space
    walls = [s for s in space.shapes if s.body.body_type == pymunk.Body.STATIC]
    assert len(walls) == 2
    robot_shapes = [s for s in space.shapes if s.body.body_type == pymunk.Body.DYNAMIC]
    assert robot_shapes
    for wall in walls:
        for shape in robot_shapes:
            assert not shape.filter.rejects_collision(wall.filter)
            assert not wall.filter.rejects_collision(shape.filter)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_gate_geometry(make_env, seed):
    env = make_env("dpr/Gate-v0", gate_width=150.0)
    _, info = env.reset(seed=seed)
    space = env.unwrapped.world.space
    walls = [s for s in space.shapes if s.body.body_type == pymunk.Body.STATIC]
    start = info["centre_of_mass"]
    middle = start / 2
    # the opening sits on the start-goal line halfway: the middle point is free, the walls are 75 + ... off it
    assert space.point_query_nearest(tuple(middle), 0.0, pymunk.ShapeFilter()) is None
    distances = [w.point_query(tuple(middle)).distance for w in walls]
    np.testing.assert_allclose(distances, 75.0, atol=1e-6)
    # walls lie across the line: points 100 beside the middle, perpendicular to it, are inside a wall
    along = -start / np.linalg.norm(start)
    across = np.array([-along[1], along[0]])
    for side in (1, -1):
        hit = space.point_query_nearest(tuple(middle + side * across * 300), 0.0, pymunk.ShapeFilter())
        assert hit is not None and hit.shape in walls
    # the swarm starts clear of the walls
    for wall in walls:
        assert not [q for q in space.shape_query(wall) if q.shape.body.body_type == pymunk.Body.DYNAMIC]


@pytest.mark.parametrize("distance", [0.0, 5.0, 40.0])
@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4, 5])
def test_gate_v1_walls_stand_gate_distance_from_the_nearest_robot(make_env, distance, seed):
    """On v1 the contracted swarm (disks) touches a wall once it has moved exactly gate_distance toward the goal;
    the walls stand across the line to the goal, the opening on that line."""
    env = make_env("dpr/Gate-v1", n_robots=9, gate_distance=distance)
    _, info = env.reset(seed=seed)
    u = env.unwrapped
    start = info["centre_of_mass"]
    along = -start / np.linalg.norm(start)

    def gap(advance: float) -> float:
        centres = u.world.swarm.position + along * advance
        distances = [w.point_query(tuple(p)).distance for w in u.world.wall_shapes for p in centres]
        return min(distances) - u.swarm_class.contracted_radius

    assert gap(distance) == pytest.approx(0.0, abs=1e-6)
    assert gap(distance - 0.5) > 0
    walls = u.world.wall_shapes
    middle = start + along * (u._gate_near + 50.0)  # halfway through the walls' thickness, on the line
    across = np.array([-along[1], along[0]])
    for side in (1, -1):
        assert min(w.point_query(tuple(middle + side * across * 74)).distance for w in walls) > 0  # the opening
        assert min(w.point_query(tuple(middle + side * across * 76)).distance for w in walls) < 0  # a wall
    assert info["gate_passage"] == 0.0 or distance == 0.0
    assert info["gate_contact_step"] == -1


def test_gate_distance_range_is_drawn_each_episode(make_env):
    """``gate_distance=[low, high]``: each reset places the walls as ``gate_distance`` = a draw in [low, high] would,
    reproducibly per seed; the starts clear the walls at ``high``; one number draws nothing (the starts as before)."""

    def walls_ahead(env, seed):  # the walls' near face, from the swarm's contracted front toward the goal
        env.reset(seed=seed)
        return env.unwrapped._gate_near

    fixed = {d: make_env("dpr/Gate-v2", n_robots=9, gate_distance=d) for d in (20.0, 150.0)}
    spread = make_env("dpr/Gate-v2", n_robots=9, gate_distance=[20.0, 150.0])
    offsets = {d: walls_ahead(env, 0) - d for d, env in fixed.items()}  # the front, where distance 0 would stand
    assert offsets[20.0] == pytest.approx(offsets[150.0])
    drawn = [walls_ahead(spread, seed) for seed in range(12)]
    assert [walls_ahead(spread, seed) for seed in range(12)] == drawn  # the same seed draws the same walls
    front = [walls_ahead(make_env("dpr/Gate-v2", n_robots=9, gate_distance=0.0), seed) for seed in range(12)]
    distances = np.subtract(drawn, front)
    assert distances.min() >= 20.0 and distances.max() <= 150.0 and distances.std() > 20.0
    assert spread.unwrapped.start_shift == fixed[150.0].unwrapped.start_shift > 0
    assert fixed[20.0].unwrapped.start_shift == 0.0


def opening_width(env) -> float:
    """The gap between the two walls' inner corners on the near face (their first corners, as ``gate_polygons``)."""
    first, second = env.unwrapped.world.walls
    return float(np.linalg.norm(first[0] - second[0]))


def test_gate_width_range_is_drawn_each_episode(make_env):
    """``gate_width=[low, high]``: each reset opens the walls by a draw in [low, high], reproducibly per seed, with
    the walls where that width puts them; the starts are drawn as for ``low``; ``[w, w]`` is the number ``w``."""
    spread = make_env("dpr/Gate-v2", n_robots=9, gate_width=[150.0, 250.0])
    widths = []
    for seed in range(12):
        spread.reset(seed=seed)
        width = opening_width(spread)
        widths.append(width)
        fixed = make_env("dpr/Gate-v2", n_robots=9, gate_width=width)
        fixed.reset(seed=seed)
        assert opening_width(fixed) == pytest.approx(width)
        assert fixed.unwrapped._gate_near == pytest.approx(spread.unwrapped._gate_near)  # as that width places them
    assert min(widths) >= 150.0 - 1e-6 and max(widths) <= 250.0 + 1e-6 and np.std(widths) > 15.0
    again = []
    for seed in range(12):
        spread.reset(seed=seed)
        again.append(opening_width(spread))
    assert again == widths
    narrowest = make_env("dpr/Gate-v2", n_robots=9, gate_width=150.0)
    assert spread.unwrapped.start_shift == narrowest.unwrapped.start_shift
    assert spread.unwrapped.gate_width == [150.0, 250.0] and narrowest.unwrapped.gate_width == 150.0
    one, same = make_env("dpr/Gate-v2", gate_width=[180.0, 180.0]), make_env("dpr/Gate-v2", gate_width=180.0)
    for env in (one, same):
        env.reset(seed=3)
    np.testing.assert_array_equal(one.unwrapped.world.swarm.position, same.unwrapped.world.swarm.position)
    assert opening_width(one) == pytest.approx(opening_width(same)) == pytest.approx(180.0)


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
def test_gate_v1_the_wave_meets_the_walls_and_the_passage_measure_says_when(make_env, robot_model):
    """The wave touches the v1 walls early while v0's stay out of reach; the passage measure counts robots past
    the near face."""
    from dpr.policies.registry import make_policy

    contact = {}
    for env_id in ("dpr/Gate-v1", "dpr/Gate-v0"):
        env = make_env(env_id, robot_model=robot_model, n_robots=9)
        observation, _ = env.reset(seed=5)
        policy = make_policy("wave", env)
        for _ in range(600):
            observation, _, _, _, info = env.step(policy(observation))
        contact[env_id] = info["gate_contact_step"]
        u = env.unwrapped
        assert info["gate_passage"] == ((u.world.swarm.position - u.start) @ u._gate_along > u._gate_near).mean()
    assert 0 < contact["dpr/Gate-v1"] <= 600
    assert contact["dpr/Gate-v0"] == -1


def test_gate_contact_step_counts_physics_steps(make_env):
    """With action_repeat=10 the contact step is the physics step of the contact, as with one decision a step."""
    actions = [np.arange(9) % 2 == (k // 5) % 2 for k in range(40)]  # a crude gait, each action held 10 steps
    contact = []
    for repeat in (1, 10):
        env = make_env("dpr/Gate-v1", robot_model="disk", n_robots=9, action_repeat=repeat, gate_distance=0.0)
        env.reset(seed=5)
        for action in actions:
            for _ in range(10 // repeat):
                _, _, _, _, info = env.step(action.astype(np.int8))
        contact.append(info["gate_contact_step"])
    assert contact[0] == contact[1] > 0


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
def test_gate_v0_keeps_the_papers_placement(make_env, robot_model):
    """Gate-v0 is the paper's gate, halfway between start and goal, whatever Gate-v1's default."""
    env = make_env("dpr/Gate-v0", robot_model=robot_model)
    assert env.unwrapped.gate_distance is None
    assert make_env("dpr/Gate-v1", robot_model=robot_model).unwrapped.gate_distance > 0


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
def test_wall_physically_blocks_robot_zero(robot_model):
    """A wall right across robot 0's path stops it when it is driven toward the wall."""
    from dpr.sim import World

    wall = np.array([(-200.0, 80.0), (200.0, 80.0), (200.0, 180.0), (-200.0, 180.0)])
    world = World(1, robot_model, centre=(0.0, 0.0), walls=[wall])
    body = world.swarm.robot_bodies[0]
    for _ in range(20):  # 200 units/s for 2 s would carry it ~400 units without the wall
        body.velocity = (0.0, 200.0)
        world.step(np.zeros(1))
    for _ in range(10):  # let the contact settle
        world.step(np.zeros(1))
    y = world.swarm.position[0, 1]
    assert 20.0 < y < 80.0 - 20.0, y


# ---------------------------------------------------------------------------------------------------------
# Manipulation


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
@pytest.mark.parametrize("n_robots", [1, 4, 9])
@pytest.mark.parametrize("object_type", ["ball", "box"])
def test_object_starts_touching_the_swarm_on_the_goal_side(make_env, robot_model, n_robots, object_type):
    env = make_env("dpr/Manipulation-v0", robot_model=robot_model, n_robots=n_robots, object_type=object_type)
    for seed in range(4):
        _, info = env.reset(seed=seed)
        world = env.unwrapped.world
        obj = np.array(tuple(world.object_body.position))
        centres = world.swarm.position
        centre = centres.mean(axis=0)
        assert np.linalg.norm(obj) < np.linalg.norm(centre)
        # on the goal side: the object is ahead of every robot along the centre-to-goal direction
        toward = -centre / np.linalg.norm(centre)
        assert (obj - centre) @ toward > ((centres - centre) @ toward).max()
        # touching: the object's surface is 1 unit from the nearest contracted robot's rim
        gap = min(world.object_shape.point_query(tuple(c)).distance for c in centres)
        assert gap == pytest.approx(env.unwrapped.swarm_class.contracted_radius + 1.0, abs=1e-6)
        # and not overlapping any robot
        assert not [q for q in world.space.shape_query(world.object_shape) if q.shape.body is not world.object_body]
        np.testing.assert_allclose(info["object_position"], obj)


@pytest.mark.parametrize("n_robots", [4, 9])
def test_object_start_paper_is_on_the_line_to_the_goal(make_env, n_robots):
    env = make_env("dpr/Manipulation-v0", n_robots=n_robots, object_start="paper")
    assert make_env("dpr/Manipulation-v0").unwrapped.object_start == "touching"
    for seed in range(3):
        _, info = env.reset(seed=seed)
        world = env.unwrapped.world
        centre = world.swarm.position.mean(axis=0)
        obj = info["object_position"]
        toward = -centre / np.linalg.norm(centre)
        offset = obj - centre
        assert abs(offset[0] * toward[1] - offset[1] * toward[0]) < 1e-6  # on the centre-goal line
        assert offset @ toward > 0  # on the goal side
        # on the square of half side ceil(sqrt(N)) / 2 * 77.5 + size / 4 around the centre
        half = math.ceil(math.sqrt(n_robots)) / 2 * 77.5 + 30.0 / 4
        assert np.abs(offset).max() == pytest.approx(half, abs=1e-6)


def test_object_kwargs(make_env):
    env = make_env("dpr/Manipulation-v0", object_type="box", object_mass=55.0, object_size=20.0)
    env.reset(seed=0)
    world = env.unwrapped.world
    assert world.object_body.mass == pytest.approx(55.0)
    assert isinstance(world.object_shape, pymunk.Poly)
    bb = world.object_shape.bb
    assert max(bb.right - bb.left, bb.top - bb.bottom) <= 2 * 20.0 * math.sqrt(2) + 1e-6
    env = make_env("dpr/Manipulation-v0")
    env.reset(seed=0)
    world = env.unwrapped.world
    assert isinstance(world.object_shape, pymunk.Circle) and world.object_shape.radius == pytest.approx(30.0)
    assert world.object_body.mass == pytest.approx(100.0)


def test_approach_reward_adds_the_closing_of_the_swarm_object_gap(make_env):
    """The shaping telescopes: over an episode it adds weight x (first gap - last gap) to the return, and the
    metrics still follow the object alone."""
    returns, metrics = {}, {}
    for weight in (0.0, 2.0):
        env = make_env("dpr/Manipulation-v0", approach_reward=weight)
        env.reset(seed=3)
        world = env.unwrapped.world
        gaps = [float(np.linalg.norm(world.object_pose[0:2] - world.centre_of_mass))]
        total = 0.0
        for step in range(60):
            # all robots expand, then contract: the swarm pushes the ball and the gap changes
            _, reward, _, _, info = env.step(np.full(4, (step // 10) % 2, dtype=np.int8))
            total += reward
        gaps.append(float(np.linalg.norm(world.object_pose[0:2] - world.centre_of_mass)))
        returns[weight], metrics[weight] = total, info["projected_displacement"]
    assert abs(gaps[0] - gaps[1]) > 1.0
    assert returns[2.0] - returns[0.0] == pytest.approx(2.0 * (gaps[0] - gaps[1]), rel=1e-6)
    assert metrics[2.0] == metrics[0.0]


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_goal_is_not_solid(make_env, env_id):
    env = make_env(env_id)
    env.reset(seed=0)
    space = env.unwrapped.world.space
    assert space.point_query((0.0, 0.0), 5.0, pymunk.ShapeFilter()) == []


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
@pytest.mark.parametrize("object_type", ["ball", "box"])
def test_object_on_goal_terminates_with_success(make_env, robot_model, object_type):
    n = 4
    env = make_env("dpr/Manipulation-v0", robot_model=robot_model, n_robots=n, object_type=object_type)
    env.reset(seed=0)
    _, _, terminated, truncated, info = env.step(np.zeros(n, dtype=np.int8))
    assert not terminated and not info["is_success"]
    world = env.unwrapped.world
    body = world.object_body
    body.position = (0.0, 0.0)
    body.velocity = (0.0, 0.0)
    body.angular_velocity = 0.0
    world.space.reindex_shapes_for_body(body)
    _, reward, terminated, truncated, info = env.step(np.zeros(n, dtype=np.int8))
    assert terminated and not truncated
    assert info["is_success"]
    assert np.linalg.norm(info["object_position"]) < 10.0
    assert reward > 0  # the object jumped toward the goal


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
@pytest.mark.parametrize("env_id", ["dpr/Navigation-v0", "dpr/Unresponsive-v0"])
def test_swarm_on_goal_terminates_with_success(make_env, robot_model, env_id):
    n = 4
    env = make_env(env_id, robot_model=robot_model, n_robots=n)
    _, info = env.reset(seed=2)
    world = env.unwrapped.world
    move_bodies(world.swarm.bodies, -world.centre_of_mass)
    _, _, terminated, truncated, info = env.step(np.zeros(n, dtype=np.int8))
    assert np.linalg.norm(info["centre_of_mass"]) < 10.0
    assert terminated and not truncated
    assert info["is_success"]


def test_swarm_near_but_outside_goal_does_not_terminate(make_env):
    n = 4
    env = make_env(n_robots=n)
    env.reset(seed=2)
    world = env.unwrapped.world
    move_bodies(world.swarm.bodies, -world.centre_of_mass + np.array([30.0, 0.0]))
    _, _, terminated, _, info = env.step(np.zeros(n, dtype=np.int8))
    assert np.linalg.norm(info["centre_of_mass"]) > 10.0
    assert not terminated and not info["is_success"]
