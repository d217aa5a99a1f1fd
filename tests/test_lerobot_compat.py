"""Datasets written by ``dpr.datasets.lerobot`` load unchanged in the real ``LeRobotDataset``.

LeRobot is not a dependency of dpr, so these tests run only where ``lerobot`` is importable (the scratch venv
described at the top of ``tools/check_lerobot_load.py``) and are skipped everywhere else. They record wave-policy
rollouts with ``dpr collect``'s pipeline, as recorded and compacted, and run the tool's checks in-process: length,
every frame's values (PNG images included), tasks, episode rows and their data files, stats, ``delta_timestamps``
padding at episode boundaries, one DataLoader epoch and an episode subset.
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path
from types import ModuleType

import gymnasium as gym
import numpy as np
import pytest

if importlib.util.find_spec("lerobot") is None:
    pytest.skip("lerobot is not installed: see tools/check_lerobot_load.py", allow_module_level=True)

TOOL_PATH = Path(__file__).resolve().parents[1] / "tools" / "check_lerobot_load.py"


def load_tool(path: Path) -> ModuleType:
    """A script of tools/ as a module, registered under its name (dataclasses resolve their module through
    sys.modules, and a tool that imports another one finds it there)."""
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def tool(tmp_path_factory: pytest.TempPathFactory) -> ModuleType:
    """tools/check_lerobot_load.py as a module, with LeRobot kept offline and its Arrow cache in a temp folder."""
    module = load_tool(TOOL_PATH)
    module.prepare_environment(tmp_path_factory.mktemp("hf-cache"))
    module.make_torchvision_importable()
    return module


@pytest.mark.parametrize("compact", [False, True], ids=["as-recorded", "compacted"])
@pytest.mark.parametrize("pixels", [False, True], ids=["state", "pixels"])
def test_dataset_loads_in_lerobot(tool: ModuleType, tmp_path: Path, pixels: bool, compact: bool) -> None:
    root = tool.record(tmp_path / "ds", pixels=pixels, episodes=3, steps=30, compact=compact)
    data_files = list((root / "data").glob("*/*.parquet"))
    assert len(data_files) == (2 if compact else 3)  # compacted: several episodes per file, in two files
    report = tool.check_dataset(root)
    assert report.ok, report.format()
    assert {c.name for c in report.checks} >= {
        "len(ds) == total frames",
        "ds[i] equals the recorded frames",
        "meta.episodes rows and the data files they name",
        "delta_timestamps values and *_is_pad at episode boundaries",
        "DataLoader(batch_size=8, shuffle=True) runs one epoch",
    }


@pytest.mark.parametrize(("repeat", "pixels"), [(6, False), (10, True)])
def test_a_dataset_of_decisions_every_k_steps_loads_in_lerobot_by_simulated_seconds(
    tool: ModuleType, tmp_path: Path, repeat: int, pixels: bool
) -> None:
    """fps 10/6 (a float) and 1: delta_timestamps of -1.2, -0.6, 0 s (or -2, -1, 0 s) pick the frames one and two
    decisions back."""
    root = tool.record(tmp_path / "ds", pixels=pixels, episodes=2, steps=8, action_repeat=repeat)
    expected = tool.Expected.read(root)
    assert expected.seconds_per_frame == repeat / 10
    report = tool.check_dataset(root, expected)
    assert report.ok, report.format()


def _tasks_without_pandas_metadata(root: Path) -> None:
    """Task strings as a plain column: LeRobot then returns the row number as the task."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    task = pq.read_table(root / "meta" / "tasks.parquet").column("__index_level_0__")[0].as_py()
    pq.write_table(pa.table({"task": [task], "task_index": pa.array([0], pa.int64())}), root / "meta" / "tasks.parquet")


def _episode_rows_reversed(root: Path) -> None:
    """Episode rows in reverse order (kept per file counts): LeRobot indexes meta.episodes by position."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    paths = sorted((root / "meta" / "episodes").glob("*/*.parquet"))
    tables = [pq.read_table(path) for path in paths]
    rows = pa.concat_tables(tables, promote_options="default")
    rows = rows.take(list(reversed(range(rows.num_rows))))
    offset = 0
    for path, table in zip(paths, tables, strict=True):
        pq.write_table(rows.slice(offset, table.num_rows), path)
        offset += table.num_rows


@pytest.mark.parametrize(
    ("mutate", "failing_check"),
    [
        (_tasks_without_pandas_metadata, "meta.tasks and item['task']"),
        (_episode_rows_reversed, "delta_timestamps values and *_is_pad at episode boundaries"),
    ],
)
def test_checker_catches_silently_wrong_layouts(tool: ModuleType, tmp_path: Path, mutate, failing_check) -> None:
    """Layouts LeRobot loads without error but reads wrongly must fail the check (else the check proves nothing)."""
    root = tool.record(tmp_path / "ds", pixels=False, episodes=2, steps=10)
    expected = tool.Expected.read(root)  # what was recorded, read before the damage
    mutate(root)
    report = tool.check_dataset(root, expected)
    failed = {c.name for c in report.failed}
    assert failed and failing_check in failed, report.format()


# LeRobot's own policies on dpr datasets (tools/lerobot_policies.py), at sizes a CPU builds in a second
TINY_POLICIES = {
    "act": {"dim_model": 32, "dim_feedforward": 64, "n_heads": 2, "n_encoder_layers": 1, "latent_dim": 8},
    "diffusion": {"down_dims": [16, 32], "horizon": 8, "n_action_steps": 4, "diffusion_step_embed_dim": 16},
}


@pytest.fixture(scope="module")
def policies(tool: ModuleType) -> ModuleType:
    """tools/lerobot_policies.py as a module (it imports the LeRobot check tool beside it)."""
    return load_tool(TOOL_PATH.with_name("lerobot_policies.py"))


@pytest.mark.parametrize("kind", ["act", "diffusion"])
@pytest.mark.parametrize("pixels", [False, True], ids=["state", "pixels"])
def test_act_and_diffusion_policy_build_and_take_a_training_step(
    tool: ModuleType, policies: ModuleType, tmp_path: Path, kind: str, pixels: bool
) -> None:
    """On a state-only dataset they read observation.environment_state; the batch holds the frames each policy's
    delta_timestamps ask for (Diffusion: two observations and a horizon of actions; ACT: a chunk of actions)."""
    root = tool.record(tmp_path / "ds", pixels=pixels, episodes=2, steps=30, action_repeat=2)
    loss, held = policies.training_step(root, kind, batch_size=4, **TINY_POLICIES[kind])
    assert np.isfinite(loss)
    config = policies.policy_config(kind, **TINY_POLICIES[kind])
    if kind == "diffusion":
        assert held["observation.state"] == held["observation.environment_state"] == config.n_obs_steps == 2
        assert held["action"] == config.horizon
    else:
        assert held["observation.state"] == 1 and held["action"] == config.chunk_size
    if pixels:
        assert held["observation.image"] == held["observation.state"]


def test_a_trained_policy_runs_in_the_env_as_a_multibinary_action(
    tool: ModuleType, policies: ModuleType, tmp_path: Path
) -> None:
    """LeRobot's training code trains a few steps, and the adapter drives the env the dataset was recorded on; the
    evaluation file is dpr's, with the episode's metrics."""
    root = tool.record(tmp_path / "ds", pixels=False, episodes=2, steps=30, action_repeat=2)
    policies.train(root, "act", steps=2, batch_size=4, out=tmp_path / "act", **TINY_POLICIES["act"])
    policy, pre, post, dataset = policies.load_policy(tmp_path / "act")
    assert dataset == root
    env = gym.make("dpr/Navigation-v0", n_robots=4, robot_model="disk", action_repeat=2)
    adapter = policies.LeRobotPolicyAdapter(policy, pre, post, env)
    observation, _ = env.reset(seed=5)
    adapter.reset(5)
    action = adapter(observation)
    assert env.action_space.contains(action)
    policies.evaluate(tmp_path / "act", [5], 40, tmp_path / "act.json")
    record = json.loads((tmp_path / "act.json").read_text())
    assert record["policy"] == str(tmp_path / "act") and [e["seed"] for e in record["episodes"]] == [5]
    assert record["episodes"][0]["steps"] == 40
    with pytest.raises(ValueError, match="--json"):
        policies.evaluate(tmp_path / "act", [5], 40, tmp_path / "act.json")
    replanning, *_ = policies.load_policy(tmp_path / "act", n_action_steps=1)  # an inference-time setting
    assert replanning.config.n_action_steps == 1
    with pytest.raises(ValueError, match="--set: \\['horizon_of_doom'\\]"):
        policies.load_policy(tmp_path / "act", horizon_of_doom=3)


def test_a_dataset_without_environment_state_is_refused_by_name(
    tool: ModuleType, policies: ModuleType, tmp_path: Path
) -> None:
    root = tool.record(tmp_path / "ds", pixels=False, episodes=2, steps=10)
    info = json.loads((root / "meta" / "info.json").read_text())
    del info["features"]["observation.environment_state"]
    (root / "meta" / "info.json").write_text(json.dumps(info))
    with pytest.raises(ValueError, match="observation.environment_state"):
        policies.check_dataset(root)
