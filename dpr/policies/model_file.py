"""A model file: SB3's zip plus the dpr_env.json member that says how the model was trained.

That member, :data:`METADATA_MEMBER`, names the algorithm, the env id and the env kwargs the model was trained
with, so that a model can be evaluated or rolled out without restating them, and the network it was built with, so
that fine-tuning builds the same. A per-robot model (one robot's local observation in, that robot's action out, for
any swarm size; :mod:`dpr.policies.per_robot_spec`) also carries its local-observation layout there.
Reading and writing it needs neither stable-baselines3 nor torch, and this module imports neither: checking a
``--policy`` argument or the env kwargs a model runs with costs nothing. Loading and saving the model itself is
:mod:`dpr.policies.sb3`'s.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from dpr.bounded_io import read_zip_member, stream_zip_member
from dpr.checks import ParameterError
from dpr.limits import MAX_MODEL_JSON_BYTES, MAX_MODEL_MEMBER_BYTES

MODEL_SUFFIX = ".zip"
METADATA_MEMBER = "dpr_env.json"
METADATA_FORMAT = 1
PPO, A2C, DQN = "ppo", "a2c", "dqn"
ALGOS = (PPO, A2C, DQN)  # the SB3 algorithms a model file may hold (`dpr train`)
# A hyperparameter entry's `policy`: SB3's own names, or the shared per-robot actor (dpr.policies.swarm_policy).
SWARM_POLICY = "SwarmPolicy"
SWARM_POLICY_MODULE = "dpr.policies.swarm_policy"  # where it is defined, as a model file names it
# The parameter that names a model file in evaluate and collect: what a bad model file is reported as by default.
POLICY_PARAMETER = "policy"
# Env kwargs whose value decides the observation or action space: a different value can never run the model.
SPACE_KWARGS = ("n_robots", "action_type", "obs_type", "obs_last_action", "image_size")
# Env kwargs a centralised model may be run with otherwise than it was trained: the two robot models make the same
# observation and action spaces (sim-to-sim transfer, e.g. from the faster disk model to the paddle model).
TRANSFERABLE_KWARGS = ("robot_model",)


def is_model_path(name: str) -> bool:
    """Whether a policy name (``--policy``) is a model file rather than a scripted policy."""
    return name.endswith(MODEL_SUFFIX)


@dataclass(frozen=True)
class ModelInfo:
    """What a model file says about how it was trained (the :data:`METADATA_MEMBER` of its zip)."""

    algo: str
    env_id: str
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    max_episode_steps: int | None = None
    # A per-robot model's layout and training swarm (dpr.policies.per_robot_spec.RobotModelSpec as data);
    # None for a model of the centralised env, whose observation is the whole swarm's state.
    per_robot: dict[str, Any] | None = None
    # The network it was built with, as its yaml entry says it (:func:`model_architecture`): what a fine-tuning run
    # must build to load its weights. None in files written before it was recorded, and in per-robot models.
    architecture: dict[str, Any] | None = None

    def as_json(self) -> str:
        data = asdict(self)
        for name in ("per_robot", "architecture"):  # files without them stay as they were
            if data[name] is None:
                del data[name]
        return json.dumps({"format": METADATA_FORMAT, **data}, indent=2, sort_keys=True)


def model_architecture(hyper) -> dict[str, Any]:
    """The network that ``hyper`` (a :class:`dpr.policies.hyperparams.Hyperparams`) builds, in yaml form:
    ``{"policy": "SwarmPolicy", "policy_kwargs": {...}}`` (the entry's policy name and its policy_kwargs, {} when it
    sets none): :attr:`ModelInfo.architecture`, and the hyperparameter overrides that build it again."""
    return {"policy": str(hyper.policy), "policy_kwargs": dict(hyper.algo_kwargs.get("policy_kwargs") or {})}


def _checked_architecture(value: Any) -> dict[str, Any] | None:
    """``value`` as :attr:`ModelInfo.architecture` (None when absent); a ValueError saying what is wrong with it."""
    if value is None:
        return None
    if (
        not isinstance(value, dict)
        or set(value) != {"policy", "policy_kwargs"}
        or not isinstance(value["policy"], str)
        or not isinstance(value["policy_kwargs"], dict)
    ):
        raise ValueError(f"architecture must be a mapping of a policy name and its policy_kwargs, got {value!r}")
    return {"policy": value["policy"], "policy_kwargs": dict(value["policy_kwargs"])}


def write_model_info(path: str | Path, info: ModelInfo) -> None:
    """Append ``info`` to the SB3 zip at ``path`` (SB3's loader ignores members it does not know)."""
    if info.algo not in ALGOS:  # checked before anything is written
        raise ValueError(f"algo must be one of {ALGOS}, got {info.algo!r}")
    with zipfile.ZipFile(path, "a") as archive:
        if METADATA_MEMBER in archive.namelist():
            raise ValueError(f"{path} already holds {METADATA_MEMBER}; save the model to a new file first")
        archive.writestr(METADATA_MEMBER, info.as_json())


def model_member_limit(name: str) -> int | None:
    """The most bytes dpr or stable-baselines3 reads of the model zip member ``name`` (None: never read)."""
    if name in ("data", METADATA_MEMBER, "_stable_baselines3_version"):
        return MAX_MODEL_JSON_BYTES
    return MAX_MODEL_MEMBER_BYTES if name.endswith(".pth") else None


def check_model_members(archive: zipfile.ZipFile, path: str | Path, parameter: str, *, stream: bool = False) -> None:
    """A :class:`ParameterError` about ``parameter`` when a member of the model zip that is read declares more bytes
    than :func:`model_member_limit`; with ``stream``, each is also read through (a chunk at a time) to check that it
    inflates to what it declares, and its CRC, before stable-baselines3 reads it whole."""
    for info in archive.infolist():
        limit = model_member_limit(info.filename)
        if limit is None:
            continue
        if stream:
            for _ in stream_zip_member(archive, info.filename, limit, path, parameter):
                pass
        elif info.file_size > limit:
            raise ParameterError(
                parameter, f"{path}: its member {info.filename!r} declares {info.file_size} bytes, more than {limit}"
            )


def read_model_info(path: str | Path, parameter: str = POLICY_PARAMETER) -> ModelInfo:
    """The :class:`ModelInfo` of the model file at ``path``; a :class:`ParameterError` about ``parameter`` (the
    caller's parameter that named the file) when the file is missing, not a zip, or not a ``dpr train`` model."""
    path = Path(path)
    if not path.is_file():
        raise ParameterError(parameter, f"no model file at {path}")
    try:
        with zipfile.ZipFile(path) as archive:
            names = archive.namelist()
            if "data" not in names:
                raise ParameterError(parameter, f"{path} is a zip but not a stable-baselines3 model (no 'data' member)")
            if METADATA_MEMBER not in names:
                raise ParameterError(
                    parameter,
                    f"{path} is an SB3 model without {METADATA_MEMBER}, so its env id and env kwargs are "
                    "unknown; use a model saved by `dpr train` (dpr.policies.sb3.save_model)",
                )
            check_model_members(archive, path, parameter)
            raw = read_zip_member(archive, METADATA_MEMBER, MAX_MODEL_JSON_BYTES, path, parameter)
    except zipfile.BadZipFile as error:
        raise ParameterError(parameter, f"{path} is not a readable .zip model file ({error})") from None
    try:
        data = json.loads(raw)
        info = ModelInfo(
            algo=data["algo"],
            env_id=data["env_id"],
            env_kwargs=dict(data["env_kwargs"]),
            max_episode_steps=data.get("max_episode_steps"),
            per_robot=None if data.get("per_robot") is None else dict(data["per_robot"]),
            architecture=_checked_architecture(data.get("architecture")),
        )
    except (ValueError, KeyError, TypeError) as error:
        raise ParameterError(parameter, f"{path}: {METADATA_MEMBER} is malformed ({error!r})") from None
    if info.algo not in ALGOS:
        raise ParameterError(
            parameter, f"{path}: unknown algo {info.algo!r} in {METADATA_MEMBER}; expected one of {ALGOS}"
        )
    return info


def _drives_any_task_like(info: ModelInfo, env_id: str) -> bool:
    """Whether a per-robot model of ``info`` runs on ``env_id``'s task too: its local observation has the same
    parts on every task with the same object or none (dpr.policies.per_robot_spec.check_per_robot_env)."""
    from dpr.envs import TASK_CLASSES, TASKS

    if info.per_robot is None or env_id not in TASKS or info.env_id not in TASKS:
        return False
    return TASK_CLASSES[TASKS[env_id]].has_object == TASK_CLASSES[TASKS[info.env_id]].has_object


def model_env_kwargs(
    path: str | Path, env_id: str, requested: dict[str, Any] | None = None, *, transfer: bool = False
) -> dict[str, Any]:
    """The env kwargs to run the model at ``path`` on ``env_id``: the model's own, plus any ``requested``
    kwargs it did not set. A requested value that differs from the model's is a ValueError naming both values,
    except ``n_robots`` for a :data:`SWARM_POLICY` model, which acts at any swarm size, and ``robot_model`` for a
    centralised model: the paddle and disk models share their spaces, so a policy learned on one runs on, and
    fine-tunes on, the other (:data:`TRANSFERABLE_KWARGS`). Another env id is a :class:`ParameterError` about
    ``env_id``, but for a per-robot model on a task with the same object or none, and with ``transfer``: a model
    run on another task as it is (zero-shot transfer; its spaces are checked when it is loaded for the env)."""
    info = read_model_info(path)
    if env_id != info.env_id and not (transfer or _drives_any_task_like(info, env_id)):
        raise ParameterError(
            "env_id",
            f"model {path} was trained on {info.env_id}; it cannot be run on {env_id} (unless as a transfer to "
            "another task with the same spaces: --transfer)",
        )
    kwargs = dict(info.env_kwargs)
    transferable = {"n_robots"} if has_swarm_actor(path) else set()  # its actor is shared by the robots: any N
    if info.per_robot is None:  # a per-robot model's local observation is laid out for its own robot model
        transferable.update(TRANSFERABLE_KWARGS)
    for name, value in (requested or {}).items():
        if name in kwargs and kwargs[name] != value and name not in transferable:
            why = (
                "makes a different observation or action space" if name in SPACE_KWARGS else "is not what it learned on"
            )
            only = f"; only a {SWARM_POLICY} model acts at any swarm size" if name == "n_robots" else ""
            raise ValueError(
                f"model {path} was trained with {name}={kwargs[name]!r}; {name}={value!r} {why} "
                f"(leave it out to use the model's value{only})"
            )
        kwargs[name] = value
    return kwargs


def has_swarm_actor(path: str | Path) -> bool:
    """Whether the model file at ``path`` holds a :data:`SWARM_POLICY`, whose actor acts at any swarm size."""
    with zipfile.ZipFile(path) as archive:
        data = json.loads(read_zip_member(archive, "data", MAX_MODEL_JSON_BYTES, path, POLICY_PARAMETER))
    return data.get("policy_class", {}).get("__module__") == SWARM_POLICY_MODULE
