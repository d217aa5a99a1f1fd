"""The robot-model registry: each robot model's name and its :class:`~dpr.sim.swarm.Swarm` subclass, the two
built-in ones and any a package adds with :func:`register_robot_model` (docs/add-a-robot-model.md).

It lives apart from :mod:`dpr.sim.swarm` so that the base class never imports its subclasses: ``swarm`` <-
``paddle``, ``disk`` <- ``models`` <- ``world``, with no import circle.
"""

from __future__ import annotations

from dpr.checks import check_choice
from dpr.sim.disk import DiskSwarm
from dpr.sim.paddle import PaddleSwarm
from dpr.sim.swarm import Swarm

_SWARM_CLASSES: dict[str, type[Swarm]] = {cls.model: cls for cls in (PaddleSwarm, DiskSwarm)}
# ["paddle", "disk"] and the models a package adds (register_robot_model): one list, so that every holder of it
# (argument choices, checks) sees them
ROBOT_MODELS: list[str] = list(_SWARM_CLASSES)


def register_robot_model(cls: type[Swarm]) -> None:
    """Add ``cls`` (a :class:`~dpr.sim.swarm.Swarm` subclass) as the robot model ``cls.model``, which every env
    (``robot_model=``), command (``--robot-model``) and wave policy then takes. Registering the same class again
    does nothing (a package imported twice); a taken or empty name is a ValueError."""
    if not (isinstance(cls, type) and issubclass(cls, Swarm)):
        raise TypeError(f"register_robot_model: expected a subclass of dpr.sim.swarm.Swarm, got {cls!r}")
    if _SWARM_CLASSES.get(cls.model) is cls:
        return
    if not isinstance(cls.model, str) or not cls.model:
        raise ValueError(f"register_robot_model: {cls.__name__}.model must name the robot model, got {cls.model!r}")
    if cls.model in _SWARM_CLASSES:
        raise ValueError(f"register_robot_model: the robot model {cls.model!r} is taken")
    _SWARM_CLASSES[cls.model] = cls
    ROBOT_MODELS.append(cls.model)


def swarm_class(model: str) -> type[Swarm]:
    """The Swarm subclass of a robot model name; :class:`~dpr.checks.ParameterError` (a ValueError) for
    ``robot_model`` names the allowed ones."""
    check_choice("robot_model", model, ROBOT_MODELS)
    return _SWARM_CLASSES[model]
