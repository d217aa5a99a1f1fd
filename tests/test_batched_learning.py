"""Evaluation, training and benchmarks on the batched engine: the same files as on pymunk, and models that run on
both engines."""

import json

import gymnasium as gym
import pytest
import torch

import dpr  # noqa: F401
from dpr import bench
from dpr.bench import bench_batched, run_batched_benchmarks
from dpr.checks import ParameterError
from dpr.cli import main
from dpr.envs.particle_env import MAX_EPISODE_STEPS
from dpr.evaluation.batched import evaluate_batched
from dpr.evaluation.scoring import evaluate, evaluation_payload
from dpr.rl.batched_train import train_batched
from dpr.rl.train import TrainConfig, train

SMALL = {"robot_model": "disk", "n_robots": 4}


def test_evaluate_batched_writes_what_evaluate_writes():
    seeds = [3, 4]
    batched = evaluate_batched(["dpr/Gate-v2"], "wave", seeds, steps=30, env_kwargs=SMALL)
    reference = evaluate(["dpr/Gate-v2"], "wave", seeds, steps=30, env_kwargs=SMALL)
    left = evaluation_payload("wave", ["dpr/Gate-v2"], SMALL, 30, seeds, batched)
    right = evaluation_payload("wave", ["dpr/Gate-v2"], SMALL, 30, seeds, reference)
    assert [sorted(e) for e in left["episodes"]] == [sorted(e) for e in right["episodes"]]
    assert sorted(left["summary"]) == sorted(right["summary"])
    assert [e["seed"] for e in left["episodes"]] == seeds
    # the same starts: both trajectories begin where gymnasium.make(...).reset(seed) puts the swarm
    for a, b in zip(left["episodes"], right["episodes"]):
        assert a["trajectory"][0] == pytest.approx(b["trajectory"][0], abs=1e-3)


@pytest.fixture(scope="module")
def batched_model(tmp_path_factory):
    config = TrainConfig(
        "ppo",
        "dpr/Navigation-v0",
        n_robots=4,
        robot_model="disk",
        n_envs=8,
        timesteps=8 * 32,
        preset="batched",
        engine="batched",
        hyperparams={"batch_size": 64},
    )
    return train_batched(config, tmp_path_factory.mktemp("batched") / "run", show_progress=False, log=lambda _: None)


def test_a_batched_run_writes_a_ppo_model_that_runs_on_both_engines(batched_model, tmp_path):
    assert batched_model.model_path.is_file() and batched_model.timesteps == 256
    record = batched_model.config_path.read_text()
    assert "engine: batched" in record and "env_steps_per_second" in record
    for engine in ("pymunk", "batched"):
        out = tmp_path / f"{engine}.json"
        argv = ["evaluate", "--policy", str(batched_model.model_path), "--env", "dpr/Navigation-v0", "--seeds", "1"]
        assert main([*argv, "--steps", "24", "--engine", engine, "--json", str(out)]) == 0
        assert json.loads(out.read_text())["episodes"][0]["steps"] == 24


def test_train_refuses_what_the_batched_engine_cannot_do():
    with pytest.raises(ParameterError, match="algo"):
        TrainConfig("a2c", "dpr/Navigation-v0", robot_model="disk", engine="batched")
    with pytest.raises(ParameterError, match="robot_model"):
        TrainConfig("ppo", "dpr/Navigation-v0", engine="batched")
    with pytest.raises(ParameterError, match="engine"):
        train(TrainConfig("ppo", "dpr/Navigation-v0", robot_model="disk", engine="batched"))


def test_train_checks_the_batched_device_and_memory_before_any_work(monkeypatch, tmp_path, capsys):
    argv = "train --algo ppo --env dpr/Navigation-v0 --robot-model disk --engine batched --timesteps 64".split()
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(SystemExit) as usage_error:
        main([*argv, "--device", "cuda", "--out", str(tmp_path / "cuda")])
    assert usage_error.value.code == 2 and "device" in capsys.readouterr().err
    monkeypatch.setattr("dpr.sim.batched.world.physical_memory", lambda: 1024)
    with pytest.raises(SystemExit) as usage_error:
        main([*argv, "--n-envs", "64", "--out", str(tmp_path / "big")])
    assert usage_error.value.code == 2
    assert "n-envs" in (err := capsys.readouterr().err) and "64 swarms of 9 robots on cpu need about" in err
    assert not list(tmp_path.iterdir())  # nothing written


def test_the_batched_bench_measures_a_rate():
    row = bench_batched(4, 4, seconds=0.0)
    assert row["env_steps_per_s"] > 0 and row["n_robots"] == 4 and row["peak_memory_mb"] > 0
    assert row["compiled"] is False  # what the world ran, not only what was asked


def test_the_batched_bench_sizes_rows_hold_the_robots_asked_for():
    rows = run_batched_benchmarks(ks=(), sizes=(40,), seconds=0.0, robots=120)
    assert [(row["num_envs"], row["n_robots"]) for row in rows] == [(3, 40)]
    assert rows[0]["pymunk_env_steps_per_s"] > 0


def test_each_batched_row_is_timed_between_blocks_of_the_pymunk_env(monkeypatch):
    timed = []
    for side, bench_class in (("pymunk", bench._Bench), ("batched", bench._BatchedBench)):
        block = bench_class.block
        monkeypatch.setattr(bench_class, "block", lambda self, *a, _b=block, _s=side: timed.append(_s) or _b(self, *a))
    rows = run_batched_benchmarks(ks=(2,), sizes=(), seconds=0.0, repeats=2)
    assert timed == ["pymunk", "batched", "pymunk", "batched", "pymunk"]
    assert rows[0]["pymunk_env_steps_per_s"] > 0


@pytest.mark.parametrize(
    "flags, named",
    [
        (["--device", "cuda", "--ks", "4", "--batched-sizes"], "--device"),
        (["--ks", "4", "--batched-sizes", "1000", "--batched-robots", "100000000000"], "--ks or --batched-robots"),
    ],
)
def test_the_batched_bench_refuses_what_the_machine_lacks_before_any_work(monkeypatch, capsys, flags, named):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    monkeypatch.setattr(bench._Bench, "__init__", lambda *a, **k: pytest.fail("the pymunk side started"))
    with pytest.raises(SystemExit) as stopped:
        main(["bench", "--engine", "batched", *flags])
    assert stopped.value.code == 2 and f"error: {named}:" in capsys.readouterr().err


def test_a_failure_inside_the_batched_bench_is_not_a_usage_error(monkeypatch):
    def failing(*args, **kwargs):
        raise ValueError("inside the bench")

    monkeypatch.setattr(bench._BatchedBench, "block", failing)
    with pytest.raises(ValueError, match="inside the bench"):
        main(["bench", "--engine", "batched", "--ks", "4", "--batched-sizes"])


def test_the_pymunk_bench_resets_its_env_at_episode_ends():
    timed = bench._Bench("disk", 9, steps=1300)  # the warm-up and one block run past the 2,500-step episode
    timed.block()
    limit = timed.env
    while not isinstance(limit, gym.wrappers.TimeLimit):
        limit = limit.env
    assert limit._elapsed_steps == 2 * 1300 - MAX_EPISODE_STEPS  # stepped on from a reset, not past the end
    timed.block()  # every step on the world the reset built: its physics are timed too
    row = timed.row()
    assert 0 < row["env_over_physics"] < 1


def test_cuda_without_cuda_is_refused_by_name():
    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA: the refusal is for machines without it")
    with pytest.raises(ParameterError, match="device"):
        evaluate_batched(["dpr/Navigation-v0"], "wave", [0], steps=5, env_kwargs=SMALL, device="cuda")
