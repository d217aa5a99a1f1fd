"""What each kind of pipeline stage does (:mod:`dpr.pipeline.stages` builders): choose a teacher, record demonstrations,
clone them, train with RL (fine-tuning a clone, or from scratch), evaluate a policy. Each reads only its settings
and the output folders of the stages it needs, and writes only into its own output and work folders; the stage
graph itself is :mod:`dpr.pipeline.campaign`'s.

Outputs: ``teacher.yaml`` (the chosen hold and bin width, every candidate's median), ``dataset/`` (LeRobot v3.0),
``model.zip`` (no optimizer state) with the run's ``config.yaml``, ``evaluation.json`` (``dpr evaluate --json``)."""

from __future__ import annotations

import shutil
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from dpr.atomic import atomic_write_text
from dpr.bounded_io import load_yaml
from dpr.envs import episode_steps
from dpr.limits import MAX_RECORD_BYTES
from dpr.pipeline.config import TEACHER, Teacher, learner_env_kwargs
from dpr.rl.recipe import physics_discount

MODEL = "model.zip"
EVALUATION = "evaluation.json"
TEACHER_FILE = "teacher.yaml"
DATASET = "dataset"


def read_teacher(folder: Path) -> Teacher:
    """The teacher a ``teacher`` stage chose."""
    chosen = load_yaml(folder / TEACHER_FILE, "out", MAX_RECORD_BYTES)
    return Teacher(int(chosen["hold_steps"]), float(chosen["bin_width"]))


def learner_kwargs(settings: Mapping[str, Any], teacher: Teacher) -> dict[str, Any]:
    """The env kwargs of the demonstrations and every learner of the task whose teacher is ``teacher``."""
    return learner_env_kwargs(settings["action_repeat"], teacher.hold)


def choose_teacher(settings: Mapping[str, Any], inputs: Mapping[str, Path], out: Path, work: Path, _: bool) -> None:
    """Among the candidates (``settings["candidates"]``: [hold, bin width] pairs), the one with the highest median
    on its evaluation (``inputs["candidate<i>"]``; the first listed of equal ones). One candidate is no choice."""
    candidates = [Teacher(int(hold), float(width)) for hold, width in settings["candidates"]]
    medians = {}
    for index, teacher in enumerate(candidates):
        if f"candidate{index}" in inputs:
            medians[teacher] = median_score(inputs[f"candidate{index}"] / EVALUATION)
    chosen = max(candidates, key=lambda teacher: medians.get(teacher, 0.0))  # max keeps the first of equal ones
    record = {
        "hold_steps": chosen.hold,
        "bin_width": chosen.bin_width,
        "policy": chosen.policy,
        "validation_medians": {teacher.stem: medians[teacher] for teacher in candidates if teacher in medians},
    }
    atomic_write_text(out / TEACHER_FILE, yaml.safe_dump(record, sort_keys=False))


def median_score(evaluation: Path) -> float:
    """The median projected displacement over an evaluation file's episodes (read through the report's checked
    loader: a damaged file is an error naming it)."""
    import numpy as np

    from dpr.evaluation.report import load_evaluation

    return float(np.median([episode["projected_displacement"] for episode in load_evaluation(evaluation)["episodes"]]))


def record_demonstrations(
    settings: Mapping[str, Any], inputs: Mapping[str, Path], out: Path, work: Path, show_progress: bool
) -> None:
    """``settings["episodes"]`` demonstrations of the chosen teacher from ``demo_seed`` on, as its learners run. They
    are recorded in the work folder, so that a stopped collection goes on from its saved episodes."""
    from tqdm import tqdm

    from dpr.datasets.collect import CollectSpec, RolloutWorkers, collect

    teacher = read_teacher(inputs[TEACHER])
    kwargs = learner_kwargs(settings, teacher)
    spec = CollectSpec(
        settings["env_id"],
        policy=teacher.policy,
        n_robots=settings["n_robots"],
        robot_model=settings.get("robot_model", "paddle"),
        steps=episode_steps(kwargs, settings["steps"]),
        env_kwargs=kwargs,
        engine=settings.get("engine", "pymunk"),
    )
    partial = work / DATASET
    with tqdm(total=settings["episodes"], desc="collect", unit="episode", disable=not show_progress) as bar:
        summary = collect(
            partial,
            spec,
            settings["episodes"],
            seed=settings["demo_seed"],
            workers=RolloutWorkers(device=settings.get("device", "cpu")),
            progress=lambda record, index: bar.update(1),
        )
    if summary.interrupted:
        raise KeyboardInterrupt
    partial.replace(out / DATASET)


def clone(settings: Mapping[str, Any], inputs: Mapping[str, Path], out: Path, work: Path, show_progress: bool) -> None:
    """Behaviour cloning of the demonstrations (``inputs["demonstrations"]``) into an actor-critic."""
    from dpr.imitation.bc import behaviour_clone
    from dpr.imitation.config import CloneConfig

    config = CloneConfig(
        algo=settings["algo"], epochs=settings["epochs"], seed=settings["seed"], hyperparams=settings["hyperparams"]
    )
    result = behaviour_clone(
        inputs["demonstrations"] / DATASET,
        settings["env_id"],
        config,
        out=_fresh(work / "run"),
        show_progress=show_progress,
        log=_quiet,
    )
    _keep_model(result.model_path, out)


def train_rl(
    settings: Mapping[str, Any], inputs: Mapping[str, Path], out: Path, work: Path, show_progress: bool
) -> None:
    """RL on the learners' env: from scratch, or fine-tuning the clone (``inputs["clone"]``) after a critic
    warm-up. Budgets are physics steps, turned into decisions here. A run stopped part-way goes on from its last
    snapshot in the work folder (:mod:`dpr.rl.resume`) to the model it would have made without the stop."""
    from dpr.policies.hyperparams import DEFAULT_PRESET, FINETUNE_PRESET
    from dpr.rl.train import TrainConfig, averaged_checkpoints

    teacher = read_teacher(inputs[TEACHER])
    kwargs = learner_kwargs(settings, teacher)
    repeat = kwargs.get("action_repeat", 1)
    if settings.get("approach_reward"):
        kwargs["approach_reward"] = float(settings["approach_reward"])
    hyperparams = dict(settings["hyperparams"])
    fine_tuning = "clone" in inputs
    if fine_tuning:
        hyperparams = {"gamma": physics_discount(repeat), **hyperparams}
    config = TrainConfig(
        algo=settings["algo"],
        env_id=settings["env_id"],
        n_robots=settings["n_robots"],
        robot_model=settings.get("robot_model", "paddle"),
        seed=settings["seed"],
        n_envs=settings["n_envs"],
        env_processes=False,  # one CPU per stage
        eval_episodes=0,  # the pipeline scores every run on its validation and test seeds instead
        timesteps=settings["physics_steps"] // repeat,
        steps_per_episode=episode_steps(kwargs, settings["steps"]),
        env_kwargs=kwargs,
        training_env_kwargs=dict(settings.get("training_env_kwargs", {})),
        hyperparams=hyperparams,
        preset=FINETUNE_PRESET if fine_tuning else DEFAULT_PRESET,
        init_from=str(inputs["clone"] / MODEL) if fine_tuning else None,
        critic_warmup=settings["critic_warmup"] // repeat if fine_tuning else 0,
        **_batched_training(settings, fine_tuning),
    )
    result = _train_resuming(config, work / "run", show_progress)
    if result.interrupted:
        raise KeyboardInterrupt
    averaged = averaged_checkpoints(result.run_dir) if settings.get("average_checkpoints") else ()
    _keep_model(result.model_path, out, averaged)


def _batched_training(settings: Mapping[str, Any], fine_tuning: bool) -> dict[str, Any]:
    """The TrainConfig fields of an RL run from scratch on the batched engine: the tensor PPO for PPO, SB3's own
    learner for the others. Fine-tuning runs on pymunk (the batched engine trains from scratch)."""
    if settings.get("engine") != "batched" or fine_tuning:
        return {}
    learner = "torch" if settings["algo"] == "ppo" else "sb3"
    return {"engine": "batched", "device": settings["device"], "learner": learner}


def _train_resuming(config, run: Path, show_progress: bool):
    """Train ``config`` into ``run``, going on from its snapshot when a stopped run of it left one there."""
    from dpr.rl.train import resumable, train

    if config.engine == "batched":
        from dpr.rl.batched_train import batched_resumable, train_batched

        resume = run.is_dir() and batched_resumable(run, config)
        if not resume:
            _fresh(run)
        return train_batched(config, run, show_progress=show_progress, resume=resume, log=_quiet)
    resume = run.is_dir() and resumable(run, config)
    if not resume:
        _fresh(run)  # stopped before its first snapshot: nothing to go on from
    return train(config, run, show_progress=show_progress, resume=resume, log=_quiet)


def evaluate_policy(
    settings: Mapping[str, Any], inputs: Mapping[str, Path], out: Path, work: Path, show_progress: bool
) -> None:
    """Score a policy on ``settings["seeds"]``: a trained model (``inputs["model"]``), the chosen teacher
    (``inputs["teacher"]``, run as its learners run), a candidate teacher, a shipped model file, or a scripted
    policy on the pipeline's env. The file names the policy as ``settings["label"]``, the same wherever it ran."""
    from tqdm import tqdm

    from dpr.evaluation.scoring import evaluate, policy_env_kwargs, save_evaluation

    env_kwargs = settings.get("env_kwargs")
    if "model" in inputs:
        policy = str(inputs["model"] / MODEL)
    elif TEACHER in inputs or "candidate" in settings:  # the chosen teacher, or a candidate: as its learners run
        teacher = read_teacher(inputs[TEACHER]) if TEACHER in inputs else Teacher(*settings["candidate"])
        policy, env_kwargs = teacher.policy, {"n_robots": settings["n_robots"], **learner_kwargs(settings, teacher)}
        if "robot_model" in settings:
            env_kwargs["robot_model"] = settings["robot_model"]
    else:
        policy = settings["path"] if "path" in settings else settings["policy"]  # a shipped model file, or by name
    env_id = settings["env_id"]
    kwargs = policy_env_kwargs(policy, env_id, env_kwargs)
    if settings.get("engine") == "batched":
        from dpr.evaluation.batched import evaluate_batched

        results = evaluate_batched([env_id], policy, settings["seeds"], settings["steps"], kwargs, settings["device"])
    else:
        with tqdm(total=len(settings["seeds"]), desc="evaluate", unit="episode", disable=not show_progress) as bar:
            results = evaluate(
                [env_id],
                policy,
                settings["seeds"],
                steps=settings["steps"],
                env_kwargs=kwargs,
                progress=lambda r: bar.update(1),
            )
    for result in results:
        result.policy = settings["label"]
    save_evaluation(
        out / EVALUATION, settings["label"], [env_id], kwargs, settings["steps"], settings["seeds"], results
    )


def _keep_model(model: Path, out: Path, average_with: Sequence[Path] = ()) -> None:
    """The run's model without its optimizer's state (its weights averaged with ``average_with``'s), and its
    config.yaml."""
    from dpr.policies.sb3 import save_slim_copy

    save_slim_copy(model, out / MODEL, average_with)
    shutil.copyfile(model.parent / "config.yaml", out / "config.yaml")


def _fresh(folder: Path) -> Path:
    if folder.exists():
        shutil.rmtree(folder)
    return folder


def _quiet(line: str) -> None:
    """The stage's own log lines are dropped: the pipeline logs one line per stage."""
