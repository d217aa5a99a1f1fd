"""Gymnasium environments of the particle-robot tasks.

``import dpr`` registers ``dpr/Navigation-v0``, ``dpr/Gate-v0``, ``dpr/Unresponsive-v0`` and
``dpr/Manipulation-v0`` (each ``max_episode_steps=2500``).
"""

from gymnasium.envs.registration import register, registry

from dpr.envs.gate import GateEnv
from dpr.envs.manipulation import ManipulationEnv
from dpr.envs.navigation import NavigationEnv
from dpr.envs.parallel import parallel_env
from dpr.envs.particle_env import ACTION_TYPES, OBS_TYPES, REWARDS, ParticleSwarmEnv
from dpr.envs.unresponsive import UnresponsiveEnv

MAX_EPISODE_STEPS = 2500
TASK_CLASSES = {
    "navigation": NavigationEnv,
    "gate": GateEnv,
    "unresponsive": UnresponsiveEnv,
    "manipulation": ManipulationEnv,
}
ENV_IDS = {task: f"dpr/{cls.__name__.removesuffix('Env')}-v0" for task, cls in TASK_CLASSES.items()}

for _task, _cls in TASK_CLASSES.items():
    if ENV_IDS[_task] not in registry:
        register(
            id=ENV_IDS[_task],
            entry_point=f"{_cls.__module__}:{_cls.__name__}",
            max_episode_steps=MAX_EPISODE_STEPS,
        )

__all__ = [
    "ACTION_TYPES",
    "ENV_IDS",
    "MAX_EPISODE_STEPS",
    "OBS_TYPES",
    "REWARDS",
    "TASK_CLASSES",
    "GateEnv",
    "ManipulationEnv",
    "NavigationEnv",
    "ParticleSwarmEnv",
    "UnresponsiveEnv",
    "parallel_env",
]
