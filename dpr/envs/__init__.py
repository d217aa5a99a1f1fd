"""Gymnasium environments of the particle-robot tasks.

``import dpr`` registers ``dpr/Navigation-v0``, ``dpr/Gate-v2``, ``dpr/Unresponsive-v0`` and
``dpr/Manipulation-v0`` (each ``max_episode_steps=MAX_EPISODE_STEPS``), and the gate's earlier versions:
``dpr/Gate-v0``, the paper's placement, which the swarm does not reach in an episode, and ``dpr/Gate-v1``, whose
state does not hold the opening. Each id's ``vector_entry_point`` is the batched disk engine
(``gymnasium.make_vec(env_id, num_envs=K, vectorization_mode="vector_entry_point", robot_model="disk")``,
:mod:`dpr.envs.batched`, imported only then: it needs torch). Tasks of other packages come in through
:func:`register_task`; the packages that ``DPR_ENV_PACKAGES`` names are imported last (``dpr --env-package``).
"""

from gymnasium.envs.registration import register, registry

from dpr.envs.gate import GateEnv
from dpr.envs.manipulation import ManipulationEnv
from dpr.envs.navigation import NavigationEnv
from dpr.envs.parallel import parallel_env
from dpr.envs.particle_env import (
    ACTION_TYPES,
    AGENT_POSITION,
    MAX_EPISODE_STEPS,
    OBS_TYPES,
    PHYSICS_ERROR,
    REWARDS,
    ParticleSwarmEnv,
    episode_steps,
)
from dpr.envs.tasks import (
    BUILT_IN_TASKS,
    EARLIER_ENV_IDS,
    ENV_IDS,
    TASK_CLASSES,
    TASKS,
    VECTOR_ENTRY_POINTS,
    load_env_packages,
    load_listed_env_packages,
    register_task,
)
from dpr.envs.unresponsive import UnresponsiveEnv

for _env_id, _task in TASKS.items():
    _cls = TASK_CLASSES[_task]
    if _env_id not in registry:
        register(
            id=_env_id,
            entry_point=f"{_cls.__module__}:{_cls.__name__}",
            max_episode_steps=MAX_EPISODE_STEPS,
            kwargs=EARLIER_ENV_IDS.get(_env_id, (_task, {}))[1],
            vector_entry_point=VECTOR_ENTRY_POINTS[_task],
        )

__all__ = [
    "ACTION_TYPES",
    "AGENT_POSITION",
    "BUILT_IN_TASKS",
    "EARLIER_ENV_IDS",
    "ENV_IDS",
    "MAX_EPISODE_STEPS",
    "OBS_TYPES",
    "PHYSICS_ERROR",
    "REWARDS",
    "TASKS",
    "TASK_CLASSES",
    "VECTOR_ENTRY_POINTS",
    "GateEnv",
    "ManipulationEnv",
    "NavigationEnv",
    "ParticleSwarmEnv",
    "UnresponsiveEnv",
    "episode_steps",
    "load_env_packages",
    "parallel_env",
    "register_task",
]

load_listed_env_packages()  # last: a package of tasks imports its base class and register_task from here
