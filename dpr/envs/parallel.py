"""One agent per robot: a PettingZoo ``ParallelEnv`` view of the particle-robot tasks, and an SB3 adapter.

``parallel_env(task, **kwargs)`` wraps ONE instance of the task's Gymnasium env (the "super-agent" env of
:mod:`dpr.envs`, which holds the physics) and splits its ``MultiBinary(N)`` (or ``Box(0, 1, (N,))``) action
into N agents ``robot_0 .. robot_{N-1}``. Stepping every agent with its entry of a super-agent action gives
exactly the super-agent env's trajectory.

Conventions (also in :class:`ParticleParallelEnv`'s docstring):

* Actions: ``Discrete(2)`` per agent for ``action_type="multibinary"`` (1 = expand), ``Box(0, 1, (1,))``
  for ``"continuous"``; ``"discrete"`` (one ``Discrete(2^N)`` choice for the whole swarm) has no per-agent
  meaning and is refused. Every agent in ``env.agents`` must be given an action at every step.
* Observations: the shared global state vector (the paper's setup), or with ``local_obs=True`` what each
  robot senses, one vector per robot whose size does not depend on N (layout in
  :class:`dpr.envs.local_obs.LocalObservation`): its own state, its goal signal, its magnet neighbours, and
  optionally a clock shared by all robots (``clock_period``).
* Rewards: ``shared_reward=True`` gives every agent the super-agent reward; ``False`` gives each agent
  ``reward / N``, so that the agents' rewards sum to the team reward.
* Dead robots (Unresponsive task) stay in ``agents``; their actions are validated and ignored (as the
  super-agent env ignores them) and ``infos[agent]["dead"]`` is True. The agent set never changes inside
  an episode, which keeps vectorised learners simple.
* All agents end together, when the super-agent env terminates (goal reached) or truncates (physics error,
  or ``max_episode_steps`` reached); ``agents`` is then ``[]`` until the next ``reset``.

``AgentsAsVecEnv(parallel_env)`` (from this module, built on first use so that ``import dpr.envs`` does not
import Stable-Baselines3 or torch) presents the agents as the N envs of an SB3 ``VecEnv``, so that one
policy network is shared by every robot::

    import torch
    from stable_baselines3 import PPO
    from dpr.envs import parallel_env
    from dpr.envs.parallel import AgentsAsVecEnv

    torch.set_num_threads(1)  # small networks train fastest on one thread beside the envs
    venv = AgentsAsVecEnv(parallel_env("navigation", n_robots=4, robot_model="disk"))
    PPO("MlpPolicy", venv, n_steps=32, batch_size=64).learn(10_000)

``SwarmsAsVecEnv([parallel_env(..., n_robots=9), parallel_env(..., n_robots=25)])`` puts the robots of several
swarms (of different sizes, with local observations of one size) into one VecEnv, so that every rollout holds
all of them (``dpr finetune-decentralised``).
"""

from __future__ import annotations

import copy
import functools
from collections.abc import Mapping
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from dpr.checks import ParameterError, check_int
from dpr.envs.local_obs import MAX_NEIGHBOURS, LocalObservation, local_observation_size, local_observations
from dpr.envs.particle_env import MAX_EPISODE_STEPS, ParticleSwarmEnv
from dpr.envs.tasks import TASK_CLASSES
from dpr.sim.constants import FPS

PER_AGENT_ACTION_TYPES = ("multibinary", "continuous")


def _check_flag(name: str, value: Any) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def _check_count(name: str, value: Any) -> int:
    return check_int(name, int(value) if isinstance(value, np.integer) else value, 1)


def _refuse_whole_swarm_kwargs(env_kwargs: Mapping[str, Any]) -> None:
    """A ValueError for super-agent env kwargs that have no per-agent meaning."""
    action_type = env_kwargs.get("action_type", "multibinary")
    if action_type == "discrete":
        raise ValueError(
            "action_type='discrete' (one Discrete(2^N) choice for the whole swarm) has no per-agent meaning; "
            f"use one of {PER_AGENT_ACTION_TYPES} with parallel_env"
        )
    obs_type = env_kwargs.get("obs_type", "state")
    if obs_type != "state":
        raise ValueError(f"parallel_env supports obs_type='state' only, got {obs_type!r}")
    if env_kwargs.get("obs_last_action"):
        raise ValueError("parallel_env does not support obs_last_action (each agent sees local observations)")


class ParticleParallelEnv(ParallelEnv):
    """A particle-robot task with one PettingZoo agent per robot, over one super-agent env.

    ## Agents
    ``robot_0 .. robot_{N-1}``; robot i is row i of the super-agent state. ``agents`` is the full list from
    ``reset`` until the episode ends, then ``[]``. Dead robots (Unresponsive) stay in ``agents``: their
    actions must still be valid and are ignored; ``infos[agent]["dead"]`` says which they are.

    ## Action Space (per agent)
    ``Discrete(2)`` (0 contract, 1 expand) for ``action_type="multibinary"``, ``Box(0, 1, (1,), float32)``
    (target expansion) for ``"continuous"``. A scalar or a one-element array is accepted. ``step`` raises
    ``ValueError`` naming the agent for an unknown agent, a missing agent or an invalid value.

    ## Observation Space (per agent)
    ``local_obs=False`` (default, the paper's setup): the super-agent env's global state vector, ``Box(6N,)``
    (``+4`` in Manipulation); every agent receives the same read-only array.

    ``local_obs=True``: what the robot senses, ``Box(6 + 7K + 3 (or 4) [+ 2] [+ 1] [+ 4],)`` float32 with
    K = ``max_neighbours`` (8), the same for every swarm size N; rows of one read-only array. In order:

    * own state (6): x, y (goal frame), vx, vy (all / 1000), angular velocity, expansion in [0, 1];
    * K neighbour slots (6 each): the robots within magnet range (the ones this robot is linked to),
      nearest first, K nearest at most: x, y relative to this robot (/ 1000), vx, vy, angular velocity,
      expansion; zeros in unused slots;
    * the neighbours' mask (K): 1 for a filled slot, 0 for padding (fewer than K neighbours, N - 1 < K);
    * the goal signal (3): the unit vector from the robot toward the goal, and its distance to the goal
      (/ 1000); with ``distance_period=P``, 4 values: the unit vector, then ``sin`` and ``cos`` of
      ``2 pi d / P`` in place of the distance d, with the own x, y zeroed (nothing grows with N);
    * with ``clock_period=T``, a clock shared by all robots (2): ``sin`` and ``cos`` of ``2 pi t / T``, t the
      steps since the reset;
    * on tasks with unresponsive robots (Unresponsive), the robot's own dead flag (1): 1 if it ignores
      commands;
    * in Manipulation, the object's x, y (goal frame), vx, vy (4), / 1000.

    :class:`dpr.envs.local_obs.LocalObservation` (``env.local_layout``) gives each part's slice.

    ## Rewards
    ``shared_reward=True`` (default): every agent receives the super-agent reward. ``False``: each agent
    receives the super-agent reward divided by N (the team reward split equally; they sum to it).

    ## Episode End
    All agents terminate together when the super-agent env terminates, and truncate together when it
    truncates (physics error, ``infos[agent]["physics_error"]``) or after ``max_episode_steps`` steps.

    ## Info
    Each agent's info is the super-agent info (metrics, ``dead_robots`` after reset) plus ``dead``.

    ## Arguments
    ``task`` (``"navigation"``, ``"gate"``, ``"unresponsive"``, ``"manipulation"``), ``max_episode_steps``
    (``MAX_EPISODE_STEPS``), ``local_obs`` (False), ``shared_reward`` (True), ``max_neighbours`` (8, an integer
    >= 1, with ``local_obs``), ``clock_period`` (None: no clock; an integer >= 2, with ``local_obs`` only),
    ``distance_period`` (None: the raw distance; a length > 0 in world units, with ``local_obs`` only), and the
    super-agent env's keyword arguments (``n_robots``, ``robot_model``, ``action_type``, ``reward``,
    ``render_mode``, task options such as ``n_dead``...). Only ``obs_type="state"`` is supported.
    ``state()`` returns the global state; ``swarm_env`` is the wrapped super-agent env.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": FPS, "is_parallelizable": True}

    def __init__(
        self,
        task: str = "navigation",
        *,
        max_episode_steps: int = MAX_EPISODE_STEPS,
        local_obs: bool = False,
        shared_reward: bool = True,
        max_neighbours: int = MAX_NEIGHBOURS,
        clock_period: int | None = None,
        distance_period: float | None = None,
        **env_kwargs: Any,
    ):
        if task not in TASK_CLASSES:
            raise ValueError(f"task must be one of {tuple(TASK_CLASSES)}, got {task!r}")
        _refuse_whole_swarm_kwargs(env_kwargs)
        self.max_episode_steps = _check_count("max_episode_steps", max_episode_steps)
        self.local_obs = _check_flag("local_obs", local_obs)
        self.shared_reward = _check_flag("shared_reward", shared_reward)
        self.max_neighbours = _check_count("max_neighbours", max_neighbours)
        if clock_period is not None:
            if not self.local_obs:
                raise ParameterError(
                    "clock_period", "the shared clock is part of the local observation: set local_obs=True"
                )
            clock_period = check_int(
                "clock_period", int(clock_period) if isinstance(clock_period, np.integer) else clock_period, 2
            )
        self.clock_period = clock_period
        if distance_period is not None and not self.local_obs:
            raise ParameterError(
                "distance_period", "the distance's phase is part of the local observation: set local_obs=True"
            )

        self._env: ParticleSwarmEnv = TASK_CLASSES[task](**env_kwargs)
        base = self._env
        self.task = task
        self.render_mode = base.render_mode
        self.metadata = {**self.metadata, "name": f"dpr_{task}_parallel_v0"}
        self.n_robots = base.n_robots
        self.possible_agents = [f"robot_{i}" for i in range(self.n_robots)]
        self.agents: list[str] = []
        self._index = {agent: i for i, agent in enumerate(self.possible_agents)}
        self._all_agents = frozenset(self.possible_agents)
        self._steps = 0

        self.local_layout = LocalObservation.for_env(base, self.max_neighbours, self.clock_period, distance_period)
        self.distance_period = self.local_layout.distance_period  # checked, as a float
        self._make_spaces()

    def _make_spaces(self) -> None:
        """Each agent's observation and action space, and the global state's."""
        base = self._env
        observation_space = self.local_layout.space() if self.local_obs else base.observation_space
        if base.action_type == "multibinary":
            action_space: spaces.Space = spaces.Discrete(2)
        else:
            action_space = spaces.Box(0.0, 1.0, (1,), dtype=np.float32)
        # One object per agent (seeding one agent's space must not seed another's), returned as is every time.
        self.observation_spaces = {a: copy.deepcopy(observation_space) for a in self.possible_agents}
        self.action_spaces = {a: copy.deepcopy(action_space) for a in self.possible_agents}
        self.state_space = copy.deepcopy(base.observation_space)

    # -- PettingZoo API -----------------------------------------------------------------------------------
    def observation_space(self, agent: str) -> spaces.Space:
        return self.observation_spaces[self._known(agent)]

    def action_space(self, agent: str) -> spaces.Space:
        return self.action_spaces[self._known(agent)]

    def reset(self, seed: int | None = None, options: dict | None = None):
        state, info = self._env.reset(seed=seed, options=options)
        self.agents = list(self.possible_agents)
        self._steps = 0
        return self._observations(state), self._infos(info)

    def step(self, actions: Mapping[str, Any]):
        if not self.agents:
            raise RuntimeError("the episode has ended (or reset() was never called): call reset() before step()")
        targets = self._targets(actions)
        state, reward, terminated, truncated, info = self._env.step(targets)
        self._steps += 1
        if self._steps >= self.max_episode_steps:
            truncated = True  # as gymnasium's TimeLimit: truncated even on the step that also terminates
        agents = self.agents
        per_agent_reward = float(reward) if self.shared_reward else float(reward) / self.n_robots
        observations = self._observations(state)
        rewards = dict.fromkeys(agents, per_agent_reward)
        terminations = dict.fromkeys(agents, bool(terminated))
        truncations = dict.fromkeys(agents, bool(truncated))
        infos = self._infos(info)
        if terminated or truncated:
            self.agents = []
        return observations, rewards, terminations, truncations, infos

    def render(self):
        return self._env.render()

    def close(self) -> None:
        self._env.close()

    def state(self) -> np.ndarray:
        """The global state vector (the super-agent observation), for centralised critics."""
        if self._env.world is None:
            raise RuntimeError("call reset() before state()")
        return self._env._state()

    @property
    def swarm_env(self) -> ParticleSwarmEnv:
        """The wrapped super-agent env (its ``world`` holds the physics)."""
        return self._env

    # -- pieces -------------------------------------------------------------------------------------------
    def _known(self, agent: str) -> str:
        if agent not in self._index:
            raise ValueError(f"unknown agent {agent!r}; agents are robot_0 .. robot_{self.n_robots - 1}")
        return agent

    def _observations(self, state: np.ndarray) -> dict[str, np.ndarray]:
        if self.local_obs:
            base = self._env
            dead = base.world.dead if self.local_layout.dead_flag else None
            rows = self.local_layout.observe(state, self.n_robots, base.swarm_class.magnet_range, self._steps, dead)
            rows.flags.writeable = False
            return dict(zip(self.possible_agents, rows))
        shared = np.array(state, dtype=np.float32)  # a copy: the agents' array outlives the env's next step
        shared.flags.writeable = False
        return dict.fromkeys(self.possible_agents, shared)

    def _infos(self, info: dict) -> dict[str, dict]:
        dead = self._env.world.dead.tolist()
        return {agent: {**info, "dead": dead[i]} for i, agent in enumerate(self.possible_agents)}

    def _action_text(self) -> str:
        if self._env.action_type == "multibinary":
            return "0 or 1 (Discrete(2))"
        return "a number in [0, 1] (Box(0, 1, (1,)))"

    def _targets(self, actions: Mapping[str, Any]) -> np.ndarray:
        """The super-agent action from a dict of per-agent actions; ValueError names a wrong agent."""
        if not isinstance(actions, Mapping):
            raise ValueError(f"actions must be a dict {{agent: action}} over env.agents, got {type(actions).__name__}")
        if actions.keys() != self._all_agents:
            unknown = [agent for agent in actions if agent not in self._index]
            if unknown:
                raise ValueError(
                    f"actions for unknown agent(s) {unknown[:5]!r}; agents are robot_0 .. robot_{self.n_robots - 1}"
                )
            missing = [agent for agent in self.agents if agent not in actions]
            raise ValueError(
                f"no action for agent(s) {missing[:5]!r} ({len(missing)} missing): every agent in "
                "env.agents needs an action at every step, dead robots included"
            )
        n = self.n_robots
        values = [actions[agent] for agent in self.possible_agents]
        try:
            array = np.asarray(values)
        except ValueError:  # ragged (scalars mixed with arrays): the per-agent path sorts it out
            array = None
        if array is not None and array.dtype.kind in "biuf" and array.shape in ((n,), (n, 1)):
            targets = array.reshape(n).astype(np.float64)
            if self._env.action_type == "multibinary":
                valid = (targets == 0.0) | (targets == 1.0)
            else:
                valid = (targets >= 0.0) & (targets <= 1.0)  # NaN fails both comparisons
            if valid.all():
                return self._for_env(targets)
        return self._for_env(np.array([self._check_one(a, v) for a, v in zip(self.possible_agents, values)]))

    def _check_one(self, agent: str, value: Any) -> float:
        array = np.asarray(value) if not isinstance(value, (str, bytes)) else None
        if array is None or array.dtype.kind not in "biuf" or array.size != 1 or array.ndim > 1:
            raise ValueError(f"action of {agent!r} must be {self._action_text()}, got {value!r}")
        number = float(array.reshape(()))
        if self._env.action_type == "multibinary":
            ok = number in (0.0, 1.0)
        else:
            ok = 0.0 <= number <= 1.0
        if not ok:
            raise ValueError(f"action of {agent!r} must be {self._action_text()}, got {value!r}")
        return number

    def _for_env(self, targets: np.ndarray) -> np.ndarray:
        # int8 takes the super-agent env's fast path for policy-made MultiBinary actions
        return targets.astype(np.int8) if self._env.action_type == "multibinary" else targets


def parallel_env(task: str, **kwargs: Any) -> ParticleParallelEnv:
    """A PettingZoo ParallelEnv of ``task`` with one agent per robot (see :class:`ParticleParallelEnv`)."""
    return ParticleParallelEnv(task, **kwargs)


__all__ = [
    "MAX_NEIGHBOURS",
    "PER_AGENT_ACTION_TYPES",
    "LocalObservation",
    "ParticleParallelEnv",
    "local_observation_size",
    "local_observations",
    "parallel_env",
]


# -- Stable-Baselines3 adapter (built on first use: SB3 imports torch) -------------------------------------
def __getattr__(name: str):
    if name == "AgentsAsVecEnv":
        return _agents_as_vec_env_class()
    if name == "SwarmsAsVecEnv":
        return _swarms_as_vec_env_class()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _pending_actions(vec_env, row: str) -> np.ndarray:
    """The actions ``step_async`` left for ``step_wait`` (taken, so that a second ``step_wait`` fails), one ``row``
    per env of the vector."""
    if vec_env._actions is None:
        raise RuntimeError("step_async() must come before step_wait()")
    actions, vec_env._actions = vec_env._actions, None
    if len(actions) != vec_env.num_envs:
        raise ValueError(f"actions must have one row per {row} ({vec_env.num_envs}), got shape {actions.shape}")
    return actions


def _on_vec_env(methods: type, name: str) -> type:
    """Class ``name`` of this module: ``methods`` (its docstring and methods) on SB3's ``VecEnv``. Built on first use
    since SB3 imports torch; pickle finds it through the module's ``__getattr__``."""
    from stable_baselines3.common.vec_env import VecEnv

    namespace = {"__doc__": methods.__doc__, "__module__": __name__, "__qualname__": name}
    return type(name, (methods, VecEnv), namespace)


@functools.cache
def _agents_as_vec_env_class() -> type:
    return _on_vec_env(_AgentsAsVecEnv, "AgentsAsVecEnv")


@functools.cache
def _swarms_as_vec_env_class() -> type:
    return _on_vec_env(_SwarmsAsVecEnv, "SwarmsAsVecEnv")


# AgentsAsVecEnv's docstring and methods; SB3's VecEnv joins them as a base on first use (_on_vec_env)
class _AgentsAsVecEnv:
    """The agents of a PettingZoo ParallelEnv as the ``num_envs`` envs of an SB3 ``VecEnv``: one
    policy with shared parameters acts for every agent (parameter sharing, as in decentralised swarms).

    Needs homogeneous agents (one observation space and one action space for all) that all act at
    every step and end together, as :class:`ParticleParallelEnv`'s do. Observations are stacked into
    ``(num_envs, *obs_shape)``; rewards and dones are per agent. When the episode ends, each agent's info
    holds ``terminal_observation`` and ``TimeLimit.truncated``, and the returned observations are those
    of the next episode (SB3's auto-reset convention). ``seed(s)`` makes the next reset use seed ``s``.
    All envs of the vector are one env: ``get_attr``/``env_method`` act on it once and repeat the
    result per index; ``render()`` returns its frame. Dead robots' transitions are not filtered out
    (their infos say ``dead``).
    """

    def __init__(self, parallel_env: ParallelEnv):
        agents = list(parallel_env.possible_agents)
        if not agents:
            raise ValueError("AgentsAsVecEnv needs a ParallelEnv with at least one possible agent")
        observation_space = parallel_env.observation_space(agents[0])
        action_space = parallel_env.action_space(agents[0])
        for agent in agents[1:]:
            if (
                parallel_env.observation_space(agent) != observation_space
                or parallel_env.action_space(agent) != action_space
            ):
                raise ValueError(
                    f"AgentsAsVecEnv needs one observation space and one action space for all agents; "
                    f"{agent!r} differs from {agents[0]!r}"
                )
        self.parallel_env = parallel_env
        self.agents = agents
        self._actions: np.ndarray | None = None
        super().__init__(len(agents), observation_space, action_space)

    def reset(self) -> np.ndarray:
        observations, infos = self.parallel_env.reset(seed=self._seeds[0], options=self._options[0] or None)
        self._reset_seeds()
        self._reset_options()
        self.reset_infos = [infos[agent] for agent in self.agents]
        return self._stack(observations)

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self):
        actions = _pending_actions(self, "agent")
        observations, rewards, terminations, truncations, infos = self.parallel_env.step(
            dict(zip(self.agents, actions))
        )
        if observations.keys() != set(self.agents):
            raise RuntimeError("AgentsAsVecEnv needs every agent to act at every step and all to end together")
        stacked = self._stack(observations)
        reward = np.array([rewards[a] for a in self.agents], dtype=np.float32)
        done = np.array([terminations[a] or truncations[a] for a in self.agents], dtype=bool)
        info_list = [dict(infos[a]) for a in self.agents]  # own copies: SB3 adds keys
        if done.any():
            if not done.all():
                raise RuntimeError("AgentsAsVecEnv needs all agents to end their episode together")
            for i, agent in enumerate(self.agents):
                info_list[i]["terminal_observation"] = stacked[i]
                info_list[i]["TimeLimit.truncated"] = bool(truncations[agent] and not terminations[agent])
            observations, reset_infos = self.parallel_env.reset()
            self.reset_infos = [reset_infos[agent] for agent in self.agents]
            stacked = self._stack(observations)
        return stacked, reward, done, info_list

    def close(self) -> None:
        self.parallel_env.close()

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        value = getattr(self.parallel_env, attr_name)
        return [value for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        setattr(self.parallel_env, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        result = getattr(self.parallel_env, method_name)(*method_args, **method_kwargs)
        return [result for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self):
        return [self.parallel_env.render()]

    def _stack(self, observations: dict) -> np.ndarray:
        return np.stack([observations[agent] for agent in self.agents])


# SwarmsAsVecEnv's docstring and methods; SB3's VecEnv joins them as a base on first use (_on_vec_env)
class _SwarmsAsVecEnv:
    """The agents of several PettingZoo ParallelEnvs (swarms, of any sizes) as one SB3 ``VecEnv``: swarm k's
    robots are the envs ``offsets[k] .. offsets[k] + N_k - 1``, each swarm an :class:`AgentsAsVecEnv`.

    One step of the vector steps every swarm once; each swarm ends and resets on its own. Every swarm must
    have the same observation and action space (a per-robot layout whose size does not depend on N), so one
    policy with shared parameters learns from swarms of several sizes in every rollout, which one
    ``AgentsAsVecEnv`` (a fixed ``num_envs``) cannot give. ``seed(s)`` gives swarm k the seed
    ``s + offsets[k]`` at its next reset. ``get_attr``/``env_method`` act once per swarm and repeat the
    result for each of its robots' indices.
    """

    def __init__(self, parallel_envs):
        parallel_envs = list(parallel_envs)
        if not parallel_envs:
            raise ValueError("SwarmsAsVecEnv needs at least one ParallelEnv")
        self.swarms = [_agents_as_vec_env_class()(env) for env in parallel_envs]
        first = self.swarms[0]
        for k, swarm in enumerate(self.swarms[1:], start=1):
            if swarm.observation_space != first.observation_space or swarm.action_space != first.action_space:
                raise ValueError(
                    f"SwarmsAsVecEnv needs one observation space and one action space for all swarms; swarm {k} "
                    f"has {swarm.observation_space}, {swarm.action_space}, swarm 0 "
                    f"{first.observation_space}, {first.action_space}"
                )
        self.offsets = [0]
        for swarm in self.swarms[:-1]:
            self.offsets.append(self.offsets[-1] + swarm.num_envs)
        self._actions: np.ndarray | None = None
        super().__init__(sum(s.num_envs for s in self.swarms), first.observation_space, first.action_space)

    @property
    def parallel_envs(self) -> list:
        """The swarms' PettingZoo envs, in order."""
        return [swarm.parallel_env for swarm in self.swarms]

    def reset(self) -> np.ndarray:
        observations, self.reset_infos = [], []
        for swarm, offset in zip(self.swarms, self.offsets):
            if self._seeds[offset] is not None:
                swarm.seed(self._seeds[offset])
            if self._options[offset]:
                swarm.set_options(self._options[offset])
            observations.append(swarm.reset())
            self.reset_infos.extend(swarm.reset_infos)
        self._reset_seeds()
        self._reset_options()
        return np.concatenate(observations)

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self):
        actions = _pending_actions(self, "robot")
        results = [
            swarm.step(actions[offset : offset + swarm.num_envs]) for swarm, offset in zip(self.swarms, self.offsets)
        ]
        self.reset_infos = [info for swarm in self.swarms for info in swarm.reset_infos]
        return (
            np.concatenate([r[0] for r in results]),
            np.concatenate([r[1] for r in results]),
            np.concatenate([r[2] for r in results]),
            [info for r in results for info in r[3]],
        )

    def close(self) -> None:
        for swarm in self.swarms:
            swarm.close()

    def _by_swarm(self, indices) -> list[tuple[int, int]]:
        """(swarm, index within it) of each vector index."""
        located = []
        for index in self._get_indices(indices):
            if not 0 <= index < self.num_envs:
                raise IndexError(f"env index {index} out of range(0, {self.num_envs})")
            k = max(k for k, offset in enumerate(self.offsets) if offset <= index)
            located.append((k, index - self.offsets[k]))
        return located

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        values = {k: swarm.get_attr(attr_name, 0)[0] for k, swarm in enumerate(self.swarms)}
        return [values[k] for k, _ in self._by_swarm(indices)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        for k in sorted({k for k, _ in self._by_swarm(indices)}):
            self.swarms[k].set_attr(attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        located = self._by_swarm(indices)
        results = {
            k: self.swarms[k].env_method(method_name, *method_args, indices=0, **method_kwargs)[0]
            for k in sorted({k for k, _ in located})
        }
        return [results[k] for k, _ in located]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self):
        return [image for swarm in self.swarms for image in swarm.get_images()]
