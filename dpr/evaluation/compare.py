"""`dpr compare`: two recipes compared on validation seeds, and the rule that decides whether a candidate replaces
the recipe in force.

Each recipe is one `dpr pipeline` run folder (or a record of one, such as ``docs/results/full-lr3e4``), or for a
candidate whose tasks ran side by side, one folder per task. For every task and learned method both recipes hold, the
episodes of every training run on the validation seeds (``eval/validation/<task>-<method>-seed<S>.json``) are
pooled, and their IQM in each recipe and the ratio candidate / current are reported. The candidate wins if the mean
over tasks of ``method``'s ratios (default ``bc-ppo``) is above 1, once every task has as many runs in both. Test
evaluations are never read, so a candidate's test seeds stay unseen until it is judged; runs scored on different
validation seeds, episode lengths (``steps``), env ids (task versions), swarm sizes, robot models or task env
kwargs are refused, naming what differs (:func:`scoring`).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from dpr.checks import ParameterError
from dpr.envs import ENV_IDS
from dpr.evaluation.report import load_evaluation
from dpr.evaluation.statistics import iqm

DEFAULT_METHOD = "bc-ppo"
RUN_FILE = re.compile(r"(?P<task>[a-z]+)-(?P<method>[a-z0-9-]+)-seed(?P<seed>\d+)\.json")


def check_run_folders(folders: Sequence[Path], parameter: str) -> list[Path]:
    """``folders`` as paths, each a run folder with validation evaluations and none given twice (its runs would
    count twice); a :class:`~dpr.checks.ParameterError` about ``parameter`` otherwise."""
    folders, seen = list(map(Path, folders)), set()
    for folder in folders:
        if not folder.is_dir():
            raise ParameterError(parameter, f"{folder}: no such folder; expected a `dpr pipeline` run folder")
        if not (folder / "eval" / "validation").is_dir():
            raise ParameterError(
                parameter, f"{folder}: no eval/validation folder; expected a `dpr pipeline` run folder"
            )
        if folder.resolve() in seen:
            raise ParameterError(parameter, f"{folder}: given twice; its runs would count twice")
        seen.add(folder.resolve())
    return folders


def validation_runs(*folders: Path, parameter: str = "folders") -> dict[tuple[str, str], list[Path]]:
    """(task, method) -> the validation evaluations of its training runs in the run folders ``folders`` (a
    recipe's tasks run side by side, each in a folder of its own); a folder given twice or a task in two of them is
    refused, as a :class:`~dpr.checks.ParameterError` about ``parameter``."""
    folders = check_run_folders(folders, parameter)
    runs: dict[tuple[str, str], list[Path]] = {}
    owner: dict[str, Path] = {}
    for folder in folders:
        for path in sorted((folder / "eval" / "validation").glob("*-seed*.json")):
            match = RUN_FILE.fullmatch(path.name)
            if match and match["task"] in ENV_IDS:
                if owner.setdefault(match["task"], folder) != folder:
                    raise ParameterError(
                        parameter, f"{match['task']}: runs in both {owner[match['task']]} and {folder}"
                    )
                runs.setdefault((match["task"], match["method"]), []).append(path)
    return runs


# env kwargs of a policy's own interface: how often it decides, what it sees, how it acts and what reward it
# trained on. Recipes may differ in them; every other kwarg sets the task or the swarm, and so what is scored.
POLICY_SIDE_KWARGS = (
    "action_repeat",
    "action_type",
    "obs_type",
    "obs_last_action",
    "image_size",
    "approach_reward",
    "render_mode",
    "render_size",
)
SWARM_DEFAULTS = {"n_robots": 9, "robot_model": "paddle"}  # the env's own, where an evaluation file names none


def scoring(payload: dict) -> dict[str, object]:
    """What decides the score of an evaluation file's episodes, by name: its validation seeds, episode length
    (``steps``), env id (and so the task's version), swarm size, robot model and the env kwargs that set the task
    (all but :data:`POLICY_SIDE_KWARGS`). Two files scored alike can be compared."""
    kwargs = dict(payload.get("env_kwargs") or {})
    swarm = {name: kwargs.pop(name, default) for name, default in SWARM_DEFAULTS.items()}
    task_kwargs = {name: value for name, value in sorted(kwargs.items()) if name not in POLICY_SIDE_KWARGS}
    return {
        "validation seeds": payload["seeds"],
        "steps (episode length)": payload.get("steps"),
        "env id (task version)": payload.get("env_ids"),
        "N (n_robots)": swarm["n_robots"],
        "robot model": swarm["robot_model"],
        "env kwargs": task_kwargs,
    }


def scoring_difference(one: dict[str, object], other: dict[str, object]) -> str | None:
    """What differs between two :func:`scoring` descriptions, each with both values ("; "-joined), or None."""
    differ = [
        f"{name} {_shown(one[name])} and {_shown(other.get(name))}" for name in one if one[name] != other.get(name)
    ]
    return "; ".join(differ) or None


def _shown(value: object) -> str:
    """``value`` as a message shows it: a long list of seeds by its ends and length."""
    if isinstance(value, list) and len(value) > 6:
        return f"[{value[0]!r}, {value[1]!r}, ..., {value[-1]!r}] ({len(value)})"
    return repr(value)


def pooled(paths: list[Path]) -> tuple[np.ndarray, dict[str, object]]:
    """Every episode's projected displacement over ``paths``, and the :func:`scoring` they share (a ValueError
    naming what differs when one file was scored otherwise than the first)."""
    values, shared = [], None
    for path in paths:
        payload = load_evaluation(path)
        described = scoring(payload)
        if shared is not None and (difference := scoring_difference(shared, described)):
            raise ValueError(f"{path}: scored otherwise than {paths[0]} ({difference}); not comparable")
        shared = described
        values += [episode["projected_displacement"] for episode in payload["episodes"]]
    return np.array(values), shared


def _check_tasks(tasks: Sequence[str]) -> list[str]:
    tasks = list(tasks)
    unknown = [task for task in tasks if task not in ENV_IDS]
    if unknown:
        raise ParameterError("tasks", f"unknown task(s) {unknown}; expected some of {list(ENV_IDS)}")
    if not tasks:
        raise ParameterError("tasks", "must name at least one task")
    if len(set(tasks)) != len(tasks):
        raise ParameterError("tasks", f"each task must appear once, got {tasks}")
    return tasks


def compare(
    current: Path,
    candidate: Path | Sequence[Path],
    tasks: Sequence[str] = tuple(ENV_IDS),
    method: str = DEFAULT_METHOD,
) -> tuple[list[dict], float | None]:
    """One row per (task, method) both recipes hold, and the mean over ``tasks`` of ``method``'s ratios (None if a
    task lacks it in either, or the candidate has fewer or more of its runs than the current recipe). The candidate
    is one run folder or several, each holding some of its tasks. Every folder is checked before any evaluation is
    read."""
    tasks = _check_tasks(tasks)
    candidates = [Path(candidate)] if isinstance(candidate, (str, Path)) else list(map(Path, candidate))
    if not candidates:
        raise ParameterError("candidate", "must name at least one run folder")
    check_run_folders([current], "current")
    check_run_folders(candidates, "candidate")
    before = validation_runs(current, parameter="current")
    after = validation_runs(*candidates, parameter="candidate")
    rows = []
    for key in sorted(set(before) & set(after), key=lambda key: (list(ENV_IDS).index(key[0]), key[1])):
        if key[0] not in tasks:
            continue
        (old, old_scoring), (new, new_scoring) = pooled(before[key]), pooled(after[key])
        difference = scoring_difference(old_scoring, new_scoring)
        if difference:
            raise ParameterError(
                "candidate",
                f"{key[0]}-{key[1]}: the two folders scored their runs differently ({difference}, current first); "
                "not comparable",
            )
        rows.append(
            {
                "task": key[0],
                "method": key[1],
                "runs": (len(before[key]), len(after[key])),
                "iqm": (float(iqm(old)), float(iqm(new))),
                "ratio": float(iqm(new) / iqm(old)),
            }
        )
    ratios = [row["ratio"] for row in rows if row["method"] == method]
    # a task counts once the candidate has as many training runs as the current recipe: a verdict on the first
    # runs to finish would be a choice made on part of the candidate
    finished = all(row["runs"][0] == row["runs"][1] for row in rows if row["method"] == method)
    complete = len(ratios) == len(tasks) and finished
    return rows, (float(np.mean(ratios)) if complete else None)


def format_comparison(rows: list[dict], mean: float | None, tasks: Sequence[str], method: str) -> str:
    """The markdown table of ``compare``'s rows and the verdict line."""
    lines = ["| task | method | runs | IQM current | IQM candidate | ratio |", "|---|---|---|---:|---:|---:|"]
    for row in rows:
        runs = " / ".join(map(str, row["runs"]))
        scores = f"{row['iqm'][0]:.1f} | {row['iqm'][1]:.1f} | {row['ratio']:.2f}"
        lines.append(f"| {row['task']} | {row['method']} | {runs} | {scores} |")
    if mean is None:
        verdict = (
            f"{method}: not every task of {list(tasks)} is finished in both folders with as many runs; no decision yet"
        )
    else:
        decision = "adopt the candidate" if mean > 1 else "keep the current recipe"
        verdict = f"mean {method} ratio over {len(tasks)} tasks: {mean:.3f} -> {decision}"
    return "\n".join(lines) + "\n\n" + verdict
