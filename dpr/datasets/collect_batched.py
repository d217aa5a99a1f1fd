"""`dpr collect --engine batched`: episodes rolled out K at a time on the batched disk engine, as the records that
:func:`dpr.datasets.collect.collect` saves, so the dataset (and its MCAP logs) has the layout a pymunk collection has.

:func:`rollout_batch` steps one vector env of ``len(seeds)`` envs, env ``i`` started from ``seeds[i]`` as the single
env's ``reset(seed=seeds[i])`` starts (:class:`dpr.envs.batched.BatchedSwarmVectorEnv`), with the policy in batch
(:mod:`dpr.policies.batched`). Each env keeps what :func:`dpr.datasets.collect.rollout` keeps of an episode and stops
at the same end: frame ``t`` holds the observation its policy saw, the action, and the reward, done and success
flags the action produced; a step whose physics blew up ends the episode before it and is not recorded. Envs whose
episode has ended go on being stepped with the rest and are ignored. The records come back in seed order, so
:func:`dpr.datasets.collect.collect` saves them as it saves rollouts from worker processes: the dataset is the same
whichever batches ran it, and a stopped collection resumes from its saved seeds.

The MCAP logs hold what the batched engine simulates: positions, velocities, angular velocities, expansions and
alive flags; the disks' angles (which the batched engine does not track) are logged as 0, the ball's too, and no
magnet segments are logged. This module imports torch: :mod:`dpr.datasets.collect` imports it only for the batched
engine.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

from dpr.datasets import features as F
from dpr.datasets.collect_summary import EpisodeRecord, RecordedFrames
from dpr.envs.particle_env import PHYSICS_ERROR
from dpr.metrics import episode_metrics
from dpr.policies.batched import make_batched_policy
from dpr.sim import constants as C

ENGINE = "batched"


def make_batched_env(spec, num_envs: int, device: str = "cpu"):
    """The vector env of ``num_envs`` envs that ``spec`` (a :class:`dpr.datasets.collect.CollectSpec`) records on: its
    ``gym.make`` kwargs, on ``device``; its unwrapped :class:`~dpr.envs.batched.BatchedSwarmVectorEnv`."""
    import dpr  # noqa: F401  (registers the ids)

    kwargs = spec.make_kwargs()
    steps = kwargs.pop("max_episode_steps")
    venv = gym.make_vec(
        spec.env_id,
        num_envs=num_envs,
        vectorization_mode="vector_entry_point",
        max_episode_steps=steps,
        device=device,
        **kwargs,
    )
    return venv.unwrapped


def check_batched_spec(spec, device: str = "cpu") -> None:
    """Make one env of ``spec`` on the batched engine and its policies in batch: a robot model, device, kwarg or
    policy it cannot run is refused here (a ValueError naming it), before anything is written."""
    env = make_batched_env(spec, 1, device)
    try:
        for name in (spec.policy, spec.label_policy):
            if name is not None:
                make_batched_policy(name, env)
    finally:
        env.close()


@dataclass
class _Episode(RecordedFrames):
    """What one env of the batch gathers while its episode runs: :class:`RecordedFrames`, its rewards and the
    agent's positions (the metrics' input), and its MCAP writer."""

    seed: int = 0
    rewards: list = field(default_factory=list)
    trajectory: list = field(default_factory=list)
    physics_error: str | None = None
    writer: object = None  # its McapEpisodeWriter, when logged

    def record(self, env, goal: np.ndarray, seconds: float):
        trajectory = np.array(self.trajectory, dtype=float)
        return EpisodeRecord(
            seed=self.seed,
            **self.arrays(env.template),
            rewards=np.array(self.rewards, dtype=np.float32),
            metrics=episode_metrics(trajectory, goal),
            physics_error=self.physics_error,
            seconds=seconds,
            trajectory=trajectory,
        )


def rollout_batch(spec, seeds: list[int], device: str = "cpu", mcap_paths: list[Path | None] | None = None):
    """Roll ``spec.policy`` out on the batched engine from each of ``seeds`` at once until every episode has ended
    (module docstring); one :class:`dpr.datasets.collect.EpisodeRecord` per seed, in order, each with its MCAP log
    written to ``mcap_paths[i]`` when given."""
    started = time.perf_counter()
    env = make_batched_env(spec, len(seeds), device)
    episodes = [_Episode(seed=seed) for seed in seeds]
    try:
        policy = make_batched_policy(spec.policy, env, seed=seeds[0])
        labeller = None if spec.label_policy is None else make_batched_policy(spec.label_policy, env, seed=seeds[0])
        observation = env.reset_tensors(seed=list(seeds))
        _start(env, episodes, spec, mcap_paths)
        running = np.ones(len(seeds), dtype=bool)
        for _ in range(spec.steps):
            if not running.any():
                break
            state = env.environment_state().cpu().numpy()
            actions = policy(observation)
            labels = actions if labeller is None else labeller(observation)
            shown = observation.cpu().numpy()
            observation, reward, terminated, truncated, blown = env.advance(env.targets(actions))
            step = _Step(shown, _numpy_actions(env, labels), _numpy_actions(env, actions), state)
            step.outcome(reward, terminated, truncated, env._info(blown))
            running = _note_step(env, episodes, running, step)
    except BaseException:
        for episode in episodes:
            if episode.writer is not None:
                episode.writer.abort()
        raise
    finally:
        env.close()
    for episode in episodes:
        if episode.writer is not None:
            episode.writer.close()
    seconds = (time.perf_counter() - started) / len(seeds)
    goal = np.asarray(env.template.goal, dtype=float)
    return [episode.record(env, goal, seconds) for episode in episodes]


def _numpy_actions(env, actions: torch.Tensor) -> np.ndarray:
    """A batch of actions as the single env takes them: [K, N] floats, or [K] joint actions (Discrete(2^N))."""
    array = torch.as_tensor(actions).cpu().numpy()
    if env.template.action_type == "discrete":
        return array.reshape(env.num_envs).astype(np.int64)
    return array.reshape(env.num_envs, env.n_robots)


@dataclass
class _Step:
    """One step of every env, as numpy: what the policies saw and did, and (after :meth:`outcome`) what came of it."""

    observation: np.ndarray
    recorded: np.ndarray  # the actions recorded (the label policy's, when there is one)
    taken: np.ndarray  # the actions the envs were given
    environment_state: np.ndarray  # before the step
    reward: np.ndarray | None = None
    done: np.ndarray | None = None
    terminated: np.ndarray | None = None
    truncated: np.ndarray | None = None
    info: dict | None = None

    def outcome(self, reward, terminated, truncated, info: dict) -> None:
        self.reward = reward.cpu().numpy()
        self.terminated, self.truncated = terminated.cpu().numpy(), truncated.cpu().numpy()
        self.done = self.terminated | self.truncated
        self.info = info


def _start(env, episodes: list[_Episode], spec, mcap_paths) -> None:
    """Each env's reset: the agent's start, and its MCAP log's scene and reset state."""
    agent = env.agent_position().cpu().numpy().astype(float)
    swarms = _Swarms.of(env) if mcap_paths is not None and any(path is not None for path in mcap_paths) else None
    for i, episode in enumerate(episodes):
        episode.trajectory.append(agent[i])
        if mcap_paths is not None and mcap_paths[i] is not None:
            episode.writer = _start_mcap_log(env, i, mcap_paths[i], episode.seed, spec, swarms)


def _note_step(env, episodes: list[_Episode], running: np.ndarray, step: _Step) -> np.ndarray:
    """Add the step to every running env's episode (not one whose physics blew up: it ends before the step); the
    envs still running after it."""
    info = step.info
    blown = info.get(f"_{PHYSICS_ERROR}", np.zeros(len(episodes), dtype=bool))
    agent = info["agent_position"].astype(float)
    logging = any(episodes[i].writer is not None for i in np.flatnonzero(running))
    swarms = _Swarms.of(env) if logging else None  # one copy of the world a step, not one per env and field
    for i in np.flatnonzero(running):
        episode = episodes[i]
        if blown[i]:
            episode.physics_error = str(info[PHYSICS_ERROR][i])
            continue
        episode.environment_states.append(step.environment_state[i])
        episode.observations.append(step.observation[i])
        episode.actions.append(step.recorded[i])
        episode.rewards.append(float(step.reward[i]))
        episode.dones.append(bool(step.done[i]))
        episode.successes.append(bool(info["is_success"][i]))
        episode.trajectory.append(agent[i])
        if episode.writer is not None:
            _log_mcap_step(env, i, episode, step, swarms)
    return running & ~step.done & ~blown


# -- MCAP ----------------------------------------------------------------------------------------------------------
def _start_mcap_log(env, i: int, path: Path, seed: int, spec, swarms: _Swarms):
    """An MCAP writer for env ``i``'s episode, its scene and reset state logged (as
    :func:`dpr.datasets.collect._start_mcap_log` logs a single env's)."""
    from dpr.datasets.mcap import McapEpisodeWriter

    metadata = {
        F.ENV_ID: spec.env_id,
        F.SEED: seed,
        F.N_ROBOTS: int(env.n_robots),
        F.ROBOT_MODEL: env.template.robot_model,
        F.POLICY: spec.policy,
        F.ENV_KWARGS: spec.make_kwargs(),
        "engine": ENGINE,
    }
    writer = McapEpisodeWriter(path, metadata=metadata, action_repeat=env.action_repeat)
    walls = env.world.walls[i].cpu().numpy() if env.world.n_walls else []
    writer.write_scene(
        goal=np.asarray(env.template.goal, dtype=float),
        walls=list(walls),
        object_kind="ball" if env.template.has_object else None,
        object_size=env.template.object_size if env.template.has_object else None,
        robot_radii=(C.DISK_CONTRACTED_RADIUS, C.DISK_EXPANDED_RADIUS),
    )
    writer.write_step(0, swarms.state(i))
    return writer


@dataclass
class _Swarms:
    """The world's state on the CPU in float64, ``[K, ...]``, copied once a step (from a GPU, one copy per field
    rather than one per env and field), for each env's MCAP step."""

    n_robots: int
    position: np.ndarray
    velocity: np.ndarray
    angular_velocity: np.ndarray
    expansion: np.ndarray
    alive: np.ndarray
    object_position: np.ndarray | None
    object_velocity: np.ndarray | None

    @classmethod
    def of(cls, env) -> _Swarms:
        world, has_object = env.world, env.template.has_object
        host = lambda tensor: tensor.double().cpu().numpy()  # noqa: E731
        return cls(
            env.n_robots,
            host(world.position),
            host(world.velocity),
            host(world.angular_velocity),
            host(world.expansion),
            world.alive.cpu().numpy(),
            host(world.object_position) if has_object else None,
            host(world.object_velocity) if has_object else None,
        )

    def state(self, i: int):
        """Env ``i``'s swarm as an MCAP step logs it (angles 0: the batched engine does not track them)."""
        from dpr.datasets.mcap import SwarmState

        position, has_object = self.position[i], self.object_position is not None
        return SwarmState(
            positions=position,
            angles=np.zeros(self.n_robots),
            velocities=self.velocity[i],
            angular_velocities=self.angular_velocity[i],
            expansions=self.expansion[i],
            alive=self.alive[i],
            object_pose=np.array([*self.object_position[i], 0.0]) if has_object else None,
            object_velocity=self.object_velocity[i] if has_object else None,
            centre_of_mass=position.mean(axis=0),
        )


def _log_mcap_step(env, i: int, episode: _Episode, step: _Step, swarms: _Swarms) -> None:
    from dpr.datasets.mcap import StepOutcome

    action = step.taken[i]
    if env.template.action_type == "discrete":  # logged as its N bits, robot 0 the most significant
        action = (int(action) >> np.arange(env.n_robots - 1, -1, -1)) & 1
    metrics = {key: step.info[key][i] for key in ("projected_displacement", "net_displacement", "total_distance")}
    metrics["is_success"] = bool(step.info["is_success"][i])
    outcome = StepOutcome(action, float(step.reward[i]), bool(step.terminated[i]), bool(step.truncated[i]), metrics)
    episode.writer.write_step(len(episode.actions), swarms.state(i), outcome)


# -- replay --------------------------------------------------------------------------------------------------------
def replay_batched(env_id: str, kwargs: dict, seed: int, actions: np.ndarray, device: str = "cpu") -> dict[str, list]:
    """An episode recorded on the batched engine, re-run there (one env, on the kind of ``device`` that recorded it)
    from ``seed`` with its recorded ``actions``: per frame the observation, reward, done and success flags and
    environment state, for :func:`dpr.datasets.replay.replay_episode` to compare. It stops where the episode ends (or
    its physics blows up)."""
    import dpr  # noqa: F401  (registers the ids)

    kwargs = dict(kwargs)
    steps = kwargs.pop("max_episode_steps", len(actions))
    venv = gym.make_vec(
        env_id, num_envs=1, vectorization_mode="vector_entry_point", max_episode_steps=steps, device=device, **kwargs
    )
    env = venv.unwrapped
    replayed: dict[str, list] = {key: [] for key in (F.OBSERVATION, F.REWARD, F.DONE, F.SUCCESS, F.ENVIRONMENT_STATE)}
    try:
        observation = env.reset_tensors(seed=[seed])
        for action in actions:
            state = env.environment_state()[0].cpu().numpy()
            shown = observation[0].cpu().numpy()
            batch = torch.as_tensor(np.array(action)).reshape(1, -1)
            if env.template.action_type == "discrete":
                batch = batch.reshape(1)
            observation, reward, terminated, truncated, blown = env.advance(env.targets(batch))
            if bool(blown[0]):
                break
            for key, value in (
                (F.ENVIRONMENT_STATE, state),
                (F.OBSERVATION, shown),
                (F.REWARD, float(reward[0])),
                (F.DONE, bool(terminated[0] | truncated[0])),
                (F.SUCCESS, bool(env.success[0])),
            ):
                replayed[key].append(value)
            if replayed[F.DONE][-1]:
                break
    finally:
        venv.close()
    return replayed
