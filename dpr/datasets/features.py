"""The names shared by everything that writes or reads a dpr dataset: feature keys and episode-meta fields.

Feature keys follow LeRobot's conventions (``observation.state``, ``observation.environment_state``, ``action``,
``next.*``). Every episode's meta row carries the fields in :data:`EPISODE_META_FIELDS`, written by
:func:`dpr.datasets.collect.save_record`. :func:`dataset_features` gives the features of a dpr env's dataset.
"""

OBSERVATION = "observation.state"
# what the env knows beyond each robot's own state (ParticleSwarmEnv.environment_state): LeRobot's FeatureType.ENV,
# which its ACT and Diffusion Policy need when a dataset has no image. Datasets recorded before it lack it.
ENVIRONMENT_STATE = "observation.environment_state"
IMAGE = "observation.image"
ACTION = "action"
REWARD = "next.reward"
DONE = "next.done"
SUCCESS = "next.success"

# Episode-meta fields (columns of meta/episodes/*.parquet beside LeRobot's own).
SEED = "seed"
ENV_ID = "env_id"
ENV_KWARGS = "env_kwargs"
POLICY = "policy"
LABEL_POLICY = "label_policy"
ROBOT_MODEL_REVISION = "robot_model_revision"
DATASET_REVISION = "dataset_revision"  # info.json's dpr object: how the dataset records time (dpr.datasets.timing)
N_ROBOTS = "n_robots"
ROBOT_MODEL = "robot_model"
PHYSICS_ERROR = "physics_error"
MCAP_FILE = "mcap_file"
METRIC_FIELDS = ("projected_displacement", "net_displacement", "total_distance", "success")
EPISODE_META_FIELDS = (
    SEED,
    ENV_ID,
    ENV_KWARGS,
    POLICY,
    LABEL_POLICY,
    N_ROBOTS,
    ROBOT_MODEL,
    *METRIC_FIELDS,
    PHYSICS_ERROR,
    MCAP_FILE,
)


def dataset_features(env, pixels: bool = False, image_size: int = 96) -> dict[str, dict]:
    """LeRobot features for ``env``'s state observation and action (named per robot), its environment state (named
    by ``environment_state_names``), rewards and flags (``env``: a dpr env made with ``obs_type="state"``, wrapped
    or not), and the image with ``pixels``."""
    base = env.unwrapped
    if base.obs_type != "state":
        raise ValueError(
            f"datasets record the state observation; make the env with obs_type='state', got {base.obs_type!r}"
        )
    n = base.n_robots
    state_names = base.state_names
    if base.action_type == "discrete":
        action = {"dtype": "int64", "shape": [1], "names": ["action"]}
    else:
        action = {"dtype": "float32", "shape": [n], "names": [f"robot{i}.expand" for i in range(n)]}
    environment_names = base.environment_state_names
    features = {
        OBSERVATION: {"dtype": "float32", "shape": [len(state_names)], "names": state_names},
        ENVIRONMENT_STATE: {"dtype": "float32", "shape": [len(environment_names)], "names": environment_names},
        ACTION: action,
        REWARD: {"dtype": "float32", "shape": [1], "names": None},
        DONE: {"dtype": "bool", "shape": [1], "names": None},
        SUCCESS: {"dtype": "bool", "shape": [1], "names": None},
    }
    if pixels:
        features[IMAGE] = {
            "dtype": "image",
            "shape": [image_size, image_size, 3],
            "names": ["height", "width", "channels"],
        }
    return features
