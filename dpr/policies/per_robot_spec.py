"""What a per-robot model reads and where it can run: :class:`RobotModelSpec` (stored in the model file's metadata as
``per_robot``, see :mod:`dpr.policies.model_file`) and :func:`check_per_robot_env`, which refuses in one line naming
what differs an env the model was not trained for: another task, robot model, clock period or neighbour count, an
object or dead flags the model does not read (or reads and the env lacks), pixel observations, or a PettingZoo env
without local observations. Loading and running the models is :mod:`dpr.policies.per_robot_model`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from dpr.checks import ParameterError, check_choice, check_int
from dpr.envs import ENV_IDS
from dpr.envs.local_obs import LocalObservation
from dpr.envs.particle_env import ParticleSwarmEnv
from dpr.policies.model_file import POLICY_PARAMETER
from dpr.sim.models import ROBOT_MODELS, swarm_class

# The layout fields a model and an env must agree on, as the error messages name them.
LAYOUT_FIELDS = ("max_neighbours", "clock_period", "dead_flag", "has_object", "distance_period")


@dataclass(frozen=True)
class RobotModelSpec:
    """What a per-robot model reads and what it was trained for (stored in its file as ``per_robot``).

    ``max_neighbours``, ``clock_period``, ``dead_flag``, ``has_object`` and ``distance_period`` (None in files written
    before it existed: the raw distance) make its :class:`~dpr.envs.local_obs.LocalObservation`; neighbours are the
    robots within ``robot_model``'s magnet range. ``hold_steps`` and ``n_phases`` say how the clock period was chosen
    (one wave cycle, ``clock_period = hold_steps x n_phases``; None when it was given directly); ``trained_n_robots``
    are the swarm sizes of its training data. Only the layout and the robot model decide where it can run: any N can.
    """

    robot_model: str
    max_neighbours: int
    clock_period: int | None
    dead_flag: bool
    has_object: bool
    hold_steps: int | None = None
    n_phases: int | None = None
    trained_n_robots: tuple[int, ...] = ()
    distance_period: float | None = None

    def __post_init__(self):
        check_choice("robot_model", self.robot_model, ROBOT_MODELS)
        # the layout validates max_neighbours >= 1, clock_period >= 2 and distance_period > 0 (kept as its float)
        object.__setattr__(self, "distance_period", self.layout.distance_period)
        for name in ("dead_flag", "has_object"):
            if not isinstance(getattr(self, name), bool):
                raise ParameterError(name, f"expected True or False, got {getattr(self, name)!r}")
        for n in self.trained_n_robots:
            check_int("trained_n_robots", n, 1)

    @property
    def layout(self) -> LocalObservation:
        return LocalObservation(
            self.max_neighbours, self.has_object, self.clock_period, self.dead_flag, self.distance_period
        )

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
            "distance_period": self.distance_period,
            "robot_model": self.robot_model,
        }

    def as_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["trained_n_robots"] = list(self.trained_n_robots)
        return data

    @classmethod
    def from_info(cls, info, path: str | Path, parameter: str = POLICY_PARAMETER) -> RobotModelSpec:
        """The spec in a model file's metadata ``info`` (a :class:`dpr.policies.model_file.ModelInfo`); a
        :class:`ParameterError` about ``parameter`` when the file holds a centralised model or a malformed spec."""
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
    if name == "distance_period":
        return "the raw distance to the goal" if value is None else f"the distance's phase (distance_period={value:g})"
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


def check_per_robot_env(path: str | Path, info, env, centralised: bool = True) -> RobotModelSpec:
    """The spec of the per-robot model at ``path`` (metadata ``info``) if it can act in ``env``: a PettingZoo env
    of :mod:`dpr.envs.parallel` made with ``local_obs=True`` for the model's task and layout, an
    ``AgentsAsVecEnv`` of one, or (``centralised``) a centralised env of any task with the same object or none,
    wrapped or not, through :class:`PerRobotPolicyAdapter`. Otherwise a ValueError (a :class:`ParameterError`
    about ``policy`` for a centralised model) naming what differs."""
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
            raise ValueError(f"per-robot model {path} reads robot states: use obs_type 'state' or 'pixels_state'")
        # In the centralised env the adapter computes every robot's observation with the model's own layout (its
        # clock, neighbour slots and dead flag: where the task has no dead robots, every flag reads 0), so the
        # model runs on any task whose observation has the same parts: a Navigation model drives Gate and
        # Unresponsive swarms too, not knowing in advance which robots are dead. Only an object must match.
        layout = LocalObservation(
            spec.max_neighbours, base.has_object, spec.clock_period, spec.dead_flag, spec.distance_period
        )
    env_id = ENV_IDS[base.task]
    problems = _layout_mismatch(spec, layout)
    if env_id != info.env_id and (is_parallel_env(env) or spec.has_object != base.has_object):
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


__all__ = ["LAYOUT_FIELDS", "RobotModelSpec", "check_per_robot_env", "is_parallel_env"]
