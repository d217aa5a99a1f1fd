"""The settings of a cloning run, each a checked dataclass: :class:`CloneConfig` (``dpr bc``,
:func:`~dpr.imitation.bc.behaviour_clone`), :class:`PerRobotCloneConfig` (``dpr bc-decentralised``,
:func:`~dpr.imitation.per_robot.behaviour_clone_per_robot`) and :class:`DaggerConfig` (the DAgger rounds of
``dpr bc``, :func:`~dpr.imitation.dagger.dagger`). A bad value raises ValueError when the settings are made, before
any dataset is read or anything is written."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from dpr.checks import ParameterError, check_int, check_number
from dpr.envs import TASKS
from dpr.envs.local_obs import MAX_NEIGHBOURS
from dpr.policies.decentralised import DEFAULT_N_PHASES
from dpr.policies.registry import WAVE_MARKOV, check_policy_name
from dpr.policies.sb3 import BC_ALGOS, DEFAULT_ALGO, FINETUNE_ALGOS
from dpr.policies.wave import BIN_WIDTH

__all__ = ["WAVE_LENGTH", "CloneConfig", "DaggerConfig", "FitConfig", "PerRobotCloneConfig", "check_env_id"]

WAVE_LENGTH = "wave"  # distance_period: one wave length, n_phases x the wave's bin width


def check_env_id(env_id: str) -> None:
    """A ValueError unless ``env_id`` is a task's id (a current one, or an earlier one kept for its runs)."""
    if env_id not in TASKS:
        raise ValueError(f"env must be one of {tuple(TASKS)}, got {env_id!r}")


@dataclass(frozen=True)
class FitConfig:
    """What every cloning run sets: the model it clones into and how it is fitted."""

    algo: str = DEFAULT_ALGO
    epochs: int = 20
    batch_size: int = 256
    lr: float = 1e-3
    val_fraction: float = 0.2  # of the episodes, held out for validation
    patience: int = 3  # epochs without a better validation NLL before training stops
    seed: int = 0  # of the model, the split and the shuffling
    # kwargs the datasets must have been recorded with (e.g. {"n_robots": 9}): restated, never changed
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    hyperparams: dict[str, Any] = field(default_factory=dict)  # overrides of the algorithm's yaml entry

    def __post_init__(self):
        if self.algo not in BC_ALGOS:
            raise ValueError(f"algo must be one of {BC_ALGOS}, got {self.algo!r}")
        check_int("epochs", self.epochs, 1)
        check_int("batch_size", self.batch_size, 1)
        check_int("patience", self.patience, 1)
        check_int("seed", self.seed, 0)
        check_number("lr", self.lr, above=0)
        check_number("val_fraction", self.val_fraction, above=0, below=1)

    def fit_record(self) -> dict[str, Any]:
        """The fit's settings as a run's config.yaml lists them under ``bc``."""
        names = ("epochs", "batch_size", "lr", "val_fraction", "patience", "seed")
        return {name: getattr(self, name) for name in names}


@dataclass(frozen=True)
class CloneConfig(FitConfig):
    """A ``dpr bc`` run: behaviour cloning of whole-swarm frames into a model of the centralised env."""

    # weight of the frames whose action differs from the previous one (the policy's decisions) in the loss;
    # above 1 it needs datasets recorded with obs_last_action=True
    change_weight: float = 1.0

    def __post_init__(self):
        super().__post_init__()
        weight = self.change_weight
        if isinstance(weight, bool) or not isinstance(weight, (int, float)) or not weight >= 1.0:
            raise ValueError(f"change_weight must be a number >= 1, got {weight!r}")


@dataclass(frozen=True)
class PerRobotCloneConfig(FitConfig):
    """A ``dpr bc-decentralised`` run: cloning every robot's action into one per-robot model (its local observation:
    ``max_neighbours`` neighbour slots, a clock of one wave cycle, the distance to the goal as a phase)."""

    batch_size: int = 512  # robot-frames
    max_neighbours: int = MAX_NEIGHBOURS
    hold_steps: int | None = None  # steps of one wave phase; None: the robot model's wave hold
    n_phases: int = DEFAULT_N_PHASES  # the clock's period is hold_steps x n_phases
    # WAVE_LENGTH (one wave length), a length in world units, or None for the raw distance to the goal
    distance_period: float | str | None = WAVE_LENGTH

    def __post_init__(self):
        if self.algo not in FINETUNE_ALGOS:
            raise ParameterError(
                "algo", f"a per-robot model is an actor-critic: one of {FINETUNE_ALGOS}, got {self.algo!r}"
            )
        super().__post_init__()
        check_int("max_neighbours", self.max_neighbours, 1)
        if "n_robots" in self.env_kwargs:
            raise ParameterError("env_kwargs", "n_robots is each dataset's own; a per-robot model runs any N")
        if self.hold_steps is not None:
            check_int("hold_steps", self.hold_steps, 1)
        check_int("n_phases", self.n_phases, 2)
        if self.distance_period not in (WAVE_LENGTH, None):
            check_number("distance_period", self.distance_period, above=0)

    @property
    def distance_length(self) -> float | None:
        """``distance_period`` in world units (None: the raw distance)."""
        if self.distance_period == WAVE_LENGTH:
            return self.n_phases * BIN_WIDTH
        if self.distance_period is None:
            return None
        return check_number("distance_period", self.distance_period, above=0)


@dataclass(frozen=True)
class DaggerConfig:
    """The DAgger rounds after cloning: ``rounds`` of ``episodes_per_round`` episodes (seeds from ``first_seed``,
    round after round) driven by the latest clone and labelled by ``expert``, rolled out by ``workers``
    processes."""

    expert: str = WAVE_MARKOV
    rounds: int = 2
    episodes_per_round: int = 10
    first_seed: int = 50_000
    workers: int = 1

    def __post_init__(self):
        check_int("rounds", self.rounds, 0)
        check_int("episodes_per_round", self.episodes_per_round, 1)
        check_int("first_seed", self.first_seed, 0)
        check_policy_name(self.expert)

    def round_seed(self, round_index: int) -> int:
        """The first seed of DAgger round ``round_index`` (1, 2, ...)."""
        return self.first_seed + (round_index - 1) * self.episodes_per_round

    @property
    def seeds(self) -> range:
        """Every DAgger episode's seed."""
        return range(self.first_seed, self.first_seed + self.rounds * self.episodes_per_round)
