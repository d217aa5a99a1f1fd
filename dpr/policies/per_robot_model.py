"""Per-robot models: one SB3 model whose observation is one robot's local observation and whose action is that
robot's ``Discrete(2)`` (1 = expand), the same weights for every robot and every swarm size.

A per-robot model file is an SB3 zip like any other (:mod:`dpr.policies.model_file`) whose metadata also holds a
:class:`RobotModelSpec`: the local-observation layout it reads (neighbour slots, clock period, dead flag, object),
the robot model and wave hold its clock was set for, and the swarm sizes it was trained on. It runs

* in the centralised env of any N: ``make_policy("model.zip", env)`` returns a
  :class:`~dpr.policies.decentralised.PerRobotPolicyAdapter` around :class:`RobotModelPolicy`, which computes every
  robot's local observation from the state, so ``dpr evaluate``, ``dpr collect`` and ``dpr view`` take the file
  with any ``--n-robots``;
* in the PettingZoo env made with ``parallel_env(task, **spec.parallel_env_kwargs(), n_robots=N)``:
  ``RobotModelPolicy.load(path).act_agents(observations)``; ``load_model(path, AgentsAsVecEnv(env),
  for_training=True)`` gives the model ready for PPO fine-tuning on it.

:func:`~dpr.policies.per_robot_spec.check_per_robot_env` refuses, in one line naming what differs, an env the model
was not trained for.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from dpr.checks import ParameterError
from dpr.envs.local_obs import LocalObservation
from dpr.policies.decentralised import PerRobotPolicyAdapter
from dpr.policies.model_file import POLICY_PARAMETER, read_model_info
from dpr.policies.per_robot_spec import RobotModelSpec, check_per_robot_env, is_parallel_env
from dpr.policies.sb3 import load_model, single_thread_torch


class RobotModelPolicy:
    """A per-robot model as a per-robot policy: ``act(rows)`` gives one deterministic 0/1 action (int8) per row
    of local observations (``layout``), ``act_agents`` one per PettingZoo agent. Stateless between steps."""

    def __init__(self, model, spec: RobotModelSpec, path: Path):
        self.model = model
        self.spec = spec
        self.layout: LocalObservation = spec.layout
        self.path = Path(path)

    @classmethod
    def load(cls, path: str | Path, parameter: str = POLICY_PARAMETER, single_thread: bool = True) -> RobotModelPolicy:
        """The per-robot model file at ``path`` (a :class:`ParameterError` about ``parameter`` for a file that is
        not one), predicting on one torch thread (``single_thread``; the batched engine keeps its threads)."""
        if single_thread:
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


__all__ = ["RobotModelPolicy", "RobotModelSpec", "check_per_robot_env", "per_robot_model_policy"]
