"""Per-swarm dynamics on the batched engine: BatchedDiskWorld's ``dynamics`` and the vector envs' ``dynamics_scale``
(each swarm's multiples of the push limit, the pull limit and the ground friction)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

import dpr  # noqa: F401
from dpr.checks import ParameterError
from dpr.sim.batched import DYNAMICS, BatchedDiskWorld
from dpr.sim.world import grid_centres


def wave(step: int, n: int = 9) -> torch.Tensor:
    """A wave of expansions along the grid's columns."""
    return (torch.arange(n) % 3 == step % 3).float()


def _world(dynamics=None, k=3, n=9) -> BatchedDiskWorld:
    world = BatchedDiskWorld(k, n)
    centres = torch.tensor(np.stack([grid_centres(n, (500.0, 0.0))] * k))
    world.reset(torch.ones(k, dtype=torch.bool), centres, torch.zeros(k, n, dtype=torch.bool), dynamics=dynamics)
    return world


def _run(world: BatchedDiskWorld, steps: int = 24) -> torch.Tensor:
    """The robots' positions after ``steps`` control steps of the wave."""
    for step in range(steps):
        world.step(wave(step, world.n_robots).expand(world.num_envs, world.n_robots))
    return world.position.clone()


def _scales(**factors) -> list[float]:
    return [factors.get(name, 1.0) for name in DYNAMICS]


def test_the_model_constants_are_the_default_and_ones_given_run_as_none_given():
    default = _world()
    assert torch.equal(default.dynamics, torch.ones(3, len(DYNAMICS)))
    ones = _world(dynamics=torch.ones(3, len(DYNAMICS)))
    assert torch.equal(_run(default), _run(ones))


@pytest.mark.parametrize("name", DYNAMICS)
@pytest.mark.parametrize("n", [9, 40])  # every pair; the cell list
def test_each_scale_changes_its_swarm_only(name, n):
    """Swarm 1 runs with one constant scaled; swarms 0 and 2 run as the model does, to the bit."""
    dynamics = torch.tensor([_scales(), _scales(**{name: 0.3}), _scales()])
    positions = _run(_world(dynamics=dynamics, n=n))
    reference = _run(_world(n=n))
    assert torch.equal(positions[0], reference[0]) and torch.equal(positions[2], reference[2])
    assert (positions[1] - reference[1]).abs().max() > 0.1


@pytest.mark.parametrize(
    "name, factor, faster",
    [
        ("push_force", 3.0, True),
        ("magnet_force", 3.0, True),
        ("magnet_force", 0.1, False),
        ("ground_friction", 0.3, True),
        ("ground_friction", 3.0, False),
    ],
)
def test_stronger_rods_and_less_ground_friction_move_the_robots_faster(name, factor, faster):
    """The robots' mean speed under the wave, against the model's (measured: 1.1 units/s; 2.3 to 3.4 with the
    faster settings, 0 to 0.1 with the slower ones)."""
    world = _world(dynamics=torch.tensor([_scales(), _scales(**{name: factor})]), k=2)
    speeds = []
    for step in range(24):
        world.step(wave(step).expand(2, 9))
        speeds.append(world.velocity.norm(dim=2).mean(dim=1))
    model, scaled = torch.stack(speeds).mean(dim=0).tolist()
    assert scaled > 2 * model if faster else scaled < model / 2


def test_the_dynamics_survive_a_masked_reset_and_a_snapshot():
    world = _world(dynamics=torch.tensor([_scales(push_force=2.0)] * 3))
    centres = torch.tensor(np.stack([grid_centres(9, (0.0, 0.0))] * 3))
    world.reset(torch.tensor([True, False, False]), centres, torch.zeros(3, 9, dtype=torch.bool))  # none given
    assert torch.all(world.dynamics[:, 0] == 2.0)
    world.reset(
        torch.tensor([False, True, False]),
        centres,
        torch.zeros(3, 9, dtype=torch.bool),
        dynamics=torch.full((3, 3), 0.5),
    )
    assert world.dynamics[:, 0].tolist() == [2.0, 0.5, 2.0]
    again = _world()
    again.load_state_dict(world.state_dict())
    assert torch.equal(again.dynamics, world.dynamics)
    assert torch.equal(_run(again, 6), _run(world, 6))


@pytest.mark.parametrize("dynamics", [torch.zeros(3, 3), torch.ones(3, 2)])
def test_world_dynamics_must_be_positive_and_shaped(dynamics):
    with pytest.raises(ParameterError) as error:
        _world(dynamics=dynamics)
    assert error.value.parameter == "dynamics"


# -- the vector envs' dynamics_scale ---------------------------------------------------------------------------
def make(num_envs=4, **kwargs):
    return gym.make_vec(
        "dpr/Gate-v2", num_envs=num_envs, vectorization_mode="vector_entry_point", robot_model="disk", **kwargs
    ).unwrapped


def test_ranges_are_drawn_per_env_within_bounds_from_the_seed():
    scale = {"push_force": [0.5, 2.0], "ground_friction": 1.5}
    first, second, other = make(dynamics_scale=scale), make(dynamics_scale=scale), make(dynamics_scale=scale)
    first.reset(seed=3), second.reset(seed=3), other.reset(seed=4)
    push, pull, friction = first.world.dynamics.t()
    assert torch.all((push >= 0.5) & (push <= 2.0)) and len(set(push.tolist())) == 4
    assert torch.all(pull == 1.0) and torch.all(friction == 1.5)
    assert torch.equal(first.world.dynamics, second.world.dynamics)
    # env i draws as a single env seeded s + i does: seed 4's env i is seed 3's env i + 1
    assert torch.equal(first.world.dynamics[1:], other.world.dynamics[:-1])


def test_starts_are_drawn_before_the_dynamics():
    plain, scaled = make(), make(dynamics_scale={"magnet_force": [0.7, 1.4]})
    np.testing.assert_array_equal(plain.reset(seed=9)[0], scaled.reset(seed=9)[0])


def test_each_episode_draws_again():
    venv = make(num_envs=2, max_episode_steps=2, dynamics_scale={"push_force": [0.5, 2.0]})
    venv.reset(seed=1)
    first = venv.world.dynamics.clone()
    for _ in range(3):  # two steps end the episodes; the third resets them (NEXT_STEP)
        venv.step(np.zeros((2, 9), dtype=np.int8))
    assert not torch.equal(first[:, 0], venv.world.dynamics[:, 0])


@pytest.mark.parametrize(
    "scale, message",
    [
        ({"push": 2.0}, "dynamics_scale: no constant named 'push'"),
        ({}, "dynamics_scale: expected a dict"),
        ([0.5, 2.0], "dynamics_scale: expected a dict"),
        ({"push_force": [2.0, 0.5]}, "dynamics_scale.push_force: expected \\[low, high\\] with low <= high"),
        ({"ground_friction": 0.0}, "dynamics_scale.ground_friction: must be >= 0.1"),
        ({"magnet_force": [1.0, 50.0]}, "dynamics_scale.magnet_force: must be <= 10"),
        ({"push_force": float("nan")}, "dynamics_scale.push_force: must be finite"),
    ],
)
def test_bad_dynamics_scale_is_one_error_naming_it(scale, message):
    with pytest.raises(ParameterError, match=message):
        make(dynamics_scale=scale)


def test_pymunk_env_refuses_dynamics_scale_naming_the_batched_engine():
    with pytest.raises(ParameterError, match="dynamics_scale: only the batched engine"):
        gym.make("dpr/Gate-v2", robot_model="disk", dynamics_scale={"push_force": 2.0})
