"""`dpr collect --engine batched`: episodes stepped K at a time on the batched disk engine, written as the same
LeRobot v3.0 dataset and MCAP logs as a pymunk collection, deterministic whatever the batches, resumable, and
replayed bit for bit on the engine that recorded them."""

import gymnasium as gym
import numpy as np
import pytest
import torch
from helpers import QUIET, run_cli

import dpr.datasets.collect as collect_module
from dpr.datasets import features as F
from dpr.datasets.collect import CollectSpec, RolloutWorkers, collect
from dpr.datasets.lerobot import DatasetError, LeRobotReader
from dpr.datasets.mcap import read_mcap
from dpr.datasets.replay import replay_dataset
from dpr.policies.batched import make_batched_policy

GATE = "dpr/Gate-v2"
SMALL = {"n_robots": 4, "robot_model": "disk", "steps": 40, "engine": "batched"}
SEEDS = [7, 8, 9]


def spec(env_id=GATE, **overrides) -> CollectSpec:
    return CollectSpec(env_id, **{**SMALL, **overrides})


def stepped_directly(env_id: str, policy: str, seeds: list[int], steps: int, **kwargs) -> list[dict]:
    """The batched vector env and the batched policy stepped by hand from ``seeds``: each env's actions and
    observations until its episode ends."""
    venv = gym.make_vec(
        env_id,
        num_envs=len(seeds),
        vectorization_mode="vector_entry_point",
        max_episode_steps=steps,
        robot_model="disk",
        **kwargs,
    )
    env = venv.unwrapped
    act = make_batched_policy(policy, env)
    observation = env.reset_tensors(seed=seeds)
    episodes = [{"action": [], "observation": []} for _ in seeds]
    running = torch.ones(len(seeds), dtype=torch.bool)
    for _ in range(steps):
        actions = act(observation)
        for i in running.nonzero().flatten().tolist():
            episodes[i]["action"].append(actions[i].numpy())
            episodes[i]["observation"].append(observation[i].numpy())
        observation, _, terminated, truncated, _ = env.advance(env.targets(actions))
        running &= ~(terminated | truncated)
    venv.close()
    return [{key: np.array(values) for key, values in episode.items()} for episode in episodes]


@pytest.mark.parametrize("env_id", [GATE, "dpr/Manipulation-v0"])
def test_a_batched_collection_is_the_vector_envs_episodes_in_the_usual_dataset(tmp_path, env_id):
    workers = RolloutWorkers(batch=2)
    summary = collect(tmp_path / "data", spec(env_id, mcap=True), len(SEEDS), seed=SEEDS[0], workers=workers)
    reader = LeRobotReader(tmp_path / "data")
    assert summary.episodes_added == 3 and reader.verify() == summary.frames_total
    assert reader.info["dpr"]["engine"] == "batched" and reader.info["robot_type"] == "disk"
    assert set(reader.features) >= {F.OBSERVATION, F.ENVIRONMENT_STATE, F.ACTION, F.REWARD, F.DONE, F.SUCCESS}
    expected = stepped_directly(env_id, "wave", SEEDS, 40, n_robots=4)
    for index, seed in enumerate(SEEDS):
        meta, frames = reader.episodes[index], reader.episode(index)
        assert meta[F.SEED] == seed and meta[F.ROBOT_MODEL] == "disk"
        assert meta["length"] == len(expected[index]["action"])
        np.testing.assert_array_equal(frames[F.ACTION], expected[index]["action"])
        np.testing.assert_array_equal(frames[F.OBSERVATION], expected[index]["observation"])
        log = read_mcap(tmp_path / "data" / meta[F.MCAP_FILE])
        assert log.n_steps == meta["length"] and log.n_robots == 4
        np.testing.assert_array_equal(log.actions, expected[index]["action"])
    assert all(check.equal for check in replay_dataset(tmp_path / "data"))


def test_the_environment_state_is_the_single_envs(tmp_path):
    collect(tmp_path / "data", spec(steps=1), 2, seed=SEEDS[0])
    states = LeRobotReader(tmp_path / "data").episode(1)[F.ENVIRONMENT_STATE]
    single = gym.make(GATE, robot_model="disk", n_robots=4)
    single.reset(seed=SEEDS[1])
    np.testing.assert_allclose(states[0], single.unwrapped.environment_state(), atol=1e-6)


def test_the_dataset_does_not_depend_on_the_batches_and_resumes(tmp_path):
    collect(tmp_path / "whole", spec(policy="wave-markov", env_kwargs={"obs_last_action": True}), 4, seed=3)
    resumed = spec(policy="wave-markov", env_kwargs={"obs_last_action": True})
    collect(tmp_path / "parts", resumed, 2, seed=3, workers=RolloutWorkers(batch=1))
    summary = collect(tmp_path / "parts", resumed, 4, seed=3, workers=RolloutWorkers(batch=3))
    assert summary.episodes_before == 2 and summary.episodes_added == 2
    whole, parts = LeRobotReader(tmp_path / "whole"), LeRobotReader(tmp_path / "parts")
    for index in range(4):
        a, b = whole.episode(index), parts.episode(index)
        for column in a:
            np.testing.assert_array_equal(a[column], b[column])


def test_a_pymunk_dataset_is_not_resumed_on_the_batched_engine(tmp_path):
    collect(tmp_path / "data", spec(engine="pymunk"), 1)
    with pytest.raises(DatasetError):
        collect(tmp_path / "data", spec(), 2)


def test_a_dataset_recorded_on_a_gpu_says_so_and_replays_only_there(tmp_path, monkeypatch):
    """Float sums on a GPU differ from the CPU's in their last bits: a batched dataset records a device other than the
    CPU, is not resumed on another, and `dpr replay` refuses it by name where torch has no such device."""
    collect(tmp_path / "cpu", spec(steps=5), 1, seed=SEEDS[0])
    assert "device" not in LeRobotReader(tmp_path / "cpu").info["dpr"]  # as datasets recorded before devices were
    recorded = collect_module._info_extra
    monkeypatch.setattr(collect_module, "_info_extra", lambda spec, device="cpu": recorded(spec, "cuda:1"))
    collect(tmp_path / "gpu", spec(steps=5), 1, seed=SEEDS[0])  # (stepped on the CPU, recorded as a GPU's)
    assert LeRobotReader(tmp_path / "gpu").info["dpr"]["device"] == "cuda"
    monkeypatch.setattr(collect_module, "_info_extra", recorded)
    with pytest.raises(DatasetError, match="device"):  # the CPU's episodes are not added to a GPU's dataset
        collect(tmp_path / "gpu", spec(steps=5), 2, seed=SEEDS[0])
    if not torch.cuda.is_available():
        with pytest.raises(DatasetError, match=r"gpu: recorded on the batched engine on 'cuda'"):
            replay_dataset(tmp_path / "gpu")


def test_the_paddle_model_pixels_and_ray_are_refused_before_anything_is_written(tmp_path):
    with pytest.raises(ValueError, match="disk"):
        collect(tmp_path / "paddle", spec(robot_model="paddle"), 1)
    with pytest.raises(ValueError, match="pixels"):
        spec(pixels=True)
    with pytest.raises(ValueError, match="Ray"):
        collect(tmp_path / "ray", spec(), 1, workers=RolloutWorkers(backend="ray"))
    assert not (tmp_path / "paddle").exists() and not (tmp_path / "ray").exists()


def test_dpr_collect_engine_batched_writes_a_dataset_that_replays_and_clones(tmp_path, capsys):
    from dpr.imitation.bc import behaviour_clone
    from dpr.imitation.config import CloneConfig

    out = tmp_path / "data"
    args = ["--env", GATE, "--engine", "batched", "--n-robots", "4", "--episodes", "3", "--steps", "20"]
    assert run_cli(["collect", *args, "--out", str(out), "--batch", "2", "--verify"]) == 0
    assert LeRobotReader(out).episodes[0][F.ROBOT_MODEL] == "disk"  # the batched engine's model by default
    assert run_cli(["replay", str(out)]) == 0
    capsys.readouterr()
    assert run_cli(["collect", *args, "--robot-model", "paddle", "--out", str(tmp_path / "paddle")]) == 2
    assert "'disk' robot model only" in capsys.readouterr().err
    assert not (tmp_path / "paddle").exists()
    clone = behaviour_clone(out, GATE, CloneConfig(epochs=1), out=tmp_path / "bc", **QUIET)
    assert clone.model_path.is_file()
