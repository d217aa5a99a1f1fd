#!/usr/bin/env python
"""Learning without demonstrations: PPO from scratch on the batched disk engine, then on the pymunk paddle model.

For each task and training seed, four steps, each skipped when its output is there (so a stopped campaign goes on
where it stopped when run again):

1. ``pretrain``: ``dpr train --engine batched --robot-model disk`` (the swarm actor, deciding every 6 physics steps,
   on ``--num-envs`` envs in one call);
2. ``zero-shot``: that actor, unchanged, on the paddle model over the validation seeds;
3. ``finetune``: ``dpr finetune --from`` it on the paddle model (the disk-pretraining recipe of the research log);
4. ``validation``: the fine-tuned actor on the validation seeds;

and steps 3 and 4 again for each further fine-tuning round (``--finetune-rounds``; Gate's default 2), each from the
actor the round before ships, in ``finetune-2``, ``finetune-3``, ...

``--report`` then prints, per task, each run's validation medians and the median run on them (the one to ship), and
with ``--test`` scores every run on the test seeds beside the paddle wave and gives the median run's score. A run's
model is its actor, pretrained or after any fine-tuning round, that scored highest on the validation seeds.

    python tools/disk_ppo.py --tasks navigation unresponsive --seeds 0 1 2 --out runs/disk-ppo
    python tools/disk_ppo.py --out runs/disk-ppo --report --test

Pretraining on a variant of the task (the experience only; validation and test run the task as it is):

    python tools/disk_ppo.py --tasks gate --pretrain-env-kwarg gate_width=250 --out runs/disk-ppo-gate-w250

The shipped runs pretrained on one torch thread (``OMP_NUM_THREADS=1``); more threads run faster and sum in another
order, so a run differs from theirs in the last digits at first and, over a run, in more.

Another fine-tuning recipe on the same pretrained actors (read from ``--pretrained-in``, never written):

    python tools/disk_ppo.py --tasks navigation --pretrained-in runs/disk-ppo --out runs/disk-ppo-lr3e-4 \
        --finetune-hyperparam learning_rate=3e-4
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
from pathlib import Path

ENVS = {
    "navigation": "dpr/Navigation-v0",
    "gate": "dpr/Gate-v2",
    "unresponsive": "dpr/Unresponsive-v0",
    "manipulation": "dpr/Manipulation-v0",
}
VALIDATION = "200-219"  # the full preset's validation seeds
TEST = "300-349"  # and its test seeds
# Per task, what the full preset gives its RL runs (dpr/pipeline/presets/full.yaml); the scores stay the task's own.
# Manipulation's learners are also paid for the swarm's approach to the ball (approach_reward). Gate's fine-tunes
# gather experience with the walls drawn 5-200 units ahead and keep the mean of their weights along the run
# (docs/learning.md: fine-tuned on the walls at 5 alone, PPO pulls Gate's actors down).
TASK_ENV_KWARGS = {"manipulation": ["--env-kwarg", "approach_reward=1.0"]}
TASK_FINETUNE_ARGS = {"gate": ["--training-env-kwarg", "gate_distance=[5, 200]", "--average-checkpoints"]}
FINETUNED_MODEL = {"gate": "averaged_model.zip"}  # the file a task's fine-tune ships (else model.zip)
# Gate's actors, pretrained twice as long, run nearer the paddle wave zero-shot (research log, disk-pretraining)
PRETRAIN_STEPS, TASK_PRETRAIN_STEPS = 600_000, {"gate": 1_200_000}
# Gate's disk swarms squeeze through the opening less than the paddle swarms do; pretrained with it 200 wide (150 in
# the task), Gate's actors run nearer the paddle wave (research log, disk-pretraining)
TASK_PRETRAIN_ENV_KWARGS = {"gate": ["gate_width=200"]}
# Gate's fine-tunes gain on every run from 100,000 to 300,000 paddle steps (research log, disk-pretraining)
FINETUNE_STEPS, TASK_FINETUNE_STEPS = 100_000, {"gate": 300_000}
# Gate's actors gain again from a second round of the fine-tune, started from the first one's weights' mean (research
# log, disk-pretraining)
FINETUNE_ROUNDS, TASK_FINETUNE_ROUNDS = 1, {"gate": 2}
FINETUNE_HYPERPARAMS = ["gamma=0.941", "n_steps=512", "batch_size=128", "n_epochs=10", "policy=SwarmPolicy"]


def dpr(*arguments: str) -> None:
    command = [sys.executable, "-m", "dpr.cli", *arguments]
    print("+", " ".join(command[2:]), file=sys.stderr, flush=True)
    subprocess.run(command, check=True)


def evaluate(model: Path, env_id: str, seeds: str, out: Path) -> None:
    if not out.exists():
        dpr("evaluate", "--policy", str(model), "--env", env_id, "--robot-model", "paddle", "--seeds", seeds,
            "--json", str(out))  # fmt: skip


def stopped(run_dir: Path, batched: bool) -> bool:
    """Whether ``run_dir`` keeps the snapshot of a stopped run that `dpr train|finetune --resume` goes on from."""
    from dpr.rl.batched_resume import snapshot_file
    from dpr.rl.resume import has_snapshot

    return snapshot_file(run_dir).is_file() if batched else has_snapshot(run_dir)


def finished(run_dir: Path, batched: bool) -> bool:
    """A run that wrote its model and keeps no snapshot to resume from (a stopped run keeps one)."""
    return (run_dir / "model.zip").exists() and not stopped(run_dir, batched)


def pretrain_folder(args, folder: Path) -> Path:
    """Where the run ``folder``'s pretrained actor is: in it, or in the same run under ``--pretrained-in``."""
    return (args.pretrained_in / folder.relative_to(args.out) if args.pretrained_in else folder) / "pretrain"


def run(task: str, seed: int, args) -> None:
    env_id, folder = ENVS[task], args.out / task / f"seed-{seed}"
    pretrain = pretrain_folder(args, folder)
    if args.pretrained_in:
        if not finished(pretrain, batched=True):
            raise SystemExit(f"--pretrained-in: {pretrain} holds no finished pretraining; run it there first")
        folder.mkdir(parents=True, exist_ok=True)
        zero_shot = pretrain.parent / "zero_shot_validation.json"
        if zero_shot.exists() and not (folder / zero_shot.name).exists():
            shutil.copy(zero_shot, folder / zero_shot.name)
    elif not finished(pretrain, batched=True):
        resume = ["--resume"] if stopped(pretrain, batched=True) else []
        dpr("train", "--algo", "ppo", "--engine", "batched", "--robot-model", "disk", "--env", env_id,
            "--timesteps", str(pretrain_steps(task, args)), "--n-envs", str(args.num_envs), "--seed", str(seed),
            *TASK_ENV_KWARGS.get(task, []), *pretrain_env_kwargs(task, args), *(["--compile"] if args.compile else []),
            *repeated("--hyperparam", args.pretrain_hyperparam),
            "--out", str(pretrain), *resume)  # fmt: skip
    evaluate(pretrain / "model.zip", env_id, VALIDATION, folder / "zero_shot_validation.json")
    if finetune_steps(task, args) == 0:
        return
    start, hyper = pretrain / "model.zip", repeated("--hyperparam", FINETUNE_HYPERPARAMS + args.finetune_hyperparam)
    for stage in finetune_stages(task, args):
        finetune = folder / stage
        if not finished(finetune, batched=False):
            dpr("finetune", "--from", str(start), "--env", env_id, "--robot-model", "paddle",
                "--timesteps", str(finetune_steps(task, args)), "--critic-warmup", "1666", "--seed", str(seed),
                *hyper, "--exploration-temperature", str(args.finetune_temperature),
                *TASK_ENV_KWARGS.get(task, []), *TASK_FINETUNE_ARGS.get(task, []), "--out", str(finetune),
                *(["--resume"] if stopped(finetune, batched=False) else []))  # fmt: skip
        start = finetune / model_file(task, stage)
        evaluate(start, env_id, VALIDATION, folder / validation_file(stage))


def pretrain_env_kwargs(task: str, args) -> list[str]:
    """The task's pretraining kwargs, then ``--pretrain-env-kwarg`` (the later wins), as `dpr train`'s
    ``--training-env-kwarg``: the pretraining's experience only (the model records the task's own kwargs, so
    validation and test run the task as it is)."""
    return repeated("--training-env-kwarg", TASK_PRETRAIN_ENV_KWARGS.get(task, []) + args.pretrain_env_kwarg)


def repeated(flag: str, values: list[str]) -> list[str]:
    """``flag`` before each of ``values``: a repeatable option of the dpr command line."""
    return [item for value in values for item in (flag, value)]


def pretrain_steps(task: str, args) -> int:
    """``--pretrain-steps`` where given, else the task's own."""
    return TASK_PRETRAIN_STEPS.get(task, PRETRAIN_STEPS) if args.pretrain_steps is None else args.pretrain_steps


def finetune_steps(task: str, args) -> int:
    """``--finetune-steps`` where given, else the task's own."""
    return TASK_FINETUNE_STEPS.get(task, FINETUNE_STEPS) if args.finetune_steps is None else args.finetune_steps


def finetune_stages(task: str, args) -> list[str]:
    """The run's fine-tuning rounds' folders: ``finetune``, then ``finetune-2``, ... (``--finetune-rounds`` where
    given, else the task's own)."""
    rounds = TASK_FINETUNE_ROUNDS.get(task, FINETUNE_ROUNDS) if args.finetune_rounds is None else args.finetune_rounds
    return ["finetune"] + [f"finetune-{r}" for r in range(2, rounds + 1)]


def validation_file(stage: str) -> str:
    """Where a stage's validation medians are: ``zero_shot_validation.json`` for the pretrained actor,
    ``finetuned_validation.json`` for the first fine-tune, ``finetuned-2_validation.json`` for the second, ..."""
    return (
        "zero_shot_validation.json"
        if stage == "pretrain"
        else f"{stage.replace('finetune', 'finetuned')}_validation.json"
    )


def model_file(task: str, stage: str) -> str:
    """The file a stage ships: the pretraining's model, or the task's fine-tuned file (:data:`FINETUNED_MODEL`)."""
    return "model.zip" if stage == "pretrain" else FINETUNED_MODEL.get(task, "model.zip")


def median_displacement(path: Path) -> float | None:
    if not path.exists():
        return None
    episodes = json.loads(path.read_text())
    episodes = episodes.get("episodes", episodes) if isinstance(episodes, dict) else episodes
    return statistics.median(e["projected_displacement"] for e in episodes)


def report(args) -> None:
    for task in args.tasks:
        env_id, runs = ENVS[task], sorted((args.out / task).glob("seed-*"))
        stages = ["pretrain", *finetune_stages(task, args)]
        scores, done = {}, {}
        for folder in runs:
            medians = {stage: median_displacement(folder / validation_file(stage)) for stage in stages}
            print(f"{task} {folder.name}: {', '.join(f'{s} {m}' for s, m in medians.items())} (validation medians)")
            if medians["pretrain"] is None:
                continue
            done[folder] = [stage for stage in stages if medians[stage] is not None]
            # each run's model is its actor that scored highest on the validation seeds (on a tie, the later one)
            best = max(reversed(done[folder]), key=lambda stage: medians[stage])
            scores[folder] = (medians[best], best)
        if not scores:
            continue
        ordered = sorted(scores, key=lambda f: scores[f][0])
        chosen = ordered[len(ordered) // 2]
        print(f"{task}: the median run on validation seeds, the one to ship: {chosen.name} ({scores[chosen][1]})")
        furthest = max(done.values(), key=len)[-1]
        reached = sum(stages_done[-1] == furthest for stages_done in done.values())
        if args.test and reached < len(scores):
            print(f"{task}: not tested, {reached} of its {len(scores)} runs reached {furthest}")
        elif args.test:
            models = {}
            for folder, (_, stage) in scores.items():
                stage_folder = pretrain_folder(args, folder) if stage == "pretrain" else folder / stage
                models[folder] = stage_folder / model_file(task, stage)
            score_every_run_on_test_seeds(task, env_id, models, args.out)


def score_every_run_on_test_seeds(task: str, env_id: str, models: dict[Path, Path], out: Path) -> None:
    """Each run's model on the test seeds beside the paddle wave, and the median run's score (the issue's figure)."""
    wave = out / task / "wave_test.json"
    if not wave.exists():
        dpr("evaluate", "--policy", "wave", "--env", env_id, "--robot-model", "paddle", "--seeds", TEST,
            "--json", str(wave))  # fmt: skip
    theirs = median_displacement(wave)
    ratios = []
    for folder, model in sorted(models.items()):
        test = folder / f"test_{model.parent.name}.json"
        evaluate(model, env_id, TEST, test)
        ours = median_displacement(test)
        ratios.append(ours / theirs)
        print(f"{task} {folder.name} ({model}): test median {ours:.1f}, wave {theirs:.1f}, {ours / theirs:.0%}")
    print(f"{task}: median of {len(ratios)} runs on the test seeds: {statistics.median(ratios):.0%} of the paddle "
          f"wave")  # fmt: skip


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", nargs="+", choices=list(ENVS), default=list(ENVS))
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--out", type=Path, default=Path("runs/disk-ppo"))
    parser.add_argument(
        "--pretrain-steps",
        type=int,
        help=f"env steps on the batched engine (default: {PRETRAIN_STEPS:,}; Gate {TASK_PRETRAIN_STEPS['gate']:,})",
    )
    parser.add_argument(
        "--pretrain-env-kwarg",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a kwarg of the pretraining's envs only, over the task's own (Gate: gate_width=200, a wider opening "
        "than the task's 150); repeatable",
    )
    parser.add_argument(
        "--pretrain-hyperparam",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a pretraining hyperparameter over the batched preset's (e.g. ent_coef=0.01); repeatable",
    )
    parser.add_argument("--num-envs", type=int, default=256)
    parser.add_argument("--compile", action="store_true", help="torch.compile the batched physics")
    parser.add_argument(
        "--finetune-steps",
        type=int,
        help=f"env steps on paddle (0: none; default: {FINETUNE_STEPS:,}; Gate {TASK_FINETUNE_STEPS['gate']:,})",
    )
    parser.add_argument(
        "--finetune-rounds",
        type=int,
        help=f"fine-tuning rounds, each from the last one's actor (default: {FINETUNE_ROUNDS}; Gate "
        f"{TASK_FINETUNE_ROUNDS['gate']})",
    )
    parser.add_argument(
        "--finetune-hyperparam",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a fine-tuning hyperparameter over the recipe's (e.g. learning_rate=3e-4); repeatable",
    )
    parser.add_argument(
        "--finetune-temperature",
        type=float,
        default=1.0,
        help="the pretrained actor's logits divided by this for the fine-tune (dpr finetune --exploration-temperature)",
    )
    parser.add_argument(
        "--pretrained-in", type=Path, help="fine-tune the pretrained actors of this campaign folder (read only)"
    )
    parser.add_argument("--report", action="store_true", help="print the runs' validation medians")
    parser.add_argument("--test", action="store_true", help="with --report: score every run on the test seeds")
    args = parser.parse_args()
    if args.finetune_rounds is not None and args.finetune_rounds < 1:
        parser.error(f"--finetune-rounds: expected 1 or more, got {args.finetune_rounds} (--finetune-steps 0: none)")
    if args.report:
        report(args)
        return 0
    for task in args.tasks:
        for seed in args.seeds:
            run(task, seed, args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
