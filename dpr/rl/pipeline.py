"""The whole learning pipeline, task by task: demonstrations -> behaviour cloning -> fine-tuning, beside RL
from scratch, all evaluated against the wave policy, then a results table and figures (``dpr pipeline``).

For each task, and each training seed ``s`` of ``train_seeds``:

1. ``datasets/<task>``: ``episodes`` demonstrations of the Markov wave (:class:`dpr.policies.wave.MarkovWavePolicy`,
   the expert whose action is a function of the observation), recorded as a LeRobot dataset (one per task);
2. ``models/<task>-bc-seed<s>.zip``: behaviour cloning of those demonstrations into a PPO actor-critic;
3. ``models/<task>-bc-<algo>-seed<s>.zip``: fine-tuning of that clone with each of ``finetune_algos``
   (a critic warm-up, then ``finetune_steps`` steps of the ``finetune`` hyperparameters);
4. ``eval/validation/<task>-<method>-seed<s>.json`` on the validation seeds, which make every choice, once every
   seed has done 2-3: a method's canonical model ``models/<task>-<method>.zip`` is its *median* training run there
   (not the best), written to ``choices.yaml`` with every run's validation median;
5. ``eval/test/<task>-<method>-seed<s>.json``: every run of 2-3 on the test seeds, which no choice ever saw
   (demonstrations use seeds from ``demo_seed``, RL its own seeded resets; all three sets are disjoint);
6. ``models/<task>-<algo>-seed<s>.zip``: each of ``scratch_algos`` trained from scratch for as many env steps as
   the fine-tuned models used in all (demonstration frames + warm-up + fine-tuning), so the comparison is fair;
   then scored, chosen from and tested as in 4-5; and the wave policy (and the chosen teacher) on the test seeds;
7. ``report/``: the table, interval estimates over test seeds x training runs, and figures (:mod:`dpr.rl.report`).

:data:`dpr.rl.pipeline_config.PRESETS` names whole configurations: ``small`` (``make run``: one task, one
training seed, minutes) and ``full`` (the headline: four tasks, each task's teacher chosen among five holds,
three training seeds, 20 validation and 50 test seeds).

Every env runs with ``obs_last_action=True`` (the previous action and how long it has been held are part of
the observation), which the Markov wave needs and which every learner gets too. On Manipulation, RL
(fine-tuning and from scratch alike) trains with ``approach_reward`` shaping (:class:`dpr.envs.ManipulationEnv`):
without it the ball's progress rewards catching up with the ball only on contact, and fine-tuning loses ground
(RESULTS.md). Each stage writes into its own file or folder under ``out`` and is skipped when that already
exists, so an interrupted pipeline resumes where it stopped and nothing written is replaced; a training run stopped
part-way goes on from its last snapshot (:mod:`dpr.rl.resume`, at most a few minutes old) to the model it would have
made without the stop. A training run's model
is needed only until its evaluations exist, or when it is the chosen run and the canonical model is missing; so a
run folder kept without its datasets, ``runs/`` and training runs' models (its ``pipeline.yaml``,
``choices.yaml``, ``eval/`` and canonical models) resumes at any stage, training only what is still missing.
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

from dpr.checks import ParameterError
from dpr.envs import episode_steps
from dpr.locks import FolderLock, LockHeld
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
from dpr.rl.run_folder import (
    evaluated,
    evaluation_path,
    evaluation_splits,
    load_choices,
    model_path,
    report_evaluations,
    report_folder,
    save_choices,
    task_done,
    tested_runs,
    write_run_settings,
)
from dpr.runs import attempt_paths, fresh_path

RUN_LOCK = ".dpr-pipeline.lock"  # held by the one pipeline writing a run folder


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


def _shipped_evaluation_path(out: Path, model: Path) -> Path:
    """Where a shipped model's test evaluation goes: named by the file's content, so that a model replaced in
    ``models/`` is evaluated again beside the old one's evaluation, not taken for it."""
    import hashlib

    digest = hashlib.sha256(model.read_bytes()).hexdigest()[:12]
    return out / "eval" / "shipped" / f"{model.stem}-{digest}.json"


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
    their tasks, and reported as ``shipped <method>``. One pipeline at a time writes a run folder: a second is
    refused, naming the first's pid (``out/.dpr-pipeline.lock``, taken over once its holder is dead)."""
    from dpr.policies.sb3 import model_env_kwargs

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ParameterError("out", f"{out} exists and is not a folder")
    for model in shipped:  # a shipped model must run on the pipeline's swarm, or its row means nothing
        model_env_kwargs(model.path, model.env_id, {"n_robots": config.n_robots})
    out.mkdir(parents=True, exist_ok=True)
    lock = FolderLock(out / RUN_LOCK)
    try:
        lock.acquire()
    except LockHeld as held:
        raise ParameterError(
            "out",
            f"another `dpr pipeline`{held.holder} is running in {out}; wait for it, or stop it and run this again",
        ) from None
    try:
        return _run_pipeline(config, out, shipped, show_progress, log)
    finally:
        lock.release()


def _run_pipeline(
    config: PipelineConfig,
    out: Path,
    shipped: Sequence[ShippedModel],
    show_progress: bool,
    log: Callable[[str], None],
) -> Path:
    """:func:`run_pipeline` in ``out``, whose lock this process holds."""
    from dpr.rl.report import REPORT_FILES, write_report

    config_path = out / "pipeline.yaml"
    resuming = config_path.exists()
    if resuming:
        previous = yaml.safe_load(config_path.read_text()).get("config")
        if not isinstance(previous, dict) or saved_settings(previous) != asdict(config):
            settings = saved_settings(previous) if isinstance(previous, dict) else {}
            differ = [
                f"{name}: {settings.get(name)!r} there, {value!r} here"
                for name, value in asdict(config).items()
                if settings.get(name) != value
            ]
            raise ParameterError(
                "out",
                f"{out} holds a pipeline run with other settings ({config_path}: {'; '.join(differ)}); "
                "use a new folder, or the same settings to resume it",
            )
    for folder in ("datasets", "runs", "models", "eval/test", "eval/validation"):
        (out / folder).mkdir(parents=True, exist_ok=True)
    if not resuming:
        write_run_settings(out, config)
    started = time.perf_counter()
    for task in config.tasks:
        teacher = _choose_teacher(config, task, out, show_progress, log)  # on the teacher seeds
        if task_done(config, task, out):  # e.g. a record of it kept without its datasets and training runs
            log(f"dpr pipeline: {task}: its canonical models and test evaluations exist, skipped")
        else:
            # the clone and its fine-tuned runs first, so that the headline method is done first and a candidate
            # recipe can be judged on its validation scores (tools/compare_recipes.py) while the runs from scratch
            # go on. Each group is trained, scored on the validation seeds, chosen from and tested before the next:
            # a run's model is then needed only until its evaluations exist (_choose_canonical_models)
            for methods in (config.cloned_methods(), config.scratch_algos):
                for seed in config.train_seeds:
                    for method in methods:
                        if not evaluated(config, task, method, seed, out):
                            _train_run(config, task, teacher, method, seed, out, show_progress, log)
                validations = _validate_runs(config, task, methods, out, show_progress, log)
                _choose_canonical_models(config, task, teacher, methods, validations, out, show_progress, log)
                for method in methods:
                    for seed in config.train_seeds:
                        _evaluate(config, task, method, seed, "test", out, show_progress, log)
        for method, seed in tested_runs(config):
            if seed is None:  # the wave and the teacher; every run was tested with its method above
                _evaluate(config, task, method, seed, "test", out, show_progress, log, teacher)
    test_evaluations = report_evaluations(config, out)  # (file, method): runs of one method share its label
    own_ids = {config.env_id(task) for task in config.tasks}
    for env_id in dict.fromkeys(model.env_id for model in shipped if model.env_id not in own_ids):
        path = out / "eval" / "shipped" / f"{BASELINE}-{env_id.removeprefix('dpr/')}.json"  # the shipped rows' bar
        _evaluate_policy(config, env_id, BASELINE, path, path.stem, show_progress, log, config.test_seeds, "test")
        test_evaluations.append((path, BASELINE))
    for model in shipped:
        path = _shipped_evaluation_path(out, model.path)
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

    sources = [path for path, _ in test_evaluations]
    report = report_folder(out, sources, log)
    if (report / REPORT_FILES[0]).exists():
        log(f"dpr pipeline: report: {report} exists, skipped")
    else:
        write_report(sources, report, labels=[method for _, method in test_evaluations])
    log(f"dpr pipeline: done in {time.perf_counter() - started:.0f} s; report in {report}")
    return report


def _teacher_env_kwargs(config: PipelineConfig, teacher: Teacher) -> dict[str, Any]:
    """The env kwargs ``teacher`` is scored with: as its learners run."""
    return {"n_robots": config.n_robots, **config.learner_env_kwargs(teacher.hold)}


def _median_displacement(evaluation: Path) -> float:
    """The median projected displacement over the episodes of an evaluation file, read through the report's
    checked loader (a damaged file from an earlier run is an error naming it)."""
    from dpr.rl.report import load_evaluation

    return _median([episode["projected_displacement"] for episode in load_evaluation(evaluation)["episodes"]])


def _median(values: Sequence[float]) -> float:
    import numpy as np

    return float(np.median(values))


def _choose_teacher(
    config: PipelineConfig, task: str, out: Path, show_progress: bool, log: Callable[[str], None]
) -> Teacher:
    """``task``'s teacher: among every teacher hold and bin width, the Markov wave with the highest median on the
    teacher seeds (the first listed of equal ones), each run as its learners will run, deciding once per their
    decision interval. Recorded in ``choices.yaml`` and read back on resume; one candidate is no choice."""
    candidates = config.teachers()
    if len(candidates) == 1:
        return candidates[0]
    choices = load_choices(out)
    key = f"{task}-{TEACHER}"
    if key in choices:
        return Teacher(int(choices[key]["hold_steps"]), float(choices[key].get("bin_width", Teacher().bin_width)))
    medians = {}
    seeds = config.teacher_choice_seeds()
    for teacher in candidates:
        path = evaluation_path(out, task, f"{TEACHER}-{teacher.stem}", None, "validation")
        kwargs = _teacher_env_kwargs(config, teacher)
        _evaluate_policy(
            config,
            config.env_id(task),
            teacher.policy,
            path,
            path.stem,
            show_progress,
            log,
            seeds,
            "validation",
            kwargs,
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
    save_choices(out, choices)
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
        config.env_id(task),
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


def _train_run(
    config: PipelineConfig,
    task: str,
    teacher: Teacher,
    method: str,
    seed: int,
    out: Path,
    show_progress: bool,
    log: Callable[[str], None],
) -> Path:
    """Train ``method``'s run with training seed ``seed`` unless its model exists, and return the model: the clone
    ("bc", from the demonstrations, recorded first if missing), a fine-tuning of the clone ("bc-<algo>", cloning
    first if the clone is missing) or a run from scratch ("<algo>")."""
    from dpr.imitation.bc import behaviour_clone
    from dpr.rl.train import TrainConfig, resumable, train

    env_id = config.env_id(task)
    dataset = out / "datasets" / task
    model = model_path(out, task, method, seed)
    if method == "bc":
        if _stage(model, f"{task}: behaviour cloning, seed {seed}", log):
            _demonstrations(config, task, teacher, dataset, show_progress, log)
            result = behaviour_clone(
                dataset,
                env_id,
                algo=BC_ALGO,
                epochs=config.bc_epochs,
                hyperparams=config.actor_hyperparams(),
                seed=seed,
                out=fresh_path(out / "runs" / f"{task}-bc-seed{seed}"),
                show_progress=show_progress,
                log=log,
            )
            _copy_new(result.model_path, model)
        return model
    repeat = config.decision_steps(teacher.hold)  # budgets are physics steps; TrainConfig counts env steps (decisions)
    fine_tuned = method in config.cloned_methods()
    settings: dict[str, Any] = {
        "algo": method.removeprefix("bc-"),
        "timesteps": (config.finetune_steps if fine_tuned else config.rl_steps) // repeat,
        "hyperparams": config.actor_hyperparams() if fine_tuned else config.scratch_hyperparams_at(teacher.hold),
    }
    warmup = f" after {config.critic_warmup} warm-up steps" if fine_tuned else ""
    what = f"{task}: {method}, seed {seed} ({settings['timesteps'] * repeat} physics steps{warmup})"
    if not _stage(model, what, log):
        return model
    if fine_tuned:
        if config.anchor:
            _demonstrations(config, task, teacher, dataset, show_progress, log)
        settings |= {
            "preset": FINETUNE_PRESET,
            "init_from": str(_train_run(config, task, teacher, "bc", seed, out, show_progress, log)),
            "critic_warmup": config.critic_warmup // repeat,
            "anchor_datasets": [str(dataset)] if config.anchor else [],
            "hyperparams": settings["hyperparams"] | config.finetune_hyperparams_at(teacher.hold),
        }
    kwargs = config.rl_env_kwargs(task, teacher.hold)
    train_config = TrainConfig(
        env_id=env_id,
        n_robots=config.n_robots,
        seed=seed,
        n_envs=config.workers,
        steps_per_episode=episode_steps(kwargs, config.steps),
        env_kwargs=kwargs,
        **settings,
    )
    run_dir = out / "runs" / f"{task}-{method}-seed{seed}"
    # a run stopped part-way goes on from its last snapshot, in its folder or in the newest one started beside it
    stopped = [folder for folder in attempt_paths(run_dir) if resumable(folder, train_config)]
    if stopped:
        run_dir = stopped[-1]
    elif run_dir.exists():
        log(f"dpr pipeline: {run_dir} has no snapshot of these settings to resume from; starting a new run beside it")
        run_dir = fresh_path(run_dir)
    result = train(train_config, run_dir, show_progress=show_progress, resume=bool(stopped), log=log)
    if result.interrupted:
        raise KeyboardInterrupt
    _copy_new(result.model_path, model)
    return model


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
    path = evaluation_path(out, task, method, seed, split)
    own_kwargs = None  # the wave's default (_evaluate_policy), or a model's own
    if method == BASELINE:
        policy = BASELINE
    elif method == TEACHER:
        policy, own_kwargs = teacher.policy, _teacher_env_kwargs(config, teacher)
    else:
        policy = str(model_path(out, task, method, seed))
    seeds = _split_seeds(config, split)
    return _evaluate_policy(
        config, config.env_id(task), policy, path, path.stem, show_progress, log, seeds, split, own_kwargs
    )


def _split_seeds(config: PipelineConfig, split: str) -> list[int]:
    """The seeds of the ``split`` ("test" or "validation")."""
    return config.test_seeds if split == "test" else config.validation_seeds


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
    config: PipelineConfig,
    task: str,
    teacher: Teacher,
    methods: list[str],
    validations: dict[str, dict[int, Path]],
    out: Path,
    show_progress: bool,
    log: Callable[[str], None],
) -> None:
    """Copy each of ``methods``' median training run (by its median on the validation seeds: ``validations``, from
    :func:`_validate_runs`) to its canonical name, without the optimizer's state
    (:func:`dpr.policies.sb3.save_slim_copy`: the file to ship), and record the choice in ``choices.yaml``. One
    training seed is its own median; nothing is evaluated.

    A chosen run whose model is gone (a record kept with its evaluations only) is trained again, and must score
    exactly what its evaluation file says before it becomes the canonical model: training is deterministic for the
    same library versions (on another machine of the same kind too), and a run that differs is an error, not a
    silent substitute."""
    from dpr.policies.sb3 import save_slim_copy

    choices = load_choices(out)
    for method in methods:
        canonical = model_path(out, task, method, None)
        key = f"{task}-{method}"
        if canonical.exists():
            continue
        if len(config.train_seeds) == 1:
            (chosen,) = config.train_seeds
            medians = {chosen: None}
        else:
            medians = {seed: _median_displacement(path) for seed, path in validations[method].items()}
            ranked = sorted(medians, key=lambda seed: (medians[seed], seed))
            chosen = ranked[(len(ranked) - 1) // 2]  # the median run (the lower one of an even count)
        choices[key] = {"chosen_seed": chosen, "validation_medians": medians}
        save_choices(out, choices)
        log(f"dpr pipeline: {key}: the median run is seed {chosen} -> {canonical}")
        if not model_path(out, task, method, chosen).exists():
            _train_run(config, task, teacher, method, chosen, out, show_progress, log)
            _check_reproduces(config, task, method, chosen, out, show_progress, log)
        save_slim_copy(model_path(out, task, method, chosen), canonical)


def _check_reproduces(
    config: PipelineConfig,
    task: str,
    method: str,
    seed: int,
    out: Path,
    show_progress: bool,
    log: Callable[[str], None],
) -> None:
    """Raise unless the retrained run ``seed`` of ``method`` scores, episode for episode, what its evaluation on the
    validation seeds (the test seeds for a single training seed) recorded."""
    import tempfile

    from dpr.rl.report import load_evaluation

    split = evaluation_splits(config)[0]
    recorded = evaluation_path(out, task, method, seed, split)
    model = model_path(out, task, method, seed)
    with tempfile.TemporaryDirectory() as folder:
        again = Path(folder) / recorded.name
        seeds = _split_seeds(config, split)
        _evaluate_policy(
            config,
            config.env_id(task),
            str(model),
            again,
            f"{recorded.stem} (retrained)",
            show_progress,
            log,
            seeds,
            split,
        )
        scores = [
            [episode["projected_displacement"] for episode in load_evaluation(path)["episodes"]]
            for path in (recorded, again)
        ]
    if scores[0] != scores[1]:
        raise RuntimeError(
            f"{model} was trained again because it is the chosen run and its model was missing, but it does not "
            f"reproduce {recorded} (median {_median(scores[1]):.2f} against {_median(scores[0]):.2f}): training is "
            "not deterministic here (another machine or library version?). Restore the run's model, or start a new "
            "folder"
        )
    log(f"dpr pipeline: {model} reproduces {recorded} episode for episode")
