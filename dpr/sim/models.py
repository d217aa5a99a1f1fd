"""The robot-model registry: each robot model's name and its :class:`~dpr.sim.swarm.Swarm` subclass.

It lives apart from :mod:`dpr.sim.swarm` so that the base class never imports its subclasses: ``swarm`` <-
``paddle``, ``disk`` <- ``models`` <- ``world``, with no import circle.
"""

from __future__ import annotations

from dpr.checks import check_choice
from dpr.sim.disk import DiskSwarm
from dpr.sim.paddle import PaddleSwarm
from dpr.sim.swarm import Swarm

_SWARM_CLASSES: dict[str, type[Swarm]] = {cls.model: cls for cls in (PaddleSwarm, DiskSwarm)}
ROBOT_MODELS = tuple(_SWARM_CLASSES)  # ("paddle", "disk")


def swarm_class(model: str) -> type[Swarm]:
    """The Swarm subclass of a robot model name; :class:`~dpr.checks.ParameterError` (a ValueError) for
    ``robot_model`` names the allowed ones."""
    check_choice("robot_model", model, ROBOT_MODELS)
    return _SWARM_CLASSES[model]
