"""Record policy rollouts as a LeRobot v3.0 dataset (and optionally one MCAP log per episode).

``collect`` rolls out a policy on one task for ``episodes`` seeds (``seed``, ``seed + 1``, ...), in worker
processes or as Ray tasks (:class:`RolloutWorkers`, local or on a cluster), and the main process appends each
finished episode to the dataset in seed order: one valid dataset whatever ran the rollouts. Frames follow
LeRobot's convention: frame ``t`` holds the observation the policy saw, the action it took, and the reward,
done and success flags that action produced (``next.*``); an episode of ``T`` steps has ``T`` frames.

Resuming: the dataset is valid after every saved episode (see :mod:`dpr.datasets.lerobot`). Running the same
command again opens the dataset, checks that it records the same env, env kwargs, policy and features, and
rolls out only the seeds it does not hold yet. A killed run loses at most the episodes in flight.

Time: ``fps`` is the decision rate, one frame per env step of ``action_repeat`` physics steps
(:mod:`dpr.datasets.timing`); a dataset recorded before that with ``action_repeat > 1`` is refused, named.
Every frame carries ``observation.environment_state`` (the env's ``environment_state()``); a dataset recorded
before it lacks it, and episodes are not added to it (one dataset, one layout), named.
"""

from __future__ import annotations

import functools
import multiprocessing as mp
import pickle
import signal
import tempfile
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym
import numpy as np

from dpr.atomic import is_temporary
from dpr.checks import ParameterError, check_choice, check_int
from dpr.datasets import features as F
from dpr.datasets.collect_summary import CollectSummary, EpisodeRecord, RecordedFrames, folder_bytes, metric_summary
from dpr.datasets.features import dataset_features
from dpr.datasets.lerobot import DatasetError, LeRobotReader, LeRobotWriter
from dpr.datasets.lerobot.format import INFO_PATH, load_info
from dpr.datasets.timing import check_dataset_time, dataset_fps, time_info
from dpr.envs import TASKS, episode_steps
from dpr.envs.batched import refuse_batched_only_kwargs
from dpr.envs.particle_env import IMAGE_SIZE_RANGE
from dpr.interrupts import sigint_deferred, wait_deferring_sigint
from dpr.metrics import EpisodeMetrics
from dpr.policies.registry import check_policy_name, make_policy
from dpr.rollout import roll_out
from dpr.sim import swarm_class

MCAP_FOLDER = "mcap"
ENGINES = ("pymunk", "batched")  # the reference engine, one episode per env; the batched disk engine
BATCHED = ENGINES[1]
# gym.make kwargs that CollectSpec sets from its own fields
RESERVED_ENV_KWARGS = ("n_robots", "robot_model", "render_mode", "render_size", "max_episode_steps")


@dataclass(frozen=True)
class CollectSpec:
    """What a dataset records: the same spec must be given to resume it."""

    env_id: str
    policy: str = "wave"
    n_robots: int = 9
    robot_model: str = "paddle"
    steps: int | None = None  # frames (env steps) per episode; None: a whole episode (dpr.envs.episode_steps)
    pixels: bool = False
    image_size: int = 96
    env_kwargs: dict = field(default_factory=dict)  # any further gym.make kwargs (e.g. object_type="box")
    # DAgger-style data: ``policy`` drives the env and the recorded action is this policy's on each observation
    label_policy: str | None = None
    mcap: bool = False  # also one MCAP log per episode, in the dataset's mcap/ folder
    engine: str = "pymunk"  # or "batched": the disk model, episodes stepped together (dpr.datasets.collect_batched)

    def __post_init__(self):
        check_choice("env_id", self.env_id, TASKS)
        check_choice("engine", self.engine, ENGINES)
        if self.engine == BATCHED and self.pixels:
            raise ParameterError("pixels", "the batched engine does not render: record pixels on the pymunk engine")
        if self.steps is None:
            object.__setattr__(self, "steps", episode_steps(self.env_kwargs))  # (frozen)
        check_policy_name(self.policy)
        if self.label_policy is not None:
            check_policy_name(self.label_policy)
        for name in ("n_robots", "steps"):
            check_int(name, getattr(self, name), 1)
        check_int("image_size", self.image_size, *IMAGE_SIZE_RANGE)  # the frames are renders of this size
        reserved = sorted(set(RESERVED_ENV_KWARGS) & set(self.env_kwargs))
        if reserved:
            raise ParameterError("env_kwargs", f"must not set {reserved}: they are CollectSpec fields")
        refuse_batched_only_kwargs(
            self.env_kwargs, "a dataset records env kwargs that every engine and learner must make its env with"
        )
        if self.policy.endswith(".zip"):  # a model records on the env it was trained on, with the same kwargs
            from dpr.policies.model_file import model_env_kwargs

            model_env_kwargs(
                self.policy,
                self.env_id,
                {"n_robots": self.n_robots, "robot_model": self.robot_model, **self.env_kwargs},
            )

    def make_kwargs(self) -> dict:
        """The ``gym.make`` kwargs that reproduce an episode (stored with every episode)."""
        kwargs = {"n_robots": self.n_robots, "robot_model": self.robot_model, **self.env_kwargs}
        kwargs["max_episode_steps"] = self.steps
        if self.pixels:
            kwargs.update(render_mode="rgb_array", render_size=self.image_size)
        return kwargs

    def make_env(self) -> gym.Env:
        import dpr  # noqa: F401  (registers the ids in worker processes)

        return gym.make(self.env_id, **self.make_kwargs())


@dataclass(frozen=True)
class SavedEpisode:
    """What a summary keeps of a recorded episode (not its arrays: memory stays bounded)."""

    seed: int
    frames: int
    metrics: EpisodeMetrics


@dataclass
class _Frames(RecordedFrames):
    """What a pymunk episode's frames gather as it runs: :class:`RecordedFrames`, and the images (taken before each
    step, as the environment states are)."""

    images: list = field(default_factory=list)

    def record(self, spec: CollectSpec, base, result, started: float) -> EpisodeRecord:
        """The frames as the arrays of an :class:`EpisodeRecord` (``base``: the unwrapped env)."""
        frames = len(self.actions)
        images = np.array(self.images[:frames], dtype=np.uint8) if spec.pixels else None
        return EpisodeRecord(
            seed=result.seed,
            **self.arrays(base),
            rewards=result.rewards.astype(np.float32),
            metrics=result.metrics,
            images=None if images is None else images.reshape(frames, spec.image_size, spec.image_size, 3),
            physics_error=result.physics_error,
            seconds=time.perf_counter() - started,
            trajectory=result.trajectory,
        )


def _start_mcap_log(env, path: Path, seed: int, policy: str):
    """An MCAP writer for the episode ``env`` was just reset into, its scene and reset state logged."""
    from dpr.datasets.mcap import McapEpisodeWriter, episode_metadata, log_env_scene, log_env_step

    metadata = episode_metadata(env, seed=seed, policy=policy)
    writer = McapEpisodeWriter(path, metadata=metadata, action_repeat=env.unwrapped.action_repeat)
    log_env_scene(writer, env)
    log_env_step(writer, env, 0)
    return writer


def _log_mcap_step(writer, env, step) -> None:
    """Log the state a :class:`dpr.rollout.Step` led to, and the step itself."""
    from dpr.datasets.mcap import StepOutcome, log_env_step

    outcome = StepOutcome(step.action, step.reward, step.terminated, step.truncated, metrics=step.info)
    log_env_step(writer, env, step.index, outcome)


def rollout(spec: CollectSpec, seed: int, mcap_path: Path | None = None) -> EpisodeRecord:
    """Roll ``spec.policy`` out from ``reset(seed=seed)`` until the episode ends (:func:`dpr.rollout.roll_out`,
    whose rule for a physics error applies: the step that blew up is not recorded); optionally log it to MCAP."""
    started = time.perf_counter()
    env = spec.make_env()
    base = env.unwrapped
    policy = make_policy(spec.policy, env)
    labeller = None if spec.label_policy is None else make_policy(spec.label_policy, env)
    frames = _Frames()
    writer = None

    def take_state() -> None:
        frames.environment_states.append(base.environment_state())
        if spec.pixels:
            frames.images.append(env.render())

    def on_reset(observation, info) -> None:
        nonlocal writer
        if labeller is not None:
            labeller.reset(seed)
        take_state()
        if mcap_path is not None:
            writer = _start_mcap_log(env, mcap_path, seed, spec.policy)

    def on_step(step) -> None:
        frames.observations.append(step.observation)
        frames.actions.append(step.action if labeller is None else labeller(step.observation))
        frames.dones.append(step.done)
        frames.successes.append(step.info["is_success"])
        if writer is not None:
            _log_mcap_step(writer, env, step)
        if not step.done:  # the frame of the next step shows the state it starts from
            take_state()

    try:
        result = roll_out(env, policy, seed, on_reset=on_reset, on_step=on_step)
    except BaseException:
        if writer is not None:
            writer.abort()
        raise
    finally:
        env.close()
    if writer is not None:
        writer.close()
    return frames.record(spec, base, result, started)


def save_record(
    writer: LeRobotWriter, spec: CollectSpec, record: EpisodeRecord, task: str, mcap_file: str | None
) -> int:
    """Append ``record`` to the dataset as one episode; returns its index."""
    frames = {
        F.OBSERVATION: record.observations,
        **({} if record.environment_states is None else {F.ENVIRONMENT_STATE: record.environment_states}),
        F.ACTION: record.actions,
        F.REWARD: record.rewards,
        F.DONE: record.dones,
        F.SUCCESS: record.successes,
    }
    if record.images is not None:
        frames[F.IMAGE] = record.images
    writer.add_frames(frames, task=task)
    metrics = record.metrics
    meta = {
        F.SEED: record.seed,
        F.ENV_ID: spec.env_id,
        F.ENV_KWARGS: spec.make_kwargs(),
        F.POLICY: spec.policy,
        F.LABEL_POLICY: spec.label_policy or "",
        F.N_ROBOTS: spec.n_robots,
        F.ROBOT_MODEL: spec.robot_model,
        **{name: getattr(metrics, name) for name in F.METRIC_FIELDS},  # (success is a bool already)
        F.PHYSICS_ERROR: record.physics_error or "",
        F.MCAP_FILE: mcap_file or "",
    }
    return writer.save_episode(meta)


def _recorded_seeds(root: Path) -> set[int]:
    if not (root / "meta" / "info.json").is_file():
        return set()
    reader = LeRobotReader(root)
    return {int(episode[F.SEED]) for episode in reader.episodes if F.SEED in episode}


def _ignore_sigint() -> None:
    # Ctrl-C reaches the whole process group: workers ignore it and the main process shuts them down.
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _rollout_job(job: tuple[CollectSpec, int, Path | None]) -> EpisodeRecord:
    return rollout(*job)


def _rollout_to_file(job: tuple[CollectSpec, int, Path | None], handoff: Path) -> Path:
    """A pool worker's rollout, left as a file in ``handoff``; only its path goes back through the pool.

    An episode runs to megabytes. Sent through the pool's result pipe, a worker blocks mid-send, holding the
    pipe's write lock, until the main process reads it; ``Pool.terminate()`` on Ctrl-C then waits for that lock
    forever once the pool has stopped reading. A path is a few hundred bytes and never blocks. (It is sent once the
    file is whole: a worker ended mid-write leaves a file nobody reads, removed with the folder.)"""
    record = _rollout_job(job)
    path = handoff / f"seed-{job[1]}.pkl"
    with open(path, "wb") as handle:
        pickle.dump(record, handle, protocol=pickle.HIGHEST_PROTOCOL)
    return path


def _take_record(path: Path) -> EpisodeRecord:
    """The record a worker of this run left at ``path`` (a private temporary folder), removed once read."""
    with open(path, "rb") as handle:
        record = pickle.load(handle)
    path.unlink()
    return record


BACKENDS = ("processes", "ray")


@dataclass(frozen=True)
class RolloutWorkers:
    """Where a collection's rollouts run: ``count`` worker processes (one: in this process), or as Ray tasks
    (``backend="ray"``) on ``count`` CPUs of a local Ray cluster, or on the running cluster at ``address``."""

    count: int = 1
    backend: str = "processes"
    address: str | None = None
    batch: int = 128  # the batched engine: episodes stepped together in one vector env
    device: str = "cpu"  # the batched engine's torch device

    def __post_init__(self):
        check_choice("backend", self.backend, BACKENDS)
        check_int("batch", self.batch, 1)
        if self.address is not None and self.backend != "ray":
            raise ParameterError("address", "is for backend='ray' (the Ray cluster to run on)")


def _import_ray():
    try:
        import ray
    except ImportError:
        raise ParameterError("backend", "'ray' needs Ray: pip install -e '.[distributed]'") from None
    return ray


def _ray_results(jobs: list, workers: int, address: str | None) -> Iterator[EpisodeRecord]:
    """The rollouts as Ray tasks, yielded in job order, with at most ``2 * workers`` in flight (memory stays
    bounded). Starts a local Ray cluster of ``workers`` CPUs unless ``address`` names a running one; on a
    multi-node cluster, MCAP paths must lie on a filesystem every node shares."""
    ray = _import_ray()
    started_here = not ray.is_initialized()
    if started_here:
        ray.init(
            address=address,
            num_cpus=None if address else workers,
            include_dashboard=False,
            log_to_driver=False,
            configure_logging=False,
        )
    rollout_task = ray.remote(num_cpus=1)(_rollout_job)
    window = max(2, 2 * workers)
    pending: list = []
    try:
        queued = iter(jobs)
        for job in queued:
            pending.append(rollout_task.remote(job))
            if len(pending) >= window:
                yield ray.get(pending.pop(0))
        while pending:
            yield ray.get(pending.pop(0))
    finally:
        for ref in pending:
            ray.cancel(ref, force=True)
        if started_here:
            ray.shutdown()


def _batched_results(jobs: list, workers: RolloutWorkers) -> Iterator[EpisodeRecord]:
    """The rollouts on the batched engine, ``workers.batch`` seeds at a time, in job order."""
    from dpr.datasets.collect_batched import rollout_batch

    for start in range(0, len(jobs), workers.batch):
        specs, seeds, paths = zip(*jobs[start : start + workers.batch], strict=True)
        yield from rollout_batch(specs[0], list(seeds), workers.device, list(paths))


def _results(jobs: list, workers: RolloutWorkers) -> Iterator[EpisodeRecord]:
    if jobs and jobs[0][0].engine == BATCHED:
        yield from _batched_results(jobs, workers)
        return
    if workers.backend == "ray":
        yield from _ray_results(jobs, workers.count, workers.address)
        return
    if workers.count <= 1 or len(jobs) <= 1:
        for job in jobs:
            yield _rollout_job(job)
        return
    # spawn, not fork: pymunk spaces and pygame must not be shared with a forked parent
    context = mp.get_context("spawn")
    with tempfile.TemporaryDirectory(prefix="dpr-collect-") as handoff:
        pool = context.Pool(min(workers.count, len(jobs)), initializer=_ignore_sigint)
        try:
            # in job (seed) order, whatever order they finish in
            paths = pool.imap(functools.partial(_rollout_to_file, handoff=Path(handoff)), jobs)
            for _ in jobs:
                yield _take_record(wait_deferring_sigint(paths.next))
            pool.close()
        finally:
            pool.terminate()
            pool.join()


def collect(
    root: str | Path,
    spec: CollectSpec,
    episodes: int,
    seed: int = 0,
    workers: RolloutWorkers = RolloutWorkers(),
    progress: Callable[[EpisodeRecord, int], None] | None = None,
    compact: bool = False,
) -> CollectSummary:
    """Record ``episodes`` episodes of seeds ``seed .. seed + episodes - 1`` into the dataset at ``root``,
    skipping seeds it already holds, rolled out by ``workers``. ``progress(record, episode_index)`` is called
    after each saved episode. Ctrl-C stops after the episodes already saved (the summary says ``interrupted``).
    ``compact=True`` packs the dataset into LeRobot's ~100 MB files once every episode is recorded (not after
    Ctrl-C or an error; see :func:`dpr.datasets.lerobot.compact`). A spec of the batched engine rolls
    ``workers.batch`` episodes out at a time on ``workers.device`` in this process
    (:mod:`dpr.datasets.collect_batched`)."""
    check_int("episodes", episodes, 1)
    check_int("seed", seed, 0)
    _check_workers(spec, workers)
    root = Path(root)
    seeds = range(seed, seed + episodes)
    features, task = _probe(spec, workers.device)
    info_extra = _info_extra(spec, workers.device)
    if (root / INFO_PATH).is_file():  # a dataset of the wrong fps is named, not resumed with the right one
        info = load_info(root)
        check_dataset_time(root, info)
        LeRobotReader(root).check_data()  # stored data is checked before anything is added to it
        features = _resumed_features(root, info, spec, features, seeds)
    bytes_before = folder_bytes(root)
    writer = LeRobotWriter.open(
        root, fps=dataset_fps(spec.env_kwargs), features=features, robot_type=spec.robot_model, info_extra=info_extra
    )
    started = time.perf_counter()
    episodes_before = writer.num_episodes
    added: list[SavedEpisode] = []
    completed = False  # every episode recorded: only then is the dataset compacted

    def save(record: EpisodeRecord) -> int:
        mcap_file = f"{MCAP_FOLDER}/seed-{record.seed:06d}.mcap" if spec.mcap else None
        return save_record(writer, spec, record, task, mcap_file)

    try:
        interrupted = _record(_pending_jobs(root, spec, seeds), workers, save, added, progress)
        completed = not interrupted
    finally:
        # releases (and deletes) the dataset's writer lock; saved episodes are already durable
        writer.finalize(compact=compact and completed)
    return CollectSummary(
        root=str(root),
        env_id=spec.env_id,
        policy=spec.policy,
        episodes_before=episodes_before,
        episodes_added=len(added),
        episodes_total=episodes_before + len(added),
        frames_added=sum(r.frames for r in added),
        frames_total=writer.num_frames,
        seconds=time.perf_counter() - started,
        bytes_written=folder_bytes(root) - bytes_before,
        interrupted=interrupted,
        metrics=metric_summary(added),
    )


def _check_workers(spec: CollectSpec, workers: RolloutWorkers) -> None:
    if spec.engine == BATCHED and workers.backend == "ray":
        raise ParameterError("backend", "the batched engine steps its episodes together in this process, not on Ray")
    if workers.backend == "ray":
        _import_ray()


def _probe(spec: CollectSpec, device: str = "cpu") -> tuple[dict, str]:
    """The dataset's features and the task's description, from an env of ``spec``; a policy that cannot run on
    it (or, on the batched engine, a robot model, device or policy it has not) fails here, before anything is
    written."""
    if spec.engine == BATCHED:
        from dpr.datasets.collect_batched import check_batched_spec

        check_batched_spec(spec, device)
    probe = spec.make_env()
    try:
        for name in (spec.policy, spec.label_policy):
            if name is not None:
                make_policy(name, probe)
        return dataset_features(probe, spec.pixels, spec.image_size), probe.unwrapped.task_description
    finally:
        probe.close()


def _info_extra(spec: CollectSpec, device: str = "cpu") -> dict:
    """What info.json records of the spec, and what must match to resume: the env, its kwargs, the policy, and
    whether episodes carry MCAP logs; for the batched engine off the CPU, the kind of device (``dpr replay`` re-runs
    the episodes there: float sums on a GPU differ from the CPU's in their last bits)."""
    recorded = {F.ENV_ID: spec.env_id, F.POLICY: spec.policy, F.ENV_KWARGS: spec.make_kwargs(), "mcap": spec.mcap}
    if spec.label_policy is not None:  # (absent otherwise, so datasets recorded before it still resume)
        recorded[F.LABEL_POLICY] = spec.label_policy
    if spec.engine != ENGINES[0]:  # (likewise: a pymunk dataset and a batched one never resume each other)
        recorded["engine"] = spec.engine
    device_type = str(device).split(":")[0]
    if spec.engine == BATCHED and device_type != "cpu":  # (absent on the CPU, as before devices were recorded)
        recorded["device"] = device_type
    revision = swarm_class(spec.robot_model).revision
    if revision > 1:  # a dataset of earlier physics is not resumed with these (first revisions record none)
        recorded[F.ROBOT_MODEL_REVISION] = revision
    recorded.update(time_info(spec.env_kwargs))  # fps is the decision rate (dpr.datasets.timing)
    return {"dpr": recorded}


def _pending_jobs(root: Path, spec: CollectSpec, seeds: range) -> list[tuple[CollectSpec, int, Path | None]]:
    """The rollouts of the seeds the dataset does not hold yet (each with its MCAP path, when logged). The MCAP
    logs a killed run had in flight are removed."""
    done = _recorded_seeds(root)
    mcap_dir = root / MCAP_FOLDER
    if spec.mcap:
        mcap_dir.mkdir(exist_ok=True)
        for leftover in filter(is_temporary, mcap_dir.iterdir()):
            leftover.unlink()
    return [(spec, s, mcap_dir / f"seed-{s:06d}.mcap" if spec.mcap else None) for s in seeds if s not in done]


def _record(
    jobs: list,
    workers: RolloutWorkers,
    save: Callable[[EpisodeRecord], int],
    added: list[SavedEpisode],
    progress: Callable[[EpisodeRecord, int], None] | None,
) -> bool:
    """Roll ``jobs`` out and ``save`` each episode, in job order, noting it in ``added``; True when Ctrl-C
    stopped the run (after the episodes already saved).

    Episodes are saved by one background thread while the next one rolls out (or arrives from a worker):
    recording then costs little more than the rollouts. Ctrl-C only reaches the main thread, so an episode being
    saved is always saved whole; at most one is in flight."""
    saver = ThreadPoolExecutor(1, thread_name_prefix="dpr-save")
    in_flight: list[tuple[Future, EpisodeRecord]] = []

    def settle() -> None:
        while in_flight:
            future, record = in_flight[0]
            index = wait_deferring_sigint(future.result)
            with sigint_deferred():
                in_flight.pop(0)
                added.append(SavedEpisode(record.seed, record.frames, record.metrics))
            if progress is not None:
                progress(record, index)

    try:
        try:
            saver.submit(int).result()  # start the thread now, not inside a later submit()
            for record in _results(jobs, workers):
                settle()
                with sigint_deferred():
                    in_flight.append((saver.submit(save, record), record))
            settle()
        except KeyboardInterrupt:
            settle()  # the episode being saved is finished, not abandoned
            return True
    finally:
        saver.shutdown(wait=True)
    return False


def _resumed_features(root: Path, info: dict, spec: CollectSpec, features: dict, seeds: range) -> dict:
    """The features to open an existing dataset with: ``features``, unless the dataset was recorded before
    datasets carried ``observation.environment_state``. Episodes with it are not added to such a dataset (a
    DatasetError naming it, the feature and what to do); a run that adds none (every seed recorded: a rerun of
    the same command, ``--verify``) opens it with its own features. A dataset of another env is named as such
    first (the tasks' environment states differ, which would hide the cause)."""
    recorded_by = info.get("dpr")
    env_id = recorded_by.get(F.ENV_ID) if isinstance(recorded_by, dict) else None
    if env_id is not None and env_id != spec.env_id:
        raise DatasetError(
            f"{root / INFO_PATH}: does not match the requested dataset: env_id is {env_id!r} in the dataset, "
            f"{spec.env_id!r} requested"
        )
    recorded = info.get("features")
    if not isinstance(recorded, dict) or F.ENVIRONMENT_STATE in recorded or F.ENVIRONMENT_STATE not in features:
        return features  # (not dpr's older layout: LeRobotWriter.open names any other difference)
    missing = set(seeds) - _recorded_seeds(root)
    if missing:
        raise DatasetError(
            f"{root}: was recorded before dpr datasets carried the feature {F.ENVIRONMENT_STATE!r} (its "
            f"meta/info.json has no such feature), and the episodes this run would add carry it: one dataset cannot "
            f"hold both layouts. Record into a new folder (the same dpr collect command with another --out); this "
            f"one still reads, and dpr bc still learns from it"
        )
    return {name: feature for name, feature in features.items() if name != F.ENVIRONMENT_STATE}


__all__ = [
    "CollectSpec",
    "DatasetError",
    "EpisodeRecord",
    "RolloutWorkers",
    "collect",
    "dataset_features",
    "rollout",
    "save_record",
]
