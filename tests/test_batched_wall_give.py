"""Walls that squeeze the robots on the batched engine (BatchedDiskWorld's and Gate's vector env's
``wall_give``), and the batched engine's own env kwargs on the command line."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
import torch
from helpers import run_cli

import dpr  # noqa: F401
from dpr.checks import ParameterError
from dpr.policies.model_file import read_model_info
from dpr.sim import constants as C
from dpr.sim.batched import BatchedDiskWorld
from dpr.sim.batched.world import MAX_WALL_GIVE
from dpr.sim.objects import gate_polygons
from dpr.sim.world import grid_centres

NEAR_FACE = 40.0  # x of the walls' near face


def _pressed_on_the_wall(wall_give: float, ball: bool = False) -> tuple[float, float]:
    """How far an expanded robot (and a ball) thrown at the upper wall's near face end up from it: the gap between
    the face and each body's centre once it has come to rest against it."""
    walls = np.stack(gate_polygons((0.0, 0.0), (300.0, 0.0), 150.0, at=NEAR_FACE))
    world = BatchedDiskWorld(1, 1, n_walls=2, object_radius=30.0 if ball else None, wall_give=wall_give)
    world.reset(
        torch.ones(1, dtype=torch.bool),
        torch.tensor([[[NEAR_FACE - 60.0, 120.0]]]),
        torch.zeros(1, 1, dtype=torch.bool),
        walls=torch.tensor(walls)[None],
        object_position=torch.tensor([[NEAR_FACE - 60.0, 300.0]]) if ball else None,
    )
    for step in range(40):
        if step < 5:
            world.bodies.vx[:] = 100.0  # every body thrown at the wall
        world.step(torch.ones(1, 1))  # the robot expands against it
    assert float(world.radius[0, 0]) == pytest.approx(C.DISK_EXPANDED_RADIUS)
    robot_gap = NEAR_FACE - float(world.position[0, 0, 0])
    ball_gap = NEAR_FACE - float(world.object_position[0, 0]) if ball else float("nan")
    return robot_gap, ball_gap


def test_by_default_a_wall_meets_the_robot_at_its_radius():
    gap, _ = _pressed_on_the_wall(0.0)
    assert gap == pytest.approx(C.DISK_EXPANDED_RADIUS, abs=0.5)


@pytest.mark.parametrize("give", [5.0, MAX_WALL_GIVE])
def test_a_giving_wall_squeezes_the_robot_by_its_give_but_not_into_its_central_body(give):
    gap, _ = _pressed_on_the_wall(give)
    assert gap == pytest.approx(C.DISK_EXPANDED_RADIUS - give, abs=0.5)
    assert gap > C.BODY_RADIUS - 0.5


def test_the_ball_does_not_give():
    _, ball_gap = _pressed_on_the_wall(MAX_WALL_GIVE, ball=True)
    assert ball_gap == pytest.approx(30.0, abs=0.5)


def test_robots_still_meet_each_other_at_full_radius():
    plain, giving = BatchedDiskWorld(1, 9), BatchedDiskWorld(1, 9, n_walls=2, wall_give=MAX_WALL_GIVE)
    centres = torch.tensor(grid_centres(9, (500.0, 0.0)))[None]
    far_walls = torch.tensor(np.stack(gate_polygons((0.0, 0.0), (1.0, 0.0), 150.0, at=5000.0)))[None]
    plain.reset(torch.ones(1, dtype=torch.bool), centres, torch.zeros(1, 9, dtype=torch.bool))
    giving.reset(torch.ones(1, dtype=torch.bool), centres, torch.zeros(1, 9, dtype=torch.bool), walls=far_walls)
    for step in range(20):
        targets = (torch.arange(9) % 3 == step % 3).float()[None]
        plain.step(targets)
        giving.step(targets)
    assert torch.allclose(plain.position, giving.position, atol=1e-4)


@pytest.mark.parametrize("give", [-1.0, MAX_WALL_GIVE + 0.1, float("nan"), "5"])
def test_world_refuses_a_give_out_of_bounds_naming_it(give):
    with pytest.raises(ParameterError, match="wall_give"):
        BatchedDiskWorld(1, 9, n_walls=2, wall_give=give)


def _vector_env(env_id: str, **kwargs):
    return gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", robot_model="disk", **kwargs)


def test_gate_vector_env_passes_the_give_to_its_world():
    env = _vector_env("dpr/Gate-v2", wall_give=7.0)
    assert env.unwrapped.world.wall_give == 7.0
    assert _vector_env("dpr/Gate-v2").unwrapped.world.wall_give == 0.0


def test_a_task_without_walls_refuses_a_give_naming_it():
    with pytest.raises(ParameterError, match="wall_give: only Gate has walls"):
        _vector_env("dpr/Navigation-v0", wall_give=7.0)


def test_pymunk_env_refuses_the_give_naming_the_batched_engine():
    with pytest.raises(ParameterError, match="wall_give: only the batched engine"):
        gym.make("dpr/Gate-v2", robot_model="disk", wall_give=7.0)


@pytest.mark.parametrize("kwarg", ["wall_give=7", 'dynamics_scale={"push_force": 2.0}'])
def test_evaluate_takes_the_batched_engines_own_kwargs(tmp_path, kwarg):
    out = tmp_path / "gate.json"
    argv = ["evaluate", "--engine", "batched", "--policy", "wave", "--env", "dpr/Gate-v2", "--seeds", "0-1"]
    assert run_cli([*argv, "--steps", "12", "--env-kwarg", kwarg, "--json", str(out)]) == 0
    assert len(json.loads(out.read_text())["episodes"]) == 2


def test_evaluate_on_pymunk_refuses_the_give_before_writing(tmp_path, capsys):
    out = tmp_path / "gate.json"
    argv = ["evaluate", "--robot-model", "disk", "--policy", "wave", "--env", "dpr/Gate-v2", "--seeds", "0"]
    assert run_cli([*argv, "--env-kwarg", "wall_give=7", "--json", str(out)]) == 2
    assert "wall_give: only the batched engine" in capsys.readouterr().err
    assert not out.exists()


TINY_TRAIN = ["train", "--algo", "ppo", "--env", "dpr/Gate-v2", "--engine", "batched", "--robot-model", "disk"]


@pytest.mark.parametrize("kwarg", ["wall_give=5", 'dynamics_scale={"push_force": 2.0}'])
def test_train_refuses_the_batched_engines_own_kwargs_as_the_models_before_writing(tmp_path, capsys, kwarg):
    out = tmp_path / "run"
    argv = [*TINY_TRAIN, "--n-envs", "2", "--timesteps", "64", "--env-kwarg", kwarg, "--out", str(out)]
    assert run_cli(argv) == 2
    error = capsys.readouterr().err
    assert "--env-kwarg" in error and "--training-env-kwarg" in error
    assert not out.exists()


def test_a_model_trained_with_the_give_runs_on_the_pymunk_engine(tmp_path):
    out = tmp_path / "run"
    argv = [*TINY_TRAIN, "--n-envs", "2", "--timesteps", "64", "--training-env-kwarg", "wall_give=5", "--out", str(out)]
    assert run_cli(argv) == 0
    assert "wall_give" not in read_model_info(out / "model.zip").env_kwargs
    evaluate = ["evaluate", "--policy", str(out / "model.zip"), "--env", "dpr/Gate-v2", "--seeds", "0", "--steps", "12"]
    assert run_cli(evaluate) == 0


@pytest.mark.parametrize("kwarg", ["wall_give=5", 'dynamics_scale={"push_force": 2.0}'])
def test_collect_refuses_the_batched_engines_own_kwargs_before_writing(tmp_path, capsys, kwarg):
    out = tmp_path / "demos"
    argv = ["collect", "--engine", "batched", "--env", "dpr/Gate-v2", "--episodes", "1", "--steps", "12"]
    assert run_cli([*argv, "--env-kwarg", kwarg, "--out", str(out)]) == 2
    assert "a dataset records env kwargs" in capsys.readouterr().err
    assert not out.exists()
