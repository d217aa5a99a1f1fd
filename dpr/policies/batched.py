"""The wave policies of :mod:`dpr.policies.wave` for K envs at once, on batched observation tensors.

Each env's action is the single-env policy's on the same observation, bit for bit: the arithmetic is the same,
in float64, on whatever device the observations are on.
"""

from __future__ import annotations

import torch

from dpr.checks import check_choice, check_int, check_number
from dpr.envs.particle_env import HELD_STEPS_CAP, LENGTH_SCALE, ROBOT_FEATURES
from dpr.policies.decentralised import DEFAULT_N_PHASES
from dpr.policies.wave import BIN_WIDTH, MODEL_DEFAULTS, START_SIDES, MarkovWavePolicy, WavePolicy


def plan_bins(positions: torch.Tensor, bin_width: float, start_side: str) -> torch.Tensor:
    """:meth:`WavePolicy.plan` for [K, N, 2] positions in the goal frame: each robot's bin [K, N] (int64)."""
    centre = positions.mean(dim=1)
    norm = centre.norm(dim=1, keepdim=True)
    fallback = torch.tensor([1.0, 0.0], dtype=positions.dtype, device=positions.device).expand_as(centre)
    direction = torch.where(norm > 0, centre / norm.clamp_min(1e-300), fallback)
    distance = (positions * direction[:, None, :]).sum(dim=2).abs()
    bins = torch.div(distance - distance.min(dim=1, keepdim=True).values, bin_width, rounding_mode="floor").long()
    if start_side == "far":
        bins = bins.max(dim=1, keepdim=True).values - bins
    return bins


def _positions(observation: torch.Tensor, n_robots: int) -> torch.Tensor:
    robots = observation[:, : ROBOT_FEATURES * n_robots].double().reshape(-1, n_robots, ROBOT_FEATURES)
    return robots[..., 0:2] * 1000.0


class BatchedWavePolicy:
    """:class:`WavePolicy` for K envs: a cycle's bins planned from each env's positions, each phase held
    ``hold_steps`` steps. Its state (bins, phases, step in the cycle) is per env; :meth:`reset` restarts the envs
    of a mask, as a single policy's ``reset`` does at an episode's start."""

    def __init__(
        self,
        num_envs: int,
        n_robots: int,
        hold_steps: int = 10,
        bin_width: float = BIN_WIDTH,
        start_side: str = "near",
        device: str | torch.device = "cpu",
    ):
        WavePolicy(n_robots, hold_steps=hold_steps, bin_width=bin_width, start_side=start_side)  # its checks
        self.n_robots, self.hold_steps, self.bin_width, self.start_side = n_robots, hold_steps, bin_width, start_side
        self.bins = torch.zeros(num_envs, n_robots, dtype=torch.long, device=device)
        self.n_phases = torch.zeros(num_envs, dtype=torch.long, device=device)
        self.step_in_cycle = torch.zeros(num_envs, dtype=torch.long, device=device)

    @classmethod
    def for_robot_model(cls, num_envs: int, n_robots: int, robot_model: str, device="cpu", **overrides):
        """The wave with ``robot_model``'s defaults (:data:`MODEL_DEFAULTS`), ``overrides`` winning."""
        return cls(num_envs, n_robots, device=device, **{**MODEL_DEFAULTS[robot_model], **overrides})

    def reset(self, mask: torch.Tensor | None = None) -> None:
        """Restart the envs of ``mask`` (all when None): their next call plans a new cycle."""
        if mask is None:
            mask = torch.ones_like(self.n_phases, dtype=torch.bool)
        self.n_phases = torch.where(mask, 0, self.n_phases)
        self.step_in_cycle = torch.where(mask, 0, self.step_in_cycle)

    def __call__(self, observation: torch.Tensor) -> torch.Tensor:
        """0/1 expansion per robot, [K, N] float32, for observations [K, D]."""
        replan = self.step_in_cycle >= self.n_phases * self.hold_steps
        if replan.any():
            bins = plan_bins(_positions(observation, self.n_robots), self.bin_width, self.start_side)
            self.bins = torch.where(replan[:, None], bins, self.bins)
            self.n_phases = torch.where(replan, self.bins.max(dim=1).values + 1, self.n_phases)
            self.step_in_cycle = torch.where(replan, 0, self.step_in_cycle)
        phase = torch.div(self.step_in_cycle, self.hold_steps, rounding_mode="floor")
        self.step_in_cycle = self.step_in_cycle + 1
        return (self.bins == phase[:, None]).float()


def bin_ranks(bins: torch.Tensor) -> torch.Tensor:
    """Each robot's bin's position among its env's non-empty bins, [K, N] (``np.searchsorted(np.unique(b), b)``)."""
    ordered, order = bins.sort(dim=1)
    steps = torch.zeros_like(ordered)
    steps[:, 1:] = (ordered[:, 1:] != ordered[:, :-1]).long()
    return torch.empty_like(bins).scatter_(1, order, steps.cumsum(dim=1))


class BatchedMarkovWavePolicy:
    """:class:`MarkovWavePolicy` for K envs: a function of the observation alone (which must end with the
    previous action and its held steps: ``obs_last_action=True``), so it keeps no state."""

    def __init__(self, n_robots: int, hold_steps: int = 10, bin_width: float = BIN_WIDTH, start_side: str = "near"):
        MarkovWavePolicy(n_robots, hold_steps=hold_steps, bin_width=bin_width, start_side=start_side)  # its checks
        self.n_robots, self.hold_steps, self.bin_width, self.start_side = n_robots, hold_steps, bin_width, start_side

    def reset(self, mask: torch.Tensor | None = None) -> None:
        """Nothing to reset: the policy keeps no state."""

    def __call__(self, observation: torch.Tensor) -> torch.Tensor:
        n = self.n_robots
        state = observation.double()
        last = state[:, -n - 1 : -1] > 0.5
        held = torch.round(state[:, -1] * HELD_STEPS_CAP)
        repeat = last.any(dim=1) & (held < self.hold_steps)
        rank = bin_ranks(plan_bins(_positions(observation, n), self.bin_width, self.start_side))
        # the bin after the nearest expanded robot's (MarkovWavePolicy.__call__ says why)
        nearest = torch.where(last, rank, torch.iinfo(rank.dtype).max).min(dim=1).values
        target = torch.where(last.any(dim=1), (nearest + 1) % (rank.max(dim=1).values + 1), 0)
        expand = rank == target[:, None]
        return torch.where(repeat[:, None], last, expand).float()


class BatchedDecentralisedWavePolicy:
    """:class:`~dpr.policies.decentralised.DecentralisedWavePolicy` for K envs, as its
    :class:`~dpr.policies.decentralised.PerRobotPolicyAdapter` runs it in one env: every robot cuts its distance to
    the goal into bands of ``bin_width`` numbered ``band mod n_phases``, and in phase p of the shared clock (period
    ``hold_steps x n_phases`` steps, counted per env from its episode's start) the robots of band number p expand
    (``start_side="far"``: band number ``-band mod n_phases``). Each robot reads only its own distance, rounded to
    float32 as its local observation holds it, so the bands are the adapter's."""

    def __init__(
        self,
        num_envs: int,
        n_robots: int,
        hold_steps: int = 10,
        n_phases: int = DEFAULT_N_PHASES,
        bin_width: float = BIN_WIDTH,
        start_side: str = "near",
        device: str | torch.device = "cpu",
    ):
        self.n_robots = check_int("n_robots", n_robots, 1)
        self.hold_steps = check_int("hold_steps", hold_steps, 1)
        self.n_phases = check_int("n_phases", n_phases, 2)
        self.bin_width = check_number("bin_width", bin_width, above=0)
        self.start_side = check_choice("start_side", start_side, START_SIDES)
        self.clock_period = self.hold_steps * self.n_phases
        self.steps = torch.zeros(num_envs, dtype=torch.long, device=device)  # since each env's episode started

    def reset(self, mask: torch.Tensor | None = None) -> None:
        """Restart the clock of the envs of ``mask`` (all when None)."""
        self.steps = torch.zeros_like(self.steps) if mask is None else torch.where(mask, 0, self.steps)

    def __call__(self, observation: torch.Tensor) -> torch.Tensor:
        n = self.n_robots
        observed = observation[:, : ROBOT_FEATURES * n].double().reshape(-1, n, ROBOT_FEATURES)[..., 0:2]
        sensed = torch.hypot(observed[..., 0], observed[..., 1]).float().double()  # as a local observation holds it
        band = torch.floor(sensed / LENGTH_SCALE / self.bin_width).long()
        phase = (self.steps % self.clock_period) * self.n_phases // self.clock_period
        self.steps = self.steps + 1
        own = band if self.start_side == "near" else -band
        return (torch.remainder(own, self.n_phases) == phase[:, None]).float()


class BatchedRandomPolicy:
    """Uniformly random 0/1 per robot, from a torch generator seeded once (the batched stream is its own: it does
    not repeat the single env's ``action_space.sample()`` draws)."""

    def __init__(self, num_envs: int, n_robots: int, seed: int = 0, device: str | torch.device = "cpu"):
        self.shape = (num_envs, n_robots)
        self.generator = torch.Generator(device=device).manual_seed(int(seed))
        self.device = device

    def reset(self, mask: torch.Tensor | None = None) -> None:
        """Nothing to reset per env."""

    def __call__(self, observation: torch.Tensor) -> torch.Tensor:
        return torch.randint(0, 2, self.shape, generator=self.generator, device=self.device).float()


class BatchedModelPolicy:
    """A centralised model file (``dpr train``, ``dpr bc``, ``dpr finetune``) acting for K envs at once: its SB3
    policy's deterministic action on the batch of observations, on their device."""

    def __init__(self, model):
        self.model = model

    def reset(self, mask: torch.Tensor | None = None) -> None:
        """Nothing to reset: the policy is a function of the observation."""

    def __call__(self, observation: torch.Tensor) -> torch.Tensor:
        policy = self.model.policy
        if next(policy.parameters()).device != observation.device:
            policy.to(observation.device)
        with torch.no_grad():
            return policy._predict(observation, deterministic=True).float()


class BatchedPerRobotModelPolicy:
    """A per-robot model file (``dpr bc-decentralised``, ``dpr finetune-decentralised``) acting for every robot of K
    envs at once: every robot's local observation computed in batch from the observations
    (:func:`dpr.policies.batched_local_obs.batched_local_observations`, with a clock counted per env from its
    episode's start and the world's dead flags where the layout has them), and the model's actor run on all K x N
    rows in one forward pass, deterministically: in each env the actions
    :class:`~dpr.policies.decentralised.PerRobotPolicyAdapter` gives there, as [K, N] targets."""

    def __init__(self, robot_policy, venv):
        self.actor = robot_policy.model.policy  # SB3's actor-critic module; only its actor's mode is used
        self.layout = robot_policy.layout
        self.venv = venv
        self.n_robots = venv.n_robots
        self.neighbour_range = float(venv.template.swarm_class.magnet_range)
        self.steps = torch.zeros(venv.num_envs, dtype=torch.long, device=venv.device)  # since each episode began

    @classmethod
    def load(cls, path: str, venv) -> BatchedPerRobotModelPolicy:
        """The per-robot model at ``path`` for the batched vector env ``venv``: a ValueError naming what differs
        where the model was not trained for ``venv``'s task and robot model."""
        from dpr.policies.model_file import read_model_info
        from dpr.policies.per_robot_model import RobotModelPolicy, check_per_robot_env

        check_per_robot_env(path, read_model_info(path), venv.template)
        return cls(RobotModelPolicy.load(path, single_thread=False), venv)

    def reset(self, mask: torch.Tensor | None = None) -> None:
        """Restart the clock of the envs of ``mask`` (all when None)."""
        self.steps = torch.zeros_like(self.steps) if mask is None else torch.where(mask, 0, self.steps)

    def local_observations(self, observation: torch.Tensor) -> torch.Tensor:
        """Every robot's local observation, [K, N, size], at the current step of each env's clock."""
        from dpr.policies.batched_local_obs import batched_local_observations

        dead = ~self.venv.world.alive if self.layout.dead_flag else None
        steps = self.steps.to(observation.device)
        return batched_local_observations(observation, self.n_robots, self.neighbour_range, self.layout, steps, dead)

    def __call__(self, observation: torch.Tensor) -> torch.Tensor:
        rows = self.local_observations(observation)
        self.steps = self.steps + 1
        if next(self.actor.parameters()).device != rows.device:
            self.actor.to(rows.device)
        with torch.no_grad():
            actions = self.actor._predict(rows.reshape(-1, rows.shape[-1]), deterministic=True)
        return actions.reshape(rows.shape[0], rows.shape[1]).float()


def make_batched_policy(name: str, venv, seed: int = 0):
    """The policy called ``name`` (:func:`dpr.policies.registry.make_policy`'s names) for the batched vector env
    ``venv``: the waves and ``random`` in batch, a centralised model file trained for ``venv``'s spaces (on either
    engine), or a per-robot model file trained for ``venv``'s robot model (any N)."""
    from dpr.policies.model_file import is_model_path, read_model_info
    from dpr.policies.registry import DECENTRALISED_WAVE, RANDOM, WAVE, WAVE_MARKOV, parse_scripted_name
    from dpr.policies.sb3 import load_model

    env = venv.template
    if is_model_path(name):
        if read_model_info(name).per_robot is not None:
            return BatchedPerRobotModelPolicy.load(name, venv)
        model, _ = load_model(name, env)
        return BatchedModelPolicy(model)
    base, settings = parse_scripted_name(name)
    if base == WAVE:
        return BatchedWavePolicy.for_robot_model(venv.num_envs, env.n_robots, env.robot_model, venv.device, **settings)
    if base == WAVE_MARKOV:
        MarkovWavePolicy.from_env(env)  # its check: the env must observe the last action
        defaults = {**MODEL_DEFAULTS[env.robot_model], **settings}
        return BatchedMarkovWavePolicy(env.n_robots, **defaults)
    if base == RANDOM:
        return BatchedRandomPolicy(venv.num_envs, env.n_robots, seed, venv.device)
    assert base == DECENTRALISED_WAVE, base  # parse_scripted_name admits no other name
    defaults = {**MODEL_DEFAULTS[env.robot_model], **settings}
    return BatchedDecentralisedWavePolicy(venv.num_envs, env.n_robots, device=venv.device, **defaults)
