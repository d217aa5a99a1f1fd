"""A robot model defined outside dpr: the disk robot with magnets that reach 120 units instead of 100.

Importing this module registers it as the robot model ``disk-long-magnets``; every env, command and wave policy
takes it (``robot_model="disk-long-magnets"``, ``--robot-model disk-long-magnets``) with
``dpr --env-package long_magnet_disk`` when this folder is on the Python path. docs/add-a-robot-model.md walks
through it.
"""

from dpr.sim import register_robot_model
from dpr.sim.disk import DiskSwarm


class LongMagnetDiskSwarm(DiskSwarm):
    """The disk model (``dpr.sim.disk.DiskSwarm``) whose magnets tie robots whose centres are closer than 120
    units: on the start grid (pitch 77.5) a robot is then tied to its diagonal neighbours (109.6 away) as well as
    to the four beside it, and the swarm holds together more stiffly. Everything else is the disk model's: bodies,
    growth, friction, the command rule, and the wave that moves it (held 4 steps, from the side nearest the goal)."""

    model = "disk-long-magnets"
    revision = 1  # raise it whenever this model's physics change: datasets record it
    magnet_range = 120.0


register_robot_model(LongMagnetDiskSwarm)
