"""What dpr gives stable-baselines3 for the pickled entries of a model file, so that loading one unpickles nothing.

SB3 writes a model's settings into the zip's ``data`` member as JSON, but pickles (cloudpickle, base64) the entries
JSON cannot hold: the policy class, the spaces, schedules, the last rollout's observations and episode buffers, and
``policy_kwargs`` that name classes. Beside each pickle it writes a plain description (a class's module and docstring,
a space's shape and dtype, a schedule's values). :func:`model_objects` builds every such entry from those descriptions
and the model's own metadata (:class:`dpr.policies.model_file.ModelInfo`), and refuses a file that holds any other
pickled entry; :func:`dpr.policies.sb3.load_model` hands them to SB3 as ``custom_objects``, which SB3 then uses
instead of unpickling. The weights are read by torch with ``weights_only=True``.
"""

from __future__ import annotations

import json
import re
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from dpr.bounded_io import read_zip_member
from dpr.checks import ParameterError
from dpr.limits import MAX_MODEL_JSON_BYTES

# The entries of a model file's `data` that SB3 pickles, and what dpr supplies in their place: a model file may
# hold nothing else pickled (models/README.md, "What a model file may contain"). Rollout state is dropped.
DROPPED_ENTRIES = ("_last_obs", "_last_original_obs", "_last_episode_starts", "ep_info_buffer", "ep_success_buffer")
SCHEDULE_ENTRIES = ("learning_rate", "lr_schedule", "clip_range", "clip_range_vf", "exploration_schedule")
_CONSTANT_SCHEDULE = re.compile(r"ConstantSchedule\(val=([-+0-9.eE]+)\)")


def _pickled(value) -> bool:
    return isinstance(value, dict) and ":serialized:" in value


def _model_data(path: Path, parameter: str) -> dict[str, Any]:
    """The model file's ``data`` member as JSON (pickled entries stay base64 text, never loaded)."""
    try:
        with zipfile.ZipFile(path) as archive:
            data = json.loads(read_zip_member(archive, "data", MAX_MODEL_JSON_BYTES, path, parameter))
    except ParameterError:
        raise
    except (zipfile.BadZipFile, KeyError, ValueError) as error:
        raise ParameterError(parameter, f"{path}: its 'data' member is not SB3's JSON ({error})") from None
    if not isinstance(data, dict):
        raise ParameterError(parameter, f"{path}: its 'data' member is not a JSON object")
    return data


def _policy_class(path: Path, entry: dict, parameter: str):
    """The policy class a file's ``policy_class`` entry names, among those dpr trains: by its module, and among
    SB3's by its docstring, which SB3 writes as plain text beside the pickle."""
    from stable_baselines3.common.policies import (
        ActorCriticCnnPolicy,
        ActorCriticPolicy,
        MultiInputActorCriticPolicy,
    )
    from stable_baselines3.dqn.policies import CnnPolicy, DQNPolicy, MultiInputPolicy

    from dpr.policies.swarm_policy import SwarmActorCriticPolicy

    if entry.get("__module__") == SwarmActorCriticPolicy.__module__:  # dpr's one policy there (its docstring changes)
        return SwarmActorCriticPolicy
    known = (ActorCriticPolicy, ActorCriticCnnPolicy, MultiInputActorCriticPolicy, DQNPolicy, CnnPolicy)
    for cls in (*known, MultiInputPolicy):
        if entry.get("__module__") == cls.__module__ and entry.get("__doc__") == cls.__doc__:
            return cls
    raise ParameterError(
        parameter, f"{path}: its policy class ({entry.get('__module__')!r}) is none of the policies dpr trains"
    )


def _classes_by_text() -> dict[str, type]:
    """The classes a model's ``policy_kwargs`` may name (the optimizers, activations and features extractor a yaml
    entry may set), by the text SB3 writes of them beside the pickle: "<class 'torch.optim.rmsprop.RMSprop'>"."""
    from torch import nn, optim

    from dpr.policies.features import SwarmFeatures

    optimizers = (optim.Adam, optim.AdamW, optim.RMSprop, optim.SGD)
    activations = (nn.ReLU, nn.Tanh, nn.ELU, nn.LeakyReLU, nn.GELU, nn.SiLU)
    classes = (*optimizers, *activations, SwarmFeatures)
    return {f"<class '{cls.__module__}.{cls.__qualname__}'>": cls for cls in classes}


def _policy_kwargs(path: Path, entry: dict, parameter: str) -> dict[str, Any]:
    """A pickled ``policy_kwargs`` from its plain fields: values as written, and the classes among
    :func:`_classes_by_text` that its text names; any other class is refused."""
    known = _classes_by_text()
    kwargs = {key: value for key, value in entry.items() if not key.startswith(":")}
    for key, value in kwargs.items():
        if isinstance(value, str) and value.startswith("<"):
            if value not in known:
                raise ParameterError(parameter, f"{path}: its policy_kwargs {key} is {value}, which dpr does not load")
            kwargs[key] = known[value]
    return kwargs


def _model_spaces(info):
    """The observation and action spaces a model of ``info`` acts in, made from its env id and kwargs as SB3
    sees them (image observations channel-first, as SB3 transposes them)."""
    import gymnasium as gym
    from gymnasium import spaces
    from stable_baselines3.common.preprocessing import is_image_space, is_image_space_channels_first
    from stable_baselines3.common.vec_env import VecTransposeImage

    from dpr.envs import TASK_CLASSES, TASKS

    kwargs = {**gym.spec(info.env_id).kwargs, **info.env_kwargs}
    if info.per_robot is not None:
        from dpr.policies.per_robot_spec import RobotModelSpec

        layout = RobotModelSpec.from_info(info, info.env_id).layout
        continuous = kwargs.get("action_type") == "continuous"
        action = spaces.Box(0.0, 1.0, (1,), dtype=np.float32) if continuous else spaces.Discrete(2)
        return layout.space(), action
    env = TASK_CLASSES[TASKS[info.env_id]](**kwargs)
    observation, action = env.observation_space, env.action_space
    env.close()

    def channel_first(space):
        if is_image_space(space) and not is_image_space_channels_first(space):
            return VecTransposeImage.transpose_space(space)
        return space

    if isinstance(observation, spaces.Dict):
        return spaces.Dict({key: channel_first(space) for key, space in observation.spaces.items()}), action
    return channel_first(observation), action


def _check_space(path: Path, name: str, space, entry: dict, parameter: str) -> None:
    """The plain fields SB3 writes beside a pickled space (shape, dtype, n) must be those of ``space``."""
    expected = {"_shape": list(space.shape or ()), "dtype": str(space.dtype) if space.dtype is not None else None}
    if hasattr(space, "n"):
        expected["n"] = int(space.n)
    found = {key: entry.get(key) for key in expected if key in entry}
    if any(str(found[key]) != str(expected[key]) for key in found):  # (SB3 writes numpy scalars as text)
        raise ParameterError(parameter, f"{path}: its {name} {found} is not the one its env kwargs make ({expected})")


def _schedule(path: Path, key: str, entry, for_training: bool, parameter: str):
    """A schedule entry. SB3 rebuilds ``lr_schedule`` and ``exploration_schedule`` from plain values when it
    loads; the others are, for prediction, a constant 0 (unused), and for training the file's plain value, or the
    schedule its plain fields describe (a constant or linear one), else an error: their code is not run."""
    if key in ("lr_schedule", "exploration_schedule"):
        return lambda _: 0.0
    if not for_training:
        return 0.0
    if all(name in entry for name in ("start", "end", "end_fraction")):
        from stable_baselines3.common.utils import LinearSchedule

        return LinearSchedule(float(entry["start"]), float(entry["end"]), float(entry["end_fraction"]))
    constant = _CONSTANT_SCHEDULE.fullmatch(str(entry.get("value_schedule", "")))
    if constant is None:
        raise ParameterError(
            parameter, f"{path}: its {key} is pickled code that dpr does not run; it cannot be trained on further"
        )
    return float(constant.group(1))


def model_objects(path: str | Path, info, for_training: bool, parameter: str):
    """What :func:`load_model` gives SB3 for every pickled entry of the model file at ``path`` (SB3's
    ``custom_objects``), so that nothing in it is unpickled; a :class:`ParameterError` when the file holds a pickled
    entry that no dpr model holds, or one whose plain description disagrees with the model's metadata."""
    from gymnasium import spaces
    from stable_baselines3.common.buffers import DictReplayBuffer, DictRolloutBuffer, ReplayBuffer, RolloutBuffer

    path = Path(path)
    data = _model_data(path, parameter)
    observation_space, action_space = _model_spaces(info)
    dict_observations = isinstance(observation_space, spaces.Dict)
    objects: dict[str, Any] = {
        "observation_space": observation_space,
        "action_space": action_space,
        "rollout_buffer_class": DictRolloutBuffer if dict_observations else RolloutBuffer,
        "replay_buffer_class": DictReplayBuffer if dict_observations else ReplayBuffer,
        **dict.fromkeys(DROPPED_ENTRIES),
    }
    if "policy_class" in data:
        objects["policy_class"] = _policy_class(path, data["policy_class"], parameter)
    if _pickled(data.get("train_freq")):  # DQN's: written with no plain fields; it only matters for training
        from stable_baselines3.common.type_aliases import TrainFreq, TrainFrequencyUnit

        objects["train_freq"] = TrainFreq(1, TrainFrequencyUnit.STEP)
    if _pickled(data.get("policy_kwargs")):
        objects["policy_kwargs"] = _policy_kwargs(path, data["policy_kwargs"], parameter)
    for name in ("observation_space", "action_space"):
        if isinstance(data.get(name), dict):
            _check_space(path, name, objects[name], data[name], parameter)
    for key in SCHEDULE_ENTRIES:
        if _pickled(data.get(key)):  # (a plain value is read as it is)
            objects[key] = _schedule(path, key, data[key], for_training, parameter)
    unknown = sorted(key for key, value in data.items() if _pickled(value) and key not in objects)
    if unknown:
        raise ParameterError(
            parameter, f"{path} holds pickled entries no dpr model holds ({', '.join(unknown)}); it is refused"
        )
    return {key: value for key, value in objects.items() if _pickled(data.get(key))}
