"""The whole learning pipeline as stages: demonstrations -> behaviour cloning -> fine-tuning, beside RL from
scratch, all evaluated against the wave policy, then a results table and figures (``dpr pipeline``).

Per task, and per training seed ``s`` of ``train_seeds`` (each item a stage of :mod:`dpr.pipeline.stage_builders`):

1. the teacher: among every teacher hold and bin width, the Markov wave (:class:`dpr.policies.wave.MarkovWavePolicy`)
   with the highest median on the teacher seeds, each candidate run as its learners will run;
2. ``episodes`` demonstrations of the teacher, recorded as a LeRobot dataset;
3. behaviour cloning of those demonstrations into an actor-critic, one run per training seed;
4. fine-tuning of each clone with each of ``finetune_algos`` (a critic warm-up, then ``finetune_steps``);
5. each of ``scratch_algos`` from scratch for as many physics steps as a fine-tuned model used in all
   (demonstrations + warm-up + fine-tuning), so the comparison is fair;
6. every run evaluated on the validation seeds, which make every choice (a method's canonical model is its *median*
   run there, not the best), and on the test seeds, which no choice saw; the wave (and the chosen teacher) too;
7. ``report/``: the table, interval estimates over test seeds x training runs, and figures
   (:mod:`dpr.evaluation.report`).

Every stage is stored in the run folder by a key of what it depends on (:mod:`dpr.pipeline.stages`), so that a
stopped run resumes, two runs of different tasks share one folder, and a candidate recipe started from a record's
settings (``reuse``) takes the record's stages that it shares, training only what differs. The run folder:

- ``pipeline.yaml``: the settings (tasks accumulate: every other setting must match to share the folder);
- ``stages/<kind>/<key>/``: every stage's output, with its ``stage.json``; ``work/``: stages in progress;
- ``choices.yaml``: every choice made on the validation (or teacher) seeds;
- ``models/<task>-<method>[-seed<s>].zip`` and ``eval/<split>/<task>-<method>[-seed<s>].json``: the stages'
  models and evaluations under readable names, the canonical model as ``models/<task>-<method>.zip``;
- ``report/``: results.md and figures (a report is never overwritten: a newer one goes beside it).

:data:`dpr.pipeline.config.PRESETS` names whole configurations: ``tiny`` (the tests), ``small`` (``make run``)
and ``full`` (the headline).
"""

from __future__ import annotations

import os
import shutil
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import yaml

from dpr.atomic import atomic_write_text, file_sha256
from dpr.bounded_io import load_yaml
from dpr.checks import ParameterError
from dpr.evaluation.model_card import ShippedModel
from dpr.limits import MAX_RECORD_BYTES
from dpr.locks import FolderLock
from dpr.pipeline import stage_builders as build
from dpr.pipeline.config import BASELINE, BC_ALGO, PIPELINE_ENV_KWARGS, SHIPPED_ROBOT_MODEL, TEACHER, PipelineConfig
from dpr.pipeline.run_folder import (
    evaluation_path,
    evaluation_splits,
    load_choices,
    model_path,
    report_folder,
    save_choices,
    tested_runs,
)
from dpr.pipeline.stages import Backend, Stage, StageStore, backend_session, run_stages

STORE = "stages"
SETTINGS_LOCK = ".dpr-settings.lock"  # held while pipeline.yaml or choices.yaml is read and written


@dataclass
class TaskStages:
    """One task's stages: its teacher choice, each training run's model (method, seed) and each evaluation
    (method, seed or None, split)."""

    teacher: Stage
    candidates: dict[str, Stage] = field(default_factory=dict)  # each candidate teacher's scoring, by its stem
    models: dict[tuple[str, int], Stage] = field(default_factory=dict)
    evaluations: dict[tuple[str, int | None, str], Stage] = field(default_factory=dict)


def task_stages(config: PipelineConfig, task: str) -> TaskStages:
    """The stages of ``task`` under ``config``, keyed by what each depends on."""
    env = {
        "env_id": config.env_id(task),
        "n_robots": config.n_robots,
        "steps": config.steps,
        "action_repeat": config.action_repeat,
        **config.engine_settings(),
    }
    stages = _teacher_stages(config, task, env)
    _learner_stages(config, task, env, stages)
    _evaluation_stages(config, task, env, stages)
    return stages


def _teacher_stages(config: PipelineConfig, task: str, env: dict[str, Any]) -> TaskStages:
    """The teacher's choice, from the scoring of each candidate on the teacher seeds when there is a choice."""
    candidates = config.teachers()
    scored: dict[str, Stage] = {}  # by stem
    if len(candidates) > 1:
        for candidate in candidates:
            settings = {**env, "candidate": [candidate.hold, candidate.bin_width], "label": candidate.policy}
            settings["seeds"] = config.teacher_choice_seeds()
            name = f"{task}: teacher candidate {candidate.stem}"
            scored[candidate.stem] = Stage("evaluate", name, settings, build.evaluate_policy)
    pairs = [[candidate.hold, candidate.bin_width] for candidate in candidates]
    needs = {f"candidate{index}": stage for index, stage in enumerate(scored.values())}
    teacher = Stage(
        "teacher", f"{task}: teacher", {"env_id": env["env_id"], "candidates": pairs}, build.choose_teacher, needs
    )
    return TaskStages(teacher, scored)


def _learner_stages(config: PipelineConfig, task: str, env: dict[str, Any], stages: TaskStages) -> None:
    """The demonstrations, and per training seed the clone, its fine-tuning and the runs from scratch."""
    demonstrations = Stage(
        "demonstrations",
        f"{task}: {config.episodes} demonstrations",
        {**env, "episodes": config.episodes, "demo_seed": config.demo_seed},
        build.record_demonstrations,
        {TEACHER: stages.teacher},
    )
    rl = {**env, "n_envs": config.n_envs}
    if task == "manipulation" and config.approach_reward:
        rl["approach_reward"] = float(config.approach_reward)
    if config.training_env_kwargs.get(task):  # only then: the other tasks' stages keep their keys
        rl["training_env_kwargs"] = dict(config.training_env_kwargs[task])
    for seed in config.train_seeds:
        cloning = {"env_id": env["env_id"], "algo": BC_ALGO, "epochs": config.bc_epochs, "seed": seed}
        cloning["hyperparams"] = config.actor_hyperparams()
        clone = Stage("clone", f"{task}: bc, seed {seed}", cloning, build.clone, {"demonstrations": demonstrations})
        stages.models["bc", seed] = clone
        for algo in config.finetune_algos:
            settings = {**rl, "algo": algo, "seed": seed, "physics_steps": config.finetune_steps}
            settings["critic_warmup"] = config.critic_warmup
            settings["hyperparams"] = config.actor_hyperparams() | config.finetune_hyperparams
            if task in config.average_checkpoints:  # only then: the other tasks' stages keep their keys
                settings["average_checkpoints"] = True
            stages.models[f"bc-{algo}", seed] = Stage(
                "rl",
                f"{task}: bc-{algo}, seed {seed}",
                settings,
                build.train_rl,
                {TEACHER: stages.teacher, "clone": clone},
            )
        for algo in config.scratch_algos:
            settings = {**rl, "algo": algo, "seed": seed, "physics_steps": config.rl_steps, "critic_warmup": 0}
            settings["hyperparams"] = config.scratch_hyperparams_at(0)
            stages.models[algo, seed] = Stage(
                "rl", f"{task}: {algo}, seed {seed}", settings, build.train_rl, {TEACHER: stages.teacher}
            )


def _evaluation_stages(config: PipelineConfig, task: str, env: dict[str, Any], stages: TaskStages) -> None:
    """Every training run on the validation seeds (when there is a choice) and the test seeds; the wave and the
    teacher on the test seeds."""
    scoring = {"env_id": env["env_id"], "steps": config.steps, **config.engine_settings()}
    for (method, seed), model in stages.models.items():
        for split in evaluation_splits(config):
            seeds = config.test_seeds if split == "test" else config.validation_seeds
            name = f"{task}: evaluate {method}, seed {seed}, on the {split} seeds"
            settings = {**scoring, "seeds": seeds, "label": f"{STORE}/{model.kind}/{model.key}/{build.MODEL}"}
            stages.evaluations[method, seed, split] = Stage(
                "evaluate", name, settings, build.evaluate_policy, {"model": model}
            )
    wave = {**scoring, "seeds": config.test_seeds, "policy": BASELINE, "label": BASELINE}
    wave["env_kwargs"] = {"n_robots": config.n_robots, **PIPELINE_ENV_KWARGS}
    if "robot_model" in scoring:
        wave["env_kwargs"]["robot_model"] = scoring["robot_model"]
    stages.evaluations[BASELINE, None, "test"] = Stage(
        "evaluate", f"{task}: evaluate the wave", wave, build.evaluate_policy
    )
    if TEACHER in config.methods():
        stages.evaluations[TEACHER, None, "test"] = Stage(
            "evaluate",
            f"{task}: evaluate the teacher",
            {**env, "seeds": config.test_seeds, "label": TEACHER},
            build.evaluate_policy,
            {TEACHER: stages.teacher},
        )


def shipped_stages(config: PipelineConfig, shipped: Sequence[ShippedModel]) -> list[tuple[Stage, str, str]]:
    """(evaluation stage, report label, file name in ``eval/shipped``) of each shipped model on the test seeds, and
    of the wave on the ids of theirs that the run's tasks do not cover (the bar of their rows), all on the paddle
    model (a model learned on the disk model runs there as it is). A model is keyed, and named, by its content's
    SHA-256: a model replaced in ``models/`` is evaluated again, beside the old one."""
    scoring = {"steps": config.steps, "seeds": config.test_seeds}
    own = {config.env_id(task) for task in config.tasks}
    out = []
    for env_id in dict.fromkeys(model.env_id for model in shipped if model.env_id not in own):
        settings = {**scoring, "env_id": env_id, "policy": BASELINE, "label": BASELINE}
        settings["env_kwargs"] = {"n_robots": config.n_robots, **PIPELINE_ENV_KWARGS}
        settings["env_kwargs"]["robot_model"] = SHIPPED_ROBOT_MODEL  # as the shipped rows, whatever the run's engine
        stage = Stage("evaluate", f"{env_id}: evaluate the wave", settings, build.evaluate_policy)
        out.append((stage, BASELINE, f"{BASELINE}-{env_id.removeprefix('dpr/')}.json"))
    for model in shipped:
        digest = file_sha256(model.path)
        settings = {**scoring, "env_id": model.env_id, "sha256": digest, "label": str(model.path)}
        settings["env_kwargs"] = {"robot_model": SHIPPED_ROBOT_MODEL}  # the wave's, whatever model it learned on
        stage = Stage(
            "evaluate",
            f"shipped {model.path.name}",
            settings,
            build.evaluate_policy,
            unkeyed={"path": str(model.path.resolve())},
        )
        out.append((stage, f"shipped {model.method}", f"{model.path.stem}-{digest[:12]}.json"))
    return out


def run_pipeline(
    config: PipelineConfig,
    out: str | Path,
    *,
    shipped: Sequence[ShippedModel] = (),
    backend: Backend = Backend(),
    reuse: Sequence[str | Path] = (),
    show_progress: bool = True,
    log: Callable[[str], None] = lambda line: print(line, file=sys.stderr),
) -> Path:
    """Run (or resume) the pipeline into the run folder ``out`` and return its report folder. ``backend.workers``
    stages run at once, on ``backend.name`` ("local" processes, or "ray": a new local cluster, or the one at
    ``backend.address``).
    ``reuse``: run folders whose stored stages are taken when they match (read, never written). ``shipped`` (a
    model card's entries) are evaluated on the test seeds too, beside the wave, and reported as ``shipped
    <method>``. The same settings give the same report whatever the backend and the number of workers."""
    from dpr.policies.model_file import model_env_kwargs

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ParameterError("out", f"{out} exists and is not a folder")
    for model in shipped:  # a shipped model must run on the pipeline's swarm, or its row means nothing
        model_env_kwargs(model.path, model.env_id, {"n_robots": config.n_robots})
    for folder in reuse:
        if not (Path(folder) / STORE).is_dir():
            raise ParameterError("reuse", f"{folder} holds no {STORE}/ folder; expected a `dpr pipeline` run folder")
    with backend_session(backend.name, backend.workers, backend.address):  # a bad one is refused before any work
        out.mkdir(parents=True, exist_ok=True)
        _join_folder(config, out)
        started = time.perf_counter()
        graph = {task: task_stages(config, task) for task in config.tasks}
        extra = shipped_stages(config, shipped)
        targets = [
            stage
            for stages in graph.values()
            for stage in (stages.teacher, *stages.candidates.values(), *stages.evaluations.values())
        ]
        targets += [stage for stages in graph.values() for stage in stages.models.values()]
        store = StageStore(out / STORE, [Path(folder) / STORE for folder in reuse])
        run_stages(
            [*targets, *(stage for stage, _, _ in extra)],
            store,
            backend=backend.name,
            workers=backend.workers,
            address=backend.address,
            show_progress=show_progress,
            log=log,
        )
    with FolderLock(out / SETTINGS_LOCK, wait=True):  # one run at a time names its outputs and writes the report
        folder_config = _folder_config(config, out)  # with the tasks of runs that joined the folder meanwhile
        for task, stages in graph.items():
            _record_task(config, task, stages, store, out, log)
        shipped_evaluations = []
        for stage, label, name in extra:
            _name(store.path(stage) / build.EVALUATION, out / "eval" / "shipped" / name, log)
            shipped_evaluations.append((out / "eval" / "shipped" / name, label))
        return _write_report(folder_config, out, shipped_evaluations, started, log)


def _join_folder(config: PipelineConfig, out: Path) -> None:
    """Record ``config`` in ``out/pipeline.yaml``, adding its tasks to those of a run already there, whose other
    settings must be the same (a ParameterError naming them otherwise)."""
    path = out / "pipeline.yaml"
    with FolderLock(out / SETTINGS_LOCK, wait=True):
        settings = asdict(config)
        if path.exists():
            record = load_yaml(path, "out", MAX_RECORD_BYTES) or {}
            earlier = record.get("config") if isinstance(record.get("config"), dict) else {}
            earlier = {**asdict(PipelineConfig()), **earlier}  # a setting added since that run had its default
            differ = [
                f"{name}: {earlier.get(name)!r} there, {value!r} here"
                for name, value in settings.items()
                if name != "tasks" and earlier.get(name) != value
            ]
            if differ:
                raise ParameterError(
                    "out",
                    f"{out} holds a pipeline run with other settings ({path}: {'; '.join(differ)}); use a new folder "
                    "(--reuse this one to take the stages they share), or the same settings",
                )
            tasks = [*earlier["tasks"], *(task for task in config.tasks if task not in earlier["tasks"])]
            settings["tasks"] = tasks
            if tasks == earlier["tasks"]:
                return
            record["config"] = settings
        else:
            record = {"config": settings, "started": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
        record["rl_steps"] = config.rl_steps
        atomic_write_text(path, yaml.safe_dump(record, sort_keys=False))


def _folder_config(config: PipelineConfig, out: Path) -> PipelineConfig:
    """``config`` with the tasks recorded in ``out/pipeline.yaml``: those of every run into the folder so far."""
    return replace(config, tasks=list(load_yaml(out / "pipeline.yaml", "out", MAX_RECORD_BYTES)["config"]["tasks"]))


def _record_task(
    config: PipelineConfig, task: str, stages: TaskStages, store: StageStore, out: Path, log: Callable[[str], None]
) -> None:
    """Give ``task``'s models and evaluations their readable names, choose each method's canonical model (its median
    run on the validation seeds; one training seed is its own) and record the choices in ``choices.yaml``."""
    before = load_choices(out)
    choices = dict(before)
    if len(config.teachers()) > 1:
        chosen = load_yaml(store.path(stages.teacher) / build.TEACHER_FILE, "out", MAX_RECORD_BYTES)
        choices[f"{task}-{TEACHER}"] = chosen
    for stem, stage in stages.candidates.items():
        _name(
            store.path(stage) / build.EVALUATION,
            evaluation_path(out, task, f"{TEACHER}-{stem}", None, "validation"),
            log,
        )
    for (method, seed), stage in stages.models.items():
        _name(store.path(stage) / build.MODEL, model_path(out, task, method, seed), log)
    for (method, seed, split), stage in stages.evaluations.items():
        _name(store.path(stage) / build.EVALUATION, evaluation_path(out, task, method, seed, split), log)
    for method in config.learned_methods():
        if len(config.train_seeds) == 1:
            (chosen_seed,) = config.train_seeds
            medians = {chosen_seed: None}
        else:
            medians = {
                seed: build.median_score(evaluation_path(out, task, method, seed, "validation"))
                for seed in config.train_seeds
            }
            ranked = sorted(medians, key=lambda seed: (medians[seed], seed))
            chosen_seed = ranked[(len(ranked) - 1) // 2]  # the median run (the lower one of an even count)
        choices[f"{task}-{method}"] = {"chosen_seed": chosen_seed, "validation_medians": medians}
        chosen_model = store.path(stages.models[method, chosen_seed]) / build.MODEL
        _name(chosen_model, model_path(out, task, method, None), log)
    if choices != before:
        save_choices(out, choices)


def _name(source: Path, name: Path, log: Callable[[str], None]) -> None:
    """Give the stored file ``source`` the readable ``name`` too (a hard link where the file system allows, else a
    copy); a name that holds other content (a stage built again) is replaced, and the log says so."""
    if name.exists():
        if name.samefile(source) or name.read_bytes() == source.read_bytes():
            return
        log(f"dpr pipeline: {name} differs from {source}, which replaces it")
    name.parent.mkdir(parents=True, exist_ok=True)
    partial = name.with_name(f".{name.name}.partial")
    partial.unlink(missing_ok=True)
    try:
        os.link(source, partial)
    except OSError:
        shutil.copyfile(source, partial)
    partial.replace(name)


def _write_report(
    config: PipelineConfig,
    out: Path,
    shipped: list[tuple[Path, str]],
    started: float,
    log: Callable[[str], None],
) -> Path:
    """The report of every task of the folder whose test evaluations all exist (a task another run is still making
    joins it when that run ends), with the shipped models' rows; an existing report is kept."""
    from dpr.evaluation.report import REPORT_FILES, write_report

    sources: list[tuple[Path, str]] = []
    for task in config.tasks:
        files = [(evaluation_path(out, task, method, seed, "test"), method) for method, seed in tested_runs(config)]
        if all(path.exists() for path, _ in files):
            sources += files
    sources += shipped
    report = report_folder(out, [path for path, _ in sources], log)
    if (report / REPORT_FILES[0]).exists():
        log(f"dpr pipeline: report: {report} exists, skipped")
    else:
        write_report([path for path, _ in sources], report, labels=[label for _, label in sources], root=out)
    log(f"dpr pipeline: done in {time.perf_counter() - started:.0f} s; report in {report}")
    return report
