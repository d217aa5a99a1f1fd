"""Shared machinery of the four particle-robot tasks (see each task's module for its docstring)."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from dpr.checks import ParameterError, check_int, check_number
from dpr.limits import MAX_N_ROBOTS
from dpr.metrics import SUCCESS_RADIUS, MetricTracker
from dpr.sim import ROBOT_MODELS, World, swarm_class
from dpr.sim import constants as C
from dpr.sim.world import ObjectSpec, grid_centres

MAX_DISTANCE = 1e5  # bound of length kwargs (start radius, reward threshold): finite, and far beyond any task
GOAL_CLEARANCE = 100.0  # the least gap between the goal and the front of the swarm (or its object) at the start
START_ANGLES = 720  # start angles checked for the clearances (their worst case gets a unit of rounding margin)
MAX_EPISODE_STEPS = 2500  # every registered task's TimeLimit, and the default episode length everywhere
MAX_ROBOTS = MAX_N_ROBOTS  # a paddle swarm of 1000 takes seconds to build; far more would look like a hang
SLOW_PADDLE_SWARM = 1000  # from this size on, a paddle swarm's build is announced (about 7 s at 1000, per reset)
IMAGE_SIZE_RANGE = (16, 2048)  # pixels per side of observations and renders (2048^2 RGB is 12 MiB a frame)

ACTION_TYPES = ("multibinary", "discrete", "continuous")
OBS_TYPES = ("state", "pixels", "pixels_state")
REWARDS = ("piecewise", "projected", "inverse_distance")
MAX_DISCRETE_ROBOTS = 16  # Discrete(2^N) beyond 65536 actions is of no use to a learner
ROBOT_FEATURES = 6  # x, y, vx, vy, angular velocity, expansion
OBJECT_FEATURES = 4  # x, y, vx, vy
LANDMARK_FEATURES = 2  # x, y of each of a task's landmarks (ParticleSwarmEnv.landmark_names)
# environment_state(): the swarm's centre and the object, each as x, y (goal frame), vx, vy, distance to the goal
AGENT_ENVIRONMENT_PARTS = ("x", "y", "vx", "vy", "distance")
HELD_STEPS_CAP = 20  # obs_last_action: steps an action has been held, counted up to twice the paper's hold
LENGTH_SCALE = 1.0 / 1000.0
GOAL = np.zeros(2)
# info keys: what the task moves (the swarm's centre, or the object), on every reset and step; and the message
# of a step whose physics blew up (the episode is truncated there; see dpr.rollout for what callers do with it)
AGENT_POSITION = "agent_position"
PHYSICS_ERROR = "physics_error"


SWARM_KWARGS = ("n_robots", "robot_model")  # what CollectSpec, TrainConfig and rollouts take as their own fields


def split_swarm_kwargs(env_kwargs: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """``env_kwargs`` as (the swarm's ``n_robots``/``robot_model``, every other kwarg)."""
    swarm = {key: value for key, value in env_kwargs.items() if key in SWARM_KWARGS}
    return swarm, {key: value for key, value in env_kwargs.items() if key not in SWARM_KWARGS}


def action_repeat(env_kwargs: dict[str, Any] | None = None) -> int:
    """Physics steps per env step of an env made with ``env_kwargs`` (its ``action_repeat``, default 1)."""
    return check_int("action_repeat", (env_kwargs or {}).get("action_repeat", 1), 1, MAX_EPISODE_STEPS)


def episode_steps(env_kwargs: dict[str, Any] | None = None, physics_steps: int = MAX_EPISODE_STEPS) -> int:
    """Env steps of an episode of ``physics_steps`` physics steps for an env made with ``env_kwargs``: each env
    step is ``action_repeat`` physics steps (the default episode: 2500, or 250 decisions of 10 steps)."""
    return -(-physics_steps // action_repeat(env_kwargs))


# Simulated time. One physics step is C.CONTROL_PERIOD (0.1 s: C.FPS = 10 per second); one env step is
# action_repeat of them. Every record of an episode (dataset fps and timestamps, MCAP log times, rerun's
# `step` and `sim_time`) takes its time from these two functions.
def seconds_per_step(env_kwargs: dict[str, Any] | None = None) -> float:
    """Simulated seconds per env step of an env made with ``env_kwargs``: the physics step (C.CONTROL_PERIOD,
    0.1 s) times ``action_repeat``, computed as ``action_repeat / C.FPS`` (6 steps: 0.6 s, not 0.6000000000000001)."""
    return action_repeat(env_kwargs) / C.FPS


def steps_per_second(env_kwargs: dict[str, Any] | None = None) -> int | float:
    """Env steps per simulated second, ``1 / seconds_per_step``: the decision rate, which a dataset records as its
    ``fps``. An int where ``action_repeat`` divides C.FPS (1, 2, 5, 10 give 10, 5, 2, 1), else a float (6 gives
    10/6 = 1.6666666666666667)."""
    repeat = action_repeat(env_kwargs)
    return C.FPS // repeat if C.FPS % repeat == 0 else C.FPS / repeat


def joint_action_bits(n_robots: int) -> np.ndarray:
    """The value of each robot's bit in a ``action_type="discrete"`` action (int64 [N]): robot 0 is the most
    significant bit, so the integer action is ``expand @ joint_action_bits(N)``."""
    return 1 << np.arange(n_robots - 1, -1, -1, dtype=np.int64)


@dataclass(frozen=True)
class StartLayout:
    """One episode's start (:meth:`ParticleSwarmEnv.draw_layout`): the swarm's centre, the robots' centres (N, 2),
    the indices of the dead robots, the walls (each a (4, 2) vertex array) and the object, if any."""

    start: np.ndarray
    centres: np.ndarray
    dead: np.ndarray
    walls: list[np.ndarray]
    obj: ObjectSpec | None


def _copy(observation):
    if isinstance(observation, dict):
        return {key: value.copy() for key, value in observation.items()}
    return observation.copy()


def _choice(name: str, value: Any, allowed: tuple) -> None:
    if value not in allowed:
        raise ValueError(f"{name} must be one of {allowed}, got {value!r}")


class ParticleSwarmEnv(gym.Env):
    """Base class of the particle-robot tasks: a swarm of N robots must bring an agent (its centre of mass,
    or an object) to the goal at the origin. Subclasses set up walls, dead robots or an object."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": C.FPS}
    task = ""
    task_description = ""  # one sentence for datasets (LeRobot's per-frame "task" string)
    has_object = False
    has_dead_robots = False  # whether some robots may ignore commands (what a robot's local dead flag is for)
    # info keys of the task's own measures of an episode, read at its last step beside the paper's metrics
    # (evaluation files and reports carry them)
    episode_measures: tuple[str, ...] = ()
    # names of a task's own values at the end of environment_state() (see _environment_extra)
    environment_extra_names: tuple[str, ...] = ()
    # names of the fixed points of a task that its state observation holds, x and y of each after the object's
    # features (see _landmark_positions); a task sets them per instance before ParticleSwarmEnv.__init__
    landmark_names: tuple[str, ...] = ()

    def __init__(
        self,
        n_robots: int = 9,
        robot_model: str = "paddle",
        action_type: str = "multibinary",
        obs_type: str = "state",
        reward: str = "piecewise",
        reward_threshold_d: float = 450.0,
        start_radius: tuple[float, float] = (450.0, 550.0),
        obs_last_action: bool = False,
        action_repeat: int = 1,
        image_size: int = 96,
        render_size: int = 512,
        render_mode: str | None = None,
        dynamics_scale: None = None,
        wall_give: None = None,
    ):
        # named here so that a pymunk env refuses the batched engine's own kwargs in words, not with a TypeError
        for name, value in (("dynamics_scale", dynamics_scale), ("wall_give", wall_give)):
            if value is not None:
                raise ParameterError(
                    name,
                    "only the batched engine takes it (gymnasium.make_vec(..., vectorization_mode="
                    "'vector_entry_point', robot_model='disk'), or --engine batched); the pymunk env simulates "
                    f"the model as it is, got {value!r}",
                )
        check_int("n_robots", n_robots, 1, MAX_ROBOTS)
        _choice("robot_model", robot_model, ROBOT_MODELS)
        _choice("action_type", action_type, ACTION_TYPES)
        _choice("obs_type", obs_type, OBS_TYPES)
        _choice("reward", reward, REWARDS)
        _choice("render_mode", render_mode, (None, *self.metadata["render_modes"]))
        if action_type == "discrete" and n_robots > MAX_DISCRETE_ROBOTS:
            raise ValueError(
                f"action_type='discrete' needs Discrete(2^N) actions; n_robots must be <= {MAX_DISCRETE_ROBOTS}"
                f" for it, got {n_robots} (use 'multibinary' or 'continuous')"
            )
        check_number("reward_threshold_d", reward_threshold_d, maximum=MAX_DISTANCE, above=0)
        if not isinstance(start_radius, (tuple, list, np.ndarray)) or len(start_radius) != 2:
            raise ParameterError("start_radius", f"expected (low, high), got {start_radius!r}")
        low, high = (check_number("start_radius", r, maximum=MAX_DISTANCE, above=0) for r in start_radius)
        if not low <= high:
            raise ParameterError("start_radius", f"expected (low, high) with low <= high, got {start_radius!r}")
        if not isinstance(obs_last_action, (bool, np.bool_)):
            raise ValueError(f"obs_last_action must be True or False, got {obs_last_action!r}")
        if obs_last_action and obs_type == "pixels":
            raise ValueError("obs_last_action=True extends the state vector: use obs_type 'state' or 'pixels_state'")
        check_int("action_repeat", action_repeat, 1, MAX_EPISODE_STEPS)
        check_int("image_size", image_size, *IMAGE_SIZE_RANGE)
        check_int("render_size", render_size, *IMAGE_SIZE_RANGE)

        self.n_robots = int(n_robots)
        self.robot_model = robot_model
        self.action_type = action_type
        self.obs_type = obs_type
        self.reward_type = reward
        self.reward_threshold_d = float(reward_threshold_d)
        self.start_radius = (float(low), float(high))
        self.obs_last_action = bool(obs_last_action)
        self.action_repeat = int(action_repeat)
        if self.action_repeat > 1:  # a video of render() frames plays at the decision rate (the class keeps C.FPS)
            self.metadata = {**self.metadata, "render_fps": steps_per_second({"action_repeat": self.action_repeat})}
        self.image_size = int(image_size)
        self.render_size = int(render_size)
        self.render_mode = render_mode
        self.swarm_class = swarm_class(robot_model)
        if robot_model == "paddle" and self.n_robots >= SLOW_PADDLE_SWARM:
            gym.logger.warn(
                f"n_robots={self.n_robots} paddle robots: every reset builds them, about 7 s per 1000 robots; "
                "robot_model='disk' is about 20x faster"
            )

        self._build_spaces()
        self.world: World | None = None
        self.goal = GOAL.copy()

        self.start = np.zeros(2)
        self._tracker: MetricTracker | None = None
        self._renderer = None
        self._image_renderer = None

    def _build_spaces(self) -> None:
        """The action and observation spaces, and where the parts of the state vector start."""
        n = self.n_robots
        if self.action_type == "multibinary":
            self.action_space = spaces.MultiBinary(n)
        elif self.action_type == "discrete":
            self.action_space = spaces.Discrete(2**n)
        else:
            self.action_space = spaces.Box(0.0, 1.0, (n,), dtype=np.float32)

        self.object_offset = ROBOT_FEATURES * n  # where the object's features start, when there is one
        self.landmark_offset = self.object_offset + (OBJECT_FEATURES if self.has_object else 0)
        self.memory_offset = self.landmark_offset + LANDMARK_FEATURES * len(self.landmark_names)
        self.state_size = self.memory_offset + (n + 1 if self.obs_last_action else 0)
        low_state = np.full(self.state_size, -np.inf, dtype=np.float32)
        high_state = np.full(self.state_size, np.inf, dtype=np.float32)
        low_state[5 : 6 * n : 6], high_state[5 : 6 * n : 6] = 0.0, 1.0  # expansion
        low_state[self.memory_offset :], high_state[self.memory_offset :] = 0.0, 1.0  # last action, held steps
        state_space = spaces.Box(low_state, high_state, dtype=np.float32)
        pixel_space = spaces.Box(0, 255, (self.image_size, self.image_size, 3), dtype=np.uint8)
        self.observation_space = {
            "state": state_space,
            "pixels": pixel_space,
            "pixels_state": spaces.Dict({"pixels": pixel_space, "state": state_space}),
        }[self.obs_type]

    # -- task hooks ---------------------------------------------------------------------------------------
    def _dead_robots(self) -> np.ndarray:
        return np.zeros(0, dtype=np.int64)

    def _walls(self, start: np.ndarray) -> list[np.ndarray]:
        return []

    def _after_physics_step(self) -> None:
        """Called after every sane physics step (``physics_step`` counts them), for a task's own measures."""

    def _object(self, start: np.ndarray, centres: np.ndarray) -> ObjectSpec | None:
        return None

    def _start_distances(self, offsets: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """The least start-to-goal distance the task needs for each unit ``direction`` (A, 2) from the start
        toward the goal, given the robots' offsets (N, 2) from the swarm's centre: here, the goal lies
        :data:`GOAL_CLEARANCE` beyond the swarm's expanded front. Tasks with walls or an object add theirs."""
        front = (offsets @ directions.T).max(axis=0) + self.swarm_class.expanded_radius
        return front + GOAL_CLEARANCE

    @functools.cached_property
    def start_shift(self) -> float:
        """How much farther than ``start_radius`` every start is drawn, so that at any start angle the goal
        (and the task's walls or object) clear the swarm: the most any angle needs beyond the circle's inner
        radius, 0 where the swarm fits (every task at N <= 16). Deterministic in the kwargs, so that the RNG
        draws, and every start that already fitted, stay as they were."""
        angles = np.linspace(0.0, 2 * math.pi, START_ANGLES, endpoint=False)
        directions = np.stack([np.cos(angles), np.sin(angles)], axis=1)
        offsets = grid_centres(self.n_robots, (0.0, 0.0))
        needed = float(self._start_distances(offsets, directions).max())
        return max(0.0, math.ceil(needed - self.start_radius[0]))

    @functools.cached_property
    def view_half_extent(self) -> float:
        """Half the side of a fixed camera centred on the goal that holds every start and the swarm."""
        swarm_half = (math.ceil(math.sqrt(self.n_robots)) / 2) * C.GRID_PITCH
        return self.start_radius[1] + self.start_shift + swarm_half + 2 * self.swarm_class.expanded_radius

    # -- gymnasium API ------------------------------------------------------------------------------------
    def draw_layout(self) -> StartLayout:
        """This episode's start, drawn from ``self.np_random``: the swarm's centre, the dead robots, the walls and
        the object (what :meth:`reset` builds its World from, and what the batched engine's vector env draws for
        each of its envs without building one)."""
        radius = self.np_random.uniform(*self.start_radius) + self.start_shift
        angle = self.np_random.uniform(0.0, 2 * math.pi)
        start = self.goal + radius * np.array([math.cos(angle), math.sin(angle)])
        dead = self._dead_robots()
        centres = grid_centres(self.n_robots, start)
        walls = self._walls(start)
        return StartLayout(start, centres, dead, walls, self._object(start, centres))

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        layout = self.draw_layout()
        self.start = layout.start
        self.world = World(
            self.n_robots, self.robot_model, centre=self.start, dead=layout.dead, walls=layout.walls, obj=layout.obj
        )
        self._tracker = MetricTracker(self._agent_position(), self.goal)
        self.physics_step = 0  # physics steps since the reset
        self._last_targets = np.zeros(self.n_robots)
        self._held_steps = 0
        self._last_obs = self._observation()
        info = self._info()
        info["dead_robots"] = np.flatnonzero(self.world.dead)
        return self._last_obs, info

    def step(self, action):
        if self.world is None:
            raise RuntimeError("call reset() before step()")
        targets = self._targets(action)
        total = 0.0
        terminated = False
        for _ in range(self.action_repeat):  # one decision, applied for action_repeat physics steps
            if self.obs_last_action:  # (off the hot path of envs that do not observe it)
                if np.array_equal(targets, self._last_targets):
                    self._held_steps += 1
                else:
                    self._last_targets, self._held_steps = targets, 1
            previous = self._tracker.last_position
            self.world.step(targets)
            if not self.world.is_sane():
                info = self._info()
                info[PHYSICS_ERROR] = "non-finite or exploding body state; episode truncated"
                return _copy(self._last_obs), 0.0, False, True, info
            self.physics_step += 1
            self._after_physics_step()
            self._tracker.update(self._agent_position())
            total += self._reward(previous)
            terminated = self._tracker.distance_to_goal < SUCCESS_RADIUS
            if terminated:
                break
        self._last_obs = self._observation()
        return self._last_obs, total, terminated, False, self._info()

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            self._renderer = self._make_renderer(self.render_size)
        return self._renderer.draw(self.world, self.goal)

    def close(self):
        self._renderer = None
        self._image_renderer = None

    @property
    def state_names(self) -> list[str]:
        """One name per value of the state vector, in order."""
        n = self.n_robots
        names = [f"robot{i}.{part}" for i in range(n) for part in ("x", "y", "vx", "vy", "omega", "expansion")]
        if self.has_object:
            names += ["object.x", "object.y", "object.vx", "object.vy"]
        names += [f"{landmark}.{part}" for landmark in self.landmark_names for part in ("x", "y")]
        if self.obs_last_action:
            names += [f"last_action.robot{i}" for i in range(n)] + ["last_action.held_steps"]
        return names

    @property
    def environment_state_names(self) -> list[str]:
        """One name per value of :meth:`environment_state`, in order."""
        names = [f"swarm.{part}" for part in AGENT_ENVIRONMENT_PARTS]
        if self.has_object:
            names += [f"object.{part}" for part in AGENT_ENVIRONMENT_PARTS]
        return names + list(self.environment_extra_names)

    def environment_state(self) -> np.ndarray:
        """What the env knows beyond each robot's own state, as the state observation shows lengths (goal frame:
        relative to the goal, world axes, / 1000): the swarm's centre of mass x, y, its velocity vx, vy (the
        robots' mean) and its distance to the goal; with an object, the object's x, y, vx, vy and distance to the
        goal; then the task's own values (:attr:`environment_extra_names`). float32, named by
        :attr:`environment_state_names`; datasets record it as ``observation.environment_state`` at every frame,
        and a policy in the env builds the same vector from this call."""
        if self.world is None:
            raise RuntimeError("call reset() before environment_state()")
        world, scale = self.world, LENGTH_SCALE
        # (Python floats: for a dozen values, cheaper than numpy's per-call cost; the robots are summed by numpy)
        x, y = (world.centre_of_mass - self.goal).tolist()
        vx, vy = world.swarm.velocity.sum(axis=0).tolist()
        mean = scale / self.n_robots
        values = [x * scale, y * scale, vx * mean, vy * mean, math.hypot(x, y) * scale]
        if self.has_object:
            ox, oy = (world.object_pose[0:2] - self.goal).tolist()
            ovx, ovy = world.object_velocity.tolist()
            values += [ox * scale, oy * scale, ovx * scale, ovy * scale, math.hypot(ox, oy) * scale]
        if self.environment_extra_names:
            values += [value * scale for value in self._environment_extra()]
        return np.array(values, dtype=np.float32)

    def _environment_extra(self) -> list[float]:
        """The task's own values of :meth:`environment_state` (one per :attr:`environment_extra_names`), in world
        units: lengths, which are scaled by 1/1000 with the rest."""
        return []

    def _landmark_positions(self) -> np.ndarray:
        """Where the task's landmarks (:attr:`landmark_names`) stand, (L, 2) in world coordinates; the state
        observation holds them in the goal frame, / 1000, like the robots' positions."""
        return np.zeros((0, 2))

    # -- pieces -------------------------------------------------------------------------------------------
    def _agent_position(self) -> np.ndarray:
        """What the task moves: the swarm's centre, or the object."""
        if self.has_object:
            return self.world.object_pose[0:2].copy()
        return self.world.centre_of_mass.copy()

    def _targets(self, action) -> np.ndarray:
        """Validate ``action`` against the action space and turn it into expansion targets in [0, 1]."""
        n = self.n_robots
        if self.action_type == "discrete":
            value = action
            if isinstance(value, np.ndarray) and value.size == 1:
                value = value.reshape(())[()]
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
                raise ValueError(f"action must be an integer in [0, {2**n}) for action_type='discrete', got {action!r}")
            if not 0 <= value < 2**n:
                raise ValueError(f"action must be in [0, {2**n}) for action_type='discrete', got {value}")
            return ((int(value) & joint_action_bits(n)) > 0).astype(float)
        if (
            self.action_type == "multibinary"
            and isinstance(action, np.ndarray)
            and action.shape == (n,)
            and action.dtype.kind == "i"
        ):
            # the common case, a policy's integer array, in two calls: x & ~1 is 0 only for x in {0, 1}
            if not np.bitwise_and(action, -2).any():
                return action.astype(float)
        array = np.asarray(action)
        if array.shape != (n,):
            raise ValueError(f"action must have shape ({n},) for action_type={self.action_type!r}, got {array.shape}")
        if array.dtype.kind not in "buif":
            raise ValueError(f"action must be numeric, got dtype {array.dtype}")
        targets = array.astype(float)
        if self.action_type == "multibinary":
            if not np.all((targets == 0.0) | (targets == 1.0)):
                raise ValueError(f"action must hold only 0 and 1 for action_type='multibinary', got {action!r}")
        elif not (np.all(np.isfinite(targets)) and targets.min() >= 0.0 and targets.max() <= 1.0):
            raise ValueError(f"action must lie in [0, 1] for action_type='continuous', got {action!r}")
        return targets

    def _reward(self, previous: tuple[float, float]) -> float:
        """Reward for the step from ``previous`` to the tracker's current agent position."""
        tracker = self._tracker
        distance = tracker.distance_to_goal
        if self.reward_type == "inverse_distance":
            return 1.0 / max(distance, 1e-6)
        (px, py), (x, y), (gx, gy) = previous, tracker.last_position, tracker.goal_position
        norm = math.hypot(gx - px, gy - py)
        progress = ((x - px) * (gx - px) + (y - py) * (gy - py)) / norm if norm > 0 else 0.0
        d = self.reward_threshold_d
        if self.reward_type == "piecewise" and distance < d:
            return progress * d / max(distance, 1e-6)
        return progress

    def _state(self) -> np.ndarray:
        swarm, n = self.world.swarm, self.n_robots
        state = np.empty(self.state_size, dtype=np.float32)
        robots = state[: ROBOT_FEATURES * n].reshape(n, ROBOT_FEATURES)
        robots[:, 0:2] = (swarm.position - self.goal) * LENGTH_SCALE
        robots[:, 2:4] = swarm.velocity * LENGTH_SCALE
        robots[:, 4] = swarm.angular_velocity
        robots[:, 5] = swarm.expansion
        if self.has_object:
            world = self.world
            at = self.object_offset
            state[at : at + 2] = (world.object_pose[0:2] - self.goal) * LENGTH_SCALE
            state[at + 2 : at + 4] = world.object_velocity * LENGTH_SCALE
        if self.landmark_names:
            landmarks = (self._landmark_positions() - self.goal) * LENGTH_SCALE
            state[self.landmark_offset : self.memory_offset] = landmarks.reshape(-1)
        if self.obs_last_action:
            at = self.memory_offset
            state[at : at + n] = self._last_targets
            state[at + n] = min(self._held_steps, HELD_STEPS_CAP) / HELD_STEPS_CAP
        return state

    def _observation(self):
        if self.obs_type == "state":
            return self._state()
        if self._image_renderer is None:
            self._image_renderer = self._make_renderer(self.image_size)
        pixels = self._image_renderer.draw(self.world, self.goal)
        if self.obs_type == "pixels":
            return pixels
        return {"pixels": pixels, "state": self._state()}

    def _info(self) -> dict:
        tracker = self._tracker
        info = {
            "is_success": tracker.success,
            "centre_of_mass": self.world.centre_of_mass.copy(),
            AGENT_POSITION: self._agent_position(),
            "projected_displacement": tracker.projected_displacement,
            "net_displacement": tracker.net_displacement,
            "total_distance": tracker.total_distance,
        }
        if self.has_object:
            info["object_position"] = self.world.object_pose[0:2].copy()
        return info

    def _make_renderer(self, size: int):
        from dpr.envs.rendering import SceneRenderer

        return SceneRenderer(size, self.goal, self.view_half_extent)

    # pygame surfaces do not pickle; renderers are rebuilt on demand.
    def __getstate__(self):
        state = self.__dict__.copy()
        state["_renderer"] = None
        state["_image_renderer"] = None
        return state
