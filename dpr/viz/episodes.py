"""Episodes as plain arrays for the viewer, from an MCAP log, a LeRobot dataset or a live rollout.

Every source becomes one :class:`EpisodeLog`: ``S`` states (row 0 is the reset state, row ``t`` the state after
the ``t``-th ``env.step``) of every robot, the agent (swarm centre, or the object in Manipulation), the scene,
and the ``S - 1`` rewards. Row ``t`` is at physics step ``t * action_repeat`` (simulated time: 0.1 s a physics
step), so episodes of policies that decide every step and every k steps share one clock. Nothing here imports
rerun; :mod:`dpr.viz.rerun_log` turns an EpisodeLog into rerun entities.

What each source holds:

* an MCAP log (``dpr-mcap/1``) has everything, magnets included, for states ``0 .. T``;
* a dataset frame ``t`` holds the observation *before* action ``t``, so a ``T``-frame episode gives states
  ``0 .. T - 1`` (the state after the last action is not recorded) and no magnets; its frames keep the dataset's
  time, ``1 / fps`` s apart (one per ``action_repeat`` physics steps of its ``env_kwargs``); walls, the goal, the
  dead robots and the object's shape are rebuilt by making the env from the episode's ``env_id``/``env_kwargs``
  and resetting it with its ``seed``. Positions come back from the float32, 1/1000-scaled observation, so they
  are exact to about 1e-4 units;
* a live rollout records states ``0 .. T`` straight from ``env.unwrapped.world``.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from dpr.checks import ParameterError
from dpr.datasets import features as F
from dpr.envs.particle_env import (
    LENGTH_SCALE,
    MAX_EPISODE_STEPS,
    ROBOT_FEATURES,
    action_repeat,
    episode_steps,
    steps_per_second,
)
from dpr.rollout import roll_out
from dpr.sim import swarm_class
from dpr.sim.constants import FPS

STEP_NS = 1_000_000_000 // FPS  # one physics step of simulated time, in integer nanoseconds
SB3_SUFFIX = ".zip"
_NAME_RE = re.compile(r"[^A-Za-z0-9_]+")
_RENDER_KWARGS = ("render_mode", "render_size")  # frames are not needed to rebuild the scene


class ViewError(ValueError):
    """A source, episode or policy that cannot be shown; the message names the file, or the argument (then it
    is a :class:`ViewParameterError`)."""


class ViewParameterError(ParameterError, ViewError):
    """A bad argument of the viewer's loaders: a :class:`~dpr.checks.ParameterError` (``.parameter`` names the
    library parameter, which the CLI says as its flag) that is also a :class:`ViewError`."""


@dataclass
class EpisodeLog:
    """One episode as arrays: ``S`` states and ``S - 1`` rewards (``rewards[i]`` came with state ``i + 1``)."""

    name: str  # entity subtree: everything of this episode is logged under /<name>/
    title: str  # what the viewer shows above its scene
    robot_radii: tuple[float, float]  # outer radius of a contracted and of an expanded robot
    positions: np.ndarray  # [S, N, 2] robot centres
    expansions: np.ndarray  # [S, N] 0 contracted .. 1 expanded
    alive: np.ndarray  # [N] bool
    centres_of_mass: np.ndarray  # [S, 2]
    agent: np.ndarray  # [S, 2] what the task moves to the goal: the swarm centre, or the object
    rewards: np.ndarray  # [S - 1]
    goal: np.ndarray  # [2]
    walls: list[np.ndarray]  # each [K, 2], a closed polygon
    object_kind: str | None = None  # "ball" | "box"
    object_size: float | None = None  # ball radius or half the box's side
    object_poses: np.ndarray | None = None  # [S, 3] x, y, angle
    magnets: list[np.ndarray] | None = None  # per state, [M_t, 2, 2]
    action_repeat: int = 1  # physics steps between two states (the env's action_repeat)

    def __post_init__(self) -> None:
        states, n = self.positions.shape[:2]
        expected = {
            "positions": (self.positions.shape, (states, n, 2)),
            "expansions": (self.expansions.shape, (states, n)),
            "alive": (self.alive.shape, (n,)),
            "centres_of_mass": (self.centres_of_mass.shape, (states, 2)),
            "agent": (self.agent.shape, (states, 2)),
            "rewards": (self.rewards.shape, (max(states - 1, 0),)),
            "goal": (self.goal.shape, (2,)),
        }
        if self.object_poses is not None:
            expected["object_poses"] = (self.object_poses.shape, (states, 3))
        for array, (got, want) in expected.items():
            if got != want:
                raise ValueError(f"EpisodeLog {self.name!r}: {array} has shape {got}, expected {want}")
        if states == 0:
            raise ValueError(f"EpisodeLog {self.name!r}: no states")
        if self.magnets is not None and len(self.magnets) != states:
            raise ValueError(f"EpisodeLog {self.name!r}: magnets for {len(self.magnets)} states, expected {states}")

    @property
    def n_states(self) -> int:
        return self.positions.shape[0]

    @property
    def n_robots(self) -> int:
        return self.positions.shape[1]

    @property
    def steps(self) -> np.ndarray:
        """Physics step of every state: ``0, k, 2k, .. (S - 1) k`` for ``k = action_repeat``."""
        return np.arange(self.n_states, dtype=np.int64) * self.action_repeat

    def radii(self) -> np.ndarray:
        """[S, N] outer robot radius, linear in the expansion between the contracted and expanded radius
        (exact for the disk model; for the paddle model, the reach of the paddle tips)."""
        contracted, expanded = self.robot_radii
        return contracted + self.expansions * (expanded - contracted)

    def running_metrics(self) -> dict[str, np.ndarray]:
        """Per state, the metrics of :mod:`dpr.metrics` on the agent's trajectory so far, and its distance to
        the goal."""
        return running_metrics(self.agent, self.goal)


def running_metrics(trajectory: np.ndarray, goal) -> dict[str, np.ndarray]:
    """``{distance_to_goal, projected_displacement, net_displacement, total_distance}``, each ``[S]``: row
    ``t`` equals :func:`dpr.metrics.episode_metrics` of ``trajectory[: t + 1]`` (vectorised: O(S), not O(S^2))."""
    trajectory = np.asarray(trajectory, dtype=np.float64)
    goal = np.asarray(goal, dtype=np.float64)
    start = trajectory[0]
    to_goal = goal - start
    norm = np.linalg.norm(to_goal)
    unit = to_goal / norm if norm > 0 else np.zeros(2)
    displacement = trajectory - start
    steps = np.linalg.norm(np.diff(trajectory, axis=0), axis=1)
    return {
        "distance_to_goal": np.linalg.norm(trajectory - goal, axis=1),
        "projected_displacement": displacement @ unit,
        "net_displacement": np.linalg.norm(displacement, axis=1),
        "total_distance": np.concatenate([[0.0], np.cumsum(steps)]),
    }


def entity_name(text: str) -> str:
    """``text`` as one entity-path part: runs of characters other than letters, digits and ``_`` become ``_``."""
    name = _NAME_RE.sub("_", text).strip("_")
    return name or "episode"


def model_radii(robot_model: str) -> tuple[float, float]:
    """(contracted, expanded) outer radius of ``robot_model``'s robots."""
    model = swarm_class(robot_model)
    return float(model.contracted_radius), float(model.expanded_radius)


def _closed(polygon: np.ndarray) -> np.ndarray:
    polygon = np.asarray(polygon, dtype=np.float64).reshape(-1, 2)
    return polygon if len(polygon) and np.array_equal(polygon[0], polygon[-1]) else np.vstack([polygon, polygon[:1]])


# -- MCAP -------------------------------------------------------------------------------------------------------
def episode_from_mcap(path: str | os.PathLike, name: str | None = None) -> EpisodeLog:
    """Read a ``dpr-mcap/1`` episode log. Raises :class:`ViewError` naming the file when it cannot be read."""
    from dpr.datasets.mcap import McapError, read_mcap

    path = Path(path)
    try:
        episode = read_mcap(path)
    except McapError as error:
        raise ViewError(str(error)) from error
    meta = episode.metadata
    try:
        radii = model_radii(meta.get("robot_model"))
    except ValueError:  # a log of another robot model: the scene still says how big its robots are
        radii = episode.scene.get("robot_radii")
        if radii is None:
            raise ViewError(
                f"{path}: neither a known robot_model in the metadata nor robot_radii in the scene"
            ) from None
    has_object = episode.object_poses is not None
    spec = episode.scene.get("object") or {}
    title = _title(meta.get(F.POLICY), meta.get(F.ENV_ID), meta.get(F.SEED), path.name)
    return EpisodeLog(
        name=name or entity_name(path.stem),
        title=title,
        robot_radii=(float(radii[0]), float(radii[1])),
        positions=episode.positions,
        expansions=episode.expansions,
        alive=episode.alive,
        centres_of_mass=episode.centres_of_mass,
        agent=episode.object_poses[:, 0:2] if has_object else episode.centres_of_mass,
        rewards=episode.rewards,
        goal=episode.goal,
        walls=[_closed(wall) for wall in episode.walls],
        object_kind=spec.get("kind") if has_object else None,
        object_size=spec.get("size") if has_object else None,
        object_poses=episode.object_poses,
        magnets=episode.magnets,
        action_repeat=episode.action_repeat,
    )


def _title(policy: Any, env_id: Any, seed: Any, source: str | None = None) -> str:
    parts = [str(p) for p in (policy, env_id) if p]
    if seed is not None:
        parts.append(f"seed {seed}")
    if source:
        parts.append(source)
    return " · ".join(parts)


# -- datasets ---------------------------------------------------------------------------------------------------
def _make_env(env_id: str, kwargs: Mapping[str, Any], where: str | None = None) -> gym.Env:
    """``gym.make(env_id, **kwargs)``; a failure is a ViewError that starts with ``where`` (a recorded
    episode), or without ``where`` a :class:`ViewParameterError` naming ``env_id`` or ``env_kwargs``."""
    import dpr  # noqa: F401  (registers the ids)

    try:
        return gym.make(env_id, **kwargs)
    except (gym.error.Error, TypeError, ValueError) as error:
        problem = f"cannot make {env_id} with {dict(kwargs)}: {error}"
        if where is not None:
            raise ViewError(f"{where}: {problem}") from error
        raise ViewParameterError("env_id" if isinstance(error, gym.error.Error) else "env_kwargs", problem) from error


def episode_from_dataset(reader, episode: int, name: str | None = None) -> EpisodeLog:
    """Episode ``episode`` (its index) of a dataset written by ``dpr collect`` (``reader``: a
    :class:`dpr.datasets.lerobot.LeRobotReader`). Raises :class:`ViewError` for an index out of range (a
    :class:`ViewParameterError` naming ``episode``) or an episode without the ``seed``/``env_id``/``env_kwargs``
    that rebuild its scene."""
    if not isinstance(episode, (int, np.integer)) or not 0 <= episode < reader.num_episodes:
        held = f"episodes 0..{reader.num_episodes - 1}" if reader.num_episodes else "no episodes"
        raise ViewParameterError("episode", f"{episode} is not in the dataset {reader.root}, which holds {held}")
    index = int(episode)
    meta = reader.episodes[index]
    missing = [key for key in (F.SEED, F.ENV_ID, F.ENV_KWARGS) if key not in meta]
    if missing:
        raise ViewError(f"{reader.root}: episode {index} lacks {missing}; it was not recorded by dpr collect")
    where = f"{reader.root} episode {index}"
    kwargs = {key: value for key, value in dict(meta[F.ENV_KWARGS]).items() if key not in _RENDER_KWARGS}
    repeat = _dataset_repeat(reader, kwargs, where)
    scene = _dataset_scene(meta, kwargs, where)
    data = reader.episode(index, columns=[F.OBSERVATION, F.REWARD])
    state = _dataset_states(data, scene, where)
    n = scene["n"]
    robots = state[:, : ROBOT_FEATURES * n].reshape(len(state), n, ROBOT_FEATURES)
    goal = scene["goal"]
    positions = robots[..., 0:2] / LENGTH_SCALE + goal  # the observation is in the goal frame, scaled by 1/1000
    centres = positions.mean(axis=1)
    spec = scene["object"]
    object_poses = None
    if scene["has_object"]:
        at = ROBOT_FEATURES * n
        xy = state[:, at : at + 2] / LENGTH_SCALE + goal
        object_poses = np.column_stack([xy, np.zeros(len(state))])  # the observation holds no object angle
    rewards = np.asarray(data[F.REWARD], dtype=np.float64).reshape(-1)[: len(state) - 1]
    return EpisodeLog(
        name=name or f"episode_{index}",
        title=_title(meta.get(F.POLICY), meta[F.ENV_ID], meta[F.SEED], f"episode {index}"),
        robot_radii=model_radii(scene["model"]),
        positions=positions,
        expansions=robots[..., 5],
        alive=scene["alive"],
        centres_of_mass=centres,
        agent=object_poses[:, 0:2] if object_poses is not None else centres,
        rewards=rewards,
        goal=goal,
        walls=scene["walls"],
        object_kind=spec.kind if spec is not None else None,
        object_size=spec.size if spec is not None else None,
        object_poses=object_poses,
        magnets=None,
        action_repeat=repeat,
    )


def _dataset_scene(meta: Mapping[str, Any], kwargs: Mapping[str, Any], where: str) -> dict[str, Any]:
    """What the observations do not hold (walls, goal, dead robots, the object's shape), rebuilt by resetting the
    episode's env with its seed."""
    env = _make_env(meta[F.ENV_ID], kwargs, where)
    try:
        env.reset(seed=int(meta[F.SEED]))
        base = env.unwrapped
        world = base.world
        return {
            "n": base.n_robots,
            "model": base.robot_model,
            "has_object": base.has_object,
            "state_width": base.memory_offset,  # the state without the last action
            "goal": np.array(base.goal, dtype=np.float64),
            "walls": [_closed(wall) for wall in world.walls],
            "alive": ~world.dead,
            "object": world.object_spec,
        }
    finally:
        env.close()


def _dataset_states(data: Mapping[str, Any], scene: Mapping[str, Any], where: str) -> np.ndarray:
    """The episode's ``[T, D]`` observations, refused unless they are states of ``scene``'s swarm."""
    state = np.asarray(data[F.OBSERVATION], dtype=np.float64)
    n = scene["n"]
    width = scene["state_width"]
    if state.ndim != 2 or state.shape[1] not in (width, width + n + 1):  # + the last action, with obs_last_action
        raise ViewError(f"{where}: observation.state has shape {state.shape}, expected [T, {width}] for {n} robots")
    if len(state) == 0:
        raise ViewError(f"{where}: the episode has no frames")
    return state


def _dataset_repeat(reader, kwargs: Mapping[str, Any], where: str) -> int:
    """Physics steps between two frames of a dataset: its fps says, which must be the decision rate of the env
    kwargs it was recorded with (a dataset recorded before that is refused, named: dpr.datasets.timing)."""
    try:
        repeat = action_repeat(dict(kwargs))
    except ValueError as error:
        raise ViewError(f"{where}: {error}") from error
    if reader.fps != steps_per_second(dict(kwargs)):
        from dpr.datasets.timing import check_dataset_time

        check_dataset_time(reader.root, reader.info)  # names a dataset of the old fps, and what to do
        raise ViewError(
            f"{where}: recorded with action_repeat={repeat}, whose decision rate is {steps_per_second(dict(kwargs)):g} "
            f"frames per second, but the dataset's fps is {reader.fps:g}"
        )
    return repeat


# -- live rollouts ----------------------------------------------------------------------------------------------
def check_view_policy(policy: str) -> str:
    """``policy`` if ``dpr view`` can roll it out (a scripted policy, or a model file written by ``dpr train``);
    a :class:`ViewParameterError` naming ``policy`` otherwise: unknown names list the choices, model files that
    do not load (:func:`dpr.policies.sb3.load_model`) are named."""
    from dpr.policies.registry import check_policy_name
    from dpr.policies.sb3 import load_model

    try:
        if policy.endswith(SB3_SUFFIX):
            load_model(policy)  # a corrupt or crafted file is refused before any rollout
            return policy
        return check_policy_name(policy)
    except ValueError as error:
        raise ViewParameterError("policy", str(error)) from error


@dataclass(frozen=True)
class ViewRollout:
    """One live rollout for the viewer: ``policy`` (a scripted policy's name or a model file) on ``env_id`` from
    ``reset(seed=seed)``, for at most ``steps`` physics steps. ``env_kwargs``: further ``gym.make`` kwargs (the
    swarm size, robot model and episode length are fields of their own). ``transfer`` runs a model file on a task
    other than its own, as ``dpr evaluate --transfer`` does. Bad values are a :class:`ViewParameterError` naming
    the field."""

    env_id: str
    policy: str
    seed: int
    n_robots: int = 9
    robot_model: str = "paddle"
    steps: int = MAX_EPISODE_STEPS
    env_kwargs: Mapping[str, Any] = field(default_factory=dict)
    transfer: bool = False

    def __post_init__(self) -> None:
        check_view_policy(self.policy)
        reserved = sorted({"n_robots", "robot_model", "max_episode_steps", *_RENDER_KWARGS} & set(self.env_kwargs))
        if reserved:
            raise ViewParameterError(
                "env_kwargs", f"must not set {reserved}: the swarm size, robot model and episode length are set apart"
            )
        object.__setattr__(self, "env_kwargs", dict(self.env_kwargs))  # (frozen) a copy the caller cannot change

    def make_kwargs(self) -> dict[str, Any]:
        """The ``gym.make`` kwargs of the rollout: a model runs with the env kwargs it was trained with."""
        kwargs = {"n_robots": self.n_robots, "robot_model": self.robot_model, **self.env_kwargs}
        if self.policy.endswith(SB3_SUFFIX):
            from dpr.policies.model_file import model_env_kwargs

            try:
                kwargs = model_env_kwargs(self.policy, self.env_id, kwargs, transfer=self.transfer)
            except ValueError as error:
                raise ViewParameterError("policy", str(error)) from error
        return {**kwargs, "max_episode_steps": episode_steps(kwargs, self.steps)}


def rollout_episode(
    rollout: ViewRollout, *, name: str | None = None, on_step: Callable[[int], None] | None = None
) -> EpisodeLog:
    """Roll ``rollout`` out (:func:`dpr.rollout.roll_out`) and record the state after every env step, at the
    physics step it belongs to (a model deciding every ``action_repeat`` = k steps: states at physics steps 0, k,
    2k, ..., the last one at ``rollout.steps`` rounded up to a decision). Stops early when the episode ends; a
    physics blow-up ends the record at the last sane state. ``on_step(p)`` is called after each env step with the
    physics steps done so far, ``p`` (for a progress bar over ``rollout.steps``; the last may pass it by less than
    a decision). Bad env kwargs for a model are a :class:`ViewParameterError` naming ``policy``."""
    from dpr.policies.registry import make_policy

    env = _make_env(rollout.env_id, rollout.make_kwargs())
    base = env.unwrapped
    repeat = base.action_repeat
    recorder: list[_Recorder] = []

    def record_step(step) -> None:
        recorder[0].add(base.world)
        if on_step is not None:
            on_step(step.index * repeat)

    try:
        result = roll_out(
            env,
            make_policy(rollout.policy, env, rollout.transfer),
            rollout.seed,
            on_reset=lambda observation, info: recorder.append(_Recorder(base.world)),
            on_step=record_step,
        )
        world = base.world
        spec = world.object_spec
        walls = [_closed(wall) for wall in world.walls]
        alive = ~world.dead
    finally:
        env.close()
    arrays = recorder[0].arrays()
    return EpisodeLog(
        name=name or entity_name(rollout.policy),
        title=_title(rollout.policy, rollout.env_id, rollout.seed),
        robot_radii=model_radii(rollout.robot_model),
        positions=arrays["positions"],
        expansions=arrays["expansions"],
        alive=alive,
        centres_of_mass=arrays["centres_of_mass"],
        agent=arrays["object_poses"][:, 0:2] if spec is not None else arrays["centres_of_mass"],
        rewards=result.rewards,
        goal=np.array(result.goal, dtype=np.float64),
        walls=walls,
        object_kind=spec.kind if spec is not None else None,
        object_size=spec.size if spec is not None else None,
        object_poses=arrays["object_poses"] if spec is not None else None,
        magnets=arrays["magnets"],
        action_repeat=repeat,
    )


class _Recorder:
    """Copies of the world's per-state arrays (the world reuses and replaces its own every step)."""

    def __init__(self, world) -> None:
        self.positions: list[np.ndarray] = []
        self.expansions: list[np.ndarray] = []
        self.centres: list[np.ndarray] = []
        self.objects: list[np.ndarray] = []
        self.magnets: list[np.ndarray] = []
        self.add(world)

    def add(self, world) -> None:
        swarm = world.swarm
        self.positions.append(np.array(swarm.position, dtype=np.float64))
        self.expansions.append(np.array(swarm.expansion, dtype=np.float64))
        self.centres.append(np.array(world.centre_of_mass, dtype=np.float64))
        self.magnets.append(np.array(swarm.magnet_segments(), dtype=np.float64).reshape(-1, 2, 2))
        if world.object_body is not None:
            self.objects.append(np.array(world.object_pose, dtype=np.float64))

    def arrays(self) -> dict[str, Any]:
        return {
            "positions": np.stack(self.positions),
            "expansions": np.stack(self.expansions),
            "centres_of_mass": np.stack(self.centres),
            "object_poses": np.stack(self.objects) if self.objects else None,
            "magnets": self.magnets,
        }
