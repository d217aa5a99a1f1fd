"""The scripted waves for K envs at once, in torch: what drives the batched engine (:mod:`dpr.envs.batched`) with
no Python loop over envs or robots.

Each class computes, row by row, the action its single-env counterpart computes from the same observation:

* :class:`BatchedWavePolicy` -- :class:`dpr.policies.wave.WavePolicy`, the paper's centralised wave (bins planned
  at each cycle's start, a step counter per env);
* :class:`BatchedMarkovWavePolicy` -- :class:`dpr.policies.wave.MarkovWavePolicy`, its phase read from the
  observation alone (``obs_last_action=True``);
* :class:`BatchedDecentralisedWavePolicy` -- :class:`dpr.policies.decentralised.DecentralisedWavePolicy` run
  through its :class:`~dpr.policies.decentralised.PerRobotPolicyAdapter` (each robot from its own distance to the
  goal and the shared clock).

Call a policy with the observations ``[K, D]`` (a torch tensor, or numpy as :meth:`step` returns them) and
``episode_start``, a bool ``[K]`` that marks the envs whose observation is the first of an episode
(``envs.episode_start``): those envs' memory is reset before they act, as ``policy.reset()`` after
``env.reset()`` does for one env. With the NEXT_STEP autoreset these are the envs that *reset at the last step*,
not those whose episode just ended::

    envs = gymnasium.make_vec("dpr/Navigation-v0", num_envs=K, vectorization_mode="vector_entry_point",
                              robot_model="disk")
    policy = BatchedWavePolicy.from_env(envs)
    observations, _ = envs.reset_tensors(seed=0)
    for _ in range(steps):
        observations, rewards, terminated, truncated, info = envs.step_tensors(
            policy(observations, envs.episode_start))

Actions come back as the envs take them: int8 ``[K, N]`` (multibinary), float32 ``[K, N]`` (continuous) or int64
``[K]`` (discrete, robot 0 the most significant bit); a tensor on the policy's device for a tensor, numpy for numpy.
"""

from __future__ import annotations

import torch

from dpr.checks import ParameterError, check_choice, check_int, check_number
from dpr.envs.particle_env import ACTION_TYPES, HELD_STEPS_CAP, LENGTH_SCALE, ROBOT_FEATURES, joint_action_bits
from dpr.policies.decentralised import DEFAULT_N_PHASES
from dpr.policies.wave import BIN_WIDTH, MODEL_DEFAULTS, START_SIDES


class _BatchedPolicy:
    """What the three waves share: arguments, the observations' conversion, the actions' encoding."""

    def __init__(self, num_envs: int, n_robots: int, action_type: str, device: str | torch.device):
        self.num_envs = check_int("num_envs", num_envs, 1)
        self.n_robots = check_int("n_robots", n_robots, 1)
        self.action_type = check_choice("action_type", action_type, ACTION_TYPES)
        self.device = torch.device(device)
        self._bits = torch.as_tensor(joint_action_bits(self.n_robots), device=self.device)

    @staticmethod
    def _env_settings(envs) -> dict:
        """The settings of a batched vector env (wrapped or not) that a wave needs, with its robot model's
        defaults (:data:`~dpr.policies.wave.MODEL_DEFAULTS`)."""
        base = envs.unwrapped
        template = getattr(base, "template", None)
        if template is None:
            raise ParameterError("envs", f"expected a dpr.envs.batched vector env, got {type(base).__name__}")
        return {
            "num_envs": base.num_envs,
            "n_robots": template.n_robots,
            "action_type": template.action_type,
            "device": base.device,
            "defaults": dict(MODEL_DEFAULTS[template.robot_model]),
            "obs_last_action": template.obs_last_action,
        }

    def _state(self, observations) -> torch.Tensor:
        """The observations as float64 ``[K, D]`` on the policy's device (the single waves read them as float64)."""
        state = torch.as_tensor(observations, device=self.device).to(torch.float64)
        if state.dim() != 2 or state.shape[0] != self.num_envs or state.shape[1] < ROBOT_FEATURES * self.n_robots:
            raise ParameterError(
                "observations",
                f"expected [{self.num_envs}, D >= {ROBOT_FEATURES * self.n_robots}] state vectors, "
                f"got {list(state.shape)}",
            )
        return state

    def _observed_positions(self, state: torch.Tensor) -> torch.Tensor:
        """The robots' positions as observed (goal frame, / 1000), ``[K, N, 2]``."""
        robots = state[:, : ROBOT_FEATURES * self.n_robots].reshape(self.num_envs, self.n_robots, ROBOT_FEATURES)
        return robots[..., 0:2]

    def _positions(self, state: torch.Tensor) -> torch.Tensor:
        """The robots' positions in world units (goal frame), ``[K, N, 2]``, as the single waves compute them."""
        return self._observed_positions(state) * 1000.0

    def _rows(self, episode_start) -> torch.Tensor | None:
        if episode_start is None:
            return None
        rows = torch.as_tensor(episode_start, device=self.device)
        if rows.shape != (self.num_envs,) or rows.dtype != torch.bool:
            raise ParameterError(
                "episode_start", f"expected a bool [{self.num_envs}], got {rows.dtype} {list(rows.shape)}"
            )
        return rows

    def _encode(self, expand: torch.Tensor, like):
        """Expand flags ``[K, N]`` as the env's actions, a tensor or numpy as ``like`` is."""
        if self.action_type == "multibinary":
            actions = expand.to(torch.int8)
        elif self.action_type == "continuous":
            actions = expand.to(torch.float32)
        else:
            actions = (expand.long() * self._bits).sum(dim=1)
        return actions if isinstance(like, torch.Tensor) else actions.cpu().numpy()


def _plan(positions: torch.Tensor, bin_width: float, start_side: str) -> torch.Tensor:
    """:meth:`WavePolicy.plan` for every env: each robot's bin (0 expands first), ``[K, N]`` int64, from positions
    ``[K, N, 2]`` in the goal frame."""
    centre = positions.mean(dim=1)
    norm = torch.sqrt((centre * centre).sum(dim=1, keepdim=True))
    fallback = torch.tensor([1.0, 0.0], dtype=positions.dtype, device=positions.device)
    direction = torch.where(norm > 0, centre / torch.where(norm > 0, norm, 1.0), fallback)
    distance = (positions * direction[:, None, :]).sum(dim=2).abs()
    bins = torch.floor((distance - distance.amin(dim=1, keepdim=True)) / bin_width).long()
    if start_side == "far":
        bins = bins.amax(dim=1, keepdim=True) - bins
    return bins


class BatchedWavePolicy(_BatchedPolicy):
    """:class:`~dpr.policies.wave.WavePolicy` for ``num_envs`` envs at once (same arguments and rule): at each
    env's cycle start its robots are binned by their distance to the line through the goal perpendicular to the
    goal direction, and phase k of the cycle, held ``hold_steps`` steps, expands bin k. Per env it keeps the
    planned bins, their count and the step inside the cycle, reset by ``episode_start`` or :meth:`reset`."""

    def __init__(
        self,
        num_envs: int,
        n_robots: int,
        action_type: str = "multibinary",
        hold_steps: int = 10,
        bin_width: float = BIN_WIDTH,
        start_side: str = "near",
        device: str | torch.device = "cpu",
    ):
        super().__init__(num_envs, n_robots, action_type, device)
        self.hold_steps = check_int("hold_steps", hold_steps, 1)
        self.bin_width = check_number("bin_width", bin_width, above=0)
        self.start_side = check_choice("start_side", start_side, START_SIDES)
        k, n = self.num_envs, self.n_robots
        self._bins = torch.zeros(k, n, dtype=torch.long, device=self.device)
        self._n_phases = torch.zeros(k, dtype=torch.long, device=self.device)
        self._step_in_cycle = torch.zeros(k, dtype=torch.long, device=self.device)

    @classmethod
    def from_env(cls, envs, **overrides) -> BatchedWavePolicy:
        """The wave for a batched vector env with its robot model's hold and side; ``overrides`` win."""
        settings = cls._env_settings(envs)
        kwargs = {**settings.pop("defaults"), **overrides}
        settings.pop("obs_last_action")
        return cls(**settings, **kwargs)

    def reset(self, rows=None) -> None:
        """Start new episodes in the envs of ``rows`` (bool ``[K]``; all by default): their next call plans a cycle."""
        rows = torch.ones(self.num_envs, dtype=torch.bool, device=self.device) if rows is None else self._rows(rows)
        self._bins = torch.where(rows[:, None], 0, self._bins)
        self._n_phases = torch.where(rows, 0, self._n_phases)
        self._step_in_cycle = torch.where(rows, 0, self._step_in_cycle)

    def __call__(self, observations, episode_start=None):
        state = self._state(observations)
        if episode_start is not None:
            self.reset(episode_start)
        replan = self._step_in_cycle >= self._n_phases * self.hold_steps
        bins = _plan(self._positions(state), self.bin_width, self.start_side)
        self._bins = torch.where(replan[:, None], bins, self._bins)
        self._n_phases = torch.where(replan, bins.amax(dim=1) + 1, self._n_phases)
        step = torch.where(replan, 0, self._step_in_cycle)
        phase = step // self.hold_steps
        self._step_in_cycle = step + 1
        return self._encode(self._bins == phase[:, None], observations)


class BatchedMarkovWavePolicy(BatchedWavePolicy):
    """:class:`~dpr.policies.wave.MarkovWavePolicy` for ``num_envs`` envs at once: a function of each env's
    observation alone (made with ``obs_last_action=True``). An env whose previous action has been held fewer
    than ``hold_steps`` steps repeats it; the others bin their robots as the wave does, rank the non-empty bins in
    wave order, and expand the bin after the nearest expanded one (the first when none is). Keeps no memory:
    ``episode_start`` is accepted and changes nothing."""

    def __init__(self, num_envs: int, n_robots: int, action_type: str = "multibinary", hold_steps: int = 10, **kwargs):
        if check_int("hold_steps", hold_steps, 1) > HELD_STEPS_CAP:
            raise ParameterError(
                "hold_steps",
                f"must be <= {HELD_STEPS_CAP} (the observation counts held steps up to it), got {hold_steps}",
            )
        super().__init__(num_envs, n_robots, action_type, hold_steps, **kwargs)

    @classmethod
    def from_env(cls, envs, **overrides) -> BatchedMarkovWavePolicy:
        if not cls._env_settings(envs)["obs_last_action"]:
            raise ParameterError(
                "obs_last_action",
                "the Markov wave reads the previous action and its held steps from the observation: "
                "make the envs with obs_last_action=True",
            )
        return super().from_env(envs, **overrides)

    def __call__(self, observations, episode_start=None):
        state = self._state(observations)
        self._rows(episode_start)  # checked, and not needed: no memory
        n = self.n_robots
        last = state[:, -n - 1 : -1] > 0.5
        held = torch.round(state[:, -1] * HELD_STEPS_CAP)  # half to even, as Python's round
        repeat = last.any(dim=1) & (held < self.hold_steps)

        bins = _plan(self._positions(state), self.bin_width, self.start_side)
        # each robot's bin's rank among its env's non-empty bins (np.unique + searchsorted, for all envs at once)
        ordered, order = torch.sort(bins, dim=1, stable=True)
        first_of_value = torch.ones_like(ordered, dtype=torch.bool)
        first_of_value[:, 1:] = ordered[:, 1:] != ordered[:, :-1]
        rank = torch.empty_like(bins).scatter_(1, order, torch.cumsum(first_of_value.long(), dim=1) - 1)
        # the bin after the nearest expanded robot's (after the last, the first; nothing expanded: the first)
        nearest = torch.where(last, rank, torch.iinfo(torch.long).max).amin(dim=1)
        target = torch.where(last.any(dim=1), (nearest + 1) % (rank.amax(dim=1) + 1), 0)
        expand = torch.where(repeat[:, None], last, rank == target[:, None])
        return self._encode(expand, observations)


class BatchedDecentralisedWavePolicy(_BatchedPolicy):
    """:class:`~dpr.policies.decentralised.DecentralisedWavePolicy` acting in ``num_envs`` centralised envs, as
    its :class:`~dpr.policies.decentralised.PerRobotPolicyAdapter` runs it in one: every robot cuts its distance to
    the goal into bands of ``bin_width`` numbered ``band mod n_phases``, and in phase p of the shared clock
    (period ``hold_steps x n_phases`` steps, counted per env since its episode started) the robots of band
    number p expand (``start_side="far"``: band number ``-band mod n_phases``). Only each robot's own distance
    and the clock are read, so the per-robot local observations (neighbours, dead flags) are never built; the
    distance is rounded to float32 as a local observation holds it, so that the bands are the adapter's."""

    def __init__(
        self,
        num_envs: int,
        n_robots: int,
        action_type: str = "multibinary",
        hold_steps: int = 4,
        n_phases: int = DEFAULT_N_PHASES,
        bin_width: float = BIN_WIDTH,
        start_side: str = "near",
        device: str | torch.device = "cpu",
    ):
        super().__init__(num_envs, n_robots, action_type, device)
        self.hold_steps = check_int("hold_steps", hold_steps, 1)
        self.n_phases = check_int("n_phases", n_phases, 2)
        self.clock_period = self.hold_steps * self.n_phases
        self.bin_width = check_number("bin_width", bin_width, above=0)
        self.start_side = check_choice("start_side", start_side, START_SIDES)
        self._steps = torch.zeros(self.num_envs, dtype=torch.long, device=self.device)  # since each env's reset

    @classmethod
    def from_env(cls, envs, **overrides) -> BatchedDecentralisedWavePolicy:
        """The wave for a batched vector env with its robot model's hold and side (what
        ``DecentralisedWavePolicy.for_env`` gives one env); ``overrides`` win."""
        settings = cls._env_settings(envs)
        kwargs = {**settings.pop("defaults"), **overrides}
        settings.pop("obs_last_action")
        return cls(**settings, **kwargs)

    def reset(self, rows=None) -> None:
        """Restart the clock of the envs of ``rows`` (bool ``[K]``; all by default)."""
        rows = torch.ones(self.num_envs, dtype=torch.bool, device=self.device) if rows is None else self._rows(rows)
        self._steps = torch.where(rows, 0, self._steps)

    def __call__(self, observations, episode_start=None):
        state = self._state(observations)
        if episode_start is not None:
            self.reset(episode_start)
        positions = self._observed_positions(state)
        sensed = torch.hypot(positions[..., 0], positions[..., 1]).to(torch.float32).to(torch.float64)
        band = torch.floor(sensed / LENGTH_SCALE / self.bin_width).long()
        phase = (self._steps % self.clock_period) * self.n_phases // self.clock_period
        self._steps = self._steps + 1
        own = band if self.start_side == "near" else -band
        return self._encode(torch.remainder(own, self.n_phases) == phase[:, None], observations)


__all__ = ["BatchedDecentralisedWavePolicy", "BatchedMarkovWavePolicy", "BatchedWavePolicy"]
