#!/usr/bin/env python
"""Train a recipe of ``tools/lerobot_recipes`` with LeRobot's own ``lerobot-train``, resuming when run again, and
score its checkpoints on validation seeds (a learning curve).

Runs in the LeRobot side environment (``make lerobot-env``). From the repository root:

    .venv-lerobot/bin/python tools/lerobot_recipe.py train --recipe diffusion_navigation \\
        --dataset runs/lerobot/nav80 --seed 0 --out runs/lerobot/train/diffusion-s0
    .venv-lerobot/bin/python tools/lerobot_recipe.py curve --run runs/lerobot/train/diffusion-s0 \\
        --wave runs/lerobot/eval/wave-val.json

A recipe is a ``lerobot-train --config_path`` file (``tools/lerobot_recipes/<name>.json``) and a row of
``tools/lerobot_recipes/recipes.json``: the env it was chosen on, its robots, the LeRobot versions it was checked
with, its CPU budget and its validation seeds. ``train`` checks all of that before any work (a dataset of another
env or swarm size, a LeRobot version the recipe was not checked with: errors), then runs

    lerobot-train --config_path=<recipe> --dataset.root=DATASET --output_dir=OUT --seed=SEED

or, where OUT already holds a checkpoint, LeRobot's own resume:

    lerobot-train --config_path=OUT/checkpoints/last/pretrained_model/train_config.json --resume=true

and adds the session's CPU seconds to ``OUT/dpr_training.json``. ``curve`` rolls every checkpoint of OUT out on
the validation seeds with ``tools/lerobot_policies.py evaluate`` (files it already wrote are kept) and writes
``OUT/curve.json``: steps, CPU hours and IQM as % of the wave's on the same seeds.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from dpr.policies.registry import LEROBOT_ENV_FILE, LEROBOT_RUN_FOLDER

TOOLS = Path(__file__).resolve().parent
RECIPES = TOOLS / "lerobot_recipes"
LAST = Path("checkpoints") / "last"
RECORD = "dpr_training.json"
AVERAGED_FOLDER = "averaged"  # in a run whose recipe names average_steps: the policy to score and ship
AVERAGED_FILE = "dpr_averaged.json"  # beside averaged weights: the run and the checkpoint steps averaged
STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT)  # passed on to lerobot-train, whose session is then still recorded


def load_recipe(name: str) -> dict:
    """The row ``name`` of recipes.json with ``config`` resolved to its file: a ValueError listing the recipes."""
    rows = json.loads((RECIPES / "recipes.json").read_text())
    if name not in rows:
        raise ValueError(f"--recipe: {name!r} is not a recipe; choose one of {sorted(rows)}")
    return {**rows[name], "name": name, "config": RECIPES / rows[name]["config"]}


def check_lerobot_version(recipe: dict, allow_unchecked: bool = False) -> str:
    """The installed LeRobot version, which must be one the recipe was checked with (else a ValueError that says
    how to get it, unless ``allow_unchecked``)."""
    try:
        version = importlib.metadata.version("lerobot")
    except importlib.metadata.PackageNotFoundError:
        raise ValueError("LeRobot is not installed here: `make lerobot-env` builds its side environment") from None
    checked = recipe["lerobot_versions"]
    if version not in checked and not allow_unchecked:
        raise ValueError(
            f"recipe {recipe['name']} was checked with LeRobot {', '.join(checked)}, and this is LeRobot {version}: "
            "`make lerobot-env` builds the checked one (--allow-unchecked-lerobot runs it anyway)"
        )
    return version


def check_dataset_fits(dataset: Path, recipe: dict) -> None:
    """The dataset must be of the recipe's env and swarm size: a ValueError naming both before any work."""
    sys.path.insert(0, str(TOOLS))
    import lerobot_policies

    from dpr.datasets import features as F
    from dpr.datasets.lerobot import LeRobotReader

    lerobot_policies.check_dataset(dataset)
    reader = LeRobotReader(dataset)
    env_ids = sorted({episode[F.ENV_ID] for episode in reader.episodes})
    robots = json.loads((dataset / "meta" / "info.json").read_text())["features"][F.ACTION]["shape"][0]
    if env_ids != [recipe["env_id"]] or robots != recipe["n_robots"]:
        raise ValueError(
            f"--dataset: {dataset} holds {', '.join(env_ids)} with {robots} robots; recipe {recipe['name']} is for "
            f"{recipe['env_id']} with {recipe['n_robots']}: record that with `dpr collect` or choose its recipe"
        )
    names = json.loads((dataset / "meta" / "info.json").read_text())["features"][F.ACTION]["names"]
    has_phases = all(name.endswith(PHASE_SUFFIX) for name in names)
    if has_phases != (recipe.get("actions") == "phase"):
        wanted = "phases (`tools/lerobot_recipe.py phase-dataset`)" if not has_phases else "0/1 expansions"
        raise ValueError(f"--dataset: recipe {recipe['name']} trains on {wanted}; {dataset} holds the other kind")


def train_command(
    recipe: dict, dataset: Path, out: Path, seed: int, steps: int | None = None, overrides: tuple[str, ...] = ()
) -> list[str]:
    """``lerobot-train``'s command line for a new run of ``recipe`` with LeRobot's own ``--NAME=VALUE``
    ``overrides`` of its config (``policy.horizon=8``), or its resume where ``out`` holds one (whose saved config
    already holds them)."""
    command = [sys.executable, "-m", "lerobot.scripts.lerobot_train"]
    resume_config = out / LEROBOT_RUN_FOLDER / "train_config.json"
    if resume_config.is_file():
        return [*command, f"--config_path={resume_config}", "--resume=true"] + ([f"--steps={steps}"] if steps else [])
    if out.exists():
        raise ValueError(f"--out: {out} exists without a checkpoint to resume from; remove it or choose another")
    command += [
        f"--config_path={recipe['config']}",
        f"--dataset.root={dataset}",
        f"--dataset.repo_id=dpr/{dataset.name}",
    ]
    command += [f"--output_dir={out}", f"--seed={seed}", f"--job_name={out.name}"]
    command += [f"--{override}" for override in overrides]
    return command + ([f"--steps={steps}"] if steps else [])


def trained_steps(out: Path) -> int:
    """The step of the run's last checkpoint (0 without one)."""
    state = out / LAST / "training_state" / "training_step.json"
    return json.loads(state.read_text())["step"] if state.is_file() else 0


def run_to_its_end(command: list[str]) -> int:
    """Run ``command``, passing SIGTERM and SIGINT on to it and waiting for it to stop, so that a stopped session is
    still recorded (its CPU seconds count toward the recipe's budget); returns its exit status."""
    child = subprocess.Popen(command)
    previous = {sig: signal.signal(sig, lambda number, _: child.send_signal(number)) for sig in STOP_SIGNALS}
    try:
        return child.wait()
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def train(
    recipe: dict, dataset: Path, out: Path, seed: int, steps: int | None = None, overrides: tuple[str, ...] = ()
) -> int:
    """Run (or resume) ``recipe`` on ``dataset`` into ``out`` with LeRobot's training; returns its exit status.
    Each session's wall and CPU seconds are added to ``out/dpr_training.json``."""
    check_dataset_fits(dataset, recipe)
    config = json.loads(Path(recipe["config"]).read_text())
    total = steps or config["steps"]
    if trained_steps(out) >= total:
        print(f"{out}: trained {trained_steps(out)} of {total} steps already", file=sys.stderr)
        average_when_done(recipe, out, total)
        return 0
    command = train_command(recipe, dataset, out, seed, steps, overrides)
    print(" ".join(command[1:]), file=sys.stderr)
    started, cpu_before = time.time(), resource.getrusage(resource.RUSAGE_CHILDREN)
    status = run_to_its_end(command)
    cpu = resource.getrusage(resource.RUSAGE_CHILDREN)
    record_path = out / RECORD
    record = (
        json.loads(record_path.read_text()) if record_path.is_file() else {"recipe": recipe["name"], "sessions": []}
    )
    record["sessions"].append({
        "command": command[1:], "exit_status": status, "until_step": trained_steps(out),
        "wall_seconds": round(time.time() - started, 1),
        "cpu_seconds": round(cpu.ru_utime + cpu.ru_stime - cpu_before.ru_utime - cpu_before.ru_stime, 1),
    })  # fmt: skip
    record["cpu_hours"] = round(sum(s["cpu_seconds"] for s in record["sessions"]) / 3600, 3)
    if out.is_dir():
        record_path.write_text(json.dumps(record, indent=2) + "\n")
    if status == 0:
        average_when_done(recipe, out, total)
    return status


def average_when_done(recipe: dict, out: Path, total: int) -> Path | None:
    """The recipe's policy, ``out/averaged``: the mean of the checkpoints its row names (``average_steps``), written
    once the run has trained ``total`` steps and holds them all (a run trained to fewer steps has none)."""
    steps, averaged = recipe.get("average_steps", []), out / AVERAGED_FOLDER
    if not steps or averaged.exists() or trained_steps(out) < total or max(steps) > total:
        return None
    print(f"{averaged}: the mean of the checkpoints at steps {steps}", file=sys.stderr)
    return average(out, steps, averaged)


def _scores(path: Path) -> dict[int, float]:
    return {e["seed"]: e["projected_displacement"] for e in json.loads(path.read_text())["episodes"]}


def curve(
    run: Path, wave: Path, seeds: list[int] | None = None, steps: int = 2500, every: int = 1, **overrides
) -> list[dict]:
    """Every checkpoint of ``run`` (whose step is a multiple of ``every``) scored on ``seeds`` (the recipe's
    validation seeds by default), as IQM % of the wave's IQM on the same seeds (``wave``: ``dpr evaluate --json``
    of the wave on them), with inference-time config ``overrides`` (e.g. ``n_action_steps=1``; then into
    ``curve-<name>-<value>``); writes and returns the rows of ``run/curve.json`` (or ``run/curve-<...>.json``)."""
    sys.path.insert(0, str(TOOLS))
    import lerobot_policies

    wave_scores = _scores(wave)
    seeds = seeds or sorted(wave_scores)  # the seeds evaluated; a row's ratio is over the seeds its file holds
    if missing := sorted(set(seeds) - set(wave_scores)):
        raise ValueError(f"--wave: {wave} has no episode of seeds {missing}")
    batch = json.loads((run / LEROBOT_RUN_FOLDER / "train_config.json").read_text())["batch_size"]
    name = "-".join(["curve", *(f"{key}-{value}" for key, value in sorted(overrides.items()))])
    rows = []
    checkpoints = sorted(p for p in (run / "checkpoints").iterdir() if p.name.isdigit() and int(p.name) % every == 0)
    for checkpoint in checkpoints:
        path = run / name / f"{checkpoint.name}.json"
        if not path.is_file():
            lerobot_policies.evaluate(checkpoint / "pretrained_model", seeds, steps, path, run.name, **overrides)
        row = evaluation_row(int(checkpoint.name) * batch, path, wave)
        rows.append({"step": int(checkpoint.name), **row})
        print(f"{run.name} step {rows[-1]['step']}: {rows[-1]['iqm_percent_of_wave']}% of the wave", file=sys.stderr)
    (run / f"{name}.json").write_text(json.dumps(rows, indent=2) + "\n")
    return rows


def ship(run: Path, out: Path, max_megabytes: float = 10.0) -> Path:
    """The run's last policy (weights as safetensors, config, normaliser) copied to ``out`` with the env it was
    trained on (``dpr_env.json``), so that it scores without its dataset; refused over ``max_megabytes``."""
    import shutil

    sys.path.insert(0, str(TOOLS))
    import lerobot_policies

    folder = lerobot_policies.policy_folder(run)
    dataset = Path(json.loads((folder / "train_config.json").read_text())["dataset"]["root"])
    env_id, env_kwargs = lerobot_policies.policy_env(folder, dataset)
    actions = lerobot_policies.policy_actions(folder, dataset)
    size = sum(p.stat().st_size for p in folder.iterdir()) / 1e6
    if size > max_megabytes:
        raise ValueError(f"{folder} is {size:.1f} MB, over {max_megabytes} MB: train a smaller network")
    shutil.copytree(folder, out)
    (out / LEROBOT_ENV_FILE).write_text(
        json.dumps({"env_id": env_id, "env_kwargs": env_kwargs, "actions": actions}, indent=2) + "\n"
    )
    return out


def average(run: Path, steps: list[int], out: Path) -> Path:
    """The mean of the weights of ``run``'s checkpoints at ``steps``, as a policy folder ``out`` (the last
    checkpoint's folder with its weights replaced), which ``evaluate``, ``curve`` and ``ship`` take like a run.
    LeRobot's Diffusion Policy keeps no moving average of its weights; the mean of the last checkpoints of a cosine
    schedule stands in for one. Refused before any work: an ``out`` that exists, a missing checkpoint, fewer than
    two steps."""
    import shutil

    from safetensors import safe_open
    from safetensors.torch import load_file, save_file

    if out.exists():
        raise ValueError(f"--out: {out} exists; averaging writes a new folder")
    if len(set(steps)) < 2:
        raise ValueError(f"--steps: expected at least two checkpoint steps, got {steps}")
    folders = [run / "checkpoints" / f"{step:06d}" / "pretrained_model" for step in sorted(set(steps))]
    if missing := [str(folder) for folder in folders if not (folder / "model.safetensors").is_file()]:
        raise ValueError(f"--steps: no checkpoint weights at {missing}")
    weights = [load_file(folder / "model.safetensors") for folder in folders]
    if any(w.keys() != weights[-1].keys() for w in weights):
        raise ValueError(f"--steps: the checkpoints of {run} hold different tensors; they are not one run's")
    with safe_open(folders[-1] / "model.safetensors", framework="pt") as last:
        metadata = last.metadata()
    mean = {
        name: (sum(w[name].double() for w in weights) / len(weights)).to(tensor.dtype)
        if tensor.is_floating_point() else tensor
        for name, tensor in weights[-1].items()
    }  # fmt: skip
    partial = out.with_name(out.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)
    shutil.copytree(folders[-1], partial)
    save_file(mean, partial / "model.safetensors", metadata=metadata)
    (partial / AVERAGED_FILE).write_text(json.dumps({"run": str(run), "steps": sorted(set(steps))}, indent=2) + "\n")
    partial.rename(out)
    return out


PHASE_SUFFIX = ".phase"  # the action names of a dataset whose actions are phases (lerobot_policies.PHASE_SUFFIX)


def phases(expand: np.ndarray, cap: int) -> np.ndarray:
    """An episode's 0/1 actions (T, N) as phases: 1 - the decisions until each robot next expands (0 where it
    expands now), capped at ``cap`` decisions, so the action is the phase thresholded at one half, exactly."""
    until = np.full(expand.shape, float(cap), dtype=np.float32)
    nxt = np.full(expand.shape[1], float(cap), dtype=np.float32)
    for t in range(len(expand) - 1, -1, -1):
        nxt = np.where(expand[t] > 0.5, 0.0, np.minimum(nxt + 1, cap))
        until[t] = nxt
    return (1.0 - until).astype(np.float32)


def phase_dataset(dataset: Path, out: Path, cap: int = 4) -> Path:
    """A new dataset at ``out``, written by dpr's writer: ``dataset``'s episodes with :func:`phases` as actions (a
    continuous target the env's 0/1 action is recovered from exactly, by thresholding at one half), the same
    episode rows and env; returns ``out``."""
    from dpr.datasets import features as F
    from dpr.datasets.lerobot import LeRobotReader, LeRobotWriter

    if out.exists():
        raise ValueError(f"--out: {out} exists; choose a new folder")
    reader = LeRobotReader(dataset)
    info = json.loads((dataset / "meta" / "info.json").read_text())
    own = {"index", "episode_index", "frame_index", "timestamp", "task_index"}  # the writer numbers these itself
    features = {key: dict(spec) for key, spec in info["features"].items() if key not in own}
    features[F.ACTION]["names"] = [name.rsplit(".", 1)[0] + PHASE_SUFFIX for name in features[F.ACTION]["names"]]
    writer = LeRobotWriter.create(
        out, fps=info["fps"], features=features, robot_type=info["robot_type"], info_extra={"dpr": info["dpr"]}
    )
    meta_keys = (F.SEED, F.ENV_ID, F.ENV_KWARGS, F.POLICY, F.LABEL_POLICY, F.N_ROBOTS, F.ROBOT_MODEL,
                 *F.METRIC_FIELDS, F.PHYSICS_ERROR, F.MCAP_FILE)  # fmt: skip
    with writer:
        for index, row in enumerate(reader.episodes):
            frames = {key: value for key, value in reader.episode(index).items() if key not in own}
            frames[F.ACTION] = phases(frames[F.ACTION], cap)
            writer.add_frames(frames, task=row["tasks"][0])
            writer.save_episode({key: row[key] for key in meta_keys})
        writer.finalize()
    return out


def evaluation_row(frames: int, evaluation: Path, wave: Path) -> dict:
    """A curve row of one evaluation file (e.g. of BC trained on ``frames`` frames): IQM as % of the wave's."""
    from dpr.evaluation.statistics import iqm

    scores, wave_scores = _scores(evaluation), _scores(wave)
    seeds = sorted(scores)
    ratio = float(iqm(np.array([scores[s] for s in seeds])) / iqm(np.array([wave_scores[s] for s in seeds])))
    median = float(np.median([scores[s] for s in seeds]))
    return {"frames": frames, "seeds": seeds, "median": median, "iqm_percent_of_wave": round(100 * ratio, 1)}


def learning_figure(curves: dict[str, list[dict]], path: Path) -> Path:
    """Score on validation seeds (IQM, % of the wave's) against training frames seen, one line per method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(10, 4.2))
    for label, rows in curves.items():
        rows = sorted(rows, key=lambda row: row["frames"])
        axes.plot([r["frames"] for r in rows], [r["iqm_percent_of_wave"] for r in rows], marker="o", label=label)
    axes.axhline(100, color="grey", linestyle="--", linewidth=1, label="wave")
    axes.set_xscale("log")
    axes.set_xlabel("training frames seen (optimizer steps x batch size)")
    axes.set_ylabel("IQM, % of the wave's")
    seeds = sorted({seed for rows in curves.values() for row in rows for seed in row["seeds"]})
    axes.set_title(f"Navigation, N=9: validation seeds (within {seeds[0]}-{seeds[-1]})")
    axes.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=120)
    plt.close(figure)
    return path


AGREEMENT = 1e-3  # units of projected displacement between lerobot-eval's sum_reward and dpr's metric


def agreement(eval_info: Path, dpr_json: Path, first_seed: int | None = None) -> dict[int, tuple[float, float]]:
    """Per seed: lerobot-eval's ``sum_reward`` (the step gains of projected displacement that lerobot_env_dpr
    returns as rewards) and dpr's ``projected_displacement``. lerobot-eval's ``eval_info.json`` keeps rewards in
    episode order without seeds; run with ``--seed=S`` its episodes are seeds S, S+1, .... With ``first_seed`` (that
    S) the dpr file must hold those seeds, and may hold more; without it, it must hold exactly as many consecutive
    seeds as lerobot-eval's episodes (a ValueError otherwise)."""
    info = json.loads(eval_info.read_text())
    rewards = [float(r) for task in info["per_task"] for r in task["metrics"]["sum_rewards"]]
    ours = _scores(dpr_json)
    if first_seed is None:
        seeds = sorted(ours)
        if len(seeds) != len(rewards) or seeds != list(range(seeds[0], seeds[0] + len(seeds))):
            raise ValueError(
                f"{dpr_json}: seeds {seeds} are not {len(rewards)} consecutive seeds as lerobot-eval ran "
                "(give --seed, lerobot-eval's, to pair part of them)"
            )
    else:
        seeds = list(range(first_seed, first_seed + len(rewards)))
        missing = [seed for seed in seeds if seed not in ours]
        if missing:
            raise ValueError(f"{dpr_json}: holds no episode of seeds {missing}, which lerobot-eval ran")
    return {seed: (reward, ours[seed]) for seed, reward in zip(seeds, rewards, strict=True)}


def build_parser() -> argparse.ArgumentParser:
    from dpr.cli.common import parse_seeds

    sys.path.insert(0, str(TOOLS))
    import lerobot_policies

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    fit = commands.add_parser("train", help="run or resume a recipe with lerobot-train")
    fit.add_argument("--recipe", required=True, help="a name of tools/lerobot_recipes/recipes.json")
    fit.add_argument("--dataset", type=Path, required=True, help="a dataset folder written by `dpr collect`")
    fit.add_argument("--seed", type=int, default=0)
    fit.add_argument("--steps", type=int, help="optimizer steps (default: the recipe's)")
    fit.add_argument("--out", type=Path, required=True, help="LeRobot's output folder; run again, it resumes")
    fit.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a lerobot-train config override for a new run, e.g. policy.horizon=8 (a resumed run keeps its own)",
    )
    fit.add_argument("--allow-unchecked-lerobot", action="store_true", help="run on a LeRobot version not checked")
    score = commands.add_parser("curve", help="score every checkpoint of a run on validation seeds")
    score.add_argument("--run", type=Path, required=True, help="a `train` output folder")
    score.add_argument("--wave", type=Path, required=True, help="`dpr evaluate --policy wave --json` on the seeds")
    score.add_argument("--seeds", type=parse_seeds, help="default: the wave file's seeds")
    score.add_argument(
        "--set",
        type=lerobot_policies._setting,
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="an inference-time config field, e.g. n_action_steps=1",
    )
    score.add_argument("--every", type=int, default=1, help="score only the checkpoints whose step is a multiple")
    copy = commands.add_parser("ship", help="copy a run's policy (at most 10 MB) with its env, to score anywhere")
    copy.add_argument("--run", type=Path, required=True, help="a `train` output folder")
    copy.add_argument("--out", type=Path, required=True, help="a new folder, e.g. models/navigation-lerobot-diffusion")
    mean = commands.add_parser("average", help="the mean of a run's checkpoints' weights, as a policy folder")
    mean.add_argument("--run", type=Path, required=True, help="a `train` output folder")
    mean.add_argument("--steps", type=int, nargs="+", required=True, help="checkpoint steps, e.g. 4000 5000 6000")
    mean.add_argument("--out", type=Path, required=True, help="a new folder, e.g. RUN-averaged")
    plot = commands.add_parser("plot", help="learning curves of runs and BC evaluations, as a PNG")
    plot.add_argument("--curve", action="append", default=[], metavar="LABEL=CURVE.json", help="a run's curve.json")
    plot.add_argument(
        "--point",
        action="append",
        default=[],
        metavar="LABEL=FRAMES:EVAL.json",
        help="an evaluation file of a model trained on FRAMES frames (e.g. BC), a point of LABEL's line",
    )
    plot.add_argument("--wave", type=Path, required=True, help="the wave's evaluation on the same seeds")
    plot.add_argument("--out", type=Path, required=True, help="the PNG to write")
    phase = commands.add_parser("phase-dataset", help="a copy of a dataset with phases as actions (ACT's recipe)")
    phase.add_argument("--dataset", type=Path, required=True, help="a dataset folder written by `dpr collect`")
    phase.add_argument("--out", type=Path, required=True, help="a new folder")
    phase.add_argument("--cap", type=int, default=4, help="decisions counted ahead at most (default 4)")
    agree = commands.add_parser("agree", help="lerobot-eval's sum_reward per seed against a dpr evaluation file")
    agree.add_argument("--lerobot-eval", type=Path, required=True, help="lerobot-eval's eval_info.json")
    agree.add_argument("--dpr", type=Path, required=True, help="tools/lerobot_policies.py evaluate --json")
    agree.add_argument("--seed", type=int, help="lerobot-eval's --seed, when the dpr file holds more seeds")
    return parser


def plot_curves(args: argparse.Namespace) -> Path:
    """The ``plot`` command: each --curve a line, each --point a point of its label's line."""
    curves: dict[str, list[dict]] = {}
    for text in args.curve:
        label, path = text.split("=", 1)
        curves[label] = json.loads(Path(path).read_text())
    for text in args.point:
        label, rest = text.split("=", 1)
        frames, path = rest.split(":", 1)
        curves.setdefault(label, []).append(evaluation_row(int(frames), Path(path), args.wave))
    return learning_figure(curves, args.out)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    sys.path.insert(0, str(TOOLS))
    import lerobot_policies

    lerobot_policies.prepare()
    if args.command == "train":
        recipe = load_recipe(args.recipe)
        check_lerobot_version(recipe, args.allow_unchecked_lerobot)
        if bad := [item for item in args.set if "=" not in item or item.startswith("-")]:
            raise SystemExit(f"--set: expected NAME=VALUE (a lerobot-train config field), got {bad}")
        return train(recipe, args.dataset, args.out, args.seed, args.steps, tuple(args.set))
    if args.command == "plot":
        print(plot_curves(args))
        return 0
    if args.command == "phase-dataset":
        print(phase_dataset(args.dataset, args.out, args.cap))
        return 0
    if args.command == "average":
        print(average(args.run, args.steps, args.out))
        return 0
    if args.command == "ship":
        print(ship(args.run, args.out))
        return 0
    if args.command == "agree":
        rows = agreement(args.lerobot_eval, args.dpr, args.seed)
        for seed, (theirs, ours) in sorted(rows.items()):
            print(f"seed {seed}: lerobot-eval sum_reward {theirs:.3f}, dpr projected_displacement {ours:.3f}")
        return 0 if all(abs(a - b) <= AGREEMENT for a, b in rows.values()) else 1
    curve(args.run, args.wave, args.seeds, every=args.every, **dict(args.set))
    return 0


if __name__ == "__main__":
    sys.exit(main())
