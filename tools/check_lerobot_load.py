#!/usr/bin/env python
"""Check that datasets written by ``dpr.datasets.lerobot`` load unchanged in the real LeRobot library.

LeRobot is not a dependency of dpr (lerobot 0.4.x pins torch<2.11; dpr uses torch 2.13), so this runs in a
scratch virtualenv holding LeRobot beside torch 2.13 (its dataset code does not need the newer pins):

    python3.11 -m venv /tmp/lerobot-venv
    /tmp/lerobot-venv/bin/pip install -U pip
    /tmp/lerobot-venv/bin/pip install torch==2.13.0
    /tmp/lerobot-venv/bin/pip install --no-deps lerobot==0.4.4
    /tmp/lerobot-venv/bin/pip install -c constraints.txt torchvision==0.28.0 "datasets>=4,<5" \\
        "huggingface-hub[hf-transfer]>=0.34.2,<0.36" "av>=15,<16" "jsonlines>=4,<5" "packaging>=24.2,<26" \\
        draccus==0.10.0 "deepdiff>=7.0.1,<9" "termcolor>=2.4,<4" "einops>=0.8,<0.9" \\
        "imageio[ffmpeg]>=2.34,<3" "gymnasium>=1.1.1,<2" "accelerate>=1.10,<2"
    /tmp/lerobot-venv/bin/pip install -c constraints.txt "pandas>=2.2,<3" "pyarrow>=18,<23" "pillow>=10,<13" \\
        "pymunk>=7.1,<8" "pygame-ce>=2.5,<3" "mcap>=1.2,<2" "pettingzoo>=1.25,<1.28" pyyaml tqdm pytest

(pip warns that lerobot wants older torch/torchvision: expected; see :func:`make_torchvision_importable`.)
From the repository root:

    PYTHONPATH=$PWD /tmp/lerobot-venv/bin/python tools/check_lerobot_load.py [--compact] [PATH ...]

Without PATH it records a state-only and a pixel dataset with ``dpr collect``'s pipeline, and two of decisions
every 6 and every 10 physics steps (fps 10/6 and 1; ``--compact``: then packs them into several LeRobot files
each) and checks them; with PATH it checks those folders. LeRobot's ``LeRobotDataset`` must give what
``LeRobotReader`` reads: length, every frame (images included), tasks, episode boundaries and the data file each
episode row points at, stats, ``delta_timestamps`` in simulated seconds (the frames one and two decisions away) and
their padding at episode edges,
a DataLoader epoch and an ``episodes=[1]`` subset. Exit status 1 when a check fails.
``tests/test_lerobot_compat.py`` runs the same checks in-process when ``lerobot`` is importable.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import tempfile
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

# delta_timestamps asked for in seconds: these frame offsets times the simulated seconds of a frame (0.1 s, or
# k x 0.1 s for a dataset of decisions every k physics steps: its env kwargs say, independently of its fps)
DELTA_FRAMES = {"observation.state": [-2, -1, 0], "action": [0, 1]}
DEFAULT_KEYS = ("timestamp", "frame_index", "episode_index", "index", "task_index")


def prepare_environment(cache_dir: Path) -> None:
    """Keep LeRobot off the network (a missing meta file fails at once) and its Arrow cache in ``cache_dir``;
    read when ``huggingface_hub``/``datasets`` are imported, so call this first."""
    offline = {"HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1", "SDL_VIDEODRIVER": "dummy"}
    for key, value in {**offline, "HF_DATASETS_CACHE": f"{cache_dir}", "HF_LEROBOT_HOME": f"{cache_dir}/home"}.items():
        os.environ.setdefault(key, value)


def make_torchvision_importable() -> None:
    """PyPI's torchvision for torch 2.13 is a CUDA build whose ``_C`` ops fail to load beside the CPU torch, and
    its import then dies registering fake kernels for undeclared ``nms``/``qnms``: declare them. LeRobot's dataset
    code only uses pure-Python transforms."""
    spec = importlib.util.find_spec("torchvision")
    if spec is None or spec.origin is None or "torchvision" in sys.modules:
        return
    hook_folder = str(Path(__file__).parent / "lerobot_plugin")  # the side environment's start-up hook
    if hook_folder not in sys.path:
        sys.path.insert(0, hook_folder)
    from dpr_lerobot_startup import declare_torchvision_ops

    declare_torchvision_ops()


def record(
    root: Path, *, pixels: bool, episodes: int = 3, steps: int = 40, compact: bool = False, action_repeat: int = 1
) -> Path:
    """Wave-policy episodes of dpr/Navigation-v0 (4 disk robots) recorded by ``dpr.datasets.collect``, deciding
    every ``action_repeat`` physics steps (fps 10 / action_repeat)."""
    from dpr.datasets.collect import CollectSpec, collect
    from dpr.datasets.lerobot import compact as compact_dataset

    spec = CollectSpec(
        "dpr/Navigation-v0",
        n_robots=4,
        robot_model="disk",
        steps=steps,
        pixels=pixels,
        image_size=24,
        env_kwargs={"action_repeat": action_repeat} if action_repeat > 1 else {},
    )
    collect(root, spec, episodes=episodes)
    if compact:  # a target of 3/4 of the column data: episodes packed (three: two to a file)
        import pyarrow.parquet as pq

        files = list((root / "data").glob("*/*.parquet"))
        data_bytes = sum(path.stat().st_size - pq.read_metadata(path).serialized_size for path in files)
        compact_dataset(root, target_bytes=data_bytes * 3 // 4)
    return root


@dataclass
class Expected:
    """What LeRobot must return, as our reader reads it: per-episode arrays, tasks and frame ranges."""

    features: dict[str, dict]
    episodes: list[dict[str, np.ndarray]]
    tasks: list[str]
    starts: list[int]
    lengths: list[int]
    seconds_per_frame: float  # simulated seconds: the env's action_repeat x 0.1 s (1 / fps for other datasets)

    @classmethod
    def read(cls, root: Path) -> Expected:
        from dpr.datasets.lerobot import LeRobotReader
        from dpr.envs.particle_env import seconds_per_step

        reader = LeRobotReader(root)
        recorded = reader.info.get("dpr", {}).get("env_kwargs")
        episodes = [reader.episode(i) for i in range(reader.num_episodes)]
        return cls(
            features={k: v for k, v in reader.features.items() if k not in DEFAULT_KEYS},
            episodes=episodes,
            tasks=[reader.tasks[int(e["task_index"][0, 0])] for e in episodes],
            starts=[int(e["dataset_from_index"]) for e in reader.episodes],
            lengths=[int(e["length"]) for e in reader.episodes],
            seconds_per_frame=seconds_per_step(recorded) if recorded is not None else 1 / reader.fps,
        )

    def delta_timestamps(self) -> dict[str, list[float]]:
        return {key: [f * self.seconds_per_frame for f in frames] for key, frames in DELTA_FRAMES.items()}


class Check(NamedTuple):
    name: str
    status: str  # "PASS" or "FAIL"
    detail: str = ""


@dataclass
class Report:
    root: Path
    checks: list[Check] = field(default_factory=list)

    @property
    def failed(self) -> list[Check]:
        return [c for c in self.checks if c.status == "FAIL"]

    @property
    def ok(self) -> bool:
        return not self.failed

    def run(self, name: str, check: Callable[[], Any]) -> Any:
        """A failed assert or any exception FAILs the check; returns the check's value (None when it failed)."""
        try:
            value = check()
        except Exception:
            self.checks.append(Check(name, "FAIL", traceback.format_exc(limit=3)))
            return None
        self.checks.append(Check(name, "PASS"))
        return value

    def format(self) -> str:
        lines = [f"== {self.root}"]
        for c in self.checks:
            lines += [f"[{c.status}] {c.name}", *(f"       {line}" for line in c.detail.rstrip().splitlines())]
        return "\n".join([*lines, f"== {'PASS' if self.ok else f'FAIL ({len(self.failed)} failed)'}"])


def check_dataset(root: Path, expected: Expected | None = None) -> Report:
    """Open ``root`` with LeRobot and compare what it returns with ``expected`` (default: our reader's view)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    root, report = Path(root), Report(Path(root))
    expected = expected or report.run("our reader opens the dataset", lambda: Expected.read(root))
    repo_id = f"local/{root.name}"
    ds = report.run(f"LeRobotDataset({repo_id!r}, root=...) opens", lambda: LeRobotDataset(repo_id, root=root))
    if expected is None or ds is None:
        return report
    total = sum(expected.lengths)
    # every frame of a small dataset; else each episode's first, second, middle and last frames
    edges = {s + t for s, n in zip(expected.starts, expected.lengths, strict=True) for t in (0, 1, n // 2, n - 1)}
    frames = range(total) if total <= 2000 else sorted(i for i in edges if i < total)
    report.run("len(ds) == total frames", lambda: _equal((len(ds), ds.num_episodes), (total, len(expected.lengths))))
    report.run("ds[i] equals the recorded frames", lambda: [_check_item(ds[i], expected, i) for i in frames])
    report.run("meta.tasks and item['task']", lambda: _check_tasks(ds, expected))
    report.run("meta.episodes rows and the data files they name", lambda: _check_episodes(ds, expected))
    report.run("meta.stats as our reader reads them", lambda: _check_stats(ds, root))
    dsd = report.run(
        "LeRobotDataset(delta_timestamps=...) opens",
        lambda: LeRobotDataset(repo_id, root=root, delta_timestamps=expected.delta_timestamps()),
    )
    if dsd is not None:
        report.run("delta_timestamps values and *_is_pad at episode boundaries", lambda: _check_delta(dsd, expected))
        report.run("DataLoader(batch_size=8, shuffle=True) runs one epoch", lambda: _check_loader(dsd, total))
    report.run(
        "LeRobotDataset(episodes=[1]) selects one episode",
        lambda: _check_subset(LeRobotDataset(repo_id, root=root, episodes=[1]), expected),
    )
    return report


def _equal(got: Any, want: Any) -> None:
    assert got == want, f"{got!r} != {want!r}"


def _check_item(item: dict, expected: Expected, index: int) -> None:
    episode = int(np.searchsorted(expected.starts, index, side="right") - 1)
    t = index - expected.starts[episode]
    want = expected.episodes[episode]
    for key in ("index", "frame_index", "episode_index", "task_index"):
        _equal((key, int(item[key])), (key, int(want[key][t, 0])))
    _equal(float(item["timestamp"]), float(want["timestamp"][t, 0]))
    for key, spec in expected.features.items():
        got = item[key].numpy()
        if spec["dtype"] == "image":  # LeRobot: float32 CHW in [0, 1], exactly uint8 / 255
            value = np.ascontiguousarray(want[key][t].transpose(2, 0, 1)).astype(np.float32) / 255
            assert got.dtype == np.float32 and np.array_equal(got, value), f"ds[{index}][{key!r}] differs"
        else:
            value = want[key][t].reshape(() if spec["shape"] == [1] else tuple(spec["shape"]))
            assert got.dtype == value.dtype and np.array_equal(got, value), f"ds[{index}][{key!r}]: {got} != {value}"


def _check_tasks(ds: Any, expected: Expected) -> None:
    assert set(expected.tasks) <= set(ds.meta.tasks.index), list(ds.meta.tasks.index)
    _equal([ds[start]["task"] for start in expected.starts], expected.tasks)


def _check_episodes(ds: Any, expected: Expected) -> None:
    import pyarrow.parquet as pq

    _equal(len(ds.meta.episodes), len(expected.lengths))
    for e, (start, length) in enumerate(zip(expected.starts, expected.lengths, strict=True)):
        row = ds.meta.episodes[e]
        _equal((row["episode_index"], row["dataset_from_index"], row["length"]), (e, start, length))
        data = pq.read_table(ds.root / ds.meta.get_data_file_path(e), columns=["episode_index", "index"])
        indices = data.column("index").to_numpy()[data.column("episode_index").to_numpy() == e]
        assert np.array_equal(indices, np.arange(start, start + length)), f"episode {e}'s data file"


def _check_stats(ds: Any, root: Path) -> None:
    from lerobot.datasets.compute_stats import aggregate_stats

    from dpr.datasets.lerobot import LeRobotReader

    ours = LeRobotReader(root).stats
    _equal(sorted(ds.meta.stats), sorted(ours))
    for feature, stats in ours.items():
        for key, value in stats.items():
            assert np.allclose(np.asarray(ds.meta.stats[feature][key]), value), f"stats[{feature!r}][{key!r}]"
    aggregate_stats([ds.meta.stats, ds.meta.stats])  # LeRobot's validation when datasets are merged


def _check_delta(dsd: Any, expected: Expected) -> None:
    """At each episode's first, second, middle and last two frames: values clamped to the episode, pad masks (the
    frames DELTA_FRAMES names, asked for in seconds)."""
    for e, (start, length) in enumerate(zip(expected.starts, expected.lengths, strict=True)):
        for t in sorted({0, 1, length // 2, length - 2, length - 1} & set(range(length))):
            item = dsd[start + t]
            for key, offsets in DELTA_FRAMES.items():
                steps = [t + offset for offset in offsets]
                _equal((e, t, key, item[f"{key}_is_pad"].tolist()), (e, t, key, [not 0 <= s < length for s in steps]))
                rows = [min(max(s, 0), length - 1) for s in steps]
                assert np.array_equal(item[key].numpy(), expected.episodes[e][key][rows]), f"{key} at {e}/{t}"


def _check_loader(dsd: Any, total: int) -> None:
    import torch

    seen = []
    for batch in torch.utils.data.DataLoader(dsd, batch_size=8, shuffle=True):
        assert batch["observation.state"].shape[1] == 3 and batch["action_is_pad"].shape[1] == 2
        assert all(isinstance(task, str) for task in batch["task"])
        seen += batch["index"].tolist()
    _equal(sorted(seen), list(range(total)))


def _check_subset(subset: Any, expected: Expected) -> None:
    _equal(len(subset), expected.lengths[1])
    for t in (0, expected.lengths[1] - 1):
        _check_item(subset[t], expected, expected.starts[1] + t)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("datasets", nargs="*", type=Path, help="dataset folders to check (default: record two)")
    parser.add_argument("--compact", action="store_true", help="compact the recorded datasets before checking")
    parser.add_argument("--keep", type=Path, help="record into this folder and keep it")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="check_lerobot_") as tmp:
        prepare_environment(Path(tmp) / "hf-cache")
        if importlib.util.find_spec("lerobot") is None:
            print("FAIL: lerobot is not importable with this python; see the top of this file", file=sys.stderr)
            return 1
        make_torchvision_importable()
        roots = args.datasets or [
            record((args.keep or Path(tmp)) / name, pixels=pixels, compact=args.compact, action_repeat=repeat)
            for name, pixels, repeat in (
                ("navigation_state", False, 1),
                ("navigation_pixels", True, 1),
                ("navigation_repeat6", False, 6),  # fps 10/6: a float
                ("navigation_repeat10", True, 10),  # fps 1
            )
        ]
        reports = [check_dataset(root) for root in roots]
        for report in reports:
            print(report.format())
        ok = all(r.ok for r in reports)
        print("OVERALL: PASS" if ok else "OVERALL: FAIL")
        return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
