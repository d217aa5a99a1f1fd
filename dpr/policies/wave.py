"""The paper's hand-crafted wave policy, and a variant whose phase is read from the observation alone."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from dpr.checks import check_int, check_number
from dpr.envs.particle_env import HELD_STEPS_CAP, ROBOT_FEATURES, ParticleSwarmEnv, joint_action_bits
from dpr.sim.models import ROBOT_MODELS, swarm_class

BIN_WIDTH = 60.0  # the 2021 code's "robot diameter"
START_SIDES = ("near", "far")


class _ModelDefaults(Mapping):
    """Per robot model: the hold and wave direction that move the swarm toward the goal, as its Swarm class says
    (``wave_hold_steps``, ``wave_start_side``; tools/wave_sweep.py chose them at N=9, and tools/model_agreement.py
    checks them at N = 9 to 225: the near side leads on both built-in models at every size)."""

    def __getitem__(self, robot_model: str) -> dict:
        if robot_model not in ROBOT_MODELS:
            raise KeyError(robot_model)
        cls = swarm_class(robot_model)
        return {"hold_steps": cls.wave_hold_steps, "start_side": cls.wave_start_side}

    def __contains__(self, robot_model) -> bool:
        return robot_model in ROBOT_MODELS

    def __iter__(self):
        return iter(list(ROBOT_MODELS))

    def __len__(self) -> int:
        return len(ROBOT_MODELS)


MODEL_DEFAULTS = _ModelDefaults()  # {"paddle": {"hold_steps": 10, "start_side": "near"}, "disk": {4, "near"}, ...}


class WavePolicy:
    """Expansion waves that travel away from the goal, so that the swarm moves toward it.

    At the start of each cycle the robots are ranked by their distance to the line through the goal
    perpendicular to the goal direction (the direction from the goal to the swarm's centre), and binned by
    ``bin_width`` (60 units). Phase k of the cycle expands the robots of bin k and contracts all others;
    each phase is held ``hold_steps`` steps (10, the paper's); then a new cycle is planned. With
    ``start_side="near"`` (the paper's) the bin nearest the goal expands first; ``"far"`` reverses the wave.

    Markov in what it is given: the action depends on the current observation's robot positions (goal
    frame) and on the policy's own state, a step counter inside the cycle and the bins planned at the cycle's
    start. Call :meth:`reset` at every episode start (:func:`dpr.rollout.roll_out` does). Observations are
    the env's ``state`` vectors (or ``pixels_state`` dicts); the returned action matches ``action_type``.
    """

    def __init__(
        self,
        n_robots: int,
        action_type: str = "multibinary",
        hold_steps: int = 10,
        bin_width: float = BIN_WIDTH,
        start_side: str = "near",
    ):
        n_robots = check_int("n_robots", int(n_robots) if isinstance(n_robots, np.integer) else n_robots, 1)
        if action_type not in ("multibinary", "discrete", "continuous"):
            raise ValueError(f"action_type must be 'multibinary', 'discrete' or 'continuous', got {action_type!r}")
        hold_steps = check_int("hold_steps", int(hold_steps) if isinstance(hold_steps, np.integer) else hold_steps, 1)
        bin_width = check_number("bin_width", bin_width, above=0)
        if start_side not in START_SIDES:
            raise ValueError(f"start_side must be one of {START_SIDES}, got {start_side!r}")
        self.n_robots = n_robots
        self.action_type = action_type
        self.hold_steps = int(hold_steps)
        self.bin_width = float(bin_width)
        self.start_side = start_side
        self.reset()

    @classmethod
    def from_env(cls, env, **overrides) -> WavePolicy:
        """A wave policy for ``env`` (wrapped or not), with its robot model's defaults (:data:`MODEL_DEFAULTS`:
        paddle hold 10, disk hold 4, both from the near side). ``overrides`` (``hold_steps=``,
        ``start_side=``, ...) win."""
        base: ParticleSwarmEnv = env.unwrapped
        if base.obs_type == "pixels":
            raise ValueError("the wave policy reads robot positions: use obs_type 'state' or 'pixels_state'")
        kwargs = dict(MODEL_DEFAULTS[base.robot_model])
        kwargs.update(overrides)
        return cls(base.n_robots, base.action_type, **kwargs)

    def reset(self, seed: int | None = None) -> None:
        """Start a new episode (``seed`` is accepted for the policy interface and unused: the wave is
        deterministic)."""
        self._bins = np.zeros(self.n_robots, dtype=np.int64)
        self._n_phases = 0
        self._step_in_cycle = 0

    def plan(self, positions: np.ndarray) -> np.ndarray:
        """Bin index of each robot (0 = the first to expand) from positions in the goal frame."""
        centre = positions.mean(axis=0)
        norm = np.linalg.norm(centre)
        direction = centre / norm if norm > 0 else np.array([1.0, 0.0])
        distance = np.abs(positions @ direction)
        bins = ((distance - distance.min()) // self.bin_width).astype(np.int64)
        if self.start_side == "far":
            bins = bins.max() - bins
        return bins

    def __call__(self, observation) -> np.ndarray | int:
        state = observation["state"] if isinstance(observation, dict) else observation
        state = np.asarray(state, dtype=np.float64)
        if self._step_in_cycle >= self._n_phases * self.hold_steps:
            positions = state[: ROBOT_FEATURES * self.n_robots].reshape(self.n_robots, ROBOT_FEATURES)[:, 0:2]
            self._bins = self.plan(positions * 1000.0)
            self._n_phases = int(self._bins.max()) + 1
            self._step_in_cycle = 0
        phase = self._step_in_cycle // self.hold_steps
        self._step_in_cycle += 1
        return encode_action((self._bins == phase).astype(np.int8), self.action_type)


def encode_action(expand: np.ndarray, action_type: str) -> np.ndarray | int:
    """0/1 per robot as the env's action: MultiBinary as is, Box as float32, Discrete as an integer whose most
    significant bit is robot 0."""
    if action_type == "multibinary":
        return expand
    if action_type == "continuous":
        return expand.astype(np.float32)
    return int(expand @ joint_action_bits(len(expand)))


class MarkovWavePolicy(WavePolicy):
    """The wave as a function of the observation alone: what a policy learned by imitation can reproduce.

    It needs the env's ``obs_last_action=True``: the state then ends with the previous action and how many
    steps it has been held (a step counter carried in the observation). While the previous action has been
    held fewer than ``hold_steps`` steps it is repeated. Then the robots are binned as in
    :class:`WavePolicy`, from the current positions, the non-empty bins taken in wave order, and the bin after
    the nearest expanded one expands (after the last bin, the first; with nothing expanded, the first). On the
    paddle model this is the 10-step wave, with bins planned at every phase instead of every cycle. Arguments
    and validation are :class:`WavePolicy`'s (``hold_steps`` at most 20, what the observation counts).
    """

    def __init__(self, n_robots: int, action_type: str = "multibinary", hold_steps: int = 10, **kwargs):
        if hold_steps > HELD_STEPS_CAP:
            raise ValueError(
                f"hold_steps must be <= {HELD_STEPS_CAP} (the observation counts held steps up to it), got {hold_steps}"
            )
        super().__init__(n_robots, action_type, hold_steps, **kwargs)

    @classmethod
    def from_env(cls, env, **overrides) -> MarkovWavePolicy:
        """A Markov wave for ``env`` (wrapped or not) with its robot model's defaults; the env must have
        ``obs_last_action=True``."""
        if not env.unwrapped.obs_last_action:
            raise ValueError(
                "wave-markov reads the previous action and its held steps from the observation: "
                "make the env with obs_last_action=True (on the command line: --env-kwarg obs_last_action=true)"
            )
        return super().from_env(env, **overrides)

    def reset(self, seed: int | None = None) -> None:
        """Nothing to reset: the policy keeps no state."""

    def __call__(self, observation) -> np.ndarray | int:
        state = observation["state"] if isinstance(observation, dict) else observation
        state = np.asarray(state, dtype=np.float64)
        n = self.n_robots
        last = state[-n - 1 : -1] > 0.5
        held = round(state[-1] * HELD_STEPS_CAP)
        if last.any() and held < self.hold_steps:
            return encode_action(last.astype(np.int8), self.action_type)
        positions = state[: ROBOT_FEATURES * n].reshape(n, ROBOT_FEATURES)[:, 0:2]
        bins = self.plan(positions * 1000.0)
        rank = np.searchsorted(np.unique(bins), bins)  # position of each robot's bin among the non-empty ones
        # The bin after the nearest expanded robot's: a robot of the last phase that drifted over a bin edge
        # would otherwise make the wave skip a bin.
        target = (int(rank[last].min()) + 1) % (int(rank.max()) + 1) if last.any() else 0
        return encode_action((rank == target).astype(np.int8), self.action_type)
