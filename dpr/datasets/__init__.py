"""Recorded swarm data: LeRobot v3.0 datasets (:mod:`dpr.datasets.lerobot`) and MCAP logs (:mod:`dpr.datasets.mcap`)."""

from dpr.datasets.lerobot import (
    CODEBASE_VERSION,
    DatasetError,
    LeRobotReader,
    LeRobotWriter,
    default_features,
    repair,
)

__all__ = ["CODEBASE_VERSION", "DatasetError", "LeRobotReader", "LeRobotWriter", "default_features", "repair"]
