"""The pipeline's settings: :class:`PipelineConfig`, checked before any work; the shipped presets
(``dpr/pipeline/presets/<name>.yaml``) and settings files (:func:`load_config`); and the names and constants every stage
of :mod:`dpr.pipeline.campaign` shares."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import yaml

from dpr.bounded_io import YamlRefused, load_yaml
from dpr.checks import ParameterError, check_choice, check_int, check_number, check_seeds
from dpr.envs import ENV_IDS, MAX_EPISODE_STEPS, TASKS
from dpr.envs.manipulation import APPROACH_REWARD_RANGE
from dpr.envs.particle_env import HELD_STEPS_CAP, MAX_DISTANCE
from dpr.limits import (
    MAX_EPISODE_SEED,
    MAX_EPISODES,
    MAX_EPOCHS,
    MAX_MODEL_SEED,
    MAX_N_ENVS,
    MAX_N_ROBOTS,
    MAX_SEEDS,
    MAX_STEPS_PER_EPISODE,
    MAX_TIMESTEPS,
    check_memory,
    env_bytes,
    frames_bytes,
)
from dpr.policies.hyperparams import DEFAULT_PRESET as DEFAULT_ENTRY
from dpr.policies.hyperparams import FINETUNE_PRESET, load_hyperparams
from dpr.policies.model_file import ALGOS, DQN, SWARM_POLICY
from dpr.policies.registry import WAVE, WAVE_MARKOV, wave_name
from dpr.policies.sb3 import DEFAULT_ALGO, FINETUNE_ALGOS
from dpr.policies.wave import BIN_WIDTH, MODEL_DEFAULTS
from dpr.rl.recipe import FINETUNE_AT_REPEAT

# The bounds of the counts among the settings: name -> (minimum, maximum) (dpr.limits).
COUNT_BOUNDS = {
    "n_robots": (1, MAX_N_ROBOTS),
    "episodes": (1, MAX_EPISODES),
    "bc_epochs": (1, MAX_EPOCHS),
    "finetune_steps": (1, MAX_TIMESTEPS),
    "n_envs": (1, MAX_N_ENVS),
    "steps": (1, MAX_STEPS_PER_EPISODE),
    "critic_warmup": (0, MAX_TIMESTEPS),
    "demo_seed": (0, MAX_EPISODE_SEED - MAX_EPISODES),
}
MAX_TEACHER_CHOICES = 1_000  # teacher holds, and teacher bin widths, to choose among
ENGINES = ("pymunk", "batched")
BATCHED_ROBOT_MODEL = "disk"  # the batched engine's only robot model
SHIPPED_ROBOT_MODEL = "paddle"  # the model card's rows, as the paper's wave: the pymunk paddle model
PIPELINE_ENV_KWARGS = {"obs_last_action": True}  # the Markov wave needs it; every learner gets it too
EXPERT = WAVE_MARKOV  # the teacher: the Markov wave, at the hold chosen per task (teacher_holds)
BASELINE = WAVE  # what every result is a percentage of: the paper's wave, its hold 10
TEACHER = "teacher"  # the chosen teacher's row in the report, when there was a choice
WAVE_HOLD = MODEL_DEFAULTS["paddle"]["hold_steps"]
PER_PHASE = 0  # action_repeat 0: the learners decide once per phase of the task's teacher (K = its hold)
SCRATCH_ALGOS = ALGOS
BC_ALGO = DEFAULT_ALGO  # what the demonstrations are cloned into: an actor-critic every FINETUNE_ALGOS can load
# Every learner's actor (clone, fine-tuning, from scratch): the yaml's MLP from the whole state to every robot's
# logit, or one network shared by the robots (dpr.policies.swarm_policy); the critic is the yaml's MLP either way.
ACTORS = {"mlp": {}, "swarm": {"policy": SWARM_POLICY}}


@dataclass(frozen=True)
class Teacher:
    """A task's teacher: the Markov wave holding each phase ``hold`` physics steps, its robots binned
    ``bin_width`` units wide along the goal direction."""

    hold: int = WAVE_HOLD
    bin_width: float = BIN_WIDTH

    @property
    def policy(self) -> str:
        """Its policy name (``dpr evaluate --policy``): the plain name at the wave's own hold and bins."""
        if (self.hold, self.bin_width) == (WAVE_HOLD, BIN_WIDTH):
            return EXPERT
        return wave_name(EXPERT, self.hold, None if self.bin_width == BIN_WIDTH else self.bin_width)

    @property
    def stem(self) -> str:
        """Its name in file names and in ``choices.yaml``: ``hold8``, or ``hold6-bin50`` with other bins."""
        return f"hold{self.hold}" + ("" if self.bin_width == BIN_WIDTH else f"-bin{self.bin_width:g}")


@dataclass
class PipelineConfig:
    """The settings of one pipeline run: its tasks, budgets, seed sets and recipe (``dpr pipeline --config``). The
    defaults are the ``small`` preset's (``make run``); :data:`PRESETS` names the shipped ones, read from
    ``dpr/pipeline/presets/<name>.yaml``."""

    tasks: list[str] = field(default_factory=lambda: ["navigation"])
    n_robots: int = 9
    episodes: int = 40  # demonstrations per task (fewer clone the wave poorly)
    demo_seed: int = 1000
    bc_epochs: int = 15
    critic_warmup: int = 10_000
    finetune_steps: int = 30_000
    approach_reward: float = 1.0  # Manipulation's shaping weight for RL, fine-tuning and from scratch (0: none)
    finetune_algos: list[str] = field(default_factory=lambda: [DEFAULT_ALGO])
    scratch_algos: list[str] = field(default_factory=lambda: [DEFAULT_ALGO])
    test_seeds: list[int] = field(default_factory=lambda: list(range(300, 305)))  # within the full preset's
    validation_seeds: list[int] = field(default_factory=list)  # needed to choose among several training seeds
    train_seeds: list[int] = field(default_factory=lambda: [0])  # seeds of BC and RL: one run per method each
    n_envs: int = 2  # envs each RL run trains on (one process: the worker count never changes a result)
    steps: int = MAX_EPISODE_STEPS  # physics steps per episode, in demonstrations, training and evaluation
    # the Markov wave's holds and bin widths among which each task's teacher is chosen (every pair), by its median
    # on the teacher_seeds
    teacher_holds: list[int] = field(default_factory=lambda: [WAVE_HOLD])
    teacher_bin_widths: list[float] = field(default_factory=lambda: [BIN_WIDTH])
    # the seeds that choose the teacher (none: the validation seeds); like them never test or demonstration seeds
    teacher_seeds: list[int] = field(default_factory=list)
    # the learners decide every this many physics steps (a divisor of every teacher hold), or PER_PHASE
    action_repeat: int = 10
    # over the yaml's `finetune` entry (FINETUNE_AT_REPEAT)
    finetune_hyperparams: dict[str, Any] = field(default_factory=lambda: dict(FINETUNE_AT_REPEAT))
    # over the yaml's entry of the env id, for the runs from scratch
    scratch_hyperparams: dict[str, Any] = field(default_factory=dict)
    actor: str = "swarm"  # one of ACTORS
    # task -> an earlier registered id of it that the task runs on instead of its current one (ENV_IDS)
    env_ids: dict[str, str] = field(default_factory=dict)
    # task -> kwargs of the envs its RL runs (fine-tuning and from scratch) gather experience on, over the task's
    # own; its models stay models of the task and are evaluated there (TrainConfig.training_env_kwargs). A task
    # this run does not run is passed over, so that a preset may name any task.
    training_env_kwargs: dict[str, dict] = field(default_factory=dict)
    # tasks whose fine-tuned models are the mean of the policy's weights a quarter, half and three quarters of the way
    # and at the end of fine-tuning, rather than the last weights; a task this run does not run is passed over
    average_checkpoints: list[str] = field(default_factory=list)
    # "batched": the disk robot model throughout, its demonstrations, evaluations and RL from scratch on the batched
    # engine (dpr.sim.batched) on ``device``; cloning and fine-tuning run on pymunk's disk model
    engine: str = "pymunk"
    device: str = "cpu"

    def __post_init__(self):
        check_types(self)
        self._check_choices()
        unknown = [task for task in self.tasks if task not in ENV_IDS]
        if not self.tasks or unknown:
            raise ParameterError(
                "tasks",
                f"expected some of {list(ENV_IDS)} (a task of another package: --env-package), got {self.tasks!r}",
            )
        if any(TASKS.get(i) != t for t, i in self.env_ids.items()):
            raise ParameterError(
                "env_ids", f"expected registered ids of the tasks ({', '.join(TASKS)}), got {self.env_ids!r}"
            )
        idle = [env_id for task, env_id in self.env_ids.items() if task not in self.tasks]
        if idle:
            raise ParameterError("env_ids", f"{idle} belong to tasks this run does not run ({self.tasks})")
        self._check_training_env_kwargs()
        if any(task not in ENV_IDS for task in self.average_checkpoints):
            raise ParameterError(
                "average_checkpoints", f"expected some of {list(ENV_IDS)}, got {self.average_checkpoints!r}"
            )
        if self.actor != "mlp" and DQN in self.scratch_algos:
            raise ParameterError("actor", f"{self.actor!r} is an actor-critic's actor; DQN from scratch has none")
        for name, allowed in (("finetune_algos", FINETUNE_ALGOS), ("scratch_algos", SCRATCH_ALGOS)):
            bad = [algo for algo in getattr(self, name) if algo not in allowed]
            if bad:
                raise ParameterError(name, f"expected some of {list(allowed)}, got {bad}")
        for name, (minimum, maximum) in COUNT_BOUNDS.items():
            check_int(name, getattr(self, name), minimum, maximum)
        for name, what in (("teacher_holds", "holds"), ("teacher_bin_widths", "widths > 0")):
            values = getattr(self, name)  # every pair is a candidate teacher: a repeat would score one twice
            if not values or len(set(values)) < len(values):
                raise ParameterError(name, f"expected a list of different {what}, got {values!r}")
            if len(values) > MAX_TEACHER_CHOICES:
                raise ParameterError(name, f"must list at most {MAX_TEACHER_CHOICES}, got {len(values)}")
        holds = [check_int("teacher_holds", hold, 1, HELD_STEPS_CAP) for hold in self.teacher_holds]
        self.teacher_bin_widths = [
            check_number("teacher_bin_widths", width, maximum=MAX_DISTANCE, above=0)
            for width in self.teacher_bin_widths
        ]
        if len(self.teachers()) > 1 and not (self.validation_seeds or self.teacher_seeds):
            raise ParameterError(
                "validation_seeds", "several teacher_holds or teacher_bin_widths need validation seeds to choose one"
            )
        repeat = check_int("action_repeat", self.action_repeat, PER_PHASE, MAX_STEPS_PER_EPISODE)
        if repeat != PER_PHASE and any(hold % repeat for hold in holds):
            raise ParameterError(
                "action_repeat",
                f"must divide every teacher hold {holds}, so that the demonstrations are the teacher's gait "
                f"(or be {PER_PHASE}: once per phase); got {repeat}",
            )
        check_number("approach_reward", self.approach_reward, *APPROACH_REWARD_RANGE)
        if self.episodes < 2:
            raise ParameterError(
                "episodes", f"must be >= 2 (behaviour cloning holds one out for validation), got {self.episodes}"
            )
        self._check_seed_sets()
        self._check_memory()
        for task in self.tasks:  # a misspelt name or value is refused now, not hours later at training
            for algo in self.finetune_algos:
                try:
                    load_hyperparams(
                        algo, self.env_id(task), FINETUNE_PRESET, self.actor_hyperparams() | self.finetune_hyperparams
                    )
                except ValueError as error:
                    raise ParameterError("finetune_hyperparams", str(error)) from None
            for algo in self.scratch_algos:
                try:
                    load_hyperparams(algo, self.env_id(task), DEFAULT_ENTRY, self.scratch_hyperparams_at(WAVE_HOLD))
                except ValueError as error:
                    raise ParameterError("scratch_hyperparams", str(error)) from None

    def _check_choices(self) -> None:
        """The actor and the engine are among the known ones."""
        if self.actor not in ACTORS:
            raise ParameterError("actor", f"expected one of {list(ACTORS)}, got {self.actor!r}")
        check_choice("engine", self.engine, ENGINES)

    def _check_training_env_kwargs(self) -> None:
        """Each entry names a task and holds kwargs that its env takes without a change of spaces."""
        from dpr.rl.train import check_training_env_kwargs

        for task, kwargs in self.training_env_kwargs.items():
            if task not in ENV_IDS or not isinstance(kwargs, dict):
                raise ParameterError(
                    "training_env_kwargs",
                    f"expected task -> mapping of env kwargs, tasks among {list(ENV_IDS)}; got {task!r}: {kwargs!r}",
                )
            if task in self.tasks:
                try:
                    check_training_env_kwargs(self.env_id(task), {}, kwargs)
                except (TypeError, ValueError) as error:  # the spaces, or a kwarg the env refuses (named)
                    ours = isinstance(error, ParameterError) and error.parameter == "training_env_kwargs"
                    raise ParameterError("training_env_kwargs", f"{task}: {error.problem if ours else error}") from None

    def _check_memory(self, workers: int = 1) -> None:
        """Refuse settings whose envs (``n_envs`` of ``n_robots`` per RL run, ``workers`` runs at once) or whose
        demonstrations (``episodes`` of ``steps``, which behaviour cloning holds in memory) cannot fit this machine's
        memory, saying the estimate."""
        envs = workers * self.n_envs
        check_memory("n_envs", f"{envs} envs of {self.n_robots} robots", envs * env_bytes(self.n_robots))
        repeat = self.action_repeat or max(self.teacher_holds)
        frames = self.episodes * max(1, self.steps // repeat)
        what = f"{self.episodes} demonstrations of {self.steps} steps of {self.n_robots} robots ({frames} frames)"
        check_memory("episodes", what, frames_bytes(frames, self.n_robots))

    def _check_seed_sets(self) -> None:
        """Training, demonstration, choosing (validation, teacher) and scoring (test) seeds never meet."""
        for name in ("test_seeds", "validation_seeds", "teacher_seeds", "train_seeds"):
            maximum = MAX_MODEL_SEED if name == "train_seeds" else MAX_EPISODE_SEED
            empty = name in ("validation_seeds", "teacher_seeds")
            check_seeds(name, getattr(self, name), allow_empty=empty, maximum=maximum, max_count=MAX_SEEDS)
        if len(self.train_seeds) > 1 and not self.validation_seeds:
            raise ParameterError(
                "validation_seeds", "several train_seeds need validation seeds to choose each method's median run"
            )
        demo_seeds = set(range(self.demo_seed, self.demo_seed + self.episodes))
        for name in ("test_seeds", "validation_seeds", "teacher_seeds"):
            seen = sorted(demo_seeds & set(getattr(self, name)))
            if seen:
                raise ParameterError(name, f"{seen} are demonstration seeds too; use seeds the models never saw")
        for name in ("validation_seeds", "teacher_seeds"):
            shared = sorted(set(getattr(self, name)) & set(self.test_seeds))
            if shared:
                raise ParameterError(
                    name, f"{shared} are test seeds too; the seeds that choose must not be the ones that score"
                )
        for name in ("test_seeds", "validation_seeds", "teacher_seeds"):  # SB3 resets the training envs with them
            seen = sorted(set(self.train_seeds) & set(getattr(self, name)))
            if seen:
                raise ParameterError(
                    "train_seeds", f"{seen} are {name.replace('_', ' ')} too; training must not start from them"
                )

    def engine_settings(self) -> dict[str, Any]:
        """What every stage that runs the batched engine adds to its settings (and so to its key); nothing on
        pymunk, so that the stages of a pymunk run keep their keys."""
        if self.engine == ENGINES[0]:
            return {}
        return {"engine": self.engine, "device": self.device, "robot_model": BATCHED_ROBOT_MODEL}

    def env_id(self, task: str) -> str:
        """The registered id ``task`` runs on: its current one, unless ``env_ids`` names another."""
        return self.env_ids.get(task, ENV_IDS[task])

    @property
    def rl_steps(self) -> int:
        """Physics steps of a fine-tuned model in all: demonstrations, critic warm-up and fine-tuning (the
        budget RL from scratch gets). Budgets count physics steps, so that learners deciding every step or every
        ``action_repeat`` steps get the same simulated time."""
        return self.episodes * self.steps + self.critic_warmup + self.finetune_steps

    def teachers(self) -> list[Teacher]:
        """The candidate teachers: every teacher hold with every teacher bin width."""
        return [Teacher(hold, width) for hold in self.teacher_holds for width in self.teacher_bin_widths]

    def teacher_choice_seeds(self) -> list[int]:
        """The seeds the candidate teachers are scored on: ``teacher_seeds``, else the validation seeds."""
        return self.teacher_seeds or self.validation_seeds

    def scratch_hyperparams_at(self, hold: int) -> dict[str, Any]:
        """The hyperparameter overrides of the runs from scratch: the actor's, then ``scratch_hyperparams``."""
        return {**self.actor_hyperparams(), **self.scratch_hyperparams}

    def actor_hyperparams(self) -> dict[str, Any]:
        """The hyperparameter overrides that give every learner its actor (:data:`ACTORS`)."""
        return dict(ACTORS[self.actor])

    def methods(self) -> list[str]:
        """Names of the policies evaluated on each task: the wave first, the chosen teacher unless it is the wave's
        Markov twin (one hold, the wave's, and the wave's bins)."""
        return [BASELINE, *([TEACHER] if self.teachers() != [Teacher()] else []), *self.learned_methods()]

    def learned_methods(self) -> list[str]:
        """Names of the methods trained once per training seed."""
        return [*self.cloned_methods(), *self.scratch_algos]

    def cloned_methods(self) -> list[str]:
        """The learned methods that start from the demonstrations: the clone and its fine-tuned versions."""
        return ["bc", *(f"bc-{algo}" for algo in self.finetune_algos)]


def learner_env_kwargs(action_repeat: int, hold: int) -> dict[str, Any]:
    """The env kwargs of the demonstrations and of every learner of a task whose teacher holds ``hold`` steps: the
    pipeline's, and the decision interval (``action_repeat``, or ``hold`` when it is PER_PHASE)."""
    repeat = hold if action_repeat == PER_PHASE else action_repeat
    return {**PIPELINE_ENV_KWARGS, "action_repeat": repeat} if repeat > 1 else dict(PIPELINE_ENV_KWARGS)


PRESET_FOLDER = Path(__file__).parent / "presets"
PRESETS = tuple(sorted(path.stem for path in PRESET_FOLDER.glob("*.yaml")))  # tiny, small, full
DEFAULT_PRESET = "small"


def preset_path(name: str) -> Path:
    """The shipped yaml file of the preset ``name``."""
    check_choice("preset", name, PRESETS)
    return PRESET_FOLDER / f"{name}.yaml"


def read_settings(path: str | Path) -> dict[str, Any]:
    """The settings in the yaml file ``path``: a mapping of PipelineConfig fields (any subset; the rest keep their
    defaults), or a run folder's ``pipeline.yaml`` (its ``config``). An unknown key or a wrong type is a
    ParameterError naming the key and the file."""
    path = Path(path)
    try:
        data = load_yaml(path, "config")
    except YamlRefused:
        raise
    except (OSError, yaml.YAMLError) as error:
        raise ParameterError("config", f"cannot read {path} as yaml: {error}") from None
    if isinstance(data, dict) and isinstance(data.get("config"), dict):  # a run folder's pipeline.yaml
        data = data["config"]
    if not isinstance(data, dict):
        raise ParameterError("config", f"{path}: expected a mapping of settings, got {type(data).__name__}")
    known = {f.name for f in fields(PipelineConfig)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ParameterError("config", f"{path}: unknown key {unknown[0]!r}; the settings are {sorted(known)}")
    for name, value in data.items():
        problem = type_problem(name, value)
        if problem:
            raise ParameterError("config", f"{path}: {name}: {problem}")
    return data


def load_config(path: str | Path | None = None, preset: str | None = None, **overrides: Any) -> PipelineConfig:
    """The settings of the file ``path``, or of the shipped ``preset`` (default :data:`DEFAULT_PRESET`), with
    ``overrides`` (PipelineConfig fields) over them, checked."""
    if path is not None and preset is not None:
        raise ParameterError("config", "give a config file or a preset, not both")
    settings = read_settings(path if path is not None else preset_path(preset or DEFAULT_PRESET))
    return PipelineConfig(**{**settings, **overrides})


def preset_config(name: str, **overrides: Any) -> PipelineConfig:
    """The preset ``name`` with ``overrides`` (PipelineConfig fields) applied and checked."""
    return load_config(preset=name, **overrides)


_TYPES = {
    "int": (lambda v: isinstance(v, int) and not isinstance(v, bool), "an integer"),
    "float": (lambda v: isinstance(v, (int, float)) and not isinstance(v, bool), "a number"),
    "str": (lambda v: isinstance(v, str), "a string"),
}


def type_problem(name: str, value: Any) -> str | None:
    """What is wrong with ``value``'s type for the setting ``name`` (None when nothing is)."""
    kind = {f.name: f.type for f in fields(PipelineConfig)}[name]
    if kind.startswith("list["):
        test, what = _TYPES[kind[5:-1]]
        if not isinstance(value, list) or not all(test(v) for v in value):
            return f"expected a list of {what.split(' ', 1)[1]}s, got {value!r}"
    elif kind.startswith("dict["):
        if not isinstance(value, dict) or not all(isinstance(k, str) for k in value):
            return f"expected a mapping, got {value!r}"
        if kind == "dict[str, str]" and not all(isinstance(v, str) for v in value.values()):  # env ids
            return f"expected a mapping to strings, got {value!r}"
    else:
        test, what = _TYPES[kind]
        if not test(value):
            return f"expected {what}, got {value!r}"
    return None


def check_types(config: PipelineConfig) -> None:
    """A ParameterError naming the first setting of ``config`` whose value has the wrong type."""
    for f in fields(config):
        problem = type_problem(f.name, getattr(config, f.name))
        if problem:
            raise ParameterError(f.name, problem)
