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
ENV_IDS = {task: f"dpr/{cls.__name__.removesuffix('Env')}-v0" for task, cls in TASK_CLASSES.items()}
TASKS = {env_id: task for task, env_id in ENV_IDS.items()}  # the inverse: "dpr/Gate-v0" -> "gate"
