"""Simulated time in a dpr dataset: its ``fps`` is the decision rate, one frame per env step.

An env made with ``action_repeat=k`` decides once per k physics steps of 0.1 s, so its dataset records
``fps = 10 / k`` (:func:`dpr.envs.particle_env.steps_per_second`: 10, 5, 2, 1 for k = 1, 2, 5, 10; a float such as
10/6 otherwise, which LeRobot's loader takes: docs/datasets.md) and timestamps ``frame_index / fps``, k x 0.1 s
apart. Datasets recorded with ``action_repeat > 1`` carry ``dataset_revision`` 2 in info.json's ``dpr`` object.
Earlier ones (no revision: 1) recorded fps 10 and timestamps 0.1 s apart whatever ``action_repeat`` was; they are
named by :func:`check_dataset_time` and are not resumed. A dataset with ``action_repeat = 1`` is the same in both
revisions and records none.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from dpr.datasets import features as F
from dpr.datasets.lerobot import DatasetError
from dpr.envs.particle_env import action_repeat, seconds_per_step, steps_per_second

DATASET_REVISION = 2  # fps is the decision rate (revision 1: fps 10 whatever action_repeat was)
DPR_INFO_KEY = "dpr"  # info.json's object of what dpr collect recorded (env id, kwargs, policy, ...)


def dataset_fps(env_kwargs: Mapping[str, Any] | None) -> int | float:
    """The ``fps`` of a dataset of an env made with ``env_kwargs``: its env steps per simulated second."""
    return steps_per_second(dict(env_kwargs or {}))


def time_info(env_kwargs: Mapping[str, Any] | None) -> dict[str, int]:
    """What info.json's ``dpr`` object records of the dataset's time: ``dataset_revision`` where the revisions
    differ (``action_repeat > 1``), else nothing (so that datasets of one decision per step resume unchanged)."""
    return {F.DATASET_REVISION: DATASET_REVISION} if action_repeat(dict(env_kwargs or {})) > 1 else {}


def time_problem(info: Mapping[str, Any]) -> str | None:
    """What is wrong with the time a dataset's info.json records, or None: the ``fps`` of a dataset recorded by
    ``dpr collect`` must be its env's decision rate. A dataset of another writer (no ``dpr`` object) is not judged."""
    recorded = info.get(DPR_INFO_KEY)
    if not isinstance(recorded, Mapping) or not isinstance(recorded.get(F.ENV_KWARGS), Mapping):
        return None
    kwargs = dict(recorded[F.ENV_KWARGS])
    try:
        expected = dataset_fps(kwargs)
    except ValueError as error:
        return f"its env_kwargs hold a bad action_repeat ({error})"
    fps = info.get("fps")
    if fps == expected:
        return None
    repeat = action_repeat(kwargs)
    seconds = seconds_per_step(kwargs)
    said = f"recorded with action_repeat={repeat} (a frame every {repeat} physics steps, {seconds:g} s)"
    if recorded.get(F.DATASET_REVISION) is None and fps == steps_per_second():
        return (
            f"{said} but meta/info.json says fps {fps} and its timestamps are 0.1 s apart: it was written before "
            f"dpr recorded simulated time (dataset revision 1), so LeRobot's delta_timestamps pick frames {repeat}x "
            f"too far apart (the right fps is {expected:g})"
        )
    return f"{said} but meta/info.json says fps {fps!r}, not its decision rate {expected:g}"


def check_dataset_time(root: str | Path, info: Mapping[str, Any]) -> None:
    """A :class:`DatasetError` naming ``root`` when the time its ``info`` records is wrong (:func:`time_problem`),
    saying what to do: record it again into a new folder."""
    problem = time_problem(info)
    if problem is not None:
        raise DatasetError(
            f"{root}: {problem}. Record it again into a new folder (the same dpr collect command with another "
            "--out); this one cannot be resumed. Its frames themselves are sound: dpr bc still reads them"
        )
