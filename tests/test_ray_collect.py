"""`dpr collect --backend ray`: rollouts as Ray tasks on a local cluster, merged into one valid dataset.

Ray is an optional extra (`pip install -e '.[distributed]'`); without it these tests skip.
"""

from dataclasses import replace

import numpy as np
import pytest

ray = pytest.importorskip("ray", reason="Ray is not installed: pip install -e '.[distributed]' to run these tests")

from dpr.cli import main  # noqa: E402
from dpr.datasets.collect import CollectSpec, RolloutWorkers, collect  # noqa: E402
from dpr.datasets.lerobot import LeRobotReader  # noqa: E402
from dpr.datasets.replay import replay_dataset  # noqa: E402

SPEC = CollectSpec("dpr/Navigation-v0", robot_model="disk", n_robots=4, steps=40)


def test_ray_backend_records_the_same_dataset_as_processes(tmp_path):
    collect(tmp_path / "processes", SPEC, episodes=4)
    summary = collect(tmp_path / "ray", replace(SPEC, mcap=True), episodes=4, workers=RolloutWorkers(2, backend="ray"))
    assert summary.episodes_added == 4 and not summary.interrupted
    assert not ray.is_initialized()  # the local cluster it started is shut down again
    ours, theirs = LeRobotReader(tmp_path / "ray"), LeRobotReader(tmp_path / "processes")
    assert [e["seed"] for e in ours.episodes] == [0, 1, 2, 3]
    for index in range(4):
        a, b = ours.episode(index), theirs.episode(index)
        for key in ("observation.state", "action", "next.reward", "next.done", "index"):
            np.testing.assert_array_equal(a[key], b[key])
    assert all(check.equal for check in replay_dataset(tmp_path / "ray"))
    assert sorted(p.name for p in (tmp_path / "ray" / "mcap").iterdir()) == [f"seed-{s:06d}.mcap" for s in range(4)]


def test_ray_backend_resumes_a_dataset(tmp_path):
    collect(tmp_path / "ds", SPEC, episodes=2)
    summary = collect(tmp_path / "ds", SPEC, episodes=3, workers=RolloutWorkers(2, backend="ray"))
    assert (summary.episodes_added, summary.episodes_total) == (1, 3)


def test_address_needs_the_ray_backend(tmp_path, capsys):
    argv = [
        "collect",
        "--env",
        "dpr/Navigation-v0",
        "--episodes",
        "1",
        "--out",
        str(tmp_path / "ds"),
        "--address",
        "127.0.0.1:6379",
    ]
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2 and "--address" in capsys.readouterr().err
    assert not (tmp_path / "ds").exists()
