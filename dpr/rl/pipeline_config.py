"""The pipeline's settings: :class:`PipelineConfig` (the ``dpr pipeline`` flags, checked before any work), the
named :data:`PRESETS`, and the names and constants every stage of :mod:`dpr.rl.pipeline` shares."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from dpr.checks import ParameterError, check_int, check_number, check_seeds
from dpr.envs import ENV_IDS, MAX_EPISODE_STEPS, TASKS
from dpr.envs.particle_env import HELD_STEPS_CAP
from dpr.policies.hyperparams import FINETUNE_PRESET, load_hyperparams
from dpr.policies.registry import WAVE, WAVE_MARKOV, wave_name
from dpr.policies.sb3 import ALGOS, DEFAULT_ALGO, DQN, FINETUNE_ALGOS, SWARM_POLICY
from dpr.policies.wave import BIN_WIDTH, MODEL_DEFAULTS

PIPELINE_ENV_KWARGS = {"obs_last_action": True}
# fine-tuning at action_repeat=10, chosen on validation seeds (docs/learning.md): shorter rollouts, more epochs
FINETUNE_AT_REPEAT = {"n_steps": 512, "batch_size": 128, "n_epochs": 10}
# The yaml's discount is per env step; fine-tuning discounts this much per *physics* step, gamma = 0.99**K per
# decision of K steps (unless finetune_hyperparams sets gamma): with 0.99 per decision at K=10 the critic learnt
# nothing (explained variance about 0, docs/learning.md)
PHYSICS_DISCOUNT = 0.99
FULL_FINETUNE_LEARNING_RATE = 3e-4  # the full preset's; the yaml's 3e-5 moved the clone too little per update
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
    """Budgets of one pipeline run (the ``dpr pipeline`` flags); the defaults are ``make run``'s but for its actor
    (:data:`PRESETS`)."""

    tasks: list[str] = field(default_factory=lambda: ["navigation"])
    n_robots: int = 9
    episodes: int = 40  # demonstrations per task (fewer clone the wave poorly: RESULTS.md)
    demo_seed: int = 1000
    bc_epochs: int = 15
    critic_warmup: int = 10_000
    finetune_steps: int = 30_000
    anchor: bool = False  # anchor fine-tuning to the task's demonstrations (dpr finetune --anchor)
    approach_reward: float = 1.0  # Manipulation's shaping weight for RL, fine-tuning and from scratch (0: none)
    finetune_algos: list[str] = field(default_factory=lambda: [DEFAULT_ALGO])
    scratch_algos: list[str] = field(default_factory=lambda: [DEFAULT_ALGO])
    test_seeds: list[int] = field(default_factory=lambda: list(range(300, 305)))  # within the full preset's
    validation_seeds: list[int] = field(default_factory=list)  # needed to choose among several training seeds
    train_seeds: list[int] = field(default_factory=lambda: [0])  # seeds of BC and RL: one run per method each
    workers: int = 2
    steps: int = MAX_EPISODE_STEPS  # physics steps per episode, in demonstrations, training and evaluation
    # the Markov wave's holds and bin widths among which each task's teacher is chosen (every pair), by its median
    # on the teacher_seeds
    teacher_holds: list[int] = field(default_factory=lambda: [WAVE_HOLD])
    teacher_bin_widths: list[float] = field(default_factory=lambda: [BIN_WIDTH])
    # the seeds that choose the teacher (none: the validation seeds); like them never test or demonstration seeds.
    # The wave is cheap to score, and its medians on 20 seeds spread too widely to rank five holds.
    teacher_seeds: list[int] = field(default_factory=list)
    # the learners decide every this many physics steps (a divisor of every teacher hold), or PER_PHASE
    action_repeat: int = 10
    # over the yaml's `finetune` entry (FINETUNE_AT_REPEAT)
    finetune_hyperparams: dict[str, Any] = field(default_factory=lambda: dict(FINETUNE_AT_REPEAT))
    actor: str = "mlp"  # one of ACTORS; mlp, what a pipeline.yaml written before the setting existed ran
    # the runs from scratch discount PHYSICS_DISCOUNT per physics step as the fine-tuning does, not the yaml's gamma
    # per decision (off: what every record before the setting existed ran)
    scratch_physics_discount: bool = False
    # task -> an earlier registered id of it that the task runs on instead of its current one (ENV_IDS), as the
    # records made before it do: {"gate": "dpr/Gate-v0"}
    env_ids: dict[str, str] = field(default_factory=dict)

    def __post_init__(self):
        unknown = [task for task in self.tasks if task not in ENV_IDS]
        if not self.tasks or unknown:
            raise ValueError(f"tasks must be among {tuple(ENV_IDS)}, got {self.tasks!r}")
        if not isinstance(self.env_ids, dict) or any(TASKS.get(i) != t for t, i in self.env_ids.items()):
            raise ParameterError(
                "env_ids", f"expected registered ids of the tasks ({', '.join(TASKS)}), got {self.env_ids!r}"
            )
        idle = [env_id for task, env_id in self.env_ids.items() if task not in self.tasks]
        if idle:
            raise ParameterError("env_ids", f"{idle} belong to tasks this run does not run ({self.tasks})")
        if self.actor not in ACTORS:
            raise ParameterError("actor", f"expected one of {list(ACTORS)}, got {self.actor!r}")
        if self.actor != "mlp" and DQN in self.scratch_algos:
            raise ParameterError("actor", f"{self.actor!r} is an actor-critic's actor; DQN from scratch has none")
        for name, allowed in (("finetune_algos", FINETUNE_ALGOS), ("scratch_algos", SCRATCH_ALGOS)):
            bad = [algo for algo in getattr(self, name) if algo not in allowed]
            if bad:
                raise ValueError(f"{name} must be among {allowed}, got {bad}")
        for name in ("n_robots", "episodes", "bc_epochs", "finetune_steps", "workers", "steps"):
            check_int(name, getattr(self, name), 1)
        for name in ("critic_warmup", "demo_seed"):
            check_int(name, getattr(self, name), 0)
        for name, what in (("teacher_holds", "holds"), ("teacher_bin_widths", "widths > 0")):
            values = getattr(self, name)  # every pair is a candidate teacher: a repeat would score one twice
            if not isinstance(values, list) or not values or len(set(values)) < len(values):
                raise ParameterError(name, f"expected a list of different {what}, got {values!r}")
        holds = [check_int("teacher_holds", hold, 1, HELD_STEPS_CAP) for hold in self.teacher_holds]
        self.teacher_bin_widths = [
            check_number("teacher_bin_widths", width, above=0) for width in self.teacher_bin_widths
        ]
        if len(self.teachers()) > 1 and not (self.validation_seeds or self.teacher_seeds):
            raise ParameterError(
                "validation_seeds", "several teacher_holds or teacher_bin_widths need validation seeds to choose one"
            )
        repeat = check_int("action_repeat", self.action_repeat, PER_PHASE)
        if repeat != PER_PHASE and any(hold % repeat for hold in holds):
            raise ParameterError(
                "action_repeat",
                f"must divide every teacher hold {holds}, so that the demonstrations are the teacher's gait "
                f"(or be {PER_PHASE}: once per phase); got {repeat}",
            )
        if not isinstance(self.scratch_physics_discount, bool):
            raise ParameterError(
                "scratch_physics_discount", f"expected true or false, got {self.scratch_physics_discount!r}"
            )
        if not isinstance(self.finetune_hyperparams, dict):
            raise ParameterError("finetune_hyperparams", f"expected a mapping, got {self.finetune_hyperparams!r}")
        if (
            isinstance(self.approach_reward, bool)
            or not isinstance(self.approach_reward, (int, float))
            or not self.approach_reward >= 0
        ):
            raise ValueError(f"approach_reward must be a number >= 0, got {self.approach_reward!r}")
        if self.episodes < 2:
            raise ParameterError(
                "episodes", f"must be >= 2 (behaviour cloning holds one out for validation), got {self.episodes}"
            )
        for name in ("test_seeds", "validation_seeds", "teacher_seeds", "train_seeds"):
            check_seeds(name, getattr(self, name), allow_empty=name in ("validation_seeds", "teacher_seeds"))
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
        for algo in self.finetune_algos:  # a misspelt name or value is refused now, not hours later at fine-tuning
            for task in self.tasks:
                try:
                    load_hyperparams(
                        algo, self.env_id(task), FINETUNE_PRESET, self.actor_hyperparams() | self.finetune_hyperparams
                    )
                except ValueError as error:
                    raise ParameterError("finetune_hyperparams", str(error)) from None

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

    def decision_steps(self, hold: int) -> int:
        """Physics steps per decision of the learners of a task whose teacher holds ``hold`` steps."""
        return hold if self.action_repeat == PER_PHASE else self.action_repeat

    def learner_env_kwargs(self, hold: int) -> dict[str, Any]:
        """The env kwargs of the demonstrations and of every learner of a task whose teacher holds ``hold``
        steps: the pipeline's, and the decision interval."""
        repeat = self.decision_steps(hold)
        return {**PIPELINE_ENV_KWARGS, "action_repeat": repeat} if repeat > 1 else dict(PIPELINE_ENV_KWARGS)

    def rl_env_kwargs(self, task: str, hold: int) -> dict[str, Any]:
        """The env kwargs RL trains ``task`` with: the learners', and Manipulation's shaping."""
        if task == "manipulation" and self.approach_reward:
            return {**self.learner_env_kwargs(hold), "approach_reward": float(self.approach_reward)}
        return self.learner_env_kwargs(hold)

    def physics_discount_at(self, hold: int) -> dict[str, float]:
        """The discount per decision that is PHYSICS_DISCOUNT per physics step, as a hyperparameter."""
        return {"gamma": round(PHYSICS_DISCOUNT ** self.decision_steps(hold), 3)}

    def finetune_hyperparams_at(self, hold: int) -> dict[str, Any]:
        """The fine-tuning hyperparameters: ``finetune_hyperparams``, discounting PHYSICS_DISCOUNT per physics
        step unless they set gamma."""
        return {**self.physics_discount_at(hold), **self.finetune_hyperparams}

    def scratch_hyperparams_at(self, hold: int) -> dict[str, Any]:
        """The hyperparameter overrides of the runs from scratch: the actor's, and PHYSICS_DISCOUNT per physics
        step when ``scratch_physics_discount`` (else the yaml's gamma, per decision)."""
        discount = self.physics_discount_at(hold) if self.scratch_physics_discount else {}
        return {**self.actor_hyperparams(), **discount}

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


# the ids every task ran on before ``env_ids`` existed: a pipeline.yaml without it ran Gate on v0
IDS_BEFORE_ENV_IDS = {"gate": "dpr/Gate-v0"}


def saved_settings(saved: dict[str, Any]) -> dict[str, Any]:
    """The settings a run folder's ``pipeline.yaml`` records under ``config``, as ``asdict(PipelineConfig)``: a
    setting added since that run started had its default value there, but for ``env_ids`` (the ids of then)."""
    settings = {**asdict(PipelineConfig()), **saved}
    if "env_ids" not in saved:
        tasks = settings["tasks"]
        settings["env_ids"] = {task: env_id for task, env_id in IDS_BEFORE_ENV_IDS.items() if task in tasks}
    return settings


DEFAULT_PRESET = "small"
PRESETS: dict[str, PipelineConfig] = {
    # the full preset's actor: with it make run's clone and fine-tuning pass the wave on its five seeds, where
    # the MLP's sat at 66% and 36% (docs/learning.md, "make run")
    "small": PipelineConfig(actor="swarm"),
    "full": PipelineConfig(
        tasks=list(ENV_IDS),
        episodes=80,
        # every learner's actor shared by the robots, cloned 40 epochs and fine-tuned 1,200,000 steps: adopted on
        # validation seeds over the 600k record (docs/learning.md, "The swarm actor is adopted on validation seeds")
        actor="swarm",
        bc_epochs=40,
        finetune_steps=1_200_000,
        train_seeds=[0, 1, 2],
        validation_seeds=list(range(200, 220)),
        test_seeds=list(range(300, 350)),
        # each task's teacher chosen among these holds and bin widths on 80 seeds of its own, its learners deciding
        # once per phase (docs/learning.md, "The teacher's tempo" and "Narrower bins")
        teacher_holds=[6, 7, 8, 10, 12],
        teacher_bin_widths=[50.0, 60.0],
        teacher_seeds=list(range(200, 280)),
        action_repeat=PER_PHASE,
        # fine-tuned at ten times the yaml's learning rate: adopted on validation seeds over the swarm record
        # (docs/learning.md, "What limits Unresponsive": "Fine-tuning at learning rate 3e-4 is adopted")
        finetune_hyperparams={**FINETUNE_AT_REPEAT, "learning_rate": FULL_FINETUNE_LEARNING_RATE},
    ),
}


def preset_config(name: str, **overrides: Any) -> PipelineConfig:
    """The preset ``name`` with ``overrides`` (PipelineConfig fields) applied and checked."""
    if name not in PRESETS:
        raise ParameterError("preset", f"expected one of {list(PRESETS)}, got {name!r}")
    return PipelineConfig(**{**asdict(PRESETS[name]), **overrides})
