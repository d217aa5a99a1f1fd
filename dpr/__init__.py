"""Deep Particle Robot: particle-robot swarms as Gymnasium tasks, demonstrations and learned policies.

``import dpr`` registers the Gymnasium ids ``dpr/Navigation-v0``, ``dpr/Gate-v1``, ``dpr/Unresponsive-v0``
and ``dpr/Manipulation-v0`` (and ``dpr/Gate-v0``, the gate at the paper's placement).
"""

from dpr import envs as envs  # registers the Gymnasium ids

__version__ = "0.1.0"
