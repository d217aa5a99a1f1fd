"""Decentralised control: a scripted wave in which every robot decides from its own local observation, and an
adapter that runs any such per-robot policy in the centralised (super-agent) env.

A per-robot policy maps one robot's local observation (:class:`dpr.envs.local_obs.LocalObservation`) to that
robot's action, the same function for every robot and every swarm size. ``act(rows)`` applies it to a stack of
rows at once (row i's action depends on row i only). It drives:

* the PettingZoo env (``parallel_env(..., local_obs=True, clock_period=T)``), one action per agent through
  ``act_agents(observations)``;
* the centralised env, through :class:`PerRobotPolicyAdapter`, which computes each robot's local observation
  from the global state (with its own step counter for the clock, and the robots' dead flags where the task has
  them) and stacks the robots' actions into the env's action. ``DecentralisedWavePolicy.for_env(env)`` is what
  ``make_policy("decentralised-wave", env)`` returns.

Usage with the PettingZoo env::

    env = parallel_env("navigation", robot_model="disk", **wave_env_kwargs("disk"))
    policy = DecentralisedWavePolicy.from_parallel_env(env)
    observations, infos = env.reset(seed=0)
    observations, *_ = env.step(policy.act_agents(observations))
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from dpr.checks import ParameterError, check_choice, check_int, check_number
from dpr.envs.local_obs import MAX_NEIGHBOURS, LocalObservation
from dpr.envs.particle_env import LENGTH_SCALE, ParticleSwarmEnv
from dpr.policies.wave import BIN_WIDTH, MODEL_DEFAULTS, START_SIDES, encode_action

# Phases of one cycle: the wave's length is n_phases x bin_width. Measured with tools/decentralised_sweep.py on
# Navigation (median projected displacement, seeds 0-4, 500 steps): 4 phases move paddle swarms of N=9/25/49
# toward the goal by 6.7/8.0/6.3 (centralised wave 5.3/5.8/4.3); 3, 5 and 6 phases move paddle N=9 less. On
# the disk model (revision 2; 2500 steps, seeds 0-2) 4 phases move N=9/100 by 30/18 (centralised 37/24) and 6
# phases by 45/80: there ``n_phases=6`` beats the centralised wave. The robot models' hold and wave side are
# WavePolicy's (MODEL_DEFAULTS), kept at every N: a robot does not know N.
DEFAULT_N_PHASES = 4
# A robot reads the step inside the cycle back from the clock's angle; float32 sin/cos are good to ~1e-7 rad,
# far inside half a step even for long cycles.
_CLOCK_ROUNDING = 0.5


def wave_env_kwargs(robot_model: str, hold_steps: int | None = None, n_phases: int = DEFAULT_N_PHASES) -> dict:
    """The ``parallel_env`` kwargs the decentralised wave needs on ``robot_model``: local observations with a
    clock whose period is one cycle (``hold_steps`` x ``n_phases``; the model's hold by default)."""
    check_choice("robot_model", robot_model, MODEL_DEFAULTS)
    hold = MODEL_DEFAULTS[robot_model]["hold_steps"] if hold_steps is None else hold_steps
    hold = check_int("hold_steps", hold, 1)
    return {"local_obs": True, "clock_period": hold * check_int("n_phases", n_phases, 2)}


class DecentralisedWavePolicy:
    """An expansion wave that every robot runs on its own, from its goal signal and the shared clock.

    Each robot cuts its sensed distance to the goal into bands of ``bin_width`` (60 units, the centralised
    wave's bin) and numbers them ``band mod n_phases``. The shared clock (period T = one cycle) is split into
    ``n_phases`` equal phases of ``T / n_phases`` steps (the hold); in phase p the robots whose band number
    is p expand and all others contract. With ``start_side="near"`` the wave runs away from the goal (the
    next phase expands the band one step farther out), as the centralised wave does on both robot models;
    ``"far"`` runs it toward the goal. Across a large swarm several waves, ``n_phases``
    bands apart, travel at once.

    With a layout that has a ``distance_period`` (a multiple of ``n_phases x bin_width``), a robot reads its band
    number modulo ``n_phases`` from the distance's phase instead: the same actions, without the raw distance.

    A robot uses its own observation only: no swarm centre, no N, no other robot's goal signal; its
    neighbour slots are not used by this rule. The layout (where the goal signal and the clock sit) comes from
    the env; it must have a clock (``clock_period``). Dead robots are given actions like the others (the env
    ignores them). Stateless: ``reset`` does nothing.
    """

    def __init__(
        self,
        layout: LocalObservation,
        action_type: str = "multibinary",
        n_phases: int = DEFAULT_N_PHASES,
        bin_width: float = BIN_WIDTH,
        start_side: str = "near",
    ):
        if not isinstance(layout, LocalObservation):
            raise ParameterError("layout", f"expected a LocalObservation, got {type(layout).__name__}")
        check_choice("action_type", action_type, ("multibinary", "continuous", "discrete"))
        self.n_phases = check_int("n_phases", n_phases, 2)
        if layout.clock_period is None:
            raise ParameterError(
                "clock_period", "the decentralised wave reads the shared clock: make the env with a clock_period"
            )
        if layout.clock_period < self.n_phases:
            raise ParameterError(
                "clock_period", f"must be >= n_phases ({self.n_phases}) for every phase to last a step"
            )
        self.layout = layout
        self.action_type = action_type
        self.bin_width = check_number("bin_width", bin_width, above=0)
        if layout.distance_period is not None:
            bands = layout.distance_period / self.bin_width
            if abs(bands - round(bands)) > 1e-9 or round(bands) % self.n_phases:
                raise ParameterError(
                    "distance_period",
                    f"the wave reads its band number from the distance's phase: the period must be a multiple of "
                    f"n_phases x bin_width ({self.n_phases} x {self.bin_width:g}), got {layout.distance_period:g}",
                )
        self.start_side = check_choice("start_side", start_side, START_SIDES)

    @property
    def clock_period(self) -> int:
        return int(self.layout.clock_period)

    @classmethod
    def from_parallel_env(cls, env, **overrides) -> DecentralisedWavePolicy:
        """The wave for a PettingZoo env made with ``local_obs=True`` and a ``clock_period`` (see
        :func:`wave_env_kwargs`), with its robot model's wave direction; ``overrides`` win."""
        if not getattr(env, "local_obs", False):
            raise ParameterError("local_obs", "the decentralised wave reads local observations: set local_obs=True")
        base: ParticleSwarmEnv = env.swarm_env
        kwargs = {"start_side": MODEL_DEFAULTS[base.robot_model]["start_side"], **overrides}
        return cls(env.local_layout, base.action_type, **kwargs)

    @classmethod
    def for_env(
        cls,
        env,
        hold_steps: int | None = None,
        max_neighbours: int = MAX_NEIGHBOURS,
        distance_period: float | None = None,
        **overrides,
    ) -> PerRobotPolicyAdapter:
        """The wave acting in a centralised env (wrapped or not): a :class:`PerRobotPolicyAdapter` that gives
        every robot its local observation, with a clock of period ``hold_steps`` x ``n_phases`` (the robot
        model's hold by default), and the distance's phase in place of the distance with ``distance_period``.
        ``overrides``: ``n_phases``, ``bin_width``, ``start_side``."""
        base: ParticleSwarmEnv = env.unwrapped
        if base.obs_type == "pixels":
            raise ParameterError("obs_type", "the decentralised wave reads robot states: use 'state' or 'pixels_state'")
        defaults = MODEL_DEFAULTS[base.robot_model]
        n_phases = overrides.get("n_phases", DEFAULT_N_PHASES)
        clock_period = wave_env_kwargs(base.robot_model, hold_steps, n_phases)["clock_period"]
        layout = LocalObservation.for_env(base, max_neighbours, clock_period, distance_period)
        kwargs = {"start_side": defaults["start_side"], **overrides}
        return PerRobotPolicyAdapter(env, cls(layout, base.action_type, **kwargs))

    def reset(self, seed: int | None = None) -> None:
        """Nothing to reset: every decision is a function of the robot's current observation."""

    def expand(self, rows: np.ndarray) -> np.ndarray:
        """Whether each robot expands (bool per row of ``rows``, shape ``(M, layout.size)``)."""
        rows = np.asarray(rows, dtype=np.float64)
        if rows.ndim != 2 or rows.shape[1] != self.layout.size:
            raise ValueError(f"expected rows of {self.layout.size} values (M, {self.layout.size}), got {rows.shape}")
        goal = self.layout.goal.start
        if self.layout.distance_period is None:
            distance = rows[:, goal + 2] / LENGTH_SCALE
        else:  # the distance modulo the period is all the band number mod n_phases needs
            cycle = np.mod(np.arctan2(rows[:, goal + 2], rows[:, goal + 3]) / (2 * math.pi), 1.0)
            distance = cycle * self.layout.distance_period
        band = np.floor(distance / self.bin_width).astype(np.int64)
        clock = rows[:, self.layout.clock]
        turn = np.mod(np.arctan2(clock[:, 0], clock[:, 1]) / (2 * math.pi), 1.0)  # fraction of the cycle
        period = self.clock_period
        step = np.floor(turn * period + _CLOCK_ROUNDING).astype(np.int64) % period
        phase = step * self.n_phases // period
        own = band if self.start_side == "near" else -band
        return np.mod(own, self.n_phases) == phase

    def act(self, rows: np.ndarray) -> np.ndarray:
        """Each robot's action, one per row: int8 0/1 (``multibinary``/``discrete``) or float32 (``continuous``)."""
        expand = self.expand(rows).astype(np.int8)
        return expand.astype(np.float32) if self.action_type == "continuous" else expand

    def act_agents(self, observations: Mapping[str, np.ndarray]) -> dict[str, Any]:
        """One action per agent of the PettingZoo env: an int for ``Discrete(2)``, a ``(1,)`` float32 array for
        ``Box(0, 1, (1,))``."""
        agents = list(observations)
        actions = self.act(np.stack([observations[agent] for agent in agents]))
        if self.action_type == "continuous":
            return {agent: actions[i : i + 1] for i, agent in enumerate(agents)}
        return {agent: int(actions[i]) for i, agent in enumerate(agents)}

    def __call__(self, observation: np.ndarray):
        """One robot's action from its own observation (a single row)."""
        action = self.act(np.asarray(observation)[None, :])
        return action[0:1] if self.action_type == "continuous" else int(action[0])


class PerRobotPolicyAdapter:
    """A per-robot policy acting in the centralised env: ``adapter(observation) -> env action``.

    At every call it computes each robot's local observation from the env's state vector (``layout`` of the
    per-robot policy; neighbours within the robot model's magnet range; the clock from the number of calls
    since :meth:`reset`; the dead flags from the env's world, where the layout has them), asks
    ``policy.act(rows)`` for one action per robot, and encodes them as the env's action (MultiBinary, Box, or
    the Discrete integer). Follows the registry's policy interface: call :meth:`reset` right after
    ``env.reset`` (:func:`dpr.rollout.roll_out` does).
    """

    def __init__(self, env, policy):
        base: ParticleSwarmEnv = env.unwrapped
        self.env = env
        self.policy = policy
        self.layout: LocalObservation = policy.layout
        self.n_robots = base.n_robots
        self.action_type = base.action_type
        self.neighbour_range = float(base.swarm_class.magnet_range)
        self._steps = 0

    def reset(self, seed: int | None = None) -> None:
        self._steps = 0
        self.policy.reset(seed)

    def local_observations(self, observation) -> np.ndarray:
        """Every robot's local observation ``(N, layout.size)`` for the env's current ``observation``."""
        state = observation["state"] if isinstance(observation, dict) else observation
        dead = self.env.unwrapped.world.dead if self.layout.dead_flag else None
        return self.layout.observe(np.asarray(state), self.n_robots, self.neighbour_range, self._steps, dead)

    def __call__(self, observation):
        rows = self.local_observations(observation)
        self._steps += 1
        return encode_action(np.asarray(self.policy.act(rows)), self.action_type)


__all__ = [
    "DEFAULT_N_PHASES",
    "MODEL_DEFAULTS",
    "DecentralisedWavePolicy",
    "PerRobotPolicyAdapter",
    "wave_env_kwargs",
]
