"""Deep Particle Robot: particle-robot swarms as Gymnasium tasks, demonstrations and learned policies.

``import dpr`` registers the Gymnasium ids ``dpr/Navigation-v0``, ``dpr/Gate-v2``, ``dpr/Unresponsive-v0``
and ``dpr/Manipulation-v0`` (and the gate's earlier versions: ``dpr/Gate-v0`` at the paper's placement,
``dpr/Gate-v1`` without the opening in the observation).
"""

from dpr import envs as envs  # registers the Gymnasium ids

__version__ = "0.1.0"
