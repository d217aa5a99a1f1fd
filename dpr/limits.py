"""Upper bounds of every count, size and duration a user gives, and up-front memory estimates.

Every number a command or a settings file takes is checked against one of these bounds before any work starts,
so that a typo (``--episodes 1000000000000``) ends in a one-line error rather than in a machine out of memory.
The bounds are far beyond any run the project makes (the shipped presets, benchmarks and model card stay well
inside them); what depends on several inputs at once (envs x robots, episodes x steps) is estimated in bytes and
compared with the machine's memory instead (:func:`check_memory`). docs/cli.md lists them.
"""

from __future__ import annotations

import os
from typing import Any

from dpr.checks import ParameterError, check_int

# -- counts ------------------------------------------------------------------------------------------------------
MAX_EPISODES = 1_000_000  # episodes (demonstrations, evaluations, DAgger rounds' episodes) in one command
MAX_SEEDS = 1_000_000  # seeds named at once ('0-999999'); a list that fits in memory
MAX_EPISODE_SEED = 2**62  # an episode's seed (stored as int64 in datasets, with room for offsets)
MAX_MODEL_SEED = 2**32 - 1  # a model's or a training run's seed: numpy's global seed (SB3) takes no more
MAX_STEPS_PER_EPISODE = 1_000_000  # physics steps (or decisions) per episode; every task's own is 2500
MAX_TIMESTEPS = 10**10  # steps of a training budget (the paper's is 10^7)
MAX_EPOCHS = 1_000_000  # epochs of a fit (behaviour cloning, PPO's n_epochs)
MAX_N_ENVS = 65_536  # envs of one run: the batched engine steps thousands at once, benchmarks up to 16,384
MAX_N_ROBOTS = 10_000  # robots of a swarm (a paddle swarm of 1000 takes seconds to build)
MAX_BATCH_SIZE = 2**24  # samples per gradient step, and steps per env per rollout (n_steps)
MAX_BUFFER_SIZE = 10**9  # a replay buffer's transitions (DQN); its memory is estimated too
MAX_LAYER_SIZE = 65_536  # units of one layer of a network
MAX_LAYERS = 1_000  # layers of a network
MAX_ROUNDS = 10_000  # DAgger rounds, benchmark repeats, and other repetitions of a whole job
MAX_TEMPERATURE = 100.0  # a fine-tune's exploration temperature: at 100 a swarm actor's robots act almost at random
MAX_RAY_WORKERS = 4_096  # stages at once on a Ray cluster: the cluster's own CPUs are not known before it is joined

# -- files -------------------------------------------------------------------------------------------------------
KiB, MiB, GiB = 2**10, 2**20, 2**30
MAX_SETTINGS_BYTES = 1 * MiB  # a yaml settings file a user writes (--config, presets, hyperparameters, model cards)
MAX_RECORD_BYTES = 16 * MiB  # a yaml record dpr writes (a run's pipeline.yaml, choices.yaml, config.yaml)
MAX_METADATA_BYTES = 64 * MiB  # a JSON metadata file of a dataset or a run
MAX_MODEL_JSON_BYTES = 64 * MiB  # a model zip's JSON members (SB3's `data`, dpr's metadata)
MAX_MODEL_MEMBER_BYTES = 1 * GiB  # any other member of a model zip that is read (the weights, .pth)
MAX_YAML_NODES = 100_000  # nodes of a yaml document with aliases, once they are expanded ("billion laughs")
MAX_YAML_ALIASES = 100  # aliases (*name) in one yaml document; the shipped hyperparameter files use 5 each

# -- memory estimates (bytes; low estimates, so that nothing that fits is refused) -------------------------------
ENV_BYTES = 64 * KiB  # one pymunk env, beside its robots
ROBOT_BYTES = {"paddle": 160 * KiB, "disk": 4 * KiB}  # one robot of a pymunk env, by robot model (measured: 230, 7)
FRAME_VALUES_PER_ROBOT = 7  # float32 values a frame of a dataset holds per robot: its 6 observed values, its action
WORKER_BYTES = 100 * MiB  # one worker process (python, numpy, the env's modules)


def workers_limit(backend: str = "local") -> int:
    """The most worker processes at once: this machine's CPUs for local processes, :data:`MAX_RAY_WORKERS` on Ray."""
    return MAX_RAY_WORKERS if backend == "ray" else os.cpu_count() or 1


def check_workers(name: str, value: Any, backend: str = "local") -> int:
    """``value`` as a count of worker processes, at least 1 and at most :func:`workers_limit`."""
    limit = workers_limit(backend)
    try:
        return check_int(name, value, 1, limit)
    except ParameterError:
        if isinstance(value, int) and value > limit:
            where = "a Ray cluster takes at most" if backend == "ray" else "this machine has"
            raise ParameterError(name, f"must be <= {limit} ({where} {limit} CPUs), got {value}") from None
        raise


def physical_memory() -> int:
    """Bytes of memory this machine has."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # a platform that does not say: assume plenty
        return 2**50


def env_bytes(n_robots: int, robot_model: str | None = None) -> int:
    """A low estimate of the memory of one pymunk env of ``n_robots`` robots (paddle robots unless ``robot_model``
    says otherwise)."""
    return ENV_BYTES + n_robots * ROBOT_BYTES.get(robot_model or "paddle", ROBOT_BYTES["disk"])


def frames_bytes(frames: int, n_robots: int) -> int:
    """A low estimate of the memory of ``frames`` frames of an ``n_robots`` swarm held at once (float32)."""
    return frames * n_robots * FRAME_VALUES_PER_ROBOT * 4


def gib(size: int) -> str:
    """``size`` bytes in GiB, as the errors say it."""
    return f"{size / GiB:.1f} GiB"


def check_memory(name: str, what: str, needed: int, available: int | None = None) -> None:
    """A :class:`ParameterError` about ``name`` when ``what`` (e.g. "65536 envs of 9 paddle robots") needs more than
    the ``available`` bytes (default: this machine's memory), saying both."""
    available = physical_memory() if available is None else available
    if needed > available:
        raise ParameterError(
            name, f"{what} need about {gib(needed)} of memory; this machine has {gib(available)}: ask for less"
        )
