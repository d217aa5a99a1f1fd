"""Imitation learning: behaviour cloning of recorded demonstrations into the SB3 policy that RL fine-tunes, and
per-robot cloning into one policy that every robot of any swarm size runs (:mod:`dpr.imitation.per_robot`); their
settings are the checked dataclasses of :mod:`dpr.imitation.config`."""

from dpr.imitation.bc import BCResult, behaviour_clone
from dpr.imitation.config import CloneConfig, DaggerConfig, PerRobotCloneConfig
from dpr.imitation.per_robot import behaviour_clone_per_robot

__all__ = [
    "BCResult",
    "CloneConfig",
    "DaggerConfig",
    "PerRobotCloneConfig",
    "behaviour_clone",
    "behaviour_clone_per_robot",
]
