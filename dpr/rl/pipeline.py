"""The whole learning pipeline, task by task: demonstrations -> behaviour cloning -> fine-tuning, beside RL
from scratch, all evaluated against the wave policy, then a results table and figures (``dpr pipeline``).

For each task:

1. ``datasets/<task>``: ``episodes`` demonstrations of the Markov wave (:class:`dpr.policies.wave.MarkovWavePolicy`,
   the expert whose action is a function of the observation), recorded as a LeRobot dataset;
2. ``models/<task>-bc.zip``: behaviour cloning of those demonstrations into a PPO actor-critic;
3. ``models/<task>-bc-<algo>.zip``: fine-tuning of the clone with each of ``finetune_algos``
   (a critic warm-up, then ``finetune_steps`` steps of the ``finetune`` hyperparameters);
4. ``models/<task>-<algo>.zip``: each of ``scratch_algos`` trained from scratch for as many env steps as the
   fine-tuned models used in all (demonstration frames + warm-up + fine-tuning), so the comparison is fair;
5. ``eval/<task>-<method>.json``: the wave policy and every model on the evaluation seeds (never seen in
   training: demonstrations use seeds from ``demo_seed``, RL its own seeded resets);
6. ``report/``: ``results.md``, ``bars.png`` and ``trajectories.png`` (:mod:`dpr.rl.report`).

Every env runs with ``obs_last_action=True`` (the previous action and how long it has been held are part of
the observation), which the Markov wave needs and which every learner gets too. On Manipulation, RL
(fine-tuning and from scratch alike) trains with ``approach_reward`` shaping (:class:`dpr.envs.ManipulationEnv`):
without it the ball's progress rewards catching up with the ball only on contact, and fine-tuning loses ground
(RESULTS.md). Each stage writes into its own file or folder under ``out`` and is skipped when that already
exists, so an interrupted pipeline resumes where it stopped and nothing written is replaced.
"""

from __future__ import annotations

import shutil
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import yaml

from dpr.checks import ParameterError, check_int
from dpr.envs import ENV_IDS, MAX_EPISODE_STEPS
from dpr.policies.hyperparams import FINETUNE_PRESET
from dpr.policies.registry import WAVE, WAVE_MARKOV
from dpr.policies.sb3 import ALGOS, DEFAULT_ALGO, FINETUNE_ALGOS
from dpr.runs import fresh_path

PIPELINE_ENV_KWARGS = {"obs_last_action": True}
EXPERT = WAVE_MARKOV
BASELINE = WAVE
SCRATCH_ALGOS = ALGOS
BC_ALGO = DEFAULT_ALGO  # what the demonstrations are cloned into: an actor-critic every FINETUNE_ALGOS can load


@dataclass
class PipelineConfig:
    """Budgets of one pipeline run (the ``dpr pipeline`` flags); the defaults are ``make run``'s."""

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
    eval_seeds: list[int] = field(default_factory=lambda: list(range(100, 105)))
    seed: int = 0
    workers: int = 2
    steps: int = MAX_EPISODE_STEPS  # per episode, in demonstrations, training and evaluation

    def __post_init__(self):
        unknown = [task for task in self.tasks if task not in ENV_IDS]
        if not self.tasks or unknown:
            raise ValueError(f"tasks must be among {tuple(ENV_IDS)}, got {self.tasks!r}")
        for name, allowed in (("finetune_algos", FINETUNE_ALGOS), ("scratch_algos", SCRATCH_ALGOS)):
            bad = [algo for algo in getattr(self, name) if algo not in allowed]
            if bad:
                raise ValueError(f"{name} must be among {allowed}, got {bad}")
        for name in ("n_robots", "episodes", "bc_epochs", "finetune_steps", "workers", "steps"):
            check_int(name, getattr(self, name), 1)
        for name in ("critic_warmup", "demo_seed", "seed"):
            check_int(name, getattr(self, name), 0)
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
        if not self.eval_seeds:
            raise ValueError("eval_seeds must name at least one seed")
        demo_seeds = set(range(self.demo_seed, self.demo_seed + self.episodes))
        seen = sorted(demo_seeds & set(self.eval_seeds))
        if seen:
            raise ValueError(f"eval_seeds {seen} are demonstration seeds too; evaluate on seeds the models never saw")

    @property
    def rl_steps(self) -> int:
        """Env steps of a fine-tuned model in all: demonstration frames, critic warm-up and fine-tuning (the
        budget RL from scratch gets)."""
        return self.episodes * self.steps + self.critic_warmup + self.finetune_steps

    def rl_env_kwargs(self, task: str) -> dict[str, Any]:
        """The env kwargs RL trains ``task`` with: the pipeline's, and Manipulation's shaping."""
        if task == "manipulation" and self.approach_reward:
            return {**PIPELINE_ENV_KWARGS, "approach_reward": float(self.approach_reward)}
        return dict(PIPELINE_ENV_KWARGS)

    def methods(self) -> list[str]:
        """Names of the policies evaluated on each task, the wave first."""
        return [BASELINE, "bc", *(f"bc-{algo}" for algo in self.finetune_algos), *self.scratch_algos]


def _stage(done: Path, what: str, log: Callable[[str], None]) -> bool:
    """Whether to run a stage whose output is ``done`` (logged either way)."""
    if done.exists():
        log(f"dpr pipeline: {what}: {done} exists, skipped")
        return False
    log(f"dpr pipeline: {what} -> {done}")
    return True


def _collect_stage(dataset: Path, episodes: int, what: str, log: Callable[[str], None]) -> bool:
    """Whether the dataset still lacks episodes (an interrupted collection resumes: it skips saved seeds)."""
    from dpr.datasets.lerobot import LeRobotReader

    if (dataset / "meta" / "info.json").exists() and LeRobotReader(dataset).num_episodes >= episodes:
        log(f"dpr pipeline: {what}: {dataset} holds them, skipped")
        return False
    log(f"dpr pipeline: {what} -> {dataset}")
    return True


def _copy_new(source: Path, target: Path) -> None:
    """Copy through a temporary name, so that ``target`` exists only once it is complete."""
    partial = target.with_name(target.name + ".partial")
    shutil.copyfile(source, partial)
    partial.replace(target)


def run_pipeline(
    config: PipelineConfig,
    out: str | Path,
    *,
    show_progress: bool = True,
    log: Callable[[str], None] = lambda line: print(line, file=sys.stderr),
) -> Path:
    """Run (or resume) the pipeline into ``out``; returns the report folder."""
    from tqdm import tqdm

    from dpr.datasets.collect import CollectSpec, collect
    from dpr.imitation.bc import behaviour_clone
    from dpr.rl.evaluation import evaluate, policy_env_kwargs, save_evaluation
    from dpr.rl.report import REPORT_FILES, format_seeds, write_report
    from dpr.rl.train import TrainConfig, train

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ParameterError("out", f"{out} exists and is not a folder")
    for folder in ("datasets", "runs", "models", "eval"):
        (out / folder).mkdir(parents=True, exist_ok=True)
    config_path = out / "pipeline.yaml"
    if config_path.exists():
        previous = yaml.safe_load(config_path.read_text()).get("config")
        if isinstance(previous, dict):  # a setting added since that run started had its default value there
            previous = {**asdict(PipelineConfig()), **previous}
        if previous != asdict(config):
            raise ParameterError(
                "out",
                f"{out} holds a pipeline run with other settings ({config_path}); "
                "use a new folder, or the same settings to resume it",
            )
    else:
        config_path.write_text(
            yaml.safe_dump(
                {
                    "config": asdict(config),
                    "rl_steps": config.rl_steps,
                    "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                },
                sort_keys=False,
            )
        )
    started = time.perf_counter()
    evaluations: list[tuple[Path, str]] = []  # (file, method)
    for task in config.tasks:
        env_id = ENV_IDS[task]
        env_kwargs = dict(PIPELINE_ENV_KWARGS)
        dataset = out / "datasets" / task
        if _collect_stage(dataset, config.episodes, f"{task}: {config.episodes} demonstrations of {EXPERT}", log):
            spec = CollectSpec(
                env_id, policy=EXPERT, n_robots=config.n_robots, steps=config.steps, env_kwargs=env_kwargs
            )
            with tqdm(total=config.episodes, desc=f"collect {task}", unit="episode", disable=not show_progress) as bar:
                summary = collect(
                    dataset,
                    spec,
                    config.episodes,
                    seed=config.demo_seed,
                    workers=config.workers,
                    progress=lambda record, index: bar.update(1),
                )
            if summary.interrupted:
                raise KeyboardInterrupt
        bc_model = out / "models" / f"{task}-bc.zip"
        if _stage(bc_model, f"{task}: behaviour cloning", log):
            result = behaviour_clone(
                dataset,
                env_id,
                algo=BC_ALGO,
                epochs=config.bc_epochs,
                seed=config.seed,
                out=fresh_path(out / "runs" / f"{task}-bc"),
                show_progress=show_progress,
                log=log,
            )
            _copy_new(result.model_path, bc_model)

        runs: list[tuple[str, dict[str, Any]]] = [
            (
                f"bc-{algo}",
                {
                    "algo": algo,
                    "preset": FINETUNE_PRESET,
                    "timesteps": config.finetune_steps,
                    "init_from": str(bc_model),
                    "critic_warmup": config.critic_warmup,
                    "anchor_datasets": [str(dataset)] if config.anchor else [],
                },
            )
            for algo in config.finetune_algos
        ] + [(algo, {"algo": algo, "timesteps": config.rl_steps}) for algo in config.scratch_algos]
        for method, settings in runs:
            model = out / "models" / f"{task}-{method}.zip"
            if _stage(
                model,
                f"{task}: {method} ({settings['timesteps']} steps"
                + (f" after {config.critic_warmup} warm-up steps)" if "init_from" in settings else ")"),
                log,
            ):
                train_config = TrainConfig(
                    env_id=env_id,
                    n_robots=config.n_robots,
                    seed=config.seed,
                    n_envs=config.workers,
                    steps_per_episode=config.steps,
                    env_kwargs=config.rl_env_kwargs(task),
                    **settings,
                )
                result = train(
                    train_config, fresh_path(out / "runs" / f"{task}-{method}"), show_progress=show_progress, log=log
                )
                if result.interrupted:
                    raise KeyboardInterrupt
                _copy_new(result.model_path, model)

        for method in config.methods():
            policy = BASELINE if method == BASELINE else str(out / "models" / f"{task}-{method}.zip")
            path = out / "eval" / f"{task}-{method}.json"
            evaluations.append((path, method))
            if not _stage(path, f"{task}: evaluate {method} on seeds {format_seeds(config.eval_seeds)}", log):
                continue
            # the wave runs on the pipeline's env; a model on the env kwargs stored in it
            kwargs = policy_env_kwargs(
                policy, env_id, {"n_robots": config.n_robots, **env_kwargs} if method == BASELINE else None
            )
            with tqdm(
                total=len(config.eval_seeds),
                desc=f"evaluate {task}-{method}",
                unit="episode",
                disable=not show_progress,
            ) as bar:
                results = evaluate(
                    [env_id],
                    policy,
                    config.eval_seeds,
                    steps=config.steps,
                    env_kwargs=kwargs,
                    workers=config.workers,
                    progress=lambda r: bar.update(1),
                )
            save_evaluation(path, policy, [env_id], kwargs, config.steps, config.eval_seeds, results)

    report = out / "report"
    if (report / REPORT_FILES[0]).exists():
        log(f"dpr pipeline: report: {report} exists, skipped")
    else:
        write_report([path for path, _ in evaluations], report, labels=[method for _, method in evaluations])
    log(f"dpr pipeline: done in {time.perf_counter() - started:.0f} s; report in {report}")
    return report
