"""Results table (markdown) and the paper's two figures from `dpr evaluate --json` files.

Each file holds one policy on one or more tasks; several files are merged, so that the same policy evaluated
task by task, or several policies, end up in one table and one pair of figures:

- the table: one row per (task, policy) with the projected displacement's median, min, max, mean ± std,
  the success rate and the median as a percentage of the wave policy's on the same seeds;
- ``bars.png``: per task, one bar per policy (median, min-max error bars), as in the paper;
- ``trajectories.png``: per task, every policy's path from the same start (one seed).

matplotlib is imported only when a figure is drawn, through its object-oriented API with the Agg canvas,
so that importing this module stays cheap and the process's pyplot backend is left alone.
"""

from __future__ import annotations

import json
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dpr.atomic import atomic_write_text
from dpr.checks import ParameterError
from dpr.envs.tasks import EARLIER_ENV_IDS
from dpr.evaluation.figures import new_figure, policy_colours
from dpr.evaluation.statistics import (
    BOOTSTRAP_REPS,
    CONFIDENCE,
    MethodScores,
    interval_figure,
    interval_rows,
    interval_table,
    profile_figure,
    scores_of_runs,
)
from dpr.metrics import summarize
from dpr.policies.model_file import is_model_path
from dpr.policies.registry import WAVE

TASK_ORDER = ("Navigation", "Gate", "Unresponsive", "Manipulation")
WAVE_POLICY = WAVE  # the baseline every row is a percentage of
REPORT_FILES = ("results.md", "bars.png", "trajectories.png", "intervals.png", "profile.png")
REQUIRED_KEYS = {"policy": str, "env_ids": list, "steps": int, "seeds": list, "episodes": list}
EPISODE_KEYS = {"env_id": str, "seed": int, "projected_displacement": (int, float), "success": (bool, int)}
NO_VALUE = "—"
INTERVALS_NOTE = (
    f"Over test seeds x training runs (one run per file of a method), with {100 * CONFIDENCE:.0f}% stratified "
    "bootstrap confidence intervals (test seeds resampled within each run; Agarwal et al., 2021). IQM: "
    "interquartile mean. P(> wave): the probability that the method beats the wave on a random seed."
)


RUN_FOLDER_STEMS = ("model", "best_model", "averaged_model")  # what `dpr train`/`finetune` name every run's models


def task_name(env_id: str) -> str:
    """'dpr/Navigation-v0' -> 'Navigation'; an earlier version of a task keeps its version, so that it is not
    taken for the current one: 'dpr/Gate-v0' -> 'Gate-v0'."""
    name = env_id.split("/")[-1]
    return name if env_id in EARLIER_ENV_IDS else name.rsplit("-v", 1)[0]


def policy_label(policy: str, tasks=()) -> str:
    """Display name of a policy: a model file's stem without the prefix of one of ``tasks`` (task names), so
    that the same method has the same name on every task (models/navigation-bc-ppo.zip on Navigation ->
    bc-ppo), or its whole path for a run's model.zip (runs/ft/nav9/model.zip -> runs/ft/nav9/model), else the
    policy's name."""
    if not is_model_path(policy):
        return policy
    stem = Path(policy).stem
    if stem in RUN_FOLDER_STEMS:  # every run's model is model.zip: runs/bc/nav9 and runs/ft/nav9 are two methods
        return policy.removesuffix(".zip")
    for task in tasks:
        prefix = task.rsplit("-v", 1)[0].lower()  # a Gate-v0 model is still gate-<method>.zip
        if stem.lower().startswith(f"{prefix}-"):
            return stem[len(prefix) + 1 :]
    return stem


def _is_a(value, kind) -> bool:
    # bool is an int in Python; a seed or a step count given as true/false is still wrong.
    return isinstance(value, kind) and not (isinstance(value, bool) and kind in (int, (int, float)))


def _check_points(value, shape: tuple[int | None, int], where: str) -> None:
    """``value`` must be numbers of ``shape`` (None: any length >= 1)."""
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{where} must be numbers") from None
    if array.ndim != len(shape) or array.shape[-1] != shape[-1] or (len(shape) == 2 and len(array) == 0):
        expected = "[x, y]" if len(shape) == 1 else "a non-empty list of [x, y]"
        raise ValueError(f"{where} must be {expected}, got shape {array.shape}")
    if not np.isfinite(array).all():
        raise ValueError(f"{where} must be finite numbers; it holds NaN or infinity")


def _check_keys(record: dict, spec: dict[str, type | tuple[type, ...]], missing: str, wrong: str) -> None:
    """ValueError with ``missing`` (formatted with the absent keys) or ``wrong`` (with the key, its expected kind and
    its value) unless ``record`` has every key of ``spec`` with a value of its type."""
    absent = [key for key in spec if key not in record]
    if absent:
        raise ValueError(missing.format(missing=absent))
    for key, kind in spec.items():
        if not _is_a(record[key], kind):
            kinds = kind if isinstance(kind, tuple) else (kind,)
            name = " or ".join(k.__name__ for k in kinds)
            raise ValueError(wrong.format(key=key, kind=name, value=record[key]))


def load_evaluation(path, label: str | None = None) -> dict:
    """The payload of a `dpr evaluate --json` file, checked, with ``source`` (the path) and ``label`` (``label``,
    else policy_label of its policy) added. A ValueError names the file and what is wrong."""
    path = Path(path)
    try:
        payload = json.loads(path.read_text())
    except OSError as error:
        raise ValueError(f"{path}: cannot read it ({error.strerror or error})") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise ValueError(f"{path}: not a JSON file ({error})") from None
    if not isinstance(payload, dict):
        kind = type(payload).__name__
        raise ValueError(f"{path}: expected a JSON object written by `dpr evaluate --json`, got a {kind}")
    _check_keys(
        payload,
        REQUIRED_KEYS,
        f"{path}: missing key(s) {{missing}}; is it a `dpr evaluate --json` file?",
        f"{path}: '{{key}}' must be a {{kind}}, got {{value!r:.60}}",
    )
    if not payload["episodes"]:
        raise ValueError(f"{path}: no episodes")
    for i, episode in enumerate(payload["episodes"]):
        where = f"{path}: episode {i}"
        if not isinstance(episode, dict):
            raise ValueError(f"{where} must be an object, got {episode!r:.60}")
        _check_keys(
            episode, EPISODE_KEYS, f"{where} lacks {{missing}}", f"{where}: '{{key}}' has a wrong type: {{value!r:.60}}"
        )
        if not np.isfinite(episode["projected_displacement"]):
            raise ValueError(
                f"{where}: projected_displacement is {episode['projected_displacement']}; expected a number"
            )
        if "trajectory" in episode:  # absent from files written before trajectories were recorded
            if "goal" not in episode:
                raise ValueError(f"{where} has a trajectory but no goal")
            _check_points(episode["goal"], (2,), f"{where}: 'goal'")
            _check_points(episode["trajectory"], (None, 2), f"{where}: 'trajectory'")
    tasks = {task_name(env_id) for env_id in payload["env_ids"]}  # a one-task file names its model by method
    return {
        **payload,
        "source": str(path),
        "label": label or policy_label(payload["policy"], tasks if len(tasks) == 1 else ()),
    }


@dataclass
class _Group:
    """The episodes of one method (a display label) on one task: one file per training run."""

    task: str
    label: str
    policy: str
    source: str
    steps: int
    runs: dict[int, tuple[str, str, list[dict]]] = field(default_factory=dict)  # file index -> source, policy, ...

    @property
    def episodes(self) -> list[dict]:
        return [episode for _, _, episodes in self.runs.values() for episode in episodes]

    @property
    def seeds(self) -> list[int]:
        return sorted({episode["seed"] for episode in self.episodes})


def _label(evaluation: dict) -> str:
    return evaluation.get("label") or policy_label(evaluation["policy"])


def _labels_in_order(evaluations: list[dict]) -> list[str]:
    """Labels in the order given, the wave policy (the reference) first."""
    labels = list(dict.fromkeys(_label(evaluation) for evaluation in evaluations))
    return sorted(labels, key=lambda label: label != WAVE_POLICY)


def _task_key(task: str) -> tuple[int, str]:
    # The paper's order; a task this module does not know comes last, by name.
    base = task.rsplit("-v", 1)[0]  # an earlier version beside its task
    return (TASK_ORDER.index(base), task) if base in TASK_ORDER else (len(TASK_ORDER), task)


def _run_key(group: _Group, index: int, evaluation: dict, source: str, seeds: set[int]) -> int:
    """The run of ``group`` that the episodes of ``evaluation`` (file ``index``) on its task join: a new one, or the
    run of the same policy in an earlier file, scored there on other seeds (one run scored in parts). The same
    policy on a seed of an earlier file is a ValueError (one run counted twice)."""
    for key, (earlier, policy, episodes) in group.runs.items():
        if policy != evaluation["policy"]:
            continue
        twice = sorted(seeds & {episode["seed"] for episode in episodes})
        if twice or evaluation["steps"] != group.steps:
            what = f"seeds {format_seeds(twice)}" if twice else f"{evaluation['steps']} steps, not {group.steps}"
            raise ValueError(
                f"policy {group.label!r} on {group.task} is in both {earlier} and {source} ({what}); "
                "give them different labels (--label) or report them separately"
            )
        return key
    group.runs[index] = (source, evaluation["policy"], [])
    return index


def _groups(evaluations: list[dict]) -> dict[str, dict[str, _Group]]:
    """task -> label -> its episodes, tasks in the paper's order and policies in the order given. One label in
    several files is several training runs of one method (models trained from different seeds), or one run scored
    in parts: the same policy in two files, on other seeds each."""
    if not evaluations:
        raise ValueError("no evaluations to report")
    by_task: dict[str, dict[str, _Group]] = {}
    for index, evaluation in enumerate(evaluations):
        label, source = _label(evaluation), evaluation.get("source", f"evaluation {index}")
        episodes_by_task: dict[str, list[dict]] = {}
        for episode in evaluation["episodes"]:
            episodes_by_task.setdefault(task_name(episode["env_id"]), []).append(episode)
        for task, episodes in episodes_by_task.items():
            groups = by_task.setdefault(task, {})
            group = groups.get(label)
            if group is None:
                group = groups[label] = _Group(task, label, evaluation["policy"], source, evaluation["steps"])
            key = _run_key(group, index, evaluation, source, {episode["seed"] for episode in episodes})
            group.runs[key][2].extend(episodes)
    order = _labels_in_order(evaluations)
    return {
        task: {label: by_task[task][label] for label in order if label in by_task[task]}
        for task in sorted(by_task, key=_task_key)
    }


def format_seeds(seeds: list[int]) -> str:
    """[0, 1, 2, 3, 5] -> '0-3,5'."""
    runs: list[list[int]] = []
    for seed in sorted(set(seeds)):
        if runs and seed == runs[-1][1] + 1:
            runs[-1][1] = seed
        else:
            runs.append([seed, seed])
    return ",".join(str(lo) if lo == hi else f"{lo}-{hi}" for lo, hi in runs)


def _median(group: _Group) -> float:
    return float(np.median([episode["projected_displacement"] for episode in group.episodes]))


def _wave_reference(groups: dict[str, _Group]) -> _Group | None:
    """The first group of the wave policy on a task (by policy name, whatever its label)."""
    return next((group for group in groups.values() if group.policy == WAVE_POLICY), None)


def _percent_of_wave(group: _Group, wave: _Group | None) -> str:
    # Only a like-for-like comparison: the same starts (seeds) and episode length; and a ratio to a median
    # that is not positive says nothing.
    if wave is None or wave.seeds != group.seeds or wave.steps != group.steps:
        return NO_VALUE
    reference = _median(wave)
    if reference <= 0:
        return NO_VALUE
    return f"{100 * _median(group) / reference:.0f}%"


def results_table(evaluations: list[dict]) -> str:
    """Markdown table: one row per (task, policy) of the projected displacement's statistics over episodes,
    the success rate, the episode count and seeds, and the median as a percentage of the wave policy's."""
    lines = [
        "| task | policy | median | min | max | mean ± std | success | n | seeds | % of wave |",
        "|---|---|---:|---:|---:|---:|---:|---:|---|---:|",
    ]
    for task, groups in _groups(evaluations).items():
        wave = _wave_reference(groups)
        for label, group in groups.items():
            s = summarize(episode["projected_displacement"] for episode in group.episodes)
            success = float(np.mean([bool(episode["success"]) for episode in group.episodes]))
            lines.append(
                f"| {task} | {label} | {s['median']:.1f} | {s['min']:.1f} | {s['max']:.1f} | "
                f"{s['mean']:.1f} ± {s['std']:.1f} | {100 * success:.0f}% | {s['n']} | "
                f"{format_seeds(group.seeds)} | {_percent_of_wave(group, wave)} |"
            )
    return "\n".join(lines)


def passage_table(evaluations: list[dict]) -> str:
    """Markdown table of the gate's passage measure, one row per (task, policy) whose episodes carry it (Gate-v1 and
    later, in evaluations made since the measure exists): the median fraction of robots past the walls' near face at
    the end, how many episodes touched a wall, and the median physics step of the first touch. Empty if none."""
    lines = []
    for task, groups in _groups(evaluations).items():
        for label, group in groups.items():
            episodes = [episode for episode in group.episodes if "gate_passage" in episode]
            if not episodes:
                continue
            passage = float(np.median([episode["gate_passage"] for episode in episodes]))
            touches = [episode["gate_contact_step"] for episode in episodes if episode["gate_contact_step"] >= 0]
            first = f"{np.median(touches):.0f}" if touches else NO_VALUE
            lines.append(f"| {task} | {label} | {100 * passage:.0f}% | {len(touches)} of {len(episodes)} | {first} |")
    if not lines:
        return ""
    header = [
        "| task | policy | robots past the walls' near face (median) | episodes touching a wall | first touch, "
        "physics step (median) |",
        "|---|---|---:|---:|---:|",
    ]
    return "\n".join(header + lines)


def bar_figure(evaluations: list[dict], path) -> Path:
    """The paper's bar chart: per task a group of bars, one per policy, of the median projected displacement
    with min-max error bars. Saved to ``path`` (PNG)."""
    by_task = _groups(evaluations)
    labels = _labels_in_order(evaluations)
    colours = policy_colours(labels)
    figure, (axes,) = new_figure(max(6.0, 1.5 + len(by_task) * (0.5 + 0.35 * len(labels))), 4.5)
    width = 0.8 / len(labels)
    for i, label in enumerate(labels):
        positions, medians, below, above = [], [], [], []
        for x, groups in enumerate(by_task.values()):
            if label in groups:
                s = summarize(episode["projected_displacement"] for episode in groups[label].episodes)
                positions.append(x - 0.4 + width * (i + 0.5))
                medians.append(s["median"])
                below.append(s["median"] - s["min"])
                above.append(s["max"] - s["median"])
        axes.bar(positions, medians, width, yerr=[below, above], capsize=3, color=colours[label], label=label)
    axes.axhline(0.0, color="black", linewidth=0.8)
    axes.set_xticks(range(len(by_task)), list(by_task))
    axes.set_ylabel("projected displacement (units)")
    axes.set_title("Projected displacement per task\n(median over seeds; error bars: min to max)")
    axes.legend(loc="best")
    figure.savefig(path, dpi=150)
    return Path(path)


@dataclass
class _Path:
    label: str
    trajectory: np.ndarray
    goal: np.ndarray


def _trajectory_plan(evaluations: list[dict], seed: int | None) -> dict[str, tuple[int, list[_Path]]]:
    """task -> (seed, the paths to draw): every policy with recorded trajectories, from the given seed or the
    smallest seed all of them have on that task. Warns about each policy skipped; a ValueError when nothing
    is left to draw."""
    plan: dict[str, tuple[int, list[_Path]]] = {}
    for task, groups in _groups(evaluations).items():
        with_paths = {label: g for label, g in groups.items() if all("trajectory" in e for e in g.episodes)}
        for label in [label for label in groups if label not in with_paths]:
            warnings.warn(
                f"{groups[label].source}: {label} on {task} has no trajectories (written by an older "
                "`dpr evaluate`); left out of the trajectory figure",
                stacklevel=3,
            )
        if not with_paths:
            continue
        if seed is None:
            common = set.intersection(*(set(g.seeds) for g in with_paths.values()))
            if not common:
                raise ParameterError("seed", f"{task}: no seed was evaluated for all of {list(with_paths)}; pick one")
            chosen = min(common)
        else:
            chosen = seed
            lacking = [label for label, g in with_paths.items() if chosen not in g.seeds]
            for label in lacking:
                warnings.warn(
                    f"{with_paths[label].source}: {label} on {task} has no episode of seed {chosen}; "
                    "left out of the trajectory figure",
                    stacklevel=3,
                )
                del with_paths[label]
            if not with_paths:
                continue
        paths = []
        for label, group in with_paths.items():
            episode = next(e for e in group.episodes if e["seed"] == chosen)
            paths.append(_Path(label, np.asarray(episode["trajectory"], float), np.asarray(episode["goal"], float)))
        plan[task] = (chosen, paths)
    if not plan:
        which = "has" if seed is None else f"has seed {seed} with"
        raise ValueError(f"no evaluation {which} trajectories; run `dpr evaluate --json` again to record them")
    return plan


def _draw_trajectories(plan: dict[str, tuple[int, list[_Path]]], labels: list[str], path) -> Path:
    colours = policy_colours(labels)
    figure, all_axes = new_figure(4.5 * len(plan), 4.8, columns=len(plan))
    for axes, (task, (seed, paths)) in zip(all_axes, plan.items()):
        start, goal = paths[0].trajectory[0], paths[0].goal
        # Hollow start marker under the paths: a short path must stay visible on top of it.
        markers = axes.plot(*start, "s", color="black", markerfacecolor="none", markersize=9, label="start", zorder=1)
        lines = []
        for p in paths:
            lines += axes.plot(
                p.trajectory[:, 0], p.trajectory[:, 1], color=colours[p.label], linewidth=1.5, label=p.label, zorder=2
            )
            axes.plot(*p.trajectory[-1], "o", color=colours[p.label], markersize=4, zorder=2)  # where it ended
        # The paths are short beside the distance to the goal: frame them, and point at the goal instead.
        points = np.vstack([p.trajectory for p in paths])
        low, high = points.min(axis=0), points.max(axis=0)
        pad = max(float((high - low).max()) * 0.25, 10.0)
        axes.set_xlim(low[0] - pad, high[0] + pad)
        axes.set_ylim(low[1] - pad, high[1] + pad)
        to_goal = goal - start
        distance = float(np.linalg.norm(to_goal))
        if distance > 0:
            tip = start + to_goal / distance * min(distance, 0.8 * float((high - low).max() + pad))
            axes.annotate(
                "", xy=tip, xytext=start, zorder=0, arrowprops={"arrowstyle": "->", "color": "0.6", "linestyle": "--"}
            )
            axes.text(*tip, f" to the goal ({distance:.0f} units)", color="0.4", fontsize="small", zorder=0)
        if (low - pad <= goal).all() and (goal <= high + pad).all():  # the goal is in the frame: mark it
            markers += axes.plot(
                *goal, "*", color="gold", markeredgecolor="black", markersize=14, label="goal", zorder=1
            )
        axes.set_aspect("equal", adjustable="box")
        axes.set_title(f"{task} (seed {seed})")
        axes.set_xlabel("x (units)")
        axes.set_ylabel("y (units)")
        axes.legend(handles=lines + markers, loc="best", fontsize="small")  # policies first
    figure.savefig(path, dpi=150)
    return Path(path)


def trajectory_figure(evaluations: list[dict], path, seed: int | None = None) -> Path:
    """One panel per task with every policy's path from the same start (``seed``, default the smallest seed
    all policies have on that task), the start and the goal. Policies without recorded trajectories are left
    out with a warning; a ValueError when none has any. Saved to ``path`` (PNG)."""
    return _draw_trajectories(_trajectory_plan(evaluations, seed), _labels_in_order(evaluations), path)


def _sources_line(evaluations: list[dict], root: str | Path | None = None) -> str:
    def named(source: str) -> str:
        return source if root is None else os.path.relpath(source, root)

    parts = [
        f"`{named(e['source'])}` ({_label(e)}: {', '.join(task_name(env_id) for env_id in e['env_ids'])}; "
        f"seeds {format_seeds(e['seeds'])}, {e['steps']} steps)"
        for e in evaluations
    ]
    return "Sources: " + "; ".join(parts) + "."


def method_scores(evaluations: list[dict]) -> dict[str, dict[str, MethodScores]]:
    """task -> label -> the method's score matrix (test seeds x training runs), for the interval estimates."""
    return {
        task: {label: scores_of_runs(task, label, list(group.runs.values())) for label, group in groups.items()}
        for task, groups in _groups(evaluations).items()
    }


def write_report(
    json_paths,
    out_dir,
    labels: list[str] | None = None,
    seed: int | None = None,
    bootstrap_reps: int = BOOTSTRAP_REPS,
    root: str | Path | None = None,
) -> list[Path]:
    """Write ``out_dir``/results.md (the table, the interval estimates of :mod:`dpr.evaluation.statistics` and the
    sources), bars.png, trajectories.png, intervals.png and profile.png from `dpr evaluate --json` files;
    ``labels``: one display name per file (files that share a label are training runs of one method).
    Checks everything first and writes nothing when a file is bad or an output already exists
    (FileExistsError). results.md is written last, whole: a folder without it holds a report stopped part-way.
    The sources are named relative to ``root`` when given (a run folder's report reads the same wherever it is).
    Returns the paths written."""
    json_paths = list(json_paths)
    if labels is not None and len(labels) != len(json_paths):
        raise ValueError(f"give one label per file: {len(json_paths)} file(s), {len(labels)} label(s)")
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise ValueError(f"{out_dir} exists and is not a folder")
    outputs = [out_dir / name for name in REPORT_FILES]
    for output in outputs:
        if output.exists():
            raise FileExistsError(f"{output} already exists; choose another folder (reports are never overwritten)")
    evaluations = [load_evaluation(p, label) for p, label in zip(json_paths, labels or [None] * len(json_paths))]
    table = results_table(evaluations)
    passage = passage_table(evaluations)
    methods = method_scores(evaluations)  # before writing anything: runs of one method must share their seeds
    plan = _trajectory_plan(evaluations, seed)  # and there may be nothing to draw
    rows = interval_rows(methods, bootstrap_reps)
    out_dir.mkdir(parents=True, exist_ok=True)
    results_md, bars_png, trajectories_png, intervals_png, profile_png = outputs
    passage_section = f"## Passage through the gate\n\n{passage}\n\n" if passage else ""
    bar_figure(evaluations, bars_png)
    _draw_trajectories(plan, _labels_in_order(evaluations), trajectories_png)
    interval_figure(rows, intervals_png)
    profile_figure(methods, profile_png)
    atomic_write_text(  # last, whole or not at all: the mark of a finished report
        results_md,
        f"# Results\n\nProjected displacement (units) over seeds.\n\n{table}\n\n{passage_section}"
        f"## Interval estimates\n\n{INTERVALS_NOTE}\n\n{interval_table(rows)}\n\n{_sources_line(evaluations, root)}\n",
    )
    return outputs
