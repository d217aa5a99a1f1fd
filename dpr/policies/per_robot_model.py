"""Per-robot models: one SB3 model whose observation is one robot's local observation and whose action is that
robot's ``Discrete(2)`` (1 = expand), the same weights for every robot and every swarm size.

A per-robot model file is an SB3 zip like any other (:mod:`dpr.policies.sb3`) whose metadata also holds a
:class:`RobotModelSpec`: the local-observation layout it reads (neighbour slots, clock period, dead flag, object),
the robot model and wave hold its clock was set for, and the swarm sizes it was trained on. It runs

* in the centralised env of any N: ``make_policy("model.zip", env)`` returns a
  :class:`~dpr.policies.decentralised.PerRobotPolicyAdapter` around :class:`RobotModelPolicy`, which computes every
  robot's local observation from the state, so ``dpr evaluate``, ``dpr collect`` and ``dpr view`` take the file
  with any ``--n-robots``;
* in the PettingZoo env made with ``parallel_env(task, **spec.parallel_env_kwargs(), n_robots=N)``:
  ``RobotModelPolicy.load(path).act_agents(observations)``; ``load_model(path, AgentsAsVecEnv(env),
  for_training=True)`` gives the model ready for PPO fine-tuning on it.

:func:`check_per_robot_env` refuses, in one line naming what differs, an env the model was not trained for: another
task, robot model, clock period or neighbour count, an object or dead flags the model does not read (or reads and
the env lacks), pixel observations, or a PettingZoo env without local observations.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dpr.checks import ParameterError, check_choice, check_int
from dpr.envs import ENV_IDS
from dpr.envs.local_obs import LocalObservation
from dpr.envs.particle_env import ParticleSwarmEnv
from dpr.policies.decentralised import PerRobotPolicyAdapter
from dpr.policies.sb3 import POLICY_PARAMETER, ModelInfo, load_model, read_model_info, single_thread_torch
from dpr.sim.models import ROBOT_MODELS, swarm_class

# The layout fields a model and an env must agree on, as the error messages name them.
LAYOUT_FIELDS = ("max_neighbours", "clock_period", "dead_flag", "has_object")


@dataclass(frozen=True)
class RobotModelSpec:
    """What a per-robot model reads and what it was trained for (stored in its file as ``per_robot``).

    ``max_neighbours``, ``clock_period``, ``dead_flag`` and ``has_object`` make its
    :class:`~dpr.envs.local_obs.LocalObservation`; neighbours are the robots within ``robot_model``'s magnet
    range. ``hold_steps`` and ``n_phases`` say how the clock period was chosen (one wave cycle, ``clock_period =
    hold_steps x n_phases``; None when it was given directly); ``trained_n_robots`` are the swarm sizes of its
    training data. Only the layout and the robot model decide where it can run: any N can.
    """

    robot_model: str
    max_neighbours: int
    clock_period: int | None
    dead_flag: bool
    has_object: bool
    hold_steps: int | None = None
    n_phases: int | None = None
    trained_n_robots: tuple[int, ...] = ()

    def __post_init__(self):
        check_choice("robot_model", self.robot_model, ROBOT_MODELS)
        self.layout  # noqa: B018  (validates max_neighbours >= 1 and clock_period >= 2)
        for name in ("dead_flag", "has_object"):
            if not isinstance(getattr(self, name), bool):
                raise ParameterError(name, f"expected True or False, got {getattr(self, name)!r}")
        for n in self.trained_n_robots:
            check_int("trained_n_robots", n, 1)

    @property
    def layout(self) -> LocalObservation:
        return LocalObservation(self.max_neighbours, self.has_object, self.clock_period, self.dead_flag)

    @property
    def neighbour_range(self) -> float:
        """The robot model's magnet range: the neighbours a robot senses are the robots it is linked to."""
        return float(swarm_class(self.robot_model).magnet_range)

    def parallel_env_kwargs(self) -> dict[str, Any]:
        """The ``parallel_env`` kwargs whose per-robot observations this model reads (``n_robots`` is free)."""
        return {
            "local_obs": True,
            "max_neighbours": self.max_neighbours,
            "clock_period": self.clock_period,
            "robot_model": self.robot_model,
        }

    def as_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["trained_n_robots"] = list(self.trained_n_robots)
        return data

    @classmethod
    def from_info(cls, info: ModelInfo, path: str | Path, parameter: str = POLICY_PARAMETER) -> RobotModelSpec:
        """The spec in a model file's metadata; a :class:`ParameterError` about ``parameter`` when the file holds
        a centralised model or a malformed spec."""
        if info.per_robot is None:
            n = info.env_kwargs.get("n_robots")
            raise ParameterError(
                parameter,
                f"{path} is a centralised model (it reads the state of all {n or 'N'} robots at once and acts for "
                "the whole swarm), not a per-robot model; per-robot models are written by `dpr bc-decentralised`",
            )
        data = dict(info.per_robot)
        try:
            data["trained_n_robots"] = tuple(data.get("trained_n_robots") or ())
            return cls(**data)
        except (TypeError, ValueError) as error:
            raise ParameterError(parameter, f"{path}: malformed per-robot metadata {info.per_robot}: {error}") from None


def _describe(name: str, value: Any) -> str:
    if name == "has_object":
        return "an object in the observation" if value else "no object"
    if name == "dead_flag":
        return "a dead-robot flag" if value else "no dead-robot flag"
    if name == "clock_period":
        return "no clock" if value is None else f"clock_period={value}"
    return f"{name}={value}"


def _layout_mismatch(spec: RobotModelSpec, layout: LocalObservation) -> list[str]:
    return [
        f"the model reads {_describe(name, getattr(spec, name))}, the env gives "
        f"{_describe(name, getattr(layout, name))}"
        for name in LAYOUT_FIELDS
        if getattr(spec, name) != getattr(layout, name)
    ]


def is_parallel_env(env) -> bool:
    """Whether ``env`` is a PettingZoo env of :mod:`dpr.envs.parallel`, or an ``AgentsAsVecEnv`` of one."""
    parallel = getattr(env, "parallel_env", env)  # AgentsAsVecEnv holds the PettingZoo env
    return hasattr(parallel, "local_layout") and hasattr(parallel, "swarm_env")


def check_per_robot_env(path: str | Path, info: ModelInfo, env, centralised: bool = True) -> RobotModelSpec:
    """The spec of the per-robot model at ``path`` (metadata ``info``) if it can act in ``env``: a PettingZoo env
    of :mod:`dpr.envs.parallel` made with ``local_obs=True``, an ``AgentsAsVecEnv`` of one, or (``centralised``)
    a centralised env, wrapped or not, through :class:`PerRobotPolicyAdapter`. Otherwise a ValueError (a
    :class:`ParameterError` about ``policy`` for a centralised model) naming what differs."""
    spec = RobotModelSpec.from_info(info, path)
    if is_parallel_env(env):
        parallel = getattr(env, "parallel_env", env)
        if not parallel.local_obs:
            raise ValueError(
                f"per-robot model {path} reads local observations: make the PettingZoo env with "
                f"local_obs=True (kwargs {spec.parallel_env_kwargs()})"
            )
        base, layout = parallel.swarm_env, parallel.local_layout
    else:
        base = getattr(env, "unwrapped", None)
        if not isinstance(base, ParticleSwarmEnv):
            raise ValueError(f"per-robot model {path} runs in a dpr env, got {type(env).__name__}")
        if not centralised:
            raise ValueError(
                f"per-robot model {path} acts in a centralised env through make_policy(path, env) (every robot's "
                "local observation computed from the state); as an SB3 model it needs the PettingZoo env "
                f"(parallel_env(task, {spec.parallel_env_kwargs()})) or its AgentsAsVecEnv"
            )
        if base.obs_type == "pixels":
            raise ValueError(f"per-robot model {path} reads robot states: make the env with obs_type 'state'")
        # In the centralised env the adapter keeps the clock and the neighbour slots: only the task's parts count.
        layout = LocalObservation.for_env(base, spec.max_neighbours, spec.clock_period)
    env_id = ENV_IDS[base.task]
    problems = _layout_mismatch(spec, layout)
    if env_id != info.env_id:
        problems.insert(0, f"it was trained on {info.env_id}, this env is {env_id}")
    if base.robot_model != spec.robot_model:
        hold = f", clock period {spec.clock_period}" if spec.clock_period is not None else ""
        problems.append(
            f"it was trained on the {spec.robot_model} robot model (magnet range {spec.neighbour_range:g}{hold}), "
            f"this env has robot_model={base.robot_model!r}"
        )
    if problems:
        raise ValueError(f"per-robot model {path} does not fit this env: {'; '.join(problems)}")
    return spec


class RobotModelPolicy:
    """A per-robot model as a per-robot policy: ``act(rows)`` gives one deterministic 0/1 action (int8) per row
    of local observations (``layout``), ``act_agents`` one per PettingZoo agent. Stateless between steps."""

    def __init__(self, model, spec: RobotModelSpec, path: Path):
        self.model = model
        self.spec = spec
        self.layout: LocalObservation = spec.layout
        self.path = Path(path)

    @classmethod
    def load(cls, path: str | Path, parameter: str = POLICY_PARAMETER) -> RobotModelPolicy:
        """The per-robot model file at ``path`` (a :class:`ParameterError` about ``parameter`` for a file that is
        not one), predicting on one torch thread."""
        single_thread_torch()
        info = read_model_info(path, parameter)
        spec = RobotModelSpec.from_info(info, path, parameter)
        model, _ = load_model(path, parameter=parameter)
        if model.observation_space.shape != (spec.layout.size,) or getattr(model.action_space, "n", None) != 2:
            raise ParameterError(
                parameter,
                f"{path}: its spaces {model.observation_space}, {model.action_space} are not one robot's "
                f"(Box({spec.layout.size},), Discrete(2))",
            )
        return cls(model, spec, Path(path))

    def reset(self, seed: int | None = None) -> None:
        """Nothing to reset: every action is a function of the robot's current observation."""

    def act(self, rows: np.ndarray) -> np.ndarray:
        rows = np.asarray(rows, dtype=np.float32)
        if rows.ndim != 2 or rows.shape[1] != self.layout.size:
            raise ValueError(f"expected rows of {self.layout.size} values (M, {self.layout.size}), got {rows.shape}")
        actions, _ = self.model.predict(rows, deterministic=True)
        return np.asarray(actions, dtype=np.int8).reshape(len(rows))

    def act_agents(self, observations: Mapping[str, np.ndarray]) -> dict[str, int]:
        agents = list(observations)
        actions = self.act(np.stack([observations[agent] for agent in agents]))
        return {agent: int(actions[i]) for i, agent in enumerate(agents)}


def per_robot_model_policy(path: str | Path, env) -> PerRobotPolicyAdapter:
    """The per-robot model at ``path`` acting in the centralised env ``env`` (any N): what ``make_policy`` returns
    for it. A ValueError naming what differs when ``env`` is not one it was trained for."""
    info = read_model_info(path)
    if is_parallel_env(env):
        raise ValueError(
            f"make_policy runs per-robot model {path} in a centralised env; in the PettingZoo env use "
            "RobotModelPolicy.load(path).act_agents(observations)"
        )
    check_per_robot_env(path, info, env)
    return PerRobotPolicyAdapter(env, RobotModelPolicy.load(path))


__all__ = [
    "RobotModelPolicy",
    "RobotModelSpec",
    "check_per_robot_env",
    "is_parallel_env",
    "per_robot_model_policy",
]
