"""The four tasks as Gymnasium vector envs on the batched disk engine (:mod:`dpr.sim.batched`): K swarms stepped
in one torch call.

``gymnasium.make_vec("dpr/Navigation-v0", num_envs=K, vectorization_mode="vector_entry_point",
robot_model="disk")`` returns a :class:`NavigationVectorEnv`; each registered id has its own class here (see
:data:`VECTOR_ENV_CLASSES`). This module imports torch, so ``dpr.envs`` never imports it: Gymnasium loads it from
the id's ``vector_entry_point`` string when ``make_vec`` is called.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from dpr.checks import ParameterError, check_int
from dpr.envs.gate import GATE_CONTACT_STEP, GATE_PASSAGE, GateEnv
from dpr.envs.manipulation import ManipulationEnv
from dpr.envs.navigation import NavigationEnv
from dpr.envs.particle_env import (
    AGENT_POSITION,
    HELD_STEPS_CAP,
    LENGTH_SCALE,
    MAX_EPISODE_STEPS,
    PHYSICS_ERROR,
    ROBOT_FEATURES,
    ParticleSwarmEnv,
    StartLayout,
    joint_action_bits,
    steps_per_second,
)
from dpr.envs.unresponsive import UnresponsiveEnv
from dpr.metrics import SUCCESS_RADIUS
from dpr.sim.batched import BatchedDiskWorld

BATCHED_ROBOT_MODEL = "disk"  # the only robot model the batched engine simulates
PHYSICS_ERROR_MESSAGE = "non-finite or exploding body state; episode truncated"  # the single env's message
DEAD_ROBOTS = "dead_robots"  # info key after a reset: the indices of the episode's unresponsive robots
_FLOOR = 1e-6  # the single env's floor under a distance it divides by


class ParticleSwarmVectorEnv(VectorEnv):
    """
    ## Description
    K independent copies of one particle-robot task (:class:`~dpr.envs.navigation.NavigationEnv` and the tasks
    built on it: see ``task_class``) whose swarms of N disk robots are simulated together by
    :class:`~dpr.sim.batched.BatchedDiskWorld`, in torch on the CPU or a GPU. Each copy follows the single env's
    rules (``gymnasium.make(env_id, robot_model="disk", **kwargs)``): the same spaces, start layouts, rewards,
    episode ends and metrics. The physics is the disk model's (revision 2) rebuilt in torch and checked against
    pymunk (``tools/batched_agreement.py``), so trajectories agree with the single env's in behaviour, not to the
    bit. Only ``robot_model="disk"`` and state observations are simulated here; for the paddle model or pixels use
    ``vectorization_mode="sync"`` or ``"async"``.

    ## Action Space
    ``batch_space`` of the single env's: ``MultiBinary((K, N))`` (default), ``MultiDiscrete`` of K ``Discrete(2^N)``
    (``action_type="discrete"``), or ``Box(0, 1, (K, N))`` (``"continuous"``). :meth:`step` checks actions as the
    single env does and raises ``ValueError`` on the wrong shape, dtype or values; :meth:`step_tensors` checks the
    shape only (a learner's samples lie in the space).

    ## Observation Space
    ``Box((K, D))`` float32, each row the single env's ``state`` vector: per robot x, y (goal frame), vx, vy (all
    / 1000), angular velocity and expansion in [0, 1]; then the object's x, y, vx, vy (Manipulation), the
    opening's centre (Gate-v2), and with ``obs_last_action=True`` the previous action and its held steps / 20.

    ## Rewards
    The single env's, per copy: ``"piecewise"`` (paper eq. 2), ``"projected"`` or ``"inverse_distance"`` of the
    agent (the swarm's centre of mass, or the object), plus Manipulation's ``approach_reward`` shaping; summed over
    the ``action_repeat`` physics steps of an env step. float32 ``[K]``.

    ## Starting State
    Copy i draws its start (swarm centre, dead robots, walls, object) with its own generator through the single
    env's :meth:`~dpr.envs.particle_env.ParticleSwarmEnv.draw_layout`: after ``reset(seed=s)`` its layout is the
    single env's after ``reset(seed=s + i)``, and each later episode of copy i is the single env's next unseeded
    reset.

    ## Episode End
    Per copy, as the single env under ``gymnasium.make``: terminated when the agent comes within
    :data:`~dpr.metrics.SUCCESS_RADIUS` (10) of the goal; truncated after ``max_episode_steps`` env steps (what
    ``make_vec`` passes: the id's 2500) or when its physics blows up (``info["physics_error"]``; the copy is put
    back at its start until its reset). Copies reset themselves on the step after their episode ends
    (``AutoresetMode.NEXT_STEP``, as ``CartPoleVectorEnv``): that step ignores the copy's action and returns its
    first observation, reward 0, and neither terminated nor truncated. :attr:`episode_start` marks those copies
    (what a policy with memory, such as the wave, resets on).

    ## Info
    Gymnasium's vector convention: each key holds an array over copies and ``"_key"`` says which copies have it.
    Every reset and step: ``is_success``, ``centre_of_mass``, ``agent_position``, ``projected_displacement``,
    ``net_displacement``, ``total_distance`` (the metrics so far), ``object_position`` (Manipulation),
    ``gate_passage`` and ``gate_contact_step`` (Gate); ``dead_robots`` (the indices, ``[K, n_dead]``) for the copies
    that just reset; ``physics_error`` (a message) for the copies whose physics blew up.

    ## Arguments
    ``gymnasium.make_vec(env_id, num_envs=K, vectorization_mode="vector_entry_point", robot_model="disk",
    device="cpu", **kwargs)``, or ``NavigationVectorEnv(num_envs=K, robot_model="disk", ...)`` directly. ``kwargs``
    are the single env's (``n_robots``, ``action_type``, ``reward``, ``reward_threshold_d``, ``start_radius``,
    ``obs_last_action``, ``action_repeat`` and the task's own) and are checked by it; ``obs_type`` must be
    ``"state"``, ``render_mode`` None and a Manipulation object a ball. ``max_episode_steps`` (default 2500; None:
    no limit) counts env steps, as ``TimeLimit`` does. ``device``: a torch device, ``"cpu"`` or ``"cuda"``. Too many
    swarms or robots for the device's memory are refused before anything is allocated.

    ## Torch
    :meth:`reset_tensors` and :meth:`step_tensors` are :meth:`reset` and :meth:`step` on torch tensors that stay on
    ``device`` (observations float32 ``[K, D]``, rewards float32 ``[K]``, flags bool ``[K]``, info tensors without
    the ``"_key"`` masks): what a torch-native PPO steps.

    ## Version History
    * v0: first version: the four tasks of ``dpr`` (Gate v0, v1, v2) on the batched disk engine.
    """

    metadata = {"render_modes": [], "render_fps": 10, "autoreset_mode": AutoresetMode.NEXT_STEP}
    task_class: type[ParticleSwarmEnv] = NavigationEnv

    def __init__(
        self,
        num_envs: int = 1,
        *,
        max_episode_steps: int | None = MAX_EPISODE_STEPS,
        device: str | torch.device = "cpu",
        robot_model: str = "paddle",
        **env_kwargs: Any,
    ):
        self.num_envs = check_int("num_envs", num_envs, minimum=1)
        if robot_model != BATCHED_ROBOT_MODEL:
            raise ParameterError(
                "robot_model",
                f"the batched engine (vectorization_mode='vector_entry_point') simulates the {BATCHED_ROBOT_MODEL!r} "
                f"model only, got {robot_model!r}: pass robot_model={BATCHED_ROBOT_MODEL!r}, or make the "
                f"{robot_model!r} envs with vectorization_mode='sync' or 'async'",
            )
        if max_episode_steps is not None:
            max_episode_steps = check_int("max_episode_steps", max_episode_steps, minimum=1)
        self.max_episode_steps = max_episode_steps
        # One single env, never reset, holds the task's kwargs (checked by its constructor), spaces and layout
        # rules; every copy's start is drawn through it with that copy's generator.
        self.template = template = self.task_class(robot_model=BATCHED_ROBOT_MODEL, **env_kwargs)
        if template.obs_type != "state":
            raise ParameterError(
                "obs_type",
                f"the batched engine returns state observations only, got {template.obs_type!r}: pixels are rendered "
                "by the single env (vectorization_mode='sync' or 'async')",
            )
        if template.render_mode is not None:
            raise ParameterError(
                "render_mode", "the batched engine does not render: use the single env (gymnasium.make) to watch"
            )
        self.render_mode = None
        self.n_robots = n = template.n_robots
        self.action_type = template.action_type
        self.reward_type = template.reward_type
        self.reward_threshold_d = template.reward_threshold_d
        self.action_repeat = template.action_repeat
        self.obs_last_action = template.obs_last_action
        self.has_object = template.has_object
        self.is_gate = isinstance(template, GateEnv)
        self.approach_reward = getattr(template, "approach_reward", 0.0)
        self.metadata = {**self.metadata, "render_fps": steps_per_second({"action_repeat": self.action_repeat})}

        # A throwaway draw tells the shapes every episode shares: walls, dead robots, object, landmarks.
        probe = self._draw(template, np.random.default_rng(0))
        layout = probe[0]
        if layout.obj is not None and layout.obj.kind != "ball":
            raise ParameterError(
                "object_type", f"the batched engine simulates a ball only, got {layout.obj.kind!r}: use the single env"
            )
        self.world = BatchedDiskWorld(
            self.num_envs,
            n,
            device=device,
            n_walls=len(layout.walls),
            object_radius=None if layout.obj is None else layout.obj.size,
            object_mass=100.0 if layout.obj is None else layout.obj.mass,
        )
        self.device = self.world.device
        # after the world, which refuses a (K, N) too large for the device before anything the size of K is made
        self.single_observation_space = template.observation_space
        self.single_action_space = template.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        k = self.num_envs
        self._generators: list[np.random.Generator | None] = [None] * k

        # This episode's layout of every copy, on the host (drawn there) and as the tensors the steps read.
        self._centres = np.zeros((k, n, 2))
        self._dead = np.zeros((k, n), dtype=bool)
        self._dead_indices = np.zeros((k, len(layout.dead)), dtype=np.int64)
        self._walls = np.zeros((k, len(layout.walls), 4, 2))
        self._object_start = np.zeros((k, 2))
        self._landmarks = np.zeros((k, len(probe[1]), 2))
        # Gate's passage measure: the swarm's centre as drawn, the unit vector from it toward the goal, and the
        # walls' near face along that vector
        self._passage = np.zeros((k, 5))

        f64 = dict(dtype=torch.float64, device=self.device)
        self._goal = torch.as_tensor(template.goal, **f64)
        self._goal32 = self._goal.float()
        self._bits = torch.as_tensor(joint_action_bits(n), device=self.device)
        zeros = lambda *shape, **kw: torch.zeros(*shape, **{"device": self.device, **kw})  # noqa: E731
        # the metrics (dpr.metrics.MetricTracker) of every copy, in float64 as the single env's
        self._first = zeros(k, 2, dtype=torch.float64)  # the agent's position at the reset
        self._last = zeros(k, 2, dtype=torch.float64)  # ... after the last physics step
        self._unit = zeros(k, 2, dtype=torch.float64)  # unit vector from the first position to the goal
        self._distance = zeros(k, dtype=torch.float64)  # from the last position to the goal
        self._path = zeros(k, dtype=torch.float64)  # total distance
        self._success = zeros(k, dtype=torch.bool)
        self._gap = zeros(k, dtype=torch.float64)  # Manipulation: swarm centre to object, for the shaping
        self._steps = zeros(k, dtype=torch.int64)  # env steps since the reset (the time limit)
        self._physics_steps = zeros(k, dtype=torch.int64)  # physics steps since the reset (gate_contact_step)
        self._contact_step = torch.full((k,), -1, dtype=torch.int64, device=self.device)
        self._last_targets = zeros(k, n)  # obs_last_action: the previous action and how long it has been held
        self._held_steps = zeros(k, dtype=torch.int64)
        self._landmark_obs = zeros(k, 2 * self._landmarks.shape[1])
        self._observations: torch.Tensor | None = None  # the last returned observations
        self._autoreset = zeros(k, dtype=torch.bool)  # copies whose episode ended at the last step
        self._episode_start = zeros(k, dtype=torch.bool)

    # -- start layouts ------------------------------------------------------------------------------------
    @staticmethod
    def _draw(template: ParticleSwarmEnv, generator: np.random.Generator) -> tuple[StartLayout, np.ndarray, tuple]:
        """One episode's layout drawn with ``generator`` through ``template``, with what the task keeps of it:
        its landmarks (L, 2) and, for the gate, the passage frame."""
        template.np_random = generator
        layout = template.draw_layout()
        passage = template.passage_frame() if isinstance(template, GateEnv) else (np.zeros(2), 0.0)
        landmarks = template._landmark_positions() if template.landmark_names else np.zeros((0, 2))
        return layout, landmarks, passage

    def _seed(self, seed: int | list[int | None] | None, rows: np.ndarray) -> None:
        """New generators for ``rows``: env i gets ``seed + i`` (an int), its own entry (a list) or fresh entropy
        (None, and for every copy not seeded yet)."""
        if isinstance(seed, (list, tuple)):
            if len(seed) != self.num_envs:
                raise ParameterError(
                    "seed", f"a list of seeds must have num_envs={self.num_envs} entries, got {len(seed)}"
                )
            seeds = list(seed)
        elif seed is None:
            seeds = [None] * self.num_envs
        else:
            seed = check_int("seed", seed, minimum=0)
            super().reset(seed=seed)  # the vector env's own generator, as Gymnasium's vector envs seed it
            seeds = [seed + i for i in range(self.num_envs)]
        for i in rows:
            if seeds[i] is not None or self._generators[i] is None:
                self._generators[i] = seeding.np_random(seeds[i])[0]

    def _start_episodes(self, rows: np.ndarray) -> None:
        """Draw new layouts for the copies ``rows`` (a Python loop over the copies that reset, none over steps),
        reset their swarms and their episode's bookkeeping."""
        for i in rows:
            layout, landmarks, (along, near) = self._draw(self.template, self._generators[i])
            self._centres[i] = layout.centres
            self._dead[i] = False
            self._dead[i, layout.dead] = True
            self._dead_indices[i] = layout.dead
            if len(layout.walls):
                self._walls[i] = np.stack(layout.walls)
            if layout.obj is not None:
                self._object_start[i] = layout.obj.position
            self._landmarks[i] = landmarks
            self._passage[i] = (*layout.start, *along, near)

        mask_np = np.zeros(self.num_envs, dtype=bool)
        mask_np[rows] = True
        mask = torch.as_tensor(mask_np, device=self.device)
        self._park(mask)
        rows_of = lambda t: mask.reshape(-1, *([1] * (t.dim() - 1)))  # noqa: E731
        renew = lambda old, new: torch.where(rows_of(old), new, old)  # noqa: E731

        self._passage_frame = torch.as_tensor(self._passage, device=self.device)
        landmarks = torch.as_tensor((self._landmarks - self.template.goal) * LENGTH_SCALE, device=self.device)
        self._landmark_obs = renew(self._landmark_obs, landmarks.reshape(self.num_envs, -1).float())
        agent = self._agent_position()
        to_goal = self._goal - agent
        norm = torch.linalg.vector_norm(to_goal, dim=1)
        self._first = renew(self._first, agent)
        self._last = renew(self._last, agent)
        self._unit = renew(self._unit, torch.where(norm[:, None] > 0, to_goal / norm.clamp(min=_FLOOR)[:, None], 0.0))
        self._distance = renew(self._distance, norm)
        self._path = renew(self._path, 0.0)
        self._success = renew(self._success, norm < SUCCESS_RADIUS)
        self._gap = renew(self._gap, self._swarm_object_gap())
        self._steps = renew(self._steps, 0)
        self._physics_steps = renew(self._physics_steps, 0)
        self._contact_step = renew(self._contact_step, -1)
        self._last_targets = renew(self._last_targets, 0.0)
        self._held_steps = renew(self._held_steps, 0)
        self._autoreset = renew(self._autoreset, False)

    def _park(self, mask: torch.Tensor) -> None:
        """Put the swarms of ``mask`` at the start of their episode's layout (also what a blown-up swarm waits in
        until its reset: non-finite positions must not reach the neighbour search)."""
        device = self.device
        self.world.reset(
            mask,
            torch.as_tensor(self._centres, dtype=torch.float32, device=device),
            torch.as_tensor(self._dead, device=device),
            torch.as_tensor(self._walls, dtype=torch.float32, device=device) if self.world.n_walls else None,
            torch.as_tensor(self._object_start, dtype=torch.float32, device=device) if self.has_object else None,
        )

    # -- Gymnasium API ------------------------------------------------------------------------------------
    def reset(self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None):
        """Start new episodes: every copy, or those of ``options["reset_mask"]`` (bool ``[K]``). ``seed``: an int
        (copy i gets ``seed + i``), a list of K ints or Nones, or None (fresh entropy the first time, then each
        copy's generator continues). Returns numpy observations ``[K, D]`` and the info of the copies reset."""
        observations, info = self.reset_tensors(seed=seed, options=options)
        return observations.cpu().numpy().copy(), self._numpy_info(info, self._episode_start)

    def step(self, actions):
        """Step every copy with ``actions`` (numpy, of :attr:`action_space`); see the class docstring for the
        autoreset. Returns numpy observations, rewards, terminations, truncations and info."""
        observations, rewards, terminated, truncated, info = self._step(self._targets_of_numpy(actions))
        errors = info.get(PHYSICS_ERROR)
        info = self._numpy_info(info, torch.ones_like(self._episode_start))
        if errors is not None:
            info[PHYSICS_ERROR] = np.where(errors.cpu().numpy(), PHYSICS_ERROR_MESSAGE, "").astype(object)
            info["_" + PHYSICS_ERROR] = errors.cpu().numpy().copy()
        host = lambda t: t.cpu().numpy().copy()  # noqa: E731
        return host(observations), host(rewards), host(terminated), host(truncated), info

    def reset_tensors(self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None):
        """:meth:`reset` returning torch tensors on :attr:`device`: observations float32 ``[K, D]`` and info
        tensors over all copies."""
        mask = (options or {}).get("reset_mask")
        if mask is None:
            rows = np.arange(self.num_envs)
        else:
            mask = np.asarray(mask.cpu() if isinstance(mask, torch.Tensor) else mask)
            if mask.shape != (self.num_envs,) or mask.dtype != np.bool_:
                raise ParameterError("reset_mask", f"expected a bool array of shape ({self.num_envs},), got {mask!r}")
            rows = np.flatnonzero(mask)
        self._seed(seed, rows)
        self._start_episodes(rows)
        start = torch.zeros(self.num_envs, dtype=torch.bool, device=self.device)
        start[torch.as_tensor(rows, device=self.device, dtype=torch.long)] = True
        observations = self._observation()
        if self._observations is not None:  # a partial reset leaves the other copies' observations as they were
            observations = torch.where(start[:, None], observations, self._observations)
        self._observations, self._episode_start = observations, start
        return observations, self._info_tensors(start)

    def step_tensors(self, actions: torch.Tensor):
        """:meth:`step` on torch: ``actions`` a tensor of the action space's shape (values are not checked), on
        any device. Returns observations float32 ``[K, D]``, rewards float32 ``[K]``, terminated and truncated bool
        ``[K]`` and info tensors, all on :attr:`device`."""
        return self._step(self._targets_of_tensor(actions))

    @property
    def episode_start(self) -> torch.Tensor:
        """bool ``[K]`` on :attr:`device`: True for the copies whose last returned observation is the first of an
        episode (all after :meth:`reset`; after a step, the copies it reset)."""
        return self._episode_start

    # -- the step -----------------------------------------------------------------------------------------
    def _step(self, targets: torch.Tensor):
        if self._observations is None:
            raise RuntimeError("call reset() before step()")
        world = self.world
        resetting = self._autoreset
        active = ~resetting  # copies still stepping in this env step (a reset copy's physics step is discarded)
        rewards = torch.zeros(self.num_envs, dtype=torch.float64, device=self.device)
        terminated = torch.zeros_like(resetting)
        broken = torch.zeros_like(resetting)
        observations = self._observations
        for _ in range(self.action_repeat):  # one decision, held for action_repeat physics steps
            if self.obs_last_action:
                same = (targets == self._last_targets).all(dim=1)
                self._held_steps = torch.where(active, torch.where(same, self._held_steps + 1, 1), self._held_steps)
                self._last_targets = torch.where(active[:, None], targets, self._last_targets)
            world.step(targets)
            sane = world.is_sane()
            broken = broken | (active & ~sane)
            active = active & sane
            if not bool(sane.all()):
                self._park(~sane)
            self._physics_steps = self._physics_steps + active
            if self.is_gate:
                touched = active & (self._contact_step < 0) & world.robots_touch_walls()
                self._contact_step = torch.where(touched, self._physics_steps, self._contact_step)
            rewards = rewards + self._track(active)
            reached = active & (self._distance < SUCCESS_RADIUS)
            terminated = terminated | reached
            observations = torch.where(active[:, None], self._observation(), observations)
            active = active & ~reached  # the single env stops its repeat at the goal
        rewards = torch.where(broken, 0.0, rewards)  # the single env's step that blows up returns 0 ...
        observations = torch.where(broken[:, None], self._observations, observations)  # ... and its last obs

        self._steps = self._steps + ~resetting
        truncated = broken.clone()
        if self.max_episode_steps is not None:
            truncated |= ~resetting & (self._steps >= self.max_episode_steps)
        rows = np.flatnonzero(resetting.cpu().numpy())
        if len(rows):
            self._start_episodes(rows)
            observations = torch.where(resetting[:, None], self._observation(), observations)
        self._observations, self._episode_start = observations, resetting
        self._autoreset = terminated | truncated
        info = self._info_tensors(resetting)
        if bool(broken.any()):
            info[PHYSICS_ERROR] = broken
        return observations, rewards.float(), terminated, truncated, info

    def _agent_position(self) -> torch.Tensor:
        """What each task moves, float64 ``[K, 2]``: the swarm's centre of mass, or the object."""
        if self.has_object:
            return self.world.object_position.double()
        return self._centre_of_mass()

    def _centre_of_mass(self) -> torch.Tensor:
        return self.world.position.double().sum(dim=1) * (1.0 / self.n_robots)

    def _swarm_object_gap(self) -> torch.Tensor:
        if not self.has_object:
            return torch.zeros(self.num_envs, dtype=torch.float64, device=self.device)
        return torch.linalg.vector_norm(self.world.object_position.double() - self._centre_of_mass(), dim=1)

    def _track(self, stepped: torch.Tensor) -> torch.Tensor:
        """After a physics step: the reward of the copies that ``stepped`` (0 for the others) and their metrics,
        as ``ParticleSwarmEnv._reward`` and ``MetricTracker.update`` compute them."""
        previous, position = self._last, self._agent_position()
        distance = torch.linalg.vector_norm(position - self._goal, dim=1)
        if self.reward_type == "inverse_distance":
            reward = 1.0 / distance.clamp(min=_FLOOR)
        else:
            to_goal = self._goal - previous
            norm = torch.linalg.vector_norm(to_goal, dim=1)
            progress = torch.where(norm > 0, ((position - previous) * to_goal).sum(dim=1) / norm.clamp(min=_FLOOR), 0.0)
            reward = progress
            if self.reward_type == "piecewise":
                d = self.reward_threshold_d
                reward = torch.where(distance < d, progress * d / distance.clamp(min=_FLOOR), progress)
        if self.approach_reward:
            gap = self._swarm_object_gap()
            reward = reward + self.approach_reward * (self._gap - gap)
            self._gap = torch.where(stepped, gap, self._gap)
        step_length = torch.linalg.vector_norm(position - previous, dim=1)
        self._path = torch.where(stepped, self._path + step_length, self._path)
        self._last = torch.where(stepped[:, None], position, self._last)
        self._distance = torch.where(stepped, distance, self._distance)
        self._success = self._success | (stepped & (distance < SUCCESS_RADIUS))
        return torch.where(stepped, reward, 0.0)

    def _observation(self) -> torch.Tensor:
        """Every copy's state vector, float32 ``[K, D]`` (``ParticleSwarmEnv._state``'s layout)."""
        world, k = self.world, self.num_envs
        robots = torch.cat(
            [
                (world.position - self._goal32) * LENGTH_SCALE,
                world.velocity * LENGTH_SCALE,
                world.angular_velocity[..., None],
                world.expansion[..., None],
            ],
            dim=2,
        )
        parts = [robots.reshape(k, ROBOT_FEATURES * self.n_robots)]
        if self.has_object:
            parts += [(world.object_position - self._goal32) * LENGTH_SCALE, world.object_velocity * LENGTH_SCALE]
        parts.append(self._landmark_obs)
        if self.obs_last_action:
            held = self._held_steps.clamp(max=HELD_STEPS_CAP).double() / HELD_STEPS_CAP
            parts += [self._last_targets, held.float()[:, None]]
        return torch.cat(parts, dim=1)

    def _info_tensors(self, started: torch.Tensor) -> dict[str, torch.Tensor]:
        """The single env's info for every copy, as tensors over copies (``dead_robots`` when any copy
        ``started``)."""
        info = {
            "is_success": self._success,
            "centre_of_mass": self._centre_of_mass(),
            AGENT_POSITION: self._last,
            "projected_displacement": ((self._last - self._first) * self._unit).sum(dim=1),
            "net_displacement": torch.linalg.vector_norm(self._last - self._first, dim=1),
            "total_distance": self._path,
        }
        if self.has_object:
            info["object_position"] = self.world.object_position.double()
        if self.is_gate:
            start, along, near = (
                self._passage_frame[:, None, 0:2],
                self._passage_frame[:, None, 2:4],
                self._passage_frame[:, 4:],
            )
            past = ((self.world.position.double() - start) * along).sum(dim=2) > near
            info[GATE_PASSAGE] = past.double().mean(dim=1)
            info[GATE_CONTACT_STEP] = self._contact_step
        if bool(started.any()):
            info[DEAD_ROBOTS] = torch.as_tensor(self._dead_indices, device=self.device)
        return info

    def _numpy_info(self, info: dict[str, torch.Tensor], present: torch.Tensor) -> dict[str, np.ndarray]:
        """Info tensors as Gymnasium's vector info: numpy arrays and their ``"_key"`` masks (``present``; for
        ``dead_robots`` the copies that started an episode)."""
        present = present.cpu().numpy().copy()
        out = {}
        for key, value in info.items():
            if key == PHYSICS_ERROR:
                continue
            out[key] = value.cpu().numpy().copy()
            out["_" + key] = self._episode_start.cpu().numpy().copy() if key == DEAD_ROBOTS else present.copy()
        return out

    # -- actions ------------------------------------------------------------------------------------------
    def _targets_of_numpy(self, actions) -> torch.Tensor:
        """Check ``actions`` as the single env checks one action, and turn them into expansion targets
        float32 ``[K, N]`` on the device."""
        k, n = self.num_envs, self.n_robots
        array = np.asarray(actions)
        if self.action_type == "discrete":
            if array.shape != (k,) or array.dtype.kind not in "iu":
                raise ParameterError(
                    "actions",
                    f"expected integers of shape ({k},) for action_type='discrete', got {array.shape} {array.dtype}",
                )
            if array.size and (array.min() < 0 or array.max() >= 2**n):
                raise ParameterError("actions", f"must lie in [0, {2**n}) for action_type='discrete', got {array}")
            return self._targets_of_tensor(torch.as_tensor(array.astype(np.int64)))
        if array.shape != (k, n):
            raise ParameterError(
                "actions", f"expected shape ({k}, {n}) for action_type={self.action_type!r}, got {array.shape}"
            )
        if array.dtype.kind not in "buif":
            raise ParameterError("actions", f"must be numeric, got dtype {array.dtype}")
        targets = array.astype(np.float32)
        if self.action_type == "multibinary" and not np.all((targets == 0.0) | (targets == 1.0)):
            raise ParameterError("actions", "must hold only 0 and 1 for action_type='multibinary'")
        if self.action_type == "continuous" and not (
            np.all(np.isfinite(targets)) and targets.min() >= 0.0 and targets.max() <= 1.0
        ):
            raise ParameterError("actions", "must lie in [0, 1] for action_type='continuous'")
        return torch.as_tensor(targets, device=self.device)

    def _targets_of_tensor(self, actions: torch.Tensor) -> torch.Tensor:
        k, n = self.num_envs, self.n_robots
        actions = torch.as_tensor(actions, device=self.device)
        if self.action_type == "discrete":
            if tuple(actions.shape) != (k,):
                raise ParameterError(
                    "actions", f"expected shape ({k},) for action_type='discrete', got {list(actions.shape)}"
                )
            return ((actions.long()[:, None] & self._bits) > 0).float()  # robot 0 is the most significant bit
        if tuple(actions.shape) != (k, n):
            raise ParameterError(
                "actions", f"expected shape ({k}, {n}) for action_type={self.action_type!r}, got {list(actions.shape)}"
            )
        return actions.float()


class NavigationVectorEnv(ParticleSwarmVectorEnv):
    """``dpr/Navigation-v0`` on the batched disk engine (see :class:`ParticleSwarmVectorEnv`)."""

    task_class = NavigationEnv


class GateVectorEnv(ParticleSwarmVectorEnv):
    """``dpr/Gate-v2`` (and v0, v1 with their ids' kwargs) on the batched disk engine (see
    :class:`ParticleSwarmVectorEnv`)."""

    task_class = GateEnv


class UnresponsiveVectorEnv(ParticleSwarmVectorEnv):
    """``dpr/Unresponsive-v0`` on the batched disk engine (see :class:`ParticleSwarmVectorEnv`)."""

    task_class = UnresponsiveEnv


class ManipulationVectorEnv(ParticleSwarmVectorEnv):
    """``dpr/Manipulation-v0`` (a ball) on the batched disk engine (see :class:`ParticleSwarmVectorEnv`)."""

    task_class = ManipulationEnv


# task name -> its vector env class; dpr.envs.tasks.VECTOR_ENTRY_POINTS names them without importing this module
VECTOR_ENV_CLASSES: dict[str, type[ParticleSwarmVectorEnv]] = {
    cls.task_class.task: cls
    for cls in (NavigationVectorEnv, GateVectorEnv, UnresponsiveVectorEnv, ManipulationVectorEnv)
}

__all__ = [
    "BATCHED_ROBOT_MODEL",
    "VECTOR_ENV_CLASSES",
    "GateVectorEnv",
    "ManipulationVectorEnv",
    "NavigationVectorEnv",
    "ParticleSwarmVectorEnv",
    "UnresponsiveVectorEnv",
]
