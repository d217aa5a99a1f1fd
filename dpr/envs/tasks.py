"""The tasks: their classes and registered Gymnasium ids, the four of ``dpr`` and any a user's package adds.

A task is a subclass of :class:`~dpr.envs.particle_env.ParticleSwarmEnv` (its hooks: walls, dead robots, an object,
the start's clearance, per-step measures) registered with :func:`register_task`, which gives it a Gymnasium id and
makes every ``dpr`` command, the pipeline and the policies see it. A package of tasks registers them when it is
imported; ``dpr --env-package PKG`` (or ``DPR_ENV_PACKAGES=PKG``) imports it in every process (docs/add-a-task.md).
"""

from __future__ import annotations

import importlib
import os
import re

from gymnasium.envs.registration import register, registry

from dpr.envs.gate import GateEnv
from dpr.envs.manipulation import ManipulationEnv
from dpr.envs.navigation import NavigationEnv
from dpr.envs.particle_env import MAX_EPISODE_STEPS, ParticleSwarmEnv
from dpr.envs.unresponsive import UnresponsiveEnv

TASK_CLASSES: dict[str, type[ParticleSwarmEnv]] = {  # task name -> class; register_task adds to it
    "navigation": NavigationEnv,
    "gate": GateEnv,
    "unresponsive": UnresponsiveEnv,
    "manipulation": ManipulationEnv,
}
BUILT_IN_TASKS = tuple(TASK_CLASSES)
VERSIONS = {"gate": 2}  # each built-in task's current version, where it is not 0
ENV_IDS = {  # each task's current id: "gate" -> "dpr/Gate-v2"
    task: f"dpr/{cls.__name__.removesuffix('Env')}-v{VERSIONS.get(task, 0)}" for task, cls in TASK_CLASSES.items()
}
# Earlier versions, still registered for the datasets, models and records made on them: id -> (task, the kwargs
# that give its dynamics)
EARLIER_ENV_IDS = {
    "dpr/Gate-v0": ("gate", {"gate_distance": None, "observe_opening": False}),
    "dpr/Gate-v1": ("gate", {"observe_opening": False}),
}
# every registered id -> its task: "dpr/Gate-v0" -> "gate", "dpr/Gate-v2" -> "gate"
TASKS = {**{env_id: task for task, env_id in ENV_IDS.items()}, **{i: t for i, (t, _) in EARLIER_ENV_IDS.items()}}
# task -> its vector env on the batched disk engine (gymnasium.make_vec's vector_entry_point), named as a string so
# that torch loads only when a batched env is made (dpr.envs.batched)
VECTOR_ENTRY_POINTS = {
    task: f"dpr.envs.batched:{cls.__name__.removesuffix('Env')}VectorEnv" for task, cls in TASK_CLASSES.items()
}
# env id -> the env id whose entry of the algorithms' hyperparameter files its learners use (a user's task has
# none of its own)
HYPERPARAMS_OF: dict[str, str] = {}

ENV_PACKAGES_VARIABLE = "DPR_ENV_PACKAGES"  # comma-separated packages that register tasks, imported by dpr.envs
TASK_NAME = re.compile(r"[a-z][a-z0-9_]*")


def register_task(
    task: str, cls: type[ParticleSwarmEnv], env_id: str, hyperparams_from: str = ENV_IDS["navigation"]
) -> None:
    """Add ``cls`` as the task ``task`` (a lower-case name: ``--tasks``, file and model names) under the Gymnasium
    id ``env_id`` (``"namespace/Name-vN"``, registered here with ``max_episode_steps=MAX_EPISODE_STEPS``). Its
    learners start from the hyperparameters of ``hyperparams_from`` (a built-in id) in ``dpr/rl/hyperparams/``.
    Registering the same task, class and id again does nothing (a package imported twice); anything else that
    is taken is a ValueError."""
    if not (isinstance(cls, type) and issubclass(cls, ParticleSwarmEnv)):
        raise TypeError(f"register_task({task!r}): expected a subclass of ParticleSwarmEnv, got {cls!r}")
    if not isinstance(task, str) or not TASK_NAME.fullmatch(task):
        raise ValueError(f"register_task: the task name must be lower case letters, digits and _, got {task!r}")
    if TASK_CLASSES.get(task) is cls and ENV_IDS.get(task) == env_id:
        return
    if task in TASK_CLASSES:
        raise ValueError(f"register_task: the task {task!r} is taken (by {TASK_CLASSES[task].__name__})")
    if env_id in TASKS or env_id in registry:
        raise ValueError(f"register_task({task!r}): the env id {env_id!r} is registered already")
    if TASKS.get(hyperparams_from) not in BUILT_IN_TASKS:
        built_in = [ENV_IDS[name] for name in BUILT_IN_TASKS]
        raise ValueError(
            f"register_task({task!r}): hyperparams_from must be one of {built_in}, got {hyperparams_from!r}"
        )
    if cls.task != task:
        raise ValueError(f"register_task({task!r}): {cls.__name__}.task is {cls.task!r}; set it to {task!r}")
    register(id=env_id, entry_point=cls, max_episode_steps=MAX_EPISODE_STEPS)
    TASK_CLASSES[task] = cls
    ENV_IDS[task] = env_id
    TASKS[env_id] = task
    HYPERPARAMS_OF[env_id] = hyperparams_from


def load_env_packages(packages: list[str] | tuple[str, ...]) -> None:
    """Import each package (whose import registers its tasks), and name them in ``DPR_ENV_PACKAGES`` so that the
    processes this one starts (env workers, Ray tasks) import them too. Importing a package runs its code, with the
    rights of whoever runs dpr. A ValueError names a package that does not import, or whose import raises, and
    the error it raised (its own code's, not a traceback)."""
    listed = [name for name in os.environ.get(ENV_PACKAGES_VARIABLE, "").split(",") if name]
    for package in packages:
        try:
            importlib.import_module(package)
        except ImportError as error:
            raise ValueError(f"env package {package!r} does not import: {error}") from None
        except (Exception, SystemExit) as error:  # the package's own code failed: named, not a traceback
            raise ValueError(
                f"env package {package!r} does not import: its code raised {type(error).__name__}: {error}"
            ) from None
        if package not in listed:
            listed.append(package)
    if listed:
        os.environ[ENV_PACKAGES_VARIABLE] = ",".join(listed)


# what importing the packages DPR_ENV_PACKAGES names raised when dpr.envs was imported (the `dpr` command reports it)
ENV_PACKAGE_ERRORS: list[str] = []


def load_listed_env_packages() -> None:
    """Import the packages ``DPR_ENV_PACKAGES`` names (done when ``dpr.envs`` is imported). One that fails is left
    out and its error kept in :data:`ENV_PACKAGE_ERRORS`, so that ``import dpr`` itself never fails on it: the
    `dpr` command refuses to run with it, naming the variable, and its tasks' ids stay unknown elsewhere."""
    listed = [name.strip() for name in os.environ.get(ENV_PACKAGES_VARIABLE, "").split(",") if name.strip()]
    for package in listed:
        try:
            load_env_packages([package])
        except ValueError as error:
            ENV_PACKAGE_ERRORS.append(str(error))
