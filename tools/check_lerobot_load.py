#!/usr/bin/env python
"""Check that datasets written by ``dpr.datasets.lerobot`` load unchanged in the real LeRobot library.

LeRobot is not a dependency of dpr (lerobot 0.4.x pins torch<2.11; dpr uses torch 2.13), so this script runs
in a scratch virtualenv that holds LeRobot beside torch 2.13 (its dataset code does not need the newer pins):

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

(pip warns that lerobot wants torch<2.11 and torchvision<0.26: expected. The torchvision wheel on PyPI is a
CUDA build whose C ops cannot load beside the CPU torch; :func:`make_torchvision_importable` works around that.)

Run from the repository root:

    PYTHONPATH=$PWD /tmp/lerobot-venv/bin/python tools/check_lerobot_load.py
        records two small datasets from real wave-policy rollouts of dpr/Navigation-v0 (state only, and with
        64x64 ``observation.image`` pixels) into a temporary folder and checks both;
    PYTHONPATH=$PWD /tmp/lerobot-venv/bin/python tools/check_lerobot_load.py PATH [PATH ...]
        checks existing dataset folders instead (values are compared with ``LeRobotReader``);
    options: --episodes 3 --steps 40 --seed 0 --keep DIR (record into DIR and keep it), --max-items 2000.

Each check prints PASS, WARN (loads, but differs from what LeRobot's own writer produces) or FAIL with the
LeRobot traceback; the exit status is 1 when any check fails, 0 otherwise. ``tests/test_lerobot_compat.py``
runs the same checks in-process when ``lerobot`` is importable.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import sys
import tempfile
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

TASK = "navigate the swarm to the goal"
ENV_ID = "dpr/Navigation-v0"
FPS = 10
IMAGE_SIZE = 64
DELTA_TIMESTAMPS = {"observation.state": [-0.2, -0.1, 0.0], "action": [0.0, 0.1]}
DEFAULT_KEYS = ("timestamp", "frame_index", "episode_index", "index", "task_index")
STAT_KEYS = ("min", "max", "mean", "std", "count", "q01", "q10", "q50", "q90", "q99")
IMAGE_NAMES = ["height", "width", "channels"]
T = TypeVar("T")

# Kept alive for the whole process: dropping a torch.library.Library removes the schemas it defined.
_TORCHVISION_FALLBACK_LIB: Any = None


# -- environment set-up (must run before lerobot / datasets / huggingface_hub are imported) -------------------


def prepare_environment(cache_dir: Path) -> None:
    """Keep LeRobot off the network and its Arrow cache out of the home folder.

    With ``root`` given LeRobot still falls back to the Hugging Face Hub when a meta file is missing or
    inconsistent; offline mode turns that into an immediate, explicit error instead of a slow connection
    failure. Both variables are read when ``huggingface_hub`` / ``datasets`` are imported, hence "before".
    """
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    os.environ.setdefault("HF_DATASETS_OFFLINE", "1")
    os.environ.setdefault("HF_DATASETS_CACHE", str(cache_dir))
    os.environ.setdefault("HF_LEROBOT_HOME", str(cache_dir / "lerobot-home"))
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")


def make_torchvision_importable() -> None:
    """Let ``import torchvision`` succeed when its compiled ops cannot load.

    PyPI's torchvision for torch 2.13 is a CUDA build: beside the CPU torch its ``_C`` library fails to load
    (missing ``libc10_cuda.so``), and torchvision 0.28 then still registers fake kernels for
    ``torchvision::nms``/``qnms`` and dies because those operators were never declared. Declaring the two
    schemas lets the import finish. LeRobot's dataset code only uses ``transforms.ToTensor`` (pure Python).
    """
    global _TORCHVISION_FALLBACK_LIB
    spec = importlib.util.find_spec("torchvision")
    if spec is None or spec.origin is None or "torchvision" in sys.modules:
        return
    import torch

    package_dir = Path(spec.origin).parent
    extension = next(iter(sorted(package_dir.glob("_C*.so"))), None)
    try:
        if extension is None:
            raise OSError("no torchvision/_C*.so")
        torch.ops.load_library(str(extension))
        return
    except OSError:
        pass
    lib = torch.library.Library("torchvision", "DEF")
    lib.define("nms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor")
    lib.define("qnms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor")
    _TORCHVISION_FALLBACK_LIB = lib


def lerobot_available() -> bool:
    """True when the ``lerobot`` package is installed (it is not imported here)."""
    return importlib.util.find_spec("lerobot") is not None


# -- recording ------------------------------------------------------------------------------------------------


@dataclass
class Recording:
    """What was fed to the writer: per episode, the stacked frames and the metadata passed to save_episode."""

    root: Path
    features: dict[str, dict]
    episodes: list[dict[str, np.ndarray]]
    episode_meta: list[dict[str, Any]]
    task: str = TASK


def dataset_features(state_size: int, n_robots: int, image_size: int | None) -> dict[str, dict]:
    """The user features of a Navigation dataset (LeRobot adds the five default columns itself)."""
    features: dict[str, dict] = {
        "observation.state": {"dtype": "float32", "shape": [state_size], "names": None},
        "action": {"dtype": "float32", "shape": [n_robots], "names": None},
        "next.reward": {"dtype": "float32", "shape": [1], "names": None},
        "next.done": {"dtype": "bool", "shape": [1], "names": None},
        "next.success": {"dtype": "bool", "shape": [1], "names": None},
    }
    if image_size is not None:
        features["observation.image"] = {
            "dtype": "image",
            "shape": [image_size, image_size, 3],
            "names": list(IMAGE_NAMES),
        }
    return features


def record_dataset(root: Path, *, pixels: bool, episodes: int = 3, steps: int = 40, seed: int = 0) -> Recording:
    """Roll out the wave policy on dpr/Navigation-v0 (9 paddle robots) and record it with LeRobotWriter.

    Each episode is cut after ``steps`` steps (or ends earlier on success); ``next.done`` is True on its last
    frame. A frame holds the observation before the action and the reward, done and success after it.
    """
    import gymnasium as gym

    import dpr  # noqa: F401  (registers the env ids)
    from dpr.datasets.lerobot import LeRobotWriter
    from dpr.policies.wave import WavePolicy

    env_kwargs: dict[str, Any] = {"n_robots": 9, "robot_model": "paddle"}
    if pixels:
        env_kwargs.update(obs_type="pixels_state", image_size=IMAGE_SIZE)
    env = gym.make(ENV_ID, **env_kwargs)
    unwrapped = env.unwrapped
    features = dataset_features(unwrapped.state_size, unwrapped.n_robots, IMAGE_SIZE if pixels else None)
    writer = LeRobotWriter.create(
        root, fps=FPS, features=features, robot_type="paddle", info_extra={"dpr": {"env_id": ENV_ID}}
    )
    recorded: list[dict[str, np.ndarray]] = []
    metas: list[dict[str, Any]] = []
    policy = WavePolicy.from_env(env)
    try:
        for episode in range(episodes):
            frames = _roll_out(env, policy, seed=seed + episode, steps=steps, pixels=pixels)
            for frame in frames:
                writer.add_frame(frame, task=TASK)
            meta = {"seed": seed + episode, "env_id": ENV_ID, "env_kwargs": dict(env_kwargs), "policy": "wave"}
            writer.save_episode(meta)
            recorded.append({key: np.stack([f[key] for f in frames]) for key in features})
            metas.append(meta)
    finally:
        writer.finalize()
        env.close()
    return Recording(root=Path(root), features=features, episodes=recorded, episode_meta=metas)


def _roll_out(env: Any, policy: Any, *, seed: int, steps: int, pixels: bool) -> list[dict[str, np.ndarray]]:
    """One episode as LeRobot frames (user features only)."""
    obs, _ = env.reset(seed=seed)
    policy.reset()
    frames = []
    for t in range(steps):
        action = policy(obs)
        next_obs, reward, terminated, truncated, info = env.step(action)
        done = bool(terminated or truncated or t == steps - 1)
        frame = {
            "observation.state": np.asarray(obs["state"] if pixels else obs, dtype=np.float32).copy(),
            "action": np.asarray(action, dtype=np.float32),
            "next.reward": np.array([reward], dtype=np.float32),
            "next.done": np.array([done], dtype=np.bool_),
            "next.success": np.array([bool(info["is_success"])], dtype=np.bool_),
        }
        if pixels:
            frame["observation.image"] = np.asarray(obs["pixels"], dtype=np.uint8).copy()
        frames.append(frame)
        obs = next_obs
        if done:
            break
    return frames


# -- report ---------------------------------------------------------------------------------------------------


@dataclass
class Check:
    name: str
    status: str  # "PASS" | "WARN" | "FAIL"
    detail: str = ""


@dataclass
class Report:
    """Results of the checks on one dataset folder."""

    root: Path
    checks: list[Check] = field(default_factory=list)

    @property
    def failed(self) -> list[Check]:
        return [c for c in self.checks if c.status == "FAIL"]

    @property
    def ok(self) -> bool:
        return not self.failed

    def add(self, name: str, status: str, detail: str = "") -> None:
        self.checks.append(Check(name, status, detail))

    def run(self, name: str, fn: Callable[[], list[str] | None]) -> bool:
        """Run one check: an exception or returned problems FAIL it; "WARN:" prefixed problems only warn."""
        try:
            problems = fn() or []
        except Exception:
            self.add(name, "FAIL", traceback.format_exc())
            return False
        failures = [p for p in problems if not p.startswith("WARN:")]
        warnings = [p[5:].strip() for p in problems if p.startswith("WARN:")]
        if failures:
            self.add(name, "FAIL", "\n".join(failures + [f"(warn) {w}" for w in warnings]))
            return False
        self.add(name, "WARN" if warnings else "PASS", "\n".join(warnings))
        return True

    def attempt(self, name: str, fn: Callable[[], T]) -> T | None:
        """Run a step whose result later checks need: PASS and its value, or FAIL with the traceback and None."""
        try:
            value = fn()
        except Exception:
            self.add(name, "FAIL", traceback.format_exc())
            return None
        self.add(name, "PASS")
        return value

    def format(self) -> str:
        lines = [f"== {self.root}"]
        for check in self.checks:
            lines.append(f"[{check.status}] {check.name}")
            lines.extend(f"       {line}" for line in check.detail.rstrip().splitlines())
        verdict = "PASS" if self.ok else f"FAIL ({len(self.failed)} of {len(self.checks)} checks failed)"
        lines.append(f"== {verdict}")
        return "\n".join(lines)


# -- expectations ---------------------------------------------------------------------------------------------


@dataclass
class Expected:
    """Per-episode arrays [T, *shape] that LeRobot must reproduce, and the episode boundaries."""

    features: dict[str, dict]
    episodes: list[dict[str, np.ndarray]]
    tasks: list[str]  # the task string of each episode
    starts: list[int]
    fps: int = FPS

    @property
    def lengths(self) -> list[int]:
        return [len(next(iter(ep.values()))) for ep in self.episodes]

    @property
    def total(self) -> int:
        return sum(self.lengths)

    def locate(self, index: int) -> tuple[int, int]:
        """(episode, frame) of a global frame index."""
        episode = int(np.searchsorted(self.starts, index, side="right") - 1)
        return episode, index - self.starts[episode]


def expected_from_recording(recording: Recording) -> Expected:
    lengths = [len(ep["action"]) for ep in recording.episodes]
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(int).tolist()
    return Expected(recording.features, recording.episodes, [recording.task] * len(lengths), starts)


def expected_from_reader(root: Path) -> Expected:
    """Expectations from our own reader (used for folders given on the command line)."""
    from dpr.datasets.lerobot import LeRobotReader

    reader = LeRobotReader(root)
    user = {k: v for k, v in reader.features.items() if k not in DEFAULT_KEYS}
    episodes, tasks = [], []
    for i in range(reader.num_episodes):
        data = reader.episode(i)
        episodes.append({k: np.asarray(data[k]) for k in user})
        task_index = int(np.asarray(data["task_index"]).reshape(-1)[0]) if "task_index" in data else 0
        tasks.append(reader.tasks[task_index])
    lengths = [len(next(iter(ep.values()))) for ep in episodes]
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(int).tolist() if lengths else []
    return Expected(user, episodes, tasks, starts, fps=int(reader.fps))


# -- the checks -----------------------------------------------------------------------------------------------


def check_dataset(root: Path, recording: Recording | None = None, *, max_items: int = 2000) -> Report:
    """Open ``root`` with LeRobot and compare everything it returns with what was recorded (or with our reader).

    Call :func:`prepare_environment` and :func:`make_torchvision_importable` first (``main`` does).
    """
    root = Path(root)
    report = Report(root)
    if recording is not None:
        expected = expected_from_recording(recording)
        report.run("our reader agrees with what was recorded", lambda: _compare_reader_with_recording(root, expected))
    else:
        expected = report.attempt("our reader opens the dataset", lambda: expected_from_reader(root))
        if expected is None:
            return report

    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    repo_id = f"local/{root.name}"
    ds = report.attempt(
        f"LeRobotDataset({repo_id!r}, root=...) opens", lambda: LeRobotDataset(repo_id=repo_id, root=root)
    )
    if ds is None:
        return report
    report.run("info.json as LeRobot writes it", lambda: _check_info(ds, expected))
    report.run("parquet column types as LeRobot writes them", lambda: _check_parquet_schema(root, expected))
    report.run("len(ds) == total frames", lambda: _check_length(ds, expected))
    report.run("ds[i] equals the recorded frames", lambda: _check_items(ds, expected, max_items))
    report.run("meta.tasks and item['task']", lambda: _check_tasks(ds, expected))
    report.run("meta.episodes boundaries and extras", lambda: _check_episodes(ds, expected, recording))
    report.run("meta.stats present and right", lambda: _check_stats(ds, expected))
    report.run("policy features (dataset_to_policy_features)", lambda: _check_policy_features(ds, expected))

    dsd = report.attempt(
        "LeRobotDataset(..., delta_timestamps=...) opens",
        lambda: LeRobotDataset(repo_id=repo_id, root=root, delta_timestamps=DELTA_TIMESTAMPS),
    )
    if dsd is not None:
        report.run("delta_timestamps values and *_is_pad at episode boundaries", lambda: _check_delta(dsd, expected))
        report.run("DataLoader(batch_size=8, shuffle=True) runs one epoch", lambda: _check_dataloader(dsd, expected))
    if len(expected.episodes) > 1:
        report.run(
            "LeRobotDataset(..., episodes=[1]) selects one episode",
            lambda: _check_episode_subset(LeRobotDataset, repo_id, root, expected),
        )
    return report


def _compare_reader_with_recording(root: Path, expected: Expected) -> list[str]:
    from dpr.datasets.lerobot import LeRobotReader

    reader = LeRobotReader(root)
    problems = []
    if reader.num_episodes != len(expected.episodes):
        problems.append(f"reader.num_episodes={reader.num_episodes}, recorded {len(expected.episodes)}")
    if reader.num_frames != expected.total:
        problems.append(f"reader.num_frames={reader.num_frames}, recorded {expected.total}")
    for e, episode in enumerate(expected.episodes[: reader.num_episodes]):
        data = reader.episode(e)
        for key, want in episode.items():
            got = np.asarray(data.get(key))
            if got.shape != want.shape or got.dtype != want.dtype or not np.array_equal(got, want):
                problems.append(
                    f"episode {e} {key!r}: reader gives {got.dtype}{got.shape}, recorded "
                    f"{want.dtype}{want.shape} (equal values: {_safe_equal(got, want)})"
                )
    return problems


def _safe_equal(a: np.ndarray, b: np.ndarray) -> bool:
    try:
        return bool(np.array_equal(a.reshape(b.shape), b))
    except ValueError:
        return False


def _check_info(ds: Any, expected: Expected) -> list[str]:
    info = ds.meta.info
    problems = []
    if info.get("codebase_version") != "v3.0":
        problems.append(f"codebase_version is {info.get('codebase_version')!r}, LeRobot writes 'v3.0'")
    if not isinstance(info.get("fps"), int):
        fps = info.get("fps")
        problems.append(f"WARN: fps is {fps!r} ({type(fps).__name__}), LeRobot writes an int")
    wanted_keys = (
        "robot_type",
        "total_episodes",
        "total_frames",
        "total_tasks",
        "chunks_size",
        "data_files_size_in_mb",
        "video_files_size_in_mb",
        "fps",
        "splits",
        "data_path",
        "video_path",
        "features",
    )
    missing = [k for k in wanted_keys if k not in info]
    if missing:
        problems.append(f"WARN: info.json lacks {missing} (LeRobot writes them; needed when it appends)")
    if info.get("total_episodes") != len(expected.episodes):
        problems.append(f"total_episodes={info.get('total_episodes')}, expected {len(expected.episodes)}")
    if info.get("total_tasks") is not None and info["total_tasks"] != len(set(expected.tasks)):
        problems.append(f"total_tasks={info['total_tasks']}, expected {len(set(expected.tasks))}")
    if info.get("splits") not in (None, {"train": f"0:{len(expected.episodes)}"}):
        problems.append(f"WARN: splits={info.get('splits')!r}, LeRobot writes {{'train': '0:<total_episodes>'}}")
    features = info["features"]
    defaults = {
        "timestamp": "float32",
        "frame_index": "int64",
        "episode_index": "int64",
        "index": "int64",
        "task_index": "int64",
    }
    for key, dtype in defaults.items():
        ft = features.get(key)
        if ft is None or ft["dtype"] != dtype or tuple(ft["shape"]) != (1,):
            problems.append(f"default feature {key!r} is {ft}, expected dtype {dtype} shape [1]")
    for key, ft in expected.features.items():
        got = features.get(key)
        if got is None:
            problems.append(f"feature {key!r} missing from info.json")
        elif got["dtype"] != ft["dtype"] or tuple(got["shape"]) != tuple(ft["shape"]):
            problems.append(
                f"feature {key!r}: info.json has {got['dtype']}{list(got['shape'])}, "
                f"expected {ft['dtype']}{list(ft['shape'])}"
            )
    return problems


def _check_parquet_schema(root: Path, expected: Expected) -> list[str]:
    """Column types LeRobot's own writer produces. Some deviations still load (WARN), some do not (FAIL)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    problems = []
    files = sorted((root / "data").glob("*/*.parquet"))
    features = {**expected.features, **{k: {"dtype": "int64", "shape": [1]} for k in DEFAULT_KEYS}}
    features["timestamp"] = {"dtype": "float32", "shape": [1]}
    for path in files:
        schema = pq.read_schema(path)
        names = set(schema.names)
        extra = names - set(features)
        if extra:
            problems.append(f"{path.relative_to(root)}: columns {sorted(extra)} are not features (LeRobot: CastError)")
        for key, ft in features.items():
            if key not in names:
                problems.append(f"{path.relative_to(root)}: no column {key!r} (LeRobot returns None for it)")
                continue
            typ = schema.field(key).type
            if ft["dtype"] == "image":
                fields = {typ.field(i).name for i in range(typ.num_fields)} if pa.types.is_struct(typ) else set()
                if fields != {"bytes", "path"}:
                    problems.append(
                        f"WARN: {path.relative_to(root)} {key!r} is {typ}, LeRobot writes "
                        "struct<bytes: binary, path: string>"
                    )
            elif tuple(ft["shape"]) == (1,):
                if pa.types.is_list(typ) or pa.types.is_fixed_size_list(typ) or pa.types.is_large_list(typ):
                    problems.append(
                        f"{path.relative_to(root)} {key!r} is {typ}: a shape-[1] feature must be a "
                        "scalar column (LeRobot fails to cast a list)"
                    )
                elif str(typ) != _arrow_name(ft["dtype"]):
                    problems.append(f"WARN: {path.relative_to(root)} {key!r} is {typ}, declared {ft['dtype']}")
            elif len(ft["shape"]) == 1:
                want = f"fixed_size_list<element: {_arrow_name(ft['dtype'])}>[{ft['shape'][0]}]"
                if str(typ) != want:
                    problems.append(f"WARN: {path.relative_to(root)} {key!r} is {typ}, LeRobot writes {want}")
    tasks = pq.read_schema(root / "meta" / "tasks.parquet")
    if b"pandas" not in (tasks.metadata or {}):
        problems.append("meta/tasks.parquet has no pandas metadata: LeRobot's item['task'] becomes an int")
    return problems


def _arrow_name(dtype: str) -> str:
    return {"float32": "float", "float64": "double", "bool": "bool"}.get(dtype, dtype)


def _check_length(ds: Any, expected: Expected) -> list[str]:
    problems = []
    if len(ds) != expected.total:
        problems.append(f"len(ds)={len(ds)}, expected {expected.total} frames")
    if ds.num_episodes != len(expected.episodes):
        problems.append(f"ds.num_episodes={ds.num_episodes}, expected {len(expected.episodes)}")
    if len(ds.hf_dataset) != expected.total:
        problems.append(f"the data parquet files hold {len(ds.hf_dataset)} rows, expected {expected.total}")
    return problems


def _sample_indices(expected: Expected, max_items: int) -> list[int]:
    """All frames of small datasets; else each episode's first, second, middle and last frames."""
    if expected.total <= max_items:
        return list(range(expected.total))
    picks: set[int] = set()
    for start, length in zip(expected.starts, expected.lengths, strict=True):
        picks.update(start + t for t in (0, 1, length // 2, length - 1) if 0 <= t < length)
    return sorted(picks)[:max_items]


def _check_items(ds: Any, expected: Expected, max_items: int) -> list[str]:
    problems: list[str] = []
    for index in _sample_indices(expected, max_items):
        item = ds[index]
        episode, t = expected.locate(index)
        problems += _compare_item(item, expected, episode, t, where=f"ds[{index}]")
        if len(problems) > 20:
            problems.append("... (stopped after 20 differences)")
            break
    return problems


def _compare_item(item: dict, expected: Expected, episode: int, t: int, *, where: str) -> list[str]:
    problems = []
    defaults = {"index": expected.starts[episode] + t, "frame_index": t, "episode_index": episode}
    for key, want in defaults.items():
        if int(item[key]) != want:
            problems.append(f"{where}[{key!r}]={int(item[key])}, expected {want}")
    if float(item["timestamp"]) != float(np.float32(t / expected.fps)):  # stored as float32, like LeRobot's
        problems.append(f"{where}['timestamp']={float(item['timestamp'])}, expected {t}/fps")
    for key, ft in expected.features.items():
        want = expected.episodes[episode][key][t]
        problems += _compare_value(item.get(key), want, ft, where=f"{where}[{key!r}]")
    return problems


def _compare_value(got: Any, want: np.ndarray, ft: dict, *, where: str) -> list[str]:
    """LeRobot gives float32 CHW images in [0, 1] (= uint8 / 255 exactly), 0-d tensors for shape [1]."""
    import torch

    if got is None:
        return [f"{where} is missing (None)"]
    if ft["dtype"] == "image":
        want_t = torch.from_numpy(np.ascontiguousarray(want)).permute(2, 0, 1).float().div(255)
        if tuple(got.shape) != tuple(want_t.shape) or got.dtype != torch.float32:
            return [f"{where}: image {got.dtype}{tuple(got.shape)}, expected float32{tuple(want_t.shape)}"]
        if not torch.equal(got, want_t):
            diff = (got - want_t).abs().max().item() * 255
            return [f"{where}: image differs from the recorded pixels (max |diff| {diff:.2f}/255)"]
        return []
    want_arr = np.asarray(want).reshape(tuple(ft["shape"]) if tuple(ft["shape"]) != (1,) else ())
    got_arr = got.numpy() if hasattr(got, "numpy") else np.asarray(got)
    if got_arr.shape != want_arr.shape:
        return [f"{where}: shape {got_arr.shape}, expected {want_arr.shape}"]
    if got_arr.dtype != np.dtype(ft["dtype"]):
        return [f"{where}: dtype {got_arr.dtype}, expected {ft['dtype']}"]
    if not np.array_equal(got_arr, want_arr):
        return [f"{where}: {got_arr.tolist()} != recorded {want_arr.tolist()}"]
    return []


def _check_tasks(ds: Any, expected: Expected) -> list[str]:
    problems = []
    tasks = ds.meta.tasks
    for task in sorted(set(expected.tasks)):
        if task not in tasks.index:
            problems.append(f"task {task!r} not in meta.tasks.index ({list(tasks.index)})")
    if list(tasks.columns) != ["task_index"]:
        problems.append(f"WARN: meta.tasks columns are {list(tasks.columns)}, LeRobot writes ['task_index']")
    for episode, start in enumerate(expected.starts):
        got = ds[start]["task"]
        if not isinstance(got, str):
            problems.append(f"ds[{start}]['task']={got!r} is a {type(got).__name__}, not the task string")
        elif got != expected.tasks[episode]:
            problems.append(f"ds[{start}]['task']={got!r} ({type(got).__name__}), expected {expected.tasks[episode]!r}")
    return problems


def _check_episodes(ds: Any, expected: Expected, recording: Recording | None) -> list[str]:
    episodes = ds.meta.episodes
    columns = set(episodes.column_names)
    problems = []
    lerobot_columns = {
        "episode_index",
        "tasks",
        "length",
        "data/chunk_index",
        "data/file_index",
        "dataset_from_index",
        "dataset_to_index",
        "meta/episodes/chunk_index",
        "meta/episodes/file_index",
    }
    if missing := sorted(lerobot_columns - columns):
        problems.append(f"WARN: episodes parquet lacks {missing} (LeRobot writes them; its tools use them)")
    if len(episodes) != len(expected.episodes):
        problems.append(f"meta.episodes has {len(episodes)} rows, expected {len(expected.episodes)}")
    for e, (start, length) in enumerate(zip(expected.starts, expected.lengths, strict=True)):
        if e >= len(episodes):
            break
        row = episodes[e]
        want = {"episode_index": e, "dataset_from_index": start, "dataset_to_index": start + length, "length": length}
        for key, value in want.items():
            if key in row and row[key] != value:
                problems.append(f"meta.episodes[{e}][{key!r}]={row[key]}, expected {value}")
        if "tasks" in row and row["tasks"] != [expected.tasks[e]]:
            problems.append(f"meta.episodes[{e}]['tasks']={row['tasks']}, expected {[expected.tasks[e]]}")
        problems += _check_data_file_of_episode(ds, e, start, length)
        if recording is not None:
            problems += _check_episode_extras(row, recording.episode_meta[e], e)
    if recording is not None and recording.episode_meta:
        if absent := [key for key in recording.episode_meta[0] if key not in columns]:
            problems.append(f"WARN: episode extras {absent} are not episodes-parquet columns")
    return problems


def _check_data_file_of_episode(ds: Any, e: int, start: int, length: int) -> list[str]:
    """data/chunk_index + data/file_index must name the file that holds the episode (hub downloads use them)."""
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    row = ds.meta.episodes[e]
    if "data/chunk_index" not in row or "data/file_index" not in row:
        return []
    path = ds.root / ds.meta.get_data_file_path(e)
    if not path.exists():
        return [f"meta.episodes[{e}] points to {path.relative_to(ds.root)}, which does not exist"]
    table = pq.read_table(path, columns=["episode_index", "index"])
    rows = table.filter(pc.equal(table["episode_index"], e))
    first = pc.min(rows["index"]).as_py() if rows.num_rows else None
    if rows.num_rows != length or first != start:
        return [
            f"{path.relative_to(ds.root)} holds {rows.num_rows} rows of episode {e} from index {first}, "
            f"expected {length} from {start}"
        ]
    return []


def _check_episode_extras(row: dict, meta: dict, e: int) -> list[str]:
    problems = []
    for key, value in meta.items():
        if key not in row:
            continue  # reported once for all episodes by the caller
        got = row[key]
        if isinstance(value, dict) and isinstance(got, str):
            got = json.loads(got)
        if got != value:
            problems.append(f"meta.episodes[{e}][{key!r}]={row[key]!r}, recorded {value!r}")
    return problems


def _check_stats(ds: Any, expected: Expected) -> list[str]:
    """Keys and shapes as LeRobot writes them; values against the recorded data; LeRobot's own aggregation."""
    from lerobot.datasets.compute_stats import aggregate_stats

    stats = ds.meta.stats
    if stats is None:
        return ["meta/stats.json is missing (policies normalise with it)"]
    problems = []
    for key, ft in expected.features.items():
        if key not in stats:
            problems.append(f"stats.json has no {key!r}")
            continue
        feature_stats = stats[key]
        if missing := [s for s in STAT_KEYS if s not in feature_stats]:
            problems.append(f"stats[{key!r}] lacks {missing}")
        data = np.concatenate([ep[key] for ep in expected.episodes]) if expected.episodes else None
        if ft["dtype"] == "image":
            problems += _check_image_stats(key, feature_stats, data)
        else:
            problems += _check_vector_stats(key, feature_stats, data, tuple(ft["shape"]))
    for key in DEFAULT_KEYS:
        if key not in stats:
            problems.append(f"WARN: stats.json has no {key!r} (LeRobot writes stats for the default columns too)")
    try:
        aggregate_stats([stats, stats])
    except Exception as error:  # LeRobot's validation when datasets are merged or appended to
        problems.append(f"lerobot aggregate_stats rejects stats.json: {type(error).__name__}: {error}")
    return problems


def _check_vector_stats(key: str, stats: dict, data: np.ndarray | None, shape: tuple) -> list[str]:
    problems = []
    for name, value in stats.items():
        want_shape = (1,) if name == "count" else shape
        if np.asarray(value).shape != want_shape:
            problems.append(f"stats[{key!r}][{name!r}] has shape {np.asarray(value).shape}, expected {want_shape}")
    if data is None or problems:
        return problems
    flat = data.reshape(len(data), -1).astype(np.float64)
    exact = {"min": flat.min(0), "max": flat.max(0), "mean": flat.mean(0), "std": flat.std(0)}
    for name, want in exact.items():
        if name in stats and not np.allclose(
            np.asarray(stats[name], np.float64).reshape(-1), want, rtol=1e-4, atol=1e-5
        ):
            problems.append(
                f"stats[{key!r}][{name!r}] differs from the data: max |diff| "
                f"{np.abs(np.asarray(stats[name], np.float64).reshape(-1) - want).max():.3g}"
            )
    if "count" in stats and int(np.asarray(stats["count"]).reshape(-1)[0]) != len(data):
        problems.append(f"stats[{key!r}]['count']={stats['count'].tolist()}, expected [{len(data)}]")
    return problems


def _check_image_stats(key: str, stats: dict, data: np.ndarray | None) -> list[str]:
    problems = []
    for name, value in stats.items():
        shape = np.asarray(value).shape
        if name != "count" and shape != (3, 1, 1):
            problems.append(f"stats[{key!r}][{name!r}] has shape {shape}, LeRobot needs (3, 1, 1)")
        elif name != "count" and not (0.0 <= np.min(value) and np.max(value) <= 1.0):
            problems.append(f"stats[{key!r}][{name!r}] is outside [0, 1]")
    if data is not None and not problems and "mean" in stats:
        channel_mean = data.reshape(-1, 3).mean(0) / 255.0
        got = np.asarray(stats["mean"]).reshape(3)
        # Writers (LeRobot's included) may compute image stats on a subsample of frames.
        if np.abs(got - channel_mean).max() > 0.02:
            problems.append(f"stats[{key!r}]['mean']={got.tolist()} far from the data's {channel_mean.tolist()}")
    return problems


def _check_policy_features(ds: Any, expected: Expected) -> list[str]:
    from lerobot.datasets.utils import dataset_to_policy_features

    policy_features = dataset_to_policy_features(ds.meta.features)
    problems = []
    for key, ft in expected.features.items():
        if ft["dtype"] == "image":
            h, w, c = ft["shape"]
            got = tuple(policy_features[key].shape)
            if got != (c, h, w):
                problems.append(
                    f"policy feature {key!r} has shape {got}, expected {(c, h, w)} (names must be {IMAGE_NAMES})"
                )
    for key in ("observation.state", "action"):
        if key not in policy_features:
            problems.append(f"{key!r} is not a policy feature")
    return problems


def _check_delta(dsd: Any, expected: Expected) -> list[str]:
    """At each episode's first, second, middle, second-to-last and last frame: clamped values and pad masks."""
    problems: list[str] = []
    offsets = {key: [round(d * expected.fps) for d in deltas] for key, deltas in DELTA_TIMESTAMPS.items()}
    for e, (start, length) in enumerate(zip(expected.starts, expected.lengths, strict=True)):
        for t in sorted({0, 1, length // 2, length - 2, length - 1}):
            if not 0 <= t < length:
                continue
            item = dsd[start + t]
            for key, deltas in offsets.items():
                pad_want = [not 0 <= t + d < length for d in deltas]
                pad_got = item.get(f"{key}_is_pad")
                if pad_got is None or pad_got.tolist() != pad_want:
                    problems.append(
                        f"dsd[{start + t}] (episode {e}, frame {t}) {key}_is_pad="
                        f"{None if pad_got is None else pad_got.tolist()}, expected {pad_want}"
                    )
                rows = [min(max(t + d, 0), length - 1) for d in deltas]
                want = expected.episodes[e][key][rows]
                got = item[key].numpy()
                if got.shape != want.shape or not np.array_equal(got, want):
                    problems.append(
                        f"dsd[{start + t}] (episode {e}, frame {t}) {key} is not frames {rows} of "
                        f"episode {e} clamped to it (shape {got.shape} vs {want.shape})"
                    )
            if len(problems) > 20:
                return [*problems, "... (stopped after 20 differences)"]
    return problems


def _check_dataloader(dsd: Any, expected: Expected) -> list[str]:
    import torch

    loader = torch.utils.data.DataLoader(dsd, batch_size=8, shuffle=True, num_workers=0)
    seen: list[int] = []
    problems = []
    state_size = expected.features["observation.state"]["shape"][0]
    n_actions = expected.features["action"]["shape"][0]
    for batch in loader:
        b = len(batch["index"])
        seen += batch["index"].tolist()
        shapes = {
            "observation.state": (b, 3, state_size),
            "action": (b, 2, n_actions),
            "observation.state_is_pad": (b, 3),
            "action_is_pad": (b, 2),
            "next.reward": (b,),
        }
        for key, ft in expected.features.items():
            if ft["dtype"] == "image":
                h, w, c = ft["shape"]
                shapes[key] = (b, c, h, w)
        for key, shape in shapes.items():
            if tuple(batch[key].shape) != shape:
                problems.append(f"batch[{key!r}] has shape {tuple(batch[key].shape)}, expected {shape}")
        if not all(isinstance(task, str) for task in batch["task"]):
            problems.append("batch['task'] holds non-strings")
        if problems:
            break
    if not problems and sorted(seen) != list(range(expected.total)):
        problems.append(
            f"one epoch yielded {len(seen)} frames / {len(set(seen))} distinct, expected "
            f"each of 0..{expected.total - 1} once"
        )
    return problems


def _check_episode_subset(dataset_cls: Any, repo_id: str, root: Path, expected: Expected) -> list[str]:
    subset = dataset_cls(repo_id=repo_id, root=root, episodes=[1])
    problems = []
    if len(subset) != expected.lengths[1]:
        problems.append(f"len(ds with episodes=[1])={len(subset)}, expected {expected.lengths[1]}")
    else:
        for t in (0, expected.lengths[1] - 1):
            problems += _compare_item(subset[t], expected, 1, t, where=f"subset[{t}]")
    return problems


# -- entry point ----------------------------------------------------------------------------------------------


def record_and_check(workdir: Path, *, episodes: int, steps: int, seed: int, max_items: int = 2000) -> Iterator[Report]:
    """Record the state-only and the pixel dataset under ``workdir`` and check each."""
    for name, pixels in (("navigation_state", False), ("navigation_pixels", True)):
        root = workdir / name
        try:
            recording = record_dataset(root, pixels=pixels, episodes=episodes, steps=steps, seed=seed)
        except Exception:
            report = Report(root)
            report.add("record with dpr.datasets.lerobot.LeRobotWriter", "FAIL", traceback.format_exc())
            yield report
            continue
        yield check_dataset(root, recording, max_items=max_items)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("datasets", nargs="*", type=Path, help="dataset folders to check (default: record two)")
    parser.add_argument("--episodes", type=int, default=3)
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--keep", type=Path, default=None, help="record into this (new) folder and keep it")
    parser.add_argument("--max-items", type=int, default=2000, help="compare every frame up to this many")
    args = parser.parse_args(argv)
    if args.episodes < 2 or args.steps < 3:
        parser.error("--episodes must be >= 2 and --steps >= 3 (the boundary checks need them)")
    for path in args.datasets:
        if not (path / "meta" / "info.json").is_file():
            parser.error(f"{path}: not a LeRobot dataset folder (no meta/info.json)")

    with tempfile.TemporaryDirectory(prefix="check_lerobot_") as tmp:
        prepare_environment(Path(tmp) / "hf-cache")
        if not lerobot_available():
            print("FAIL: lerobot is not importable with this python; see the top of this file", file=sys.stderr)
            return 1
        make_torchvision_importable()
        if args.datasets:
            reports = [check_dataset(path, max_items=args.max_items) for path in args.datasets]
        else:
            workdir = args.keep if args.keep is not None else Path(tmp) / "datasets"
            workdir.mkdir(parents=True, exist_ok=True)
            reports = list(
                record_and_check(
                    workdir, episodes=args.episodes, steps=args.steps, seed=args.seed, max_items=args.max_items
                )
            )
        for report in reports:
            print(report.format())
        ok = all(r.ok for r in reports)
        print("OVERALL: PASS" if ok else "OVERALL: FAIL")
        return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
