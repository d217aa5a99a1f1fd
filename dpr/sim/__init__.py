"""Particle-robot physics on pymunk (no gymnasium here).

``World`` holds one swarm of either robot model (``"paddle"``: the paper's robot; ``"disk"``: a fast
single-body model), optional static walls and an optional object, and steps them at the 10 Hz control rate.
"""

from dpr.sim.models import ROBOT_MODELS, register_robot_model, swarm_class
from dpr.sim.swarm import Swarm
from dpr.sim.world import ObjectSpec, World, grid_centres

__all__ = ["ROBOT_MODELS", "ObjectSpec", "Swarm", "World", "grid_centres", "register_robot_model", "swarm_class"]
