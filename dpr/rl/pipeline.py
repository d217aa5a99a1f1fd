"""The whole learning pipeline, task by task: demonstrations -> behaviour cloning -> fine-tuning, beside RL
from scratch, all evaluated against the wave policy, then a results table and figures (``dpr pipeline``).

For each task, and each training seed ``s`` of ``train_seeds``:

1. ``datasets/<task>``: ``episodes`` demonstrations of the Markov wave (:class:`dpr.policies.wave.MarkovWavePolicy`,
   the expert whose action is a function of the observation), recorded as a LeRobot dataset (one per task);
2. ``models/<task>-bc-seed<s>.zip``: behaviour cloning of those demonstrations into a PPO actor-critic;
3. ``models/<task>-bc-<algo>-seed<s>.zip``: fine-tuning of that clone with each of ``finetune_algos``
   (a critic warm-up, then ``finetune_steps`` steps of the ``finetune`` hyperparameters);
4. ``models/<task>-<algo>-seed<s>.zip``, once every seed has done 2-3: each of ``scratch_algos`` trained from
   scratch for as many env steps as the fine-tuned models used in all (demonstration frames + warm-up +
   fine-tuning), so the comparison is fair;
5. ``eval/validation/<task>-<method>-seed<s>.json`` on the validation seeds, which make every choice (the clones
   and fine-tuned runs are scored as soon as every seed has done 2-3, before step 4): a method's canonical model
   ``models/<task>-<method>.zip`` is its *median* training run there (not the best), written to ``choices.yaml``
   with every run's validation median;
6. ``eval/test/<task>-<method>-seed<s>.json``: the wave policy and every run on the test seeds, which no choice
   ever saw (demonstrations use seeds from ``demo_seed``, RL its own seeded resets; all three sets are disjoint);
7. ``report/``: the table, interval estimates over test seeds x training runs, and figures (:mod:`dpr.rl.report`).

:data:`dpr.rl.pipeline_config.PRESETS` names whole configurations: ``small`` (``make run``: one task, one
training seed, minutes) and ``full`` (the headline: four tasks, each task's teacher chosen among five holds,
three training seeds, 20 validation and 50 test seeds).

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
from collections.abc import Callable, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import yaml

from dpr.atomic import atomic_write_text
from dpr.checks import ParameterError
from dpr.envs import ENV_IDS, episode_steps
from dpr.policies.hyperparams import FINETUNE_PRESET
from dpr.rl.model_card import ShippedModel
from dpr.rl.pipeline_config import (
    BASELINE,
    BC_ALGO,
    PIPELINE_ENV_KWARGS,
    TEACHER,
    PipelineConfig,
    Teacher,
    saved_settings,
)
from dpr.runs import fresh_path


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
    shipped: Sequence[ShippedModel] = (),
    show_progress: bool = True,
    log: Callable[[str], None] = lambda line: print(line, file=sys.stderr),
) -> Path:
    """Run (or resume) the pipeline into ``out``; returns the report folder. ``shipped`` (a model card's
    entries, :func:`dpr.rl.model_card.load_model_card`) are evaluated on the test seeds too, beside the wave on
    their tasks, and reported as ``shipped <method>``."""
    from dpr.policies.sb3 import model_env_kwargs
    from dpr.rl.report import REPORT_FILES, write_report

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ParameterError("out", f"{out} exists and is not a folder")
    for model in shipped:  # a shipped model must run on the pipeline's swarm, or its row means nothing
        model_env_kwargs(model.path, model.env_id, {"n_robots": config.n_robots})
    for folder in ("datasets", "runs", "models", "eval/test", "eval/validation"):
        (out / folder).mkdir(parents=True, exist_ok=True)
    config_path = out / "pipeline.yaml"
    if config_path.exists():
        previous = yaml.safe_load(config_path.read_text()).get("config")
        if not isinstance(previous, dict) or saved_settings(previous) != asdict(config):
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
    for task in config.tasks:
        dataset = out / "datasets" / task
        teacher = _choose_teacher(config, task, out, show_progress, log)  # on validation seeds
        if _task_done(config, task, out):  # e.g. a record of it kept without its datasets and training runs
            log(f"dpr pipeline: {task}: its canonical models and test evaluations exist, skipped")
        else:
            _demonstrations(config, task, teacher, dataset, show_progress, log)
            # every seed's clone and fine-tuning before any run from scratch: the headline method's runs end first,
            # and are scored on the validation seeds then, so that a candidate recipe can be judged on them
            # (tools/compare_recipes.py) while its runs from scratch go on
            for from_scratch in (False, True):
                for seed in config.train_seeds:
                    _train_runs(config, task, teacher.hold, dataset, seed, out, show_progress, log, from_scratch)
                if not from_scratch:
                    _validate_runs(config, task, config.cloned_methods(), out, show_progress, log)
        _choose_canonical_models(config, task, out, show_progress, log)  # on validation seeds, before any test
        for method, seed in _test_runs(config):
            _evaluate(config, task, method, seed, "test", out, show_progress, log, teacher)
    test_evaluations = report_evaluations(config, out)  # (file, method): runs of one method share its label
    for task in dict.fromkeys(model.task for model in shipped if model.task not in config.tasks):
        test_evaluations.append((_evaluate(config, task, BASELINE, None, "test", out, show_progress, log), BASELINE))
    for model in shipped:
        path = out / "eval" / "shipped" / f"{model.path.stem}.json"
        _evaluate_policy(
            config,
            model.env_id,
            str(model.path),
            path,
            f"shipped {model.path.name}",
            show_progress,
            log,
            config.test_seeds,
            "test",
        )
        test_evaluations.append((path, f"shipped {model.method}"))

    report = out / "report"
    if (report / REPORT_FILES[0]).exists():
        log(f"dpr pipeline: report: {report} exists, skipped")
    else:
        write_report([path for path, _ in test_evaluations], report, labels=[method for _, method in test_evaluations])
    log(f"dpr pipeline: done in {time.perf_counter() - started:.0f} s; report in {report}")
    return report


def _task_done(config: PipelineConfig, task: str, out: Path) -> bool:
    """Whether ``task`` needs nothing more: every method's canonical model and every test evaluation exist. Its
    demonstrations and training runs are then not needed, so a record of the run without them (the models, the
    evaluations and ``choices.yaml``) resumes as it is."""
    return all(_model_path(out, task, method, None).exists() for method in config.learned_methods()) and all(
        _evaluation_path(out, task, method, seed, "test").exists() for method, seed in _test_runs(config)
    )


def report_evaluations(config: PipelineConfig, out: Path) -> list[tuple[Path, str]]:
    """(file, method) of every test evaluation of ``config``'s tasks in the run folder ``out``, in the report's
    order: per task the wave, the teacher, then each method's training runs."""
    return [
        (_evaluation_path(Path(out), task, method, seed, "test"), method)
        for task in config.tasks
        for method, seed in _test_runs(config)
    ]


def _test_runs(config: PipelineConfig) -> list[tuple[str, int | None]]:
    """(method, training seed) of every test evaluation of a task: the wave and the teacher once (seed None),
    every training run."""
    once = (BASELINE, TEACHER)
    return [
        (method, seed) for method in config.methods() for seed in ([None] if method in once else config.train_seeds)
    ]


def _evaluation_path(out: Path, task: str, method: str, seed: int | None, split: str) -> Path:
    """The evaluation of the wave or a method's training run (``seed``) on the ``split`` seeds."""
    name = f"{task}-{method}" if seed is None else f"{task}-{method}-seed{seed}"
    return out / "eval" / split / f"{name}.json"


def _model_path(out: Path, task: str, method: str, seed: int | None) -> Path:
    """A training run's model (``seed``), or the method's canonical model (None)."""
    return out / "models" / (f"{task}-{method}.zip" if seed is None else f"{task}-{method}-seed{seed}.zip")


def _teacher_env_kwargs(config: PipelineConfig, teacher: Teacher) -> dict[str, Any]:
    """The env kwargs ``teacher`` is scored with: as its learners run."""
    return {"n_robots": config.n_robots, **config.learner_env_kwargs(teacher.hold)}


def _load_choices(out: Path) -> dict[str, Any]:
    """``choices.yaml``: every choice made on the validation seeds so far."""
    path = out / "choices.yaml"
    return yaml.safe_load(path.read_text()) if path.exists() else {}


def _save_choices(out: Path, choices: dict[str, Any]) -> None:
    atomic_write_text(out / "choices.yaml", yaml.safe_dump(choices, sort_keys=True))


def _median_displacement(evaluation: Path) -> float:
    """The median projected displacement over the episodes of an evaluation file, read through the report's
    checked loader (a damaged file from an earlier run is an error naming it)."""
    import numpy as np

    from dpr.rl.report import load_evaluation

    episodes = load_evaluation(evaluation)["episodes"]
    return float(np.median([episode["projected_displacement"] for episode in episodes]))


def _choose_teacher(
    config: PipelineConfig, task: str, out: Path, show_progress: bool, log: Callable[[str], None]
) -> Teacher:
    """``task``'s teacher: among every teacher hold and bin width, the Markov wave with the highest median on the
    teacher seeds (the first listed of equal ones), each run as its learners will run, deciding once per their
    decision interval. Recorded in ``choices.yaml`` and read back on resume; one candidate is no choice."""
    candidates = config.teachers()
    if len(candidates) == 1:
        return candidates[0]
    choices = _load_choices(out)
    key = f"{task}-{TEACHER}"
    if key in choices:
        return Teacher(int(choices[key]["hold_steps"]), float(choices[key].get("bin_width", Teacher().bin_width)))
    medians = {}
    seeds = config.teacher_choice_seeds()
    for teacher in candidates:
        path = _evaluation_path(out, task, f"{TEACHER}-{teacher.stem}", None, "validation")
        kwargs = _teacher_env_kwargs(config, teacher)
        _evaluate_policy(
            config, ENV_IDS[task], teacher.policy, path, path.stem, show_progress, log, seeds, "validation", kwargs
        )
        medians[teacher] = _median_displacement(path)
    chosen = max(candidates, key=lambda teacher: medians[teacher])  # max keeps the first of equal ones
    # keyed by hold alone while every candidate has the wave's bins (the records made before bin widths read so)
    by_hold = config.teacher_bin_widths == [Teacher().bin_width]
    choices[key] = {
        "hold_steps": chosen.hold,
        **({} if chosen.bin_width == Teacher().bin_width else {"bin_width": chosen.bin_width}),
        "validation_medians": {teacher.hold if by_hold else teacher.stem: medians[teacher] for teacher in candidates},
    }
    _save_choices(out, choices)
    log(f"dpr pipeline: {key}: {chosen.policy} ({medians[chosen]:.1f} on validation seeds)")
    return chosen


def _demonstrations(
    config: PipelineConfig,
    task: str,
    teacher: Teacher,
    dataset: Path,
    show_progress: bool,
    log: Callable[[str], None],
) -> None:
    from tqdm import tqdm

    from dpr.datasets.collect import CollectSpec, collect

    what = f"{task}: {config.episodes} demonstrations of {teacher.policy}"
    if not _collect_stage(dataset, config.episodes, what, log):
        return
    kwargs = config.learner_env_kwargs(teacher.hold)
    spec = CollectSpec(
        ENV_IDS[task],
        policy=teacher.policy,
        n_robots=config.n_robots,
        steps=episode_steps(kwargs, config.steps),
        env_kwargs=kwargs,
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


def _train_runs(
    config: PipelineConfig,
    task: str,
    hold: int,
    dataset: Path,
    seed: int,
    out: Path,
    show_progress: bool,
    log: Callable[[str], None],
    from_scratch: bool,
) -> None:
    """Training seed ``seed``'s clone and its fine-tuned models, or (``from_scratch``) its models trained from
    scratch."""
    from dpr.imitation.bc import behaviour_clone
    from dpr.rl.train import TrainConfig, train

    env_id = ENV_IDS[task]
    repeat = config.decision_steps(hold)  # budgets are physics steps; TrainConfig counts env steps (decisions)
    runs: list[tuple[str, dict[str, Any]]]
    if from_scratch:
        runs = [(algo, {"algo": algo, "timesteps": config.rl_steps // repeat}) for algo in config.scratch_algos]
    else:
        bc_model = _model_path(out, task, "bc", seed)
        if _stage(bc_model, f"{task}: behaviour cloning, seed {seed}", log):
            result = behaviour_clone(
                dataset,
                env_id,
                algo=BC_ALGO,
                epochs=config.bc_epochs,
                seed=seed,
                out=fresh_path(out / "runs" / f"{task}-bc-seed{seed}"),
                show_progress=show_progress,
                log=log,
            )
            _copy_new(result.model_path, bc_model)
        runs = [
            (
                f"bc-{algo}",
                {
                    "algo": algo,
                    "preset": FINETUNE_PRESET,
                    "timesteps": config.finetune_steps // repeat,
                    "init_from": str(bc_model),
                    "critic_warmup": config.critic_warmup // repeat,
                    "anchor_datasets": [str(dataset)] if config.anchor else [],
                    "hyperparams": config.finetune_hyperparams_at(hold),
                },
            )
            for algo in config.finetune_algos
        ]
    for method, settings in runs:
        model = _model_path(out, task, method, seed)
        warmup = f" after {config.critic_warmup} warm-up steps" if "init_from" in settings else ""
        physics = settings["timesteps"] * repeat
        if not _stage(model, f"{task}: {method}, seed {seed} ({physics} physics steps{warmup})", log):
            continue
        kwargs = config.rl_env_kwargs(task, hold)
        train_config = TrainConfig(
            env_id=env_id,
            n_robots=config.n_robots,
            seed=seed,
            n_envs=config.workers,
            steps_per_episode=episode_steps(kwargs, config.steps),
            env_kwargs=kwargs,
            **settings,
        )
        result = train(
            train_config, fresh_path(out / "runs" / f"{task}-{method}-seed{seed}"), show_progress=show_progress, log=log
        )
        if result.interrupted:
            raise KeyboardInterrupt
        _copy_new(result.model_path, model)


def _evaluate(
    config: PipelineConfig,
    task: str,
    method: str,
    seed: int | None,
    split: str,
    out: Path,
    show_progress: bool,
    log: Callable[[str], None],
    teacher: Teacher = Teacher(),
) -> Path:
    """Evaluate the wave or ``teacher`` (``seed`` None), or a training run, on the ``split`` seeds ("test" or
    "validation"). The wave runs on the pipeline's env, the teacher as its learners run."""
    path = _evaluation_path(out, task, method, seed, split)
    own_kwargs = None  # the wave's default (_evaluate_policy), or a model's own
    if method == BASELINE:
        policy = BASELINE
    elif method == TEACHER:
        policy, own_kwargs = teacher.policy, _teacher_env_kwargs(config, teacher)
    else:
        policy = str(_model_path(out, task, method, seed))
    seeds = config.test_seeds if split == "test" else config.validation_seeds
    return _evaluate_policy(
        config, ENV_IDS[task], policy, path, path.stem, show_progress, log, seeds, split, own_kwargs
    )


def _evaluate_policy(
    config: PipelineConfig,
    env_id: str,
    policy: str,
    path: Path,
    name: str,
    show_progress: bool,
    log: Callable[[str], None],
    seeds: Sequence[int],
    split: str,
    own_kwargs: dict[str, Any] | None = None,
) -> Path:
    """Evaluate ``policy`` on ``env_id`` and ``seeds`` (the ``split``'s: "test" or "validation") into ``path``: a
    scripted policy on ``own_kwargs`` (by default the wave's: the pipeline's env), a model file on the env kwargs
    stored in it."""
    from tqdm import tqdm

    from dpr.policies.sb3 import is_model_path
    from dpr.rl.evaluation import evaluate, policy_env_kwargs, save_evaluation
    from dpr.rl.report import format_seeds

    if not _stage(path, f"{name}: evaluate on the {split} seeds {format_seeds(seeds)}", log):
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    if own_kwargs is None and not is_model_path(policy):
        own_kwargs = {"n_robots": config.n_robots, **PIPELINE_ENV_KWARGS}
    kwargs = policy_env_kwargs(policy, env_id, own_kwargs)
    with tqdm(total=len(seeds), desc=f"evaluate {name} ({split})", unit="episode", disable=not show_progress) as bar:
        results = evaluate(
            [env_id],
            policy,
            seeds,
            steps=config.steps,
            env_kwargs=kwargs,
            workers=config.workers,
            progress=lambda r: bar.update(1),
        )
    save_evaluation(path, policy, [env_id], kwargs, config.steps, seeds, results)
    return path


def _validate_runs(
    config: PipelineConfig,
    task: str,
    methods: list[str],
    out: Path,
    show_progress: bool,
    log: Callable[[str], None],
) -> dict[str, dict[int, Path]]:
    """Score every training run of ``methods`` on the validation seeds (each file is made once): method -> training
    seed -> its evaluation. One training seed is no choice, so nothing is scored then."""
    if len(config.train_seeds) == 1:
        return {}
    return {
        method: {
            seed: _evaluate(config, task, method, seed, "validation", out, show_progress, log)
            for seed in config.train_seeds
        }
        for method in methods
    }


def _choose_canonical_models(
    config: PipelineConfig, task: str, out: Path, show_progress: bool, log: Callable[[str], None]
) -> None:
    """Copy each method's median training run (by its median on the validation seeds) to its canonical name,
    without the optimizer's state (:func:`dpr.policies.sb3.save_slim_copy`: the file to ship), and record the
    choice in ``choices.yaml``. One training seed is its own median; nothing is evaluated."""
    from dpr.policies.sb3 import save_slim_copy

    choices = _load_choices(out)
    for method in config.learned_methods():
        canonical = _model_path(out, task, method, None)
        key = f"{task}-{method}"
        if canonical.exists():
            continue
        if len(config.train_seeds) == 1:
            (chosen,) = config.train_seeds
            medians = {chosen: None}
        else:
            evaluations = _validate_runs(config, task, [method], out, show_progress, log)[method]
            medians = {seed: _median_displacement(path) for seed, path in evaluations.items()}
            ranked = sorted(medians, key=lambda seed: (medians[seed], seed))
            chosen = ranked[(len(ranked) - 1) // 2]  # the median run (the lower one of an even count)
        choices[key] = {"chosen_seed": chosen, "validation_medians": medians}
        _save_choices(out, choices)
        log(f"dpr pipeline: {key}: the median run is seed {chosen} -> {canonical}")
        save_slim_copy(_model_path(out, task, method, chosen), canonical)
