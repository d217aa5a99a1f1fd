"""Trained stable-baselines3 models as policies: the ``.zip`` files that ``dpr train`` writes.

A model file is SB3's own zip plus one small JSON member, :data:`METADATA_MEMBER`, that names the algorithm,
the env id and the env kwargs the model was trained with, so that a model can be evaluated or rolled out
without restating them. stable-baselines3 and torch are imported inside functions only: the scripted
policies (and everything that imports this package) must not pay for them.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

MODEL_SUFFIX = ".zip"
METADATA_MEMBER = "dpr_env.json"
METADATA_FORMAT = 1
ALGOS = ("ppo", "a2c", "dqn")
# Env kwargs whose value decides the observation or action space: a different value can never run the model.
SPACE_KWARGS = ("n_robots", "action_type", "obs_type", "obs_last_action", "image_size")


def is_model_path(name: str) -> bool:
    """Whether a ``--policy`` value names a model file rather than a scripted policy."""
    return name.endswith(MODEL_SUFFIX)


@dataclass(frozen=True)
class ModelInfo:
    """What a model file says about how it was trained (the :data:`METADATA_MEMBER` of its zip)."""

    algo: str
    env_id: str
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    max_episode_steps: int | None = None

    def as_json(self) -> str:
        return json.dumps({"format": METADATA_FORMAT, **asdict(self)}, indent=2, sort_keys=True)


def algo_class(algo: str):
    """The SB3 class of ``algo`` ("ppo", "a2c" or "dqn")."""
    if algo not in ALGOS:
        raise ValueError(f"algo must be one of {ALGOS}, got {algo!r}")
    import stable_baselines3

    return getattr(stable_baselines3, algo.upper())


def write_model_info(path: str | Path, info: ModelInfo) -> None:
    """Append ``info`` to the SB3 zip at ``path`` (SB3's loader ignores members it does not know)."""
    algo_class(info.algo)  # validates the name before anything is written
    with zipfile.ZipFile(path, "a") as archive:
        if METADATA_MEMBER in archive.namelist():
            raise ValueError(f"{path} already holds {METADATA_MEMBER}; save the model to a new file first")
        archive.writestr(METADATA_MEMBER, info.as_json())


def read_model_info(path: str | Path) -> ModelInfo:
    """The :class:`ModelInfo` of the model file at ``path``; ValueError naming the path when the file is
    missing, not a zip, or not a model written by ``dpr train``."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"--policy: no model file at {path}")
    try:
        with zipfile.ZipFile(path) as archive:
            names = archive.namelist()
            if "data" not in names:
                raise ValueError(f"--policy: {path} is a zip but not a stable-baselines3 model (no 'data' member)")
            if METADATA_MEMBER not in names:
                raise ValueError(
                    f"--policy: {path} is an SB3 model without {METADATA_MEMBER}, so its env id and env kwargs are "
                    "unknown; use a model saved by `dpr train` (dpr.rl.models.save_model)"
                )
            raw = archive.read(METADATA_MEMBER)
    except zipfile.BadZipFile as error:
        raise ValueError(f"--policy: {path} is not a readable .zip model file ({error})") from None
    try:
        data = json.loads(raw)
        info = ModelInfo(
            algo=data["algo"], env_id=data["env_id"], env_kwargs=dict(data["env_kwargs"]),
            max_episode_steps=data.get("max_episode_steps"),
        )
    except (ValueError, KeyError, TypeError) as error:
        raise ValueError(f"--policy: {path}: {METADATA_MEMBER} is malformed ({error!r})") from None
    if info.algo not in ALGOS:
        raise ValueError(f"--policy: {path}: unknown algo {info.algo!r} in {METADATA_MEMBER}; expected one of {ALGOS}")
    return info


def model_env_kwargs(path: str | Path, env_id: str, requested: dict[str, Any] | None = None) -> dict[str, Any]:
    """The env kwargs to run the model at ``path`` on ``env_id``: the model's own, plus any ``requested``
    kwargs it did not set. A requested value that differs from the model's, or another env id, is a
    ValueError naming both values."""
    info = read_model_info(path)
    if env_id != info.env_id:
        raise ValueError(
            f"model {path} was trained on {info.env_id}; it cannot be run on {env_id} (evaluate it with --env {info.env_id})"
        )
    kwargs = dict(info.env_kwargs)
    for name, value in (requested or {}).items():
        if name in kwargs and kwargs[name] != value:
            why = "makes a different observation or action space" if name in SPACE_KWARGS else "is not what it learned on"
            raise ValueError(
                f"model {path} was trained with {name}={kwargs[name]!r}; {name}={value!r} {why} "
"(leave it out to use the model's value)"
            )
        kwargs[name] = value
    return kwargs


def describe_space(space) -> str:
    """A space in one short line (a Box's repr lists every bound)."""
    shape = getattr(space, "shape", None)
    if type(space).__name__ == "Box":
        return f"Box(shape={shape}, dtype={space.dtype})"
    return str(space)


def _space_mismatch(path: Path, info: ModelInfo, model, env) -> str | None:
    """A sentence on why ``model`` cannot act in ``env``, or None when the spaces agree."""
    problems = []
    if model.observation_space != env.observation_space:
        problems.append(
            f"observation space {describe_space(model.observation_space)} vs the env's {describe_space(env.observation_space)}"
        )
    if model.action_space != env.action_space:
        problems.append(f"action space {describe_space(model.action_space)} vs the env's {describe_space(env.action_space)}")
    if not problems:
        return None
    base = getattr(env, "unwrapped", None)  # a VecEnv has none: then only the spaces are named
    differing = [
        f"{name}={info.env_kwargs[name]!r} (the env has {name}={getattr(base, name)!r})"
        for name in SPACE_KWARGS
        if name in info.env_kwargs and hasattr(base, name) and getattr(base, name) != info.env_kwargs[name]
    ]
    trained = f"; it was trained with {', '.join(differing)}" if differing else ""
    return f"model {path} does not fit this env: {'; '.join(problems)}{trained}"


def load_model(path: str | Path, env=None, *, for_training: bool = False):
    """The SB3 model at ``path`` and its :class:`ModelInfo`, checked against ``env`` (a gymnasium env: its id
    and spaces; or a VecEnv: its spaces) when one is given. With ``for_training`` the model's schedules are
    restored and ``env`` is attached, ready for ``learn``; otherwise schedules are not unpickled (prediction
    does not need them, and they may reference code that is not importable here)."""
    path = Path(path)
    info = read_model_info(path)
    env_id = getattr(getattr(env, "spec", None), "id", None)
    if env_id is not None and env_id != info.env_id:
        raise ValueError(f"model {path} was trained on {info.env_id}; this env is {env_id}")
    custom = None if for_training else {"learning_rate": 0.0, "lr_schedule": lambda _: 0.0, "clip_range": lambda _: 0.0}
    try:
        model = algo_class(info.algo).load(path, device="cpu", custom_objects=custom)
    except (KeyError, ValueError, RuntimeError, zipfile.BadZipFile, EOFError) as error:
        raise ValueError(f"--policy: cannot load {info.algo} model {path}: {error}") from None
    if env is not None:
        # Spaces are compared here rather than by SB3's load(env=...), so that the error names the env kwargs.
        mismatch = _space_mismatch(path, info, model, env)
        if mismatch:
            raise ValueError(mismatch)
        if for_training:
            model.set_env(env)
    return model, info


class ModelPolicy:
    """A trained model as a ``policy(observation) -> action`` callable: deterministic actions, so
    ``reset(seed)`` has nothing to reseed."""

    def __init__(self, model, info: ModelInfo, path: Path):
        self.model = model
        self.info = info
        self.path = path

    def reset(self, seed: int | None = None) -> None:
        """Nothing to reset: the policy is a pure function of the observation."""

    def __call__(self, observation):
        action, _ = self.model.predict(observation, deterministic=True)
        return action


def single_thread_torch() -> None:
    """One torch thread in this process. The networks are small MLPs, which more threads do not speed up;
    envs and evaluation run one process per core, and torch's spinning worker threads competing with them
    slowed training and evaluation down tenfold and more on 2 cores."""
    import torch

    torch.set_num_threads(1)


def load_model_policy(path: str | Path, env) -> ModelPolicy:
    """The model file at ``path`` as a policy for ``env`` (ValueError when it was made for another env),
    predicting on one torch thread (:func:`single_thread_torch`)."""
    single_thread_torch()
    model, info = load_model(path, env)
    return ModelPolicy(model, info, Path(path))
