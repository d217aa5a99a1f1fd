"""The four tasks: their classes and registered Gymnasium ids (registered by ``dpr.envs``)."""

from dpr.envs.gate import GateEnv
from dpr.envs.manipulation import ManipulationEnv
from dpr.envs.navigation import NavigationEnv
from dpr.envs.unresponsive import UnresponsiveEnv

TASK_CLASSES = {
    "navigation": NavigationEnv,
    "gate": GateEnv,
    "unresponsive": UnresponsiveEnv,
    "manipulation": ManipulationEnv,
}
VERSIONS = {"gate": 1}  # each task's current version, where it is not 0
ENV_IDS = {  # each task's current id: "gate" -> "dpr/Gate-v1"
    task: f"dpr/{cls.__name__.removesuffix('Env')}-v{VERSIONS.get(task, 0)}" for task, cls in TASK_CLASSES.items()
}
# Earlier versions, still registered for the datasets, models and records made on them: id -> (task, the kwargs
# that give its dynamics)
EARLIER_ENV_IDS = {"dpr/Gate-v0": ("gate", {"gate_distance": None})}
# every registered id -> its task: "dpr/Gate-v0" -> "gate", "dpr/Gate-v1" -> "gate"
TASKS = {**{env_id: task for task, env_id in ENV_IDS.items()}, **{i: t for i, (t, _) in EARLIER_ENV_IDS.items()}}
