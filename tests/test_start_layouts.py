"""Every task's start fits the swarm at every size: no robot inside a wall or the object, the object between
the swarm and the goal, the goal clear of the swarm. Checked on the real pymunk world after ``reset``."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import dpr  # noqa: F401  (registers the env ids)
from dpr.envs.particle_env import SLOW_PADDLE_SWARM
from dpr.envs.tasks import TASKS as REGISTERED

TASKS = sorted(REGISTERED)  # every registered id, earlier versions too
# Square swarms and ragged ones; the paddle model costs seconds to build at 1000 robots, so it stops at 400 but on
# the current gate, whose walls stand right at the swarm's front
SIZES = {"disk": (9, 10, 49, 50, 100, 150, 225, 400, 630, 1000), "paddle": (9, 49, 50, 100, 400)}
CASES = [(task, model, n) for model, sizes in SIZES.items() for n in sizes for task in TASKS]
CASES.append(("dpr/Gate-v1", "paddle", 1000))


def robot_overlaps(world) -> int:
    """How many robot shapes overlap a wall or the object, as pymunk's shape query sees it."""
    obstacles = [shape for shape in world.space.shapes if shape.body.body_type == shape.body.STATIC]
    if world.object_shape is not None:
        obstacles.append(world.object_shape)
    robots = {shape for body in world.swarm.bodies for shape in body.shapes}
    return sum(hit.shape in robots for obstacle in obstacles for hit in world.space.shape_query(obstacle))


@pytest.mark.parametrize(("env_id", "robot_model", "n_robots"), CASES)
def test_start_fits_the_swarm(env_id: str, robot_model: str, n_robots: int) -> None:
    env = gym.make(env_id, n_robots=n_robots, robot_model=robot_model).unwrapped
    for seed in (0, 1) if n_robots < SLOW_PADDLE_SWARM or robot_model == "disk" else (0,):
        obs, _ = env.reset(seed=seed)
        world = env.world
        assert robot_overlaps(world) == 0
        assert env.observation_space.contains(obs)
        centres = world.swarm.position
        goal_gap = np.linalg.norm(centres - env.goal, axis=1).min()
        assert goal_gap > env.swarm_class.expanded_radius, "the goal lies under a robot"
        if world.object_shape is not None:
            to_object = world.object_pose[:2] - env.goal
            to_swarm = world.centre_of_mass - env.goal
            assert np.linalg.norm(to_object) < np.linalg.norm(to_swarm), "the object starts behind the swarm"
            assert to_object @ to_swarm > 0, "the object starts beyond the goal"
            assert np.linalg.norm(to_object) > env.object_size, "the goal lies under the object"


@pytest.mark.parametrize("robot_model", ["paddle", "disk"])
@pytest.mark.parametrize("env_id", ["dpr/Gate-v0", "dpr/Gate-v1"])
def test_a_resting_swarm_stays_put_beside_the_gate(env_id: str, robot_model: str) -> None:
    """Robots started inside a wall are shoved out of it: a swarm that never expands would drift."""
    env = gym.make(env_id, n_robots=49, robot_model=robot_model).unwrapped
    env.reset(seed=0)
    start = env.world.centre_of_mass.copy()
    for _ in range(20):
        env.step(np.zeros(49, dtype=np.int8))
    assert np.linalg.norm(env.world.centre_of_mass - start) < 0.5


def test_small_swarms_keep_their_starts() -> None:
    """The shift that makes room for large swarms is zero where the swarm fits, so recorded starts hold."""
    for env_id in TASKS:
        for robot_model in SIZES:
            env = gym.make(env_id, n_robots=9, robot_model=robot_model).unwrapped
            assert env.start_shift == 0.0, env_id
