"""Hyperparameters of the SB3 algorithms, read from ``dpr/rl/hyperparams/<algo>.yml`` (rl-zoo style).

Each file has one entry per env id (laptop-sized defaults, preset ``default``) and one ``paper`` entry (Shen et
al.'s values, any env id). An entry holds ``n_timesteps``, ``policy`` (SB3's names, or ``SwarmPolicy``: the actor
shared by the robots of :mod:`dpr.policies.swarm_policy`), ``learning_rate`` (a number or ``"lin_X"``: linear from
X to 0 over training), ``policy_kwargs`` (``net_arch``, ``activation_fn``, ``features_extractor``: ``flatten`` or
``swarm``, see :mod:`dpr.policies.features`; ``robot_net``: SwarmPolicy's per-robot layers; ``critic``:
SwarmPolicy's critic, ``mlp`` or ``swarm``),
``env_kwargs`` (gym.make kwargs the algorithm needs, e.g. DQN's discrete actions) and any other keyword
argument of the SB3 class. Everything stays plain yaml data until :meth:`Hyperparams.model_kwargs` turns it
into the objects SB3 wants, so the resolved values can be saved as they were read.

The loader lives beside :func:`dpr.policies.sb3.build_model`, below both behaviour cloning and RL, which build
their models from it; the yaml files stay with the rest of the training setup in ``dpr/rl/hyperparams/``
(package data, and where the docs point).
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from dpr.bounded_io import load_yaml
from dpr.checks import ParameterError, check_int, check_number
from dpr.envs import TASKS
from dpr.envs.tasks import HYPERPARAMS_OF
from dpr.limits import (
    MAX_BATCH_SIZE,
    MAX_BUFFER_SIZE,
    MAX_EPISODES,
    MAX_EPOCHS,
    MAX_LAYER_SIZE,
    MAX_LAYERS,
    MAX_TIMESTEPS,
)
from dpr.policies.model_file import ALGOS, SWARM_POLICY
from dpr.policies.sb3 import algo_class

HYPERPARAMS_DIR = Path(__file__).resolve().parents[1] / "rl" / "hyperparams"
DEFAULT_PRESET = "default"
PAPER_PRESET = "paper"
FINETUNE_PRESET = "finetune"  # the env id's entry with the yaml's `finetune` entry on top (dpr finetune)
BATCHED_PRESET = "batched"  # the env id's entry with the `batched` entry on top (dpr train --engine batched)
PRESETS = (DEFAULT_PRESET, PAPER_PRESET, FINETUNE_PRESET, BATCHED_PRESET)
ON_TOP = (FINETUNE_PRESET, BATCHED_PRESET)  # presets whose entry goes over the env id's
LINEAR_PREFIX = "lin_"
ACTIVATIONS = ("tanh", "relu")
POLICY_KWARGS = ("net_arch", "activation_fn", "features_extractor", "robot_net", "critic")
SWARM_CRITICS = ("mlp", "swarm")  # dpr.policies.swarm_policy.CRITICS (not imported here: torch)
FEATURES_EXTRACTORS = ("flatten", "swarm")  # SB3's default; dpr.policies.features.SwarmFeatures
# Bounds of the numeric keyword arguments of the SB3 classes (None: SB3's own default), so that a typo is refused
# when the entry is read, naming the value, and not by SB3 after a run folder is written: name -> (minimum, maximum).
INT_HYPERPARAMS = {
    "n_steps": (1, MAX_BATCH_SIZE),
    "batch_size": (1, MAX_BATCH_SIZE),
    "n_epochs": (1, MAX_EPOCHS),
    "buffer_size": (1, MAX_BUFFER_SIZE),
    "learning_starts": (0, MAX_TIMESTEPS),
    "gradient_steps": (-1, MAX_BATCH_SIZE),
    "target_update_interval": (1, MAX_TIMESTEPS),
    "stats_window_size": (1, MAX_EPISODES),
}
UNIT_HYPERPARAMS = (
    "gamma",
    "gae_lambda",
    "tau",
    "exploration_fraction",
    "exploration_initial_eps",
    "exploration_final_eps",
)  # numbers in [0, 1]
POSITIVE_HYPERPARAMS = ("clip_range", "clip_range_vf", "target_kl", "max_grad_norm", "rms_prop_eps")  # > 0
NON_NEGATIVE_HYPERPARAMS = ("ent_coef", "vf_coef")
# Set by the trainer itself, never by a yaml entry.
RESERVED = ("env", "seed", "verbose", "tensorboard_log", "device", "_init_setup_model")


@dataclass(frozen=True)
class Hyperparams:
    """The resolved hyperparameters of one run, as yaml data."""

    algo: str
    env_id: str
    preset: str
    n_timesteps: int
    policy: str
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    algo_kwargs: dict[str, Any] = field(default_factory=dict)  # learning_rate, policy_kwargs, n_steps, ...

    def model_kwargs(self, n_robots: int | None = None) -> dict[str, Any]:
        """Keyword arguments for the SB3 class (schedules, activation and features extractor classes built
        here; the ``swarm`` extractor needs ``n_robots``)."""
        kwargs = dict(self.algo_kwargs)
        if "learning_rate" in kwargs:
            kwargs["learning_rate"] = learning_rate(kwargs["learning_rate"])
        if "policy_kwargs" in kwargs:
            policy_kwargs = dict(kwargs["policy_kwargs"])
            if "activation_fn" in policy_kwargs:
                import torch

                classes = {"tanh": torch.nn.Tanh, "relu": torch.nn.ReLU}
                policy_kwargs["activation_fn"] = classes[policy_kwargs["activation_fn"]]
            if policy_kwargs.pop("features_extractor", "flatten") == "swarm":
                from dpr.policies.features import SwarmFeatures

                if n_robots is None:
                    raise ValueError("the swarm features extractor needs n_robots")
                policy_kwargs["features_extractor_class"] = SwarmFeatures
                policy_kwargs["features_extractor_kwargs"] = {"n_robots": int(n_robots)}
            kwargs["policy_kwargs"] = policy_kwargs
        return kwargs

    def as_dict(self) -> dict[str, Any]:
        return {
            "preset": self.preset,
            "n_timesteps": self.n_timesteps,
            "policy": self.policy,
            "env_kwargs": dict(self.env_kwargs),
            **self.algo_kwargs,
        }


def learning_rate(value: float | str):
    """A constant learning rate, or for ``"lin_X"`` a schedule from X (start) to 0 (end)."""
    if isinstance(value, str):
        from stable_baselines3.common.utils import LinearSchedule

        return LinearSchedule(_linear_start(value, "learning_rate"), 0.0, 1.0)
    return float(value)


def _linear_start(value: str, where: str) -> float:
    try:
        start = float(value.removeprefix(LINEAR_PREFIX)) if value.startswith(LINEAR_PREFIX) else None
    except ValueError:
        start = None
    if start is None or not 0 < start < float("inf"):
        raise ValueError(f"{where}: expected a number > 0 or 'lin_X' with X > 0, got {value!r}")
    return start


def hyperparams_file(algo: str) -> Path:
    if algo not in ALGOS:
        raise ValueError(f"algo must be one of {ALGOS}, got {algo!r}")
    return HYPERPARAMS_DIR / f"{algo}.yml"


def read_entries(algo: str) -> dict[str, dict]:
    """All entries of ``algo``'s yaml file, by env id or preset name."""
    path = hyperparams_file(algo)
    entries = load_yaml(path, "hyperparams")
    if not isinstance(entries, dict):
        raise ValueError(f"{path}: expected a mapping of env ids and presets to entries")
    return entries


def load_hyperparams(
    algo: str, env_id: str, preset: str = DEFAULT_PRESET, overrides: dict[str, Any] | None = None
) -> Hyperparams:
    """The hyperparameters of ``algo`` on ``env_id`` for ``preset`` ("default": the env id's entry; "paper";
    "finetune" or "batched": the env id's entry updated with that entry),
    with ``overrides`` (yaml-style values, e.g. ``{"n_steps": 64, "learning_rate": "lin_1e-3"}``) applied.
    Unknown algo, preset, env id or key: a ValueError listing the choices."""
    path = hyperparams_file(algo)
    if preset not in PRESETS:
        raise ValueError(f"preset must be one of {PRESETS}, got {preset!r}")
    if env_id not in TASKS:
        raise ValueError(f"env must be one of {tuple(TASKS)}, got {env_id!r}")
    entries = read_entries(algo)
    # a user's task (dpr.envs.register_task) takes the entry of the built-in task it names
    key = PAPER_PRESET if preset == PAPER_PRESET else HYPERPARAMS_OF.get(env_id, env_id)
    keys = [key, preset] if preset in ON_TOP else [key]
    for name in keys:
        if name not in entries:
            raise ValueError(f"{path} has no entry {name!r}; it has {sorted(entries)}")
    entry = {k: v for name in keys for k, v in entries[name].items()}
    entry.update(overrides or {})
    key = " + ".join(keys)
    return _validate(algo, env_id, preset, entry, f"{path} [{key}]" + (" with overrides" if overrides else ""))


def _check_int(where: str, name: str, value: Any, minimum: int, maximum: int | None = None) -> None:
    """:func:`dpr.checks.check_int`, its message prefixed by the yaml entry ``where`` the value was read from."""
    try:
        check_int(name, value, minimum, maximum)
    except ParameterError as error:
        raise ValueError(f"{where}: {error}") from None


def _check_numbers(where: str, entry: dict[str, Any]) -> None:
    """The bounds of :data:`INT_HYPERPARAMS` and of the numbers that must lie in [0, 1], be > 0 or >= 0 (a value of
    None is SB3's default, and a DQN ``train_freq`` of [N, "step"] is SB3's to check)."""
    for name, (low, high) in INT_HYPERPARAMS.items():
        if entry.get(name) is not None:
            _check_int(where, name, entry[name], low, high)
    if isinstance(entry.get("train_freq"), int) or isinstance(entry.get("train_freq"), float):
        _check_int(where, "train_freq", entry["train_freq"], 1, MAX_TIMESTEPS)
    bounds = [(name, {"minimum": 0, "maximum": 1}) for name in UNIT_HYPERPARAMS]
    bounds += [(name, {"above": 0}) for name in POSITIVE_HYPERPARAMS]
    bounds += [(name, {"minimum": 0}) for name in NON_NEGATIVE_HYPERPARAMS]
    for name, bound in bounds:
        if entry.get(name) is not None:
            try:
                check_number(name, entry[name], **bound)
            except ParameterError as error:
                raise ValueError(f"{where}: {error}") from None


def _validate(algo: str, env_id: str, preset: str, entry: dict[str, Any], where: str) -> Hyperparams:
    entry = dict(entry)
    n_timesteps = entry.pop("n_timesteps", None)
    _check_int(where, "n_timesteps", n_timesteps, 1, MAX_TIMESTEPS)
    policy = entry.pop("policy", "MlpPolicy")
    env_kwargs = entry.pop("env_kwargs", None) or {}
    if not isinstance(env_kwargs, dict):
        raise ValueError(f"{where}: env_kwargs must be a mapping, got {env_kwargs!r}")
    allowed = set(inspect.signature(algo_class(algo).__init__).parameters) - {"self", "policy", *RESERVED}
    unknown = sorted(set(entry) - allowed)
    if unknown:
        raise ValueError(f"{where}: unknown hyperparameter(s) {unknown} for {algo}; choose from {sorted(allowed)}")
    _check_numbers(where, entry)
    if "learning_rate" in entry:
        value = entry["learning_rate"]
        if isinstance(value, str):
            _linear_start(value, f"{where}: learning_rate")
        elif isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value < float("inf"):
            raise ValueError(f"{where}: learning_rate must be a number > 0 or 'lin_X', got {value!r}")
    policy_kwargs = entry.get("policy_kwargs") or {}
    if not isinstance(policy_kwargs, dict) or set(policy_kwargs) - set(POLICY_KWARGS):
        raise ValueError(f"{where}: policy_kwargs may only set {POLICY_KWARGS}, got {policy_kwargs!r}")
    for name, layers in (
        ("net_arch", policy_kwargs.get("net_arch", [64])),
        ("robot_net", policy_kwargs.get("robot_net", [64])),
    ):
        if not isinstance(layers, list) or (name == "robot_net" and not layers) or len(layers) > MAX_LAYERS:
            raise ValueError(
                f"{where}: policy_kwargs.{name} must be a list of at most {MAX_LAYERS} layer sizes, got {layers!r}"
            )
        for size in layers:
            _check_int(where, f"policy_kwargs.{name} (layer sizes)", size, 1, MAX_LAYER_SIZE)
    if policy_kwargs.get("features_extractor", "flatten") not in FEATURES_EXTRACTORS:
        raise ValueError(
            f"{where}: policy_kwargs.features_extractor must be one of {FEATURES_EXTRACTORS}, "
            f"got {policy_kwargs['features_extractor']!r}"
        )
    if "critic" in policy_kwargs and (str(policy) != SWARM_POLICY or policy_kwargs["critic"] not in SWARM_CRITICS):
        raise ValueError(
            f"{where}: policy_kwargs.critic is {SWARM_POLICY}'s, one of {SWARM_CRITICS}; "
            f"got {policy_kwargs['critic']!r} with policy {policy!r}"
        )
    if policy_kwargs.get("activation_fn", "tanh") not in ACTIVATIONS:
        raise ValueError(
            f"{where}: policy_kwargs.activation_fn must be one of {ACTIVATIONS}, got {policy_kwargs['activation_fn']!r}"
        )
    return Hyperparams(algo, env_id, preset, n_timesteps, str(policy), dict(env_kwargs), entry)
