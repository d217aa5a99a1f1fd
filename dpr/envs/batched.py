"""The four tasks on the batched disk engine: K envs in one Gymnasium ``VectorEnv``, stepped in one call.

``gymnasium.make_vec("dpr/Navigation-v0", num_envs=K, vectorization_mode="vector_entry_point", robot_model="disk")``
returns one of the classes below. This module imports torch, so Gymnasium imports it only when ``make_vec`` asks
for it: ``import dpr`` stays free of torch.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from dpr.checks import ParameterError, check_int, check_number_range
from dpr.envs.gate import GATE_CONTACT_STEP, GATE_PASSAGE, GateEnv
from dpr.envs.manipulation import ManipulationEnv
from dpr.envs.navigation import NavigationEnv
from dpr.envs.particle_env import (
    AGENT_POSITION,
    HELD_STEPS_CAP,
    LENGTH_SCALE,
    MAX_EPISODE_STEPS,
    PHYSICS_ERROR,
    ParticleSwarmEnv,
    joint_action_bits,
)
from dpr.envs.unresponsive import UnresponsiveEnv
from dpr.metrics import SUCCESS_RADIUS
from dpr.sim.batched import DYNAMICS, BatchedDiskWorld, SolverSettings, compiled_if

ROBOT_MODEL = "disk"  # the only robot model the batched engine has
METRICS = ("projected_displacement", "net_displacement", "total_distance")
DYNAMICS_SCALE_BOUNDS = (0.1, 10.0)  # what dynamics_scale may multiply a constant by
# The kwargs only the batched engine takes (the pymunk envs refuse them): physics to train in, never a model's own.
BATCHED_ONLY_KWARGS = ("dynamics_scale", "wall_give")


def refuse_batched_only_kwargs(env_kwargs: dict[str, Any], because: str) -> None:
    """A ParameterError about ``env_kwargs`` if it holds one of :data:`BATCHED_ONLY_KWARGS`: for env kwargs that are
    recorded (a model's, a dataset's) and so must make an env on either engine; ``because`` says who records them
    (``{name}`` in it: the kwarg)."""
    for name in BATCHED_ONLY_KWARGS:
        if name in env_kwargs:
            raise ParameterError(
                "env_kwargs", f"{name} is physics only the batched engine has, and {because.format(name=name)}"
            )


class BatchedSwarmVectorEnv(VectorEnv):
    """K envs of one particle-robot task on the batched disk engine (:class:`dpr.sim.batched.BatchedDiskWorld`).

    ## Description
    The task of :attr:`task_class` (Navigation, Gate, Unresponsive or Manipulation: see each env's docstring) for
    ``num_envs`` swarms of the disk robot model at once. The physics, the observation, the reward and the episode's
    end are the single env's; every step is tensor operations over all envs on ``device`` (``"cpu"`` or
    ``"cuda"``), with no Python loop over envs or robots.

    ## Action Space
    The single env's action space, batched: ``MultiBinary((K, N))`` (``action_type="multibinary"``),
    ``Box(0, 1, (K, N))`` (``"continuous"``) or ``MultiDiscrete`` of ``2^N`` (``"discrete"``).

    ## Observation Space
    The single env's state observation, batched: ``Box((K, D))``, float32 (``obs_type="state"`` only).

    ## Rewards
    The single env's (``reward``: ``piecewise``, ``projected`` or ``inverse_distance``; Manipulation's
    ``approach_reward`` shaping beside it), summed over ``action_repeat`` physics steps.

    ## Starting State
    Env ``i`` draws its start as the single env does (:meth:`ParticleSwarmEnv.draw_layout`) from a generator of its
    own: after ``reset(seed=s)`` env ``i`` starts where ``gymnasium.make(id, robot_model="disk").reset(seed=s + i)``
    starts. Starts are drawn on the CPU, once per episode; an ended episode's env draws its next start from the
    same generator.

    ## Episode End
    Terminated when the agent (the swarm's centre, or the object) comes within ``SUCCESS_RADIUS`` of the goal;
    truncated after ``max_episode_steps`` env steps (2500 by default), or when an env's physics blows up (its
    ``info["_physics_error"]`` is set). Autoreset is ``NEXT_STEP``: the step after an episode's end resets that env
    and ignores its action, with reward 0.

    ## Info
    Per env (arrays of K, each with Gymnasium's ``_key`` mask): ``is_success``, ``agent_position``, ``centre_of_mass``,
    ``projected_displacement``, ``net_displacement``, ``total_distance``; Gate adds ``gate_passage`` and
    ``gate_contact_step``, Manipulation ``object_position``.

    ## Arguments
    ``num_envs``, ``max_episode_steps``, ``device``, ``compile`` (``torch.compile`` each physics substep, the command
    rule and growth, the observation and the rewards: seconds of compiling at the first step, then about 3 times
    faster on a CPU; :class:`dpr.sim.batched.SolverSettings`),
    ``dynamics_scale`` and ``wall_give`` (below) and the single env's kwargs (``robot_model`` must be ``"disk"``,
    ``obs_type`` ``"state"``).

    ``dynamics_scale`` (default None: the model's constants) multiplies the disk model's constants per env, for
    training that must not lean on one set of them: a dict from any of ``push_force`` (the rods' push limit),
    ``magnet_force`` (their pull limit) and ``ground_friction`` (both ground friction limits) to a factor or
    ``[low, high]``, within 0.1 to 10. A range is drawn log-uniformly (so ``[0.5, 2]`` halves as often as it
    doubles) at every episode's start, after the start, from the env's generator: the same seed draws the same
    dynamics. Only the batched engine has it; the observation does not show it.

    ``wall_give`` (Gate only; default 0, at most 13.75 units) lets the walls squeeze each robot's disk down to its
    central body (:class:`dpr.sim.batched.BatchedDiskWorld`), as a paddle robot's paddles fold back against a wall.
    Only the batched engine has it.

    ## Tensor interface
    :meth:`reset_tensors` and :meth:`step_tensors` return torch tensors on ``device`` and reset an ended env in the
    same step (its last observation in ``final_observation``): what a learner on the device wants
    (:mod:`dpr.rl.batched_ppo`).

    ## Version History
    * v0: Initial version.
    """

    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}
    task_class: type[ParticleSwarmEnv] = NavigationEnv

    def __init__(
        self,
        num_envs: int,
        max_episode_steps: int = MAX_EPISODE_STEPS,
        device: str = "cpu",
        compile: bool = False,
        **env_kwargs: Any,
    ):
        check_int("num_envs", num_envs, 1)
        check_int("max_episode_steps", max_episode_steps, 1)
        robot_model = env_kwargs.get("robot_model", "paddle")  # the single env's default: never silently disk
        if robot_model != ROBOT_MODEL:
            raise ParameterError(
                "robot_model",
                f"the batched engine simulates the {ROBOT_MODEL!r} robot model only, got {robot_model!r}: pass "
                "robot_model='disk', or vectorization_mode='sync' or 'async' for the paddle model",
            )
        if env_kwargs.get("obs_type", "state") != "state":
            raise ParameterError(
                "obs_type", f"the batched engine observes 'state' only, got {env_kwargs['obs_type']!r}"
            )
        if env_kwargs.get("render_mode") is not None:
            raise ParameterError("render_mode", "the batched engine does not render: use gymnasium.make to render")
        self.dynamics_scale = env_kwargs.pop("dynamics_scale", None)
        self._dynamics_ranges = _dynamics_ranges(self.dynamics_scale)
        wall_give = env_kwargs.pop("wall_give", 0.0)
        n_walls = 2 if issubclass(self.task_class, GateEnv) else 0
        if wall_give != 0 and not n_walls:
            raise ParameterError(
                "wall_give", f"only Gate has walls to squeeze the robots, not {self.task_class.__name__}"
            )
        self.template = self.task_class(**env_kwargs)  # the single env: its checks, spaces and start draws
        if self.template.has_object and self.template.object_type != "ball":
            raise ParameterError(
                "object_type", f"the batched engine has the ball only, got {self.template.object_type!r}"
            )
        self.num_envs = int(num_envs)
        self.max_episode_steps = int(max_episode_steps)
        self.n_robots = self.template.n_robots
        self.action_repeat = self.template.action_repeat
        self.single_observation_space = self.template.observation_space
        self.single_action_space = self.template.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.world = BatchedDiskWorld(
            self.num_envs,
            self.n_robots,
            device=device,
            n_walls=n_walls,
            object_radius=self.template.object_size if self.template.has_object else None,
            object_mass=self.template.object_mass if self.template.has_object else 100.0,
            wall_give=wall_give,
            solver=SolverSettings(compile=compile),
        )
        self.device = self.world.position.device
        # With a compiled world the env's own work around each physics step is compiled too: eager, its few dozen
        # small ops cost about a tenth of a step at thousands of envs
        self._observe = compiled_if(type(self)._observation, self.world.compiled)
        self._step_reward = compiled_if(type(self)._physics_step_reward, self.world.compiled)
        self._allocate()
        self._generators = [seeding.np_random()[0] for _ in range(self.num_envs)]
        self._autoreset = torch.zeros(self.num_envs, dtype=torch.bool, device=self.device)
        self._started = False

    # -- state kept per env ---------------------------------------------------------------------------------
    def _allocate(self) -> None:
        k, device = self.num_envs, self.device
        zeros = lambda *shape: torch.zeros(shape, dtype=torch.float32, device=device)  # noqa: E731
        self.start = zeros(k, 2)
        self.toward_goal = zeros(k, 2)  # unit vector from the start to the goal
        self.last_position = zeros(k, 2)  # of the agent
        self.total_distance = zeros(k)
        self.success = torch.zeros(k, dtype=torch.bool, device=device)
        self.steps = torch.zeros(k, dtype=torch.int64, device=device)  # env steps of the episode
        self.physics_steps = torch.zeros(k, dtype=torch.int64, device=device)
        self.landmarks = zeros(k, len(self.template.landmark_names), 2)
        self.gate_near = zeros(k)  # Gate: the walls' near face, in units from the start along toward_goal
        self.gate_centre = zeros(k, 2)  # Gate: the opening's centre
        self.contact_step = torch.full((k,), -1, dtype=torch.int64, device=device)
        self.last_targets = zeros(k, self.n_robots)
        self.held_steps = torch.zeros(k, dtype=torch.int64, device=device)
        self.object_gap = zeros(k)  # Manipulation: the swarm's centre to the object, after the last physics step
        self.goal = torch.as_tensor(self.template.goal, dtype=torch.float32, device=device)

    def _draw_starts(self, envs: list[int]) -> None:
        """Draw the starts of ``envs`` on the CPU, each from its own generator, and reset them in the world."""
        n, walls_per_env = self.n_robots, 2 if isinstance(self.template, GateEnv) else 0
        centres = np.zeros((self.num_envs, n, 2), dtype=np.float32)
        dead = np.zeros((self.num_envs, n), dtype=bool)
        walls = np.zeros((self.num_envs, walls_per_env, 4, 2), dtype=np.float32)
        objects = np.zeros((self.num_envs, 2), dtype=np.float32)
        starts = np.zeros((self.num_envs, 2), dtype=np.float32)
        dynamics = np.ones((self.num_envs, len(DYNAMICS)), dtype=np.float32)
        for env in envs:
            self.template.np_random = self._generators[env]
            layout = self.template.draw_layout()
            dynamics[env] = self._draw_dynamics(self._generators[env])
            starts[env], centres[env] = layout.start, layout.centres
            dead[env, layout.dead] = True
            if walls_per_env:
                walls[env] = np.stack(layout.walls)
            if layout.obj is not None:
                objects[env] = layout.obj.position
        mask = torch.zeros(self.num_envs, dtype=torch.bool)
        mask[envs] = True
        mask = mask.to(self.device)
        tensor = lambda array: torch.as_tensor(array, device=self.device)  # noqa: E731
        self.world.reset(
            mask,
            tensor(centres),
            tensor(dead),
            walls=tensor(walls) if walls_per_env else None,
            object_position=tensor(objects) if self.template.has_object else None,
            dynamics=tensor(dynamics) if self.dynamics_scale is not None else None,
        )
        self._reset_trackers(mask, tensor(starts), tensor(walls) if walls_per_env else None)
        self._last_observation = self.observation()

    def _draw_dynamics(self, generator: np.random.Generator) -> list[float]:
        """One episode's multiples of the constants in :data:`DYNAMICS`: each range drawn log-uniformly, in that
        order; a single factor draws nothing."""
        return [
            low if low == high else float(np.exp(generator.uniform(np.log(low), np.log(high))))
            for low, high in self._dynamics_ranges
        ]

    def _reset_trackers(self, mask: torch.Tensor, starts: torch.Tensor, walls: torch.Tensor | None) -> None:
        where = mask[:, None]
        self.start = torch.where(where, starts, self.start)
        offset = self.goal - self.start
        self.toward_goal = offset / offset.norm(dim=1, keepdim=True).clamp_min(1e-12)
        self.last_position = torch.where(where, self.agent_position(), self.last_position)
        self.total_distance = torch.where(mask, 0.0, self.total_distance)
        start_distance = (self.last_position - self.goal).norm(dim=1)
        self.success = torch.where(mask, start_distance < SUCCESS_RADIUS, self.success)
        self.steps = torch.where(mask, 0, self.steps)
        self.physics_steps = torch.where(mask, 0, self.physics_steps)
        self.contact_step = torch.where(mask, -1, self.contact_step)
        self.last_targets = torch.where(where, 0.0, self.last_targets)
        self.held_steps = torch.where(mask, 0, self.held_steps)
        if self.template.has_object:
            self.object_gap = torch.where(mask, self._swarm_object_gap(), self.object_gap)
        if walls is not None:
            # the opening's centre: the mean of the walls' four inner corners (GateEnv._walls)
            centre = (walls[:, 0, 0] + walls[:, 0, 3] + walls[:, 1, 0] + walls[:, 1, 3]) / 4
            near = ((walls[:, 0, 0] + walls[:, 0, 1]) / 2 - self.start) * self.toward_goal
            self.gate_near = torch.where(mask, near.sum(dim=1), self.gate_near)
            self.gate_centre = torch.where(where, centre, self.gate_centre)
            if self.landmarks.shape[1]:
                self.landmarks = torch.where(mask[:, None, None], centre[:, None, :], self.landmarks)

    # -- what the envs see --------------------------------------------------------------------------------
    def agent_position(self) -> torch.Tensor:
        """What each task moves, [K, 2]: the swarm's centre, or the object."""
        if self.template.has_object:
            return self.world.object_position
        return self.world.centre_of_mass

    def _swarm_object_gap(self) -> torch.Tensor:
        """The distance from the swarm's centre to the object, [K]."""
        return (self.world.object_position - self.world.centre_of_mass).norm(dim=1)

    def observation(self) -> torch.Tensor:
        """The single env's state observation of every env, [K, D] float32."""
        return self._observe(self)

    def _observation(self) -> torch.Tensor:
        world, k = self.world, self.num_envs
        robots = torch.cat(
            (
                (world.position - self.goal) * LENGTH_SCALE,
                world.velocity * LENGTH_SCALE,
                world.angular_velocity[..., None],
                world.expansion[..., None],
            ),
            dim=2,
        )
        parts = [robots.reshape(k, -1)]
        if self.template.has_object:
            parts += [(world.object_position - self.goal) * LENGTH_SCALE, world.object_velocity * LENGTH_SCALE]
        if self.landmarks.shape[1]:
            parts.append(((self.landmarks - self.goal) * LENGTH_SCALE).reshape(k, -1))
        if self.template.obs_last_action:
            held = self.held_steps.clamp(max=HELD_STEPS_CAP).float() / HELD_STEPS_CAP
            parts += [self.last_targets, held[:, None]]
        return torch.cat(parts, dim=1)

    def environment_state(self) -> torch.Tensor:
        """The single env's :meth:`~dpr.envs.particle_env.ParticleSwarmEnv.environment_state` of every env, [K, E]
        float32 (named by ``template.environment_state_names``): the swarm's centre, mean velocity and distance to
        the goal, the object's, then the task's own values (Gate's opening relative to the swarm's centre,
        Unresponsive's dead flags)."""
        world = self.world

        def part(position: torch.Tensor, velocity: torch.Tensor) -> list[torch.Tensor]:
            offset = position - self.goal
            return [offset * LENGTH_SCALE, velocity * LENGTH_SCALE, offset.norm(dim=1, keepdim=True) * LENGTH_SCALE]

        centre = world.centre_of_mass
        parts = part(centre, world.velocity.mean(dim=1))
        if self.template.has_object:
            parts += part(world.object_position, world.object_velocity)
        if self.template.environment_extra_names:
            parts.append((self.gate_centre - centre) * LENGTH_SCALE)
        if self.template.has_dead_robots:  # Unresponsive: each robot's dead flag, not scaled
            parts.append((~world.alive).float())
        return torch.cat(parts, dim=1)

    # -- stepping -------------------------------------------------------------------------------------------
    def targets(self, actions) -> torch.Tensor:
        """Actions (numpy or torch, [K, N] or [K] for discrete) as expansion targets [K, N] in [0, 1]."""
        actions = torch.as_tensor(actions, device=self.device)
        if self.template.action_type == "discrete":
            bits = torch.as_tensor(joint_action_bits(self.n_robots), device=self.device)
            return ((actions.reshape(-1, 1).long() & bits) > 0).float()
        if actions.shape != (self.num_envs, self.n_robots):
            raise ValueError(f"actions must have shape ({self.num_envs}, {self.n_robots}), got {tuple(actions.shape)}")
        return actions.float().clamp(0.0, 1.0)

    def advance(self, targets: torch.Tensor):
        """One env step of every env (``action_repeat`` physics steps): the observation [K, D] (of an env that
        ended inside the step, where it ended; of one whose physics blew up, the one before), and reward,
        terminated, truncated and blown-up flags [K]."""
        reward = torch.zeros(self.num_envs, device=self.device)
        ended = torch.zeros(self.num_envs, dtype=torch.bool, device=self.device)
        blown = torch.zeros_like(ended)
        frozen, frozen_at = None, torch.zeros_like(ended)  # observations of envs that ended inside a repeat
        if self.template.obs_last_action:
            same = (targets == self.last_targets).all(dim=1)
            self.held_steps = torch.where(same, self.held_steps + 1, 1)
            self.last_targets = targets
        for repeat in range(self.action_repeat):
            self.world.step(targets)
            live = ~ended
            blown |= live & ~self.world.is_sane()
            live &= ~blown
            self.physics_steps += live.long()
            reward += torch.where(live, self._step_reward(self, live), 0.0)
            if isinstance(self.template, GateEnv):
                touching = self.world.robots_touch_walls() & (self.contact_step < 0) & live
                self.contact_step = torch.where(touching, self.physics_steps, self.contact_step)
            reached = live & ((self.last_position - self.goal).norm(dim=1) < SUCCESS_RADIUS)
            if repeat < self.action_repeat - 1 and reached.any():  # it stops here; the world goes on
                now = self.observation()
                frozen = now if frozen is None else torch.where(reached[:, None], now, frozen)
                frozen_at |= reached
            ended |= reached | blown
        self.steps += 1
        observation = self.observation()
        if frozen is not None:
            observation = torch.where(frozen_at[:, None], frozen, observation)
        observation = torch.where(blown[:, None], self._last_observation, observation)
        self._last_observation = observation
        terminated = ~blown & ((self.last_position - self.goal).norm(dim=1) < SUCCESS_RADIUS)
        truncated = ~terminated & ((self.steps >= self.max_episode_steps) | blown)
        return observation, torch.where(blown, 0.0, reward), terminated, truncated, blown

    def _physics_step_reward(self, live: torch.Tensor) -> torch.Tensor:
        """The single env's reward of one physics step, and the trackers moved to the agent's new position."""
        previous = self.last_position
        position = torch.where(live[:, None], self.agent_position(), previous)
        self.total_distance = self.total_distance + (position - previous).norm(dim=1)
        self.last_position = position
        distance = (position - self.goal).norm(dim=1)
        self.success |= distance < SUCCESS_RADIUS
        reward = self._goal_reward(previous, position, distance)
        weight = getattr(self.template, "approach_reward", 0.0)
        if weight:  # Manipulation's shaping (ManipulationEnv._reward): the swarm's approach to the object
            gap = torch.where(live, self._swarm_object_gap(), self.object_gap)
            reward = reward + weight * (self.object_gap - gap)
            self.object_gap = gap
        return reward

    def _goal_reward(self, previous: torch.Tensor, position: torch.Tensor, distance: torch.Tensor) -> torch.Tensor:
        if self.template.reward_type == "inverse_distance":
            return 1.0 / distance.clamp_min(1e-6)
        to_goal = self.goal - previous
        norm = to_goal.norm(dim=1)
        progress = torch.where(norm > 0, ((position - previous) * to_goal).sum(dim=1) / norm.clamp_min(1e-12), 0.0)
        if self.template.reward_type == "piecewise":
            d = self.template.reward_threshold_d
            progress = torch.where(distance < d, progress * d / distance.clamp_min(1e-6), progress)
        return progress

    # -- Gymnasium's vector API ---------------------------------------------------------------------------------
    def reset(self, *, seed: int | list[int] | None = None, options: dict | None = None):
        super().reset(seed=seed if isinstance(seed, int) else None)
        if seed is not None:
            seeds = seed if isinstance(seed, list) else [seed + env for env in range(self.num_envs)]
            if len(seeds) != self.num_envs:
                raise ValueError(f"seed must be one int or {self.num_envs} of them, got {len(seeds)}")
            self._generators = [seeding.np_random(s)[0] for s in seeds]
        self._draw_starts(list(range(self.num_envs)))
        self._autoreset[:] = False
        self._started = True
        return self.observation().cpu().numpy(), self._info(torch.zeros_like(self._autoreset))

    def step(self, actions):
        if not self._started:
            raise RuntimeError("call reset() before step()")
        targets = self.targets(actions)
        resetting = self._autoreset.clone()
        observation, reward, terminated, truncated, blown = self.advance(targets)
        if resetting.any():  # NEXT_STEP: these envs ended last step; their action is ignored
            self._draw_starts(resetting.nonzero().flatten().tolist())
            observation = torch.where(resetting[:, None], self.observation(), observation)
            zero = torch.zeros_like(terminated)
            reward = torch.where(resetting, 0.0, reward)
            terminated, truncated, blown = (
                torch.where(resetting, zero, flag) for flag in (terminated, truncated, blown)
            )
        self._autoreset = terminated | truncated
        numpy = lambda tensor: tensor.cpu().numpy()  # noqa: E731
        return numpy(observation), numpy(reward), numpy(terminated), numpy(truncated), self._info(blown)

    def reset_tensors(self, seed: int | None = None) -> torch.Tensor:
        """Reset every env (seeded as :meth:`reset`); the observations, a [K, D] tensor on ``device``."""
        self.reset(seed=seed)
        return self.observation()

    def step_tensors(self, actions: torch.Tensor):
        """One step with same-step autoreset, on the device: ``(observation, reward, terminated, truncated,
        final_observation)``; an env whose episode ended is already reset in ``observation``."""
        final_observation, reward, terminated, truncated, _ = self.advance(self.targets(actions))
        ended = terminated | truncated
        observation = final_observation
        if ended.any():
            self._draw_starts(ended.nonzero().flatten().tolist())
            observation = torch.where(ended[:, None], self.observation(), final_observation)
        return observation, reward, terminated, truncated, final_observation

    def _info(self, blown: torch.Tensor) -> dict[str, Any]:
        agent = self.agent_position()
        values = {
            "is_success": self.success,
            AGENT_POSITION: agent,
            "centre_of_mass": self.world.centre_of_mass,
            "projected_displacement": ((agent - self.start) * self.toward_goal).sum(dim=1),
            "net_displacement": (agent - self.start).norm(dim=1),
            "total_distance": self.total_distance,
        }
        if self.template.has_object:
            values["object_position"] = self.world.object_position
        if isinstance(self.template, GateEnv):
            along = ((self.world.position - self.start[:, None]) * self.toward_goal[:, None]).sum(dim=2)
            values[GATE_PASSAGE] = (along > self.gate_near[:, None]).float().mean(dim=1)
            values[GATE_CONTACT_STEP] = self.contact_step
        info: dict[str, Any] = {}
        everywhere = np.ones(self.num_envs, dtype=bool)
        for key, value in values.items():
            info[key], info[f"_{key}"] = value.cpu().numpy(), everywhere
        if bool(blown.any()):
            info[PHYSICS_ERROR] = np.where(blown.cpu().numpy(), "non-finite or exploding body state", "")
            info[f"_{PHYSICS_ERROR}"] = blown.cpu().numpy()
        return info

    def close_extras(self, **kwargs: Any) -> None:
        self.template.close()


def _dynamics_ranges(dynamics_scale) -> list[tuple[float, float]]:
    """``dynamics_scale`` checked, as a (low, high) per constant of :data:`DYNAMICS` ((1, 1) for one not named)."""
    if dynamics_scale is None:
        return [(1.0, 1.0)] * len(DYNAMICS)
    if not isinstance(dynamics_scale, dict) or not dynamics_scale:
        raise ParameterError(
            "dynamics_scale",
            f"expected a dict from any of {', '.join(DYNAMICS)} to a factor or [low, high], got {dynamics_scale!r}",
        )
    unknown = sorted(set(dynamics_scale) - set(DYNAMICS), key=str)
    if unknown:
        expected = ", ".join(DYNAMICS)
        raise ParameterError("dynamics_scale", f"no constant named {unknown[0]!r}: expected any of {expected}")
    low, high = DYNAMICS_SCALE_BOUNDS
    return [check_number_range(f"dynamics_scale.{name}", dynamics_scale.get(name, 1.0), low, high) for name in DYNAMICS]


class NavigationVectorEnv(BatchedSwarmVectorEnv):
    task_class = NavigationEnv


class GateVectorEnv(BatchedSwarmVectorEnv):
    task_class = GateEnv


class UnresponsiveVectorEnv(BatchedSwarmVectorEnv):
    task_class = UnresponsiveEnv


class ManipulationVectorEnv(BatchedSwarmVectorEnv):
    task_class = ManipulationEnv


VECTOR_ENV_CLASSES: dict[type[ParticleSwarmEnv], type[BatchedSwarmVectorEnv]] = {
    cls.task_class: cls for cls in (NavigationVectorEnv, GateVectorEnv, UnresponsiveVectorEnv, ManipulationVectorEnv)
}
