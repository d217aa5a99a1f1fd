"""The model card: which shipped model stands for which (task, method) in the headline.

``models/card.yaml`` is data, one entry per shipped model::

    format: 1
    models:
      - task: navigation          # a key of dpr.envs.ENV_IDS
        method: bc-ppo            # the pipeline's method name (bc, bc-ppo, ppo, ...)
        file: navigation-bc-ppo.zip   # beside the card
        made_by: dpr pipeline --preset full --tasks all (median training seed)
        env_id: dpr/Gate-v0       # optional: an earlier id of the task that the model was made on
        sha256: 5f1c...           # optional: the file's sha256, checked on load

and, optionally, the per-robot models (one robot's local observation in, its action out; any swarm size), which
``tools/decentralised_sweep.py`` scores across swarm sizes rather than the pipeline at one N::

    per_robot_models:
      - robot_model: paddle       # a key of dpr.sim.ROBOT_MODELS: the model's own, checked against its file
        method: bc-ppo
        file: decentralised-bc-ppo.zip
        made_by: dpr bc-decentralised ... then dpr finetune-decentralised ... (median training seed)
        sha256: 9a0c...           # optional, as above

and, optionally, LeRobot policies trained on dpr's datasets (LeRobot's own ``save_pretrained`` folders, which
dpr checks but cannot run: their networks are LeRobot's code; ``tools/lerobot_policies.py evaluate`` scores them
in LeRobot's side environment)::

    lerobot_policies:
      - task: navigation
        policy: diffusion         # LeRobot's policy type: its config.json's "type"
        folder: navigation-lerobot-diffusion   # beside the card: config.json, model.safetensors, dpr_env.json, ...
        made_by: tools/lerobot_recipe.py train --recipe ... (median training seed)
        sha256: 3b7e...           # optional: model.safetensors' sha256, checked on load

``models/README.md`` describes the same models for people; ``dpr pipeline --shipped models/card.yaml`` (what
``make run`` does) evaluates each of them on the pipeline's test seeds, so that the claim is checked where the
user runs it. :func:`load_model_card` checks the whole card, files included (their sha256 where the card gives it,
and each loaded as a model, which unpickles nothing), before anything runs.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import yaml

from dpr.atomic import file_sha256
from dpr.bounded_io import YamlRefused, load_yaml
from dpr.checks import ParameterError
from dpr.envs import ENV_IDS, TASKS
from dpr.policies.model_file import ModelInfo
from dpr.policies.sb3 import load_model

CARD_FORMAT = 1
ENTRY_KEYS = ("task", "method", "file", "made_by")
PER_ROBOT_KEYS = ("robot_model", "method", "file", "made_by")
PER_ROBOT_OPTIONAL_KEYS = ("sha256",)
LEROBOT_KEYS = ("task", "policy", "folder", "made_by")
LEROBOT_OPTIONAL_KEYS = ("sha256",)
LEROBOT_MAX_MEGABYTES = 10.0  # a shipped LeRobot policy's folder, at most
CARD_KEYS = {"format", "models", "per_robot_models", "lerobot_policies"}
# env_id: the task's registered id the model runs on, when not its current one; sha256: the file's, checked
OPTIONAL_KEYS = ("env_id", "sha256")


@dataclass(frozen=True)
class ShippedModel:
    """One entry of the card: ``path`` is the model file (resolved beside the card)."""

    task: str
    method: str
    path: Path
    made_by: str
    task_env_id: str | None = None  # the card's env_id: an earlier id of the task

    @property
    def env_id(self) -> str:
        return self.task_env_id or ENV_IDS[self.task]


@dataclass(frozen=True)
class ShippedPerRobotModel:
    """One entry of the card's ``per_robot_models``: ``path`` is the model file (resolved beside the card)."""

    robot_model: str
    method: str
    path: Path
    made_by: str


@dataclass(frozen=True)
class ShippedLeRobotPolicy:
    """One entry of the card's ``lerobot_policies``: ``path`` is LeRobot's policy folder (beside the card)."""

    task: str
    policy: str
    path: Path
    made_by: str


def load_model_card(card: str | Path, parameter: str = "shipped") -> list[ShippedModel]:
    """The entries of the model card at ``card`` (its per-robot models are checked too, and returned by
    :func:`load_per_robot_models`); a :class:`ParameterError` about ``parameter`` naming the card, the entry and
    what was expected when the card is malformed, names an unknown task, repeats a (task, method) or a per-robot
    (robot_model, method), or names a model file that does not exist."""
    return _load(card, parameter)[0]


def load_per_robot_models(card: str | Path, parameter: str = "shipped") -> list[ShippedPerRobotModel]:
    """The card's per-robot models, after the whole card is checked as :func:`load_model_card` does; each file
    must hold a per-robot model of the entry's robot model."""
    return _load(card, parameter)[1]


def load_lerobot_policies(card: str | Path, parameter: str = "shipped") -> list[ShippedLeRobotPolicy]:
    """The card's LeRobot policies, after the whole card is checked as :func:`load_model_card` does; each folder
    must hold LeRobot's files of the entry's policy type (``model.safetensors`` at the card's sha256), at most
    :data:`LEROBOT_MAX_MEGABYTES`, and the env it was trained on (its ``dpr_env.json``) must be the entry's task."""
    return _load(card, parameter)[2]


def _load(
    card: str | Path, parameter: str
) -> tuple[list[ShippedModel], list[ShippedPerRobotModel], list[ShippedLeRobotPolicy]]:
    card = Path(card)
    if not card.is_file():
        raise ParameterError(parameter, f"no model card at {card}")
    try:
        data = load_yaml(card, parameter)
    except YamlRefused:
        raise
    except yaml.YAMLError as error:
        raise ParameterError(parameter, f"{card} is not YAML: {error}") from None
    keys = set(data) if isinstance(data, dict) else set()
    if not {"format", "models"} <= keys <= CARD_KEYS or data.get("format") != CARD_FORMAT:
        raise ParameterError(
            parameter, f"{card}: expected a mapping with 'format: {CARD_FORMAT}' and 'models' (and 'per_robot_models')"
        )
    entries = data.get("models")
    if not isinstance(entries, list) or not entries:
        raise ParameterError(parameter, f"{card}: 'models' must be a non-empty list of entries")
    models: list[ShippedModel] = []
    for index, entry in enumerate(entries):
        where = f"{card}: models[{index}]"
        _check_entry(where, entry, ENTRY_KEYS, OPTIONAL_KEYS, parameter)
        _check_task(where, entry, parameter)
        if "env_id" in entry and TASKS.get(entry["env_id"]) != entry["task"]:
            ids = [env_id for env_id, task in TASKS.items() if task == entry["task"]]
            raise ParameterError(parameter, f"{where}: env_id must be one of {ids}, got {entry['env_id']!r}")
        path = _entry_file(card, where, entry, parameter)
        if any((model.task, model.method) == (entry["task"], entry["method"]) for model in models):
            raise ParameterError(parameter, f"{where}: a second {entry['task']} {entry['method']} model")
        models.append(ShippedModel(entry["task"], entry["method"], path, entry["made_by"], entry.get("env_id")))
    per_robot_entries = data.get("per_robot_models", [])
    per_robot = _per_robot_entries(card, per_robot_entries, parameter)
    for index, (entry, model) in enumerate(zip(entries, models)):  # the files, once the card itself holds
        _check_file(f"{card}: models[{index}]", entry, model.path, parameter)
    for index, (entry, model) in enumerate(zip(per_robot_entries, per_robot)):
        _check_per_robot_file(f"{card}: per_robot_models[{index}]", entry, model, parameter)
    lerobot: list[ShippedLeRobotPolicy] = []
    for index, entry in enumerate(_entry_list(card, data.get("lerobot_policies", []), "lerobot_policies", parameter)):
        where = f"{card}: lerobot_policies[{index}]"
        policy = _lerobot_entry(where, card, entry, parameter)
        if any((other.task, other.policy) == (policy.task, policy.policy) for other in lerobot):
            raise ParameterError(parameter, f"{where}: a second {policy.task} {policy.policy} policy")
        lerobot.append(policy)
    return models, per_robot, lerobot


def _check_entry(where: str, entry, keys: tuple[str, ...], optional: tuple[str, ...], parameter: str) -> None:
    """An entry is a mapping of exactly ``keys`` (and any of ``optional``) to non-empty strings."""
    if not isinstance(entry, dict) or not set(keys) <= set(entry) <= {*keys, *optional}:
        raise ParameterError(
            parameter, f"{where} must have the keys {list(keys)} (and may have {list(optional)}), got {entry!r}"
        )
    if not all(isinstance(value, str) and value for value in entry.values()):
        raise ParameterError(parameter, f"{where}: every value must be a non-empty string")


def _entry_file(card: Path, where: str, entry: dict, parameter: str) -> Path:
    path = card.parent / entry["file"]
    if not path.is_file():
        raise ParameterError(parameter, f"{where} names {entry['file']}, but there is no file {path}")
    return path


def _check_file(where: str, entry: dict, path: Path, parameter: str) -> ModelInfo:
    """The file's :class:`ModelInfo`, once its sha256 (where the card gives one) matches and it loads as a model."""
    _check_sha256(where, entry, path, parameter)
    return load_model(path, parameter=parameter)[1]  # a corrupt or crafted file is refused now, not hours later


def _per_robot_entries(card: Path, entries, parameter: str) -> list[ShippedPerRobotModel]:
    from dpr.sim.models import ROBOT_MODELS

    models: list[ShippedPerRobotModel] = []
    for index, entry in enumerate(_entry_list(card, entries, "per_robot_models", parameter)):
        where = f"{card}: per_robot_models[{index}]"
        _check_entry(where, entry, PER_ROBOT_KEYS, PER_ROBOT_OPTIONAL_KEYS, parameter)
        if entry["robot_model"] not in ROBOT_MODELS:
            raise ParameterError(
                parameter, f"{where}: robot_model must be one of {list(ROBOT_MODELS)}, got {entry['robot_model']!r}"
            )
        path = _entry_file(card, where, entry, parameter)
        if any((model.robot_model, model.method) == (entry["robot_model"], entry["method"]) for model in models):
            raise ParameterError(parameter, f"{where}: a second {entry['robot_model']} {entry['method']} model")
        models.append(ShippedPerRobotModel(entry["robot_model"], entry["method"], path, entry["made_by"]))
    return models


def _check_per_robot_file(where: str, entry: dict, model: ShippedPerRobotModel, parameter: str) -> None:
    """:func:`_check_file`, and the file holds a per-robot model of the entry's robot model."""
    from dpr.policies.per_robot_spec import RobotModelSpec

    info = _check_file(where, entry, model.path, parameter)
    spec = RobotModelSpec.from_info(info, model.path, parameter)
    if spec.robot_model != model.robot_model:
        raise ParameterError(
            parameter,
            f"{where}: {model.path} is a per-robot model of the {spec.robot_model} robot model, not of "
            f"{model.robot_model}",
        )


def _entry_list(card: Path, entries, key: str, parameter: str) -> list:
    if not isinstance(entries, list):
        raise ParameterError(parameter, f"{card}: '{key}' must be a list of entries")
    return entries


def _check_task(where: str, entry: dict, parameter: str) -> None:
    if entry["task"] not in ENV_IDS:
        raise ParameterError(parameter, f"{where}: task must be one of {list(ENV_IDS)}, got {entry['task']!r}")


def _check_sha256(where: str, entry: dict, path: Path, parameter: str) -> None:
    """``path``'s content must be the one the entry's ``sha256`` (where it gives one) names."""
    if "sha256" in entry and file_sha256(path) != entry["sha256"]:
        raise ParameterError(parameter, f"{where}: {path} is not the file the card names (its sha256 differs)")


def _lerobot_entry(where: str, card: Path, entry, parameter: str) -> ShippedLeRobotPolicy:
    """One ``lerobot_policies`` entry, its folder checked as :func:`load_lerobot_policies` says (no LeRobot needed)."""
    import json

    from dpr.policies.registry import LEROBOT_ENV_FILE, LEROBOT_POLICY_FILES, lerobot_policy_type

    _check_entry(where, entry, LEROBOT_KEYS, LEROBOT_OPTIONAL_KEYS, parameter)
    _check_task(where, entry, parameter)
    folder = card.parent / entry["folder"]
    missing = [name for name in (*LEROBOT_POLICY_FILES, LEROBOT_ENV_FILE) if not (folder / name).is_file()]
    if missing:
        raise ParameterError(parameter, f"{where}: {folder} must be a LeRobot policy folder; it lacks {missing}")
    if (kind := lerobot_policy_type(folder)) != entry["policy"]:
        raise ParameterError(parameter, f"{where}: {folder} holds a LeRobot {kind!r} policy, not {entry['policy']!r}")
    _check_sha256(where, entry, folder / "model.safetensors", parameter)
    if (size := sum(path.stat().st_size for path in folder.iterdir()) / 1e6) > LEROBOT_MAX_MEGABYTES:
        raise ParameterError(parameter, f"{where}: {folder} is {size:.1f} MB, over {LEROBOT_MAX_MEGABYTES:g} MB")
    env_id = json.loads((folder / LEROBOT_ENV_FILE).read_text()).get("env_id")
    if TASKS.get(env_id) != entry["task"]:
        raise ParameterError(parameter, f"{where}: {folder} was trained on {env_id}, not on a {entry['task']} env")
    return ShippedLeRobotPolicy(entry["task"], entry["policy"], folder, entry["made_by"])
