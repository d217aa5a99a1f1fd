"""Interval estimates of a method's score over training runs and test seeds, after Agarwal et al., "Deep RL at
the edge of the statistical precipice" (NeurIPS 2021), with the definitions of their ``rliable`` library.

A *method* is one label in a report (``bc-ppo``, say); each `dpr evaluate --json` file under that label is one
*training run* (a model trained from one training seed), scored on the same *test seeds*. Per task and method
its scores form a matrix of test seeds x runs, and every statistic here comes with a 95% stratified bootstrap
confidence interval whose strata are the runs: test seeds are resampled within each run.

- the median and the interquartile mean (IQM: the mean of the middle 50%, robust to a few failed starts and
  less noisy than the median) of the projected displacement, over all (run, test seed) pairs;
- the ratio of the method's IQM to the wave policy's on the same test seeds (paired: a bootstrap sample draws
  the same seeds for both, so how hard a start is cancels out);
- the probability of improvement P(method > wave): the chance that the method, on a random test seed and run,
  moves farther than the wave on a random test seed (Mann-Whitney), averaged over runs.

The IQM and P(improvement) are rliable's (``metrics.aggregate_iqm``, ``metrics.probability_of_improvement``;
tests compare them), vectorised over bootstrap samples; the intervals are percentile intervals of our own
stratified bootstrap (:func:`_estimates` says why), seeded so that the same files always give the same report.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dpr.evaluation.figures import new_figure, policy_colours
from dpr.policies.registry import WAVE

CONFIDENCE = 0.95
BOOTSTRAP_REPS = 2000
BOOTSTRAP_SEED = 0  # the intervals of a report are reproducible
BOOTSTRAP_CHUNK = 100  # bootstrap samples per batch: the improvement compares every seed pair of every run
PROFILE_RATIOS = np.linspace(0.0, 3.0, 121)  # x axis of the performance profile: fraction of the wave's median

Interval = tuple[float, float, float]  # point estimate, lower and upper bound


@dataclass
class MethodScores:
    """One method on one task: ``scores[i, r]`` is run ``runs[r]``'s projected displacement on ``seeds[i]``."""

    task: str
    label: str
    policy: str
    seeds: list[int]
    runs: list[str]
    scores: np.ndarray


@dataclass
class IntervalRow:
    """The estimates of one method on one task (``ratio`` and ``p_improvement`` need the wave on its seeds)."""

    task: str
    label: str
    n_runs: int
    n_seeds: int
    median: Interval
    iqm: Interval
    ratio: Interval | None = None
    p_improvement: Interval | None = None


def scores_of_runs(task: str, label: str, runs: list[tuple[str, str, list[dict]]]) -> MethodScores:
    """The score matrix of a method on ``task`` from its ``runs`` (source, policy, episodes). Every run must
    hold the same test seeds, each once (ValueError naming the sources otherwise)."""
    seeds = sorted(episode["seed"] for episode in runs[0][2])
    columns = []
    for source, _, episodes in runs:
        by_seed = {episode["seed"]: episode["projected_displacement"] for episode in episodes}
        if sorted(by_seed) != seeds or len(by_seed) != len(episodes):
            raise ValueError(
                f"{label!r} on {task}: every run must be scored once on the same seeds; {runs[0][0]} and {source} "
                "differ (evaluate every training seed's model with the same --seeds)"
            )
        columns.append([by_seed[seed] for seed in seeds])
    policies = {policy for _, policy, _ in runs}
    return MethodScores(
        task, label, ", ".join(sorted(policies)), seeds, [source for source, _, _ in runs], np.array(columns).T
    )


def probability_of_improvement(x: np.ndarray, y: np.ndarray) -> float:
    """P(X > Y) + P(X = Y) / 2 per column of two (seeds, runs) matrices, averaged over columns: the Mann-Whitney
    statistic that ``rliable.metrics.probability_of_improvement`` computes."""
    return float(_improvement(x[None], y[None])[0])


def _improvement(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """:func:`probability_of_improvement` of every pair ``x[b], y[b]`` of two (batch, seeds, runs) arrays."""
    greater = (x[:, :, None, :] > y[:, None, :, :]).mean(axis=(1, 2))
    equal = (x[:, :, None, :] == y[:, None, :, :]).mean(axis=(1, 2))
    return (greater + 0.5 * equal).mean(axis=-1)


def iqm(values: np.ndarray) -> np.ndarray:
    """The interquartile mean over the last axis: the mean of what is left after cutting ``int(n / 4)`` values
    from each end, as ``rliable.metrics.aggregate_iqm`` (scipy's ``trim_mean(..., 0.25)``) does."""
    n = values.shape[-1]
    cut = int(0.25 * n)
    return np.sort(values, axis=-1)[..., cut : n - cut].mean(axis=-1)


def _percentile_interval(point: float, samples: np.ndarray) -> Interval:
    low, high = np.percentile(samples, [50 * (1 - CONFIDENCE), 50 * (1 + CONFIDENCE)])
    return float(point), float(low), float(high)


def _estimates(scores: np.ndarray, wave: np.ndarray | None, reps: int) -> IntervalRow:
    """The stratified bootstrap of one method's (seeds, runs) ``scores``, paired with the ``wave``'s (seeds,).

    Written here rather than taken from ``rliable.library.get_interval_estimates``, for two reasons measured on
    rliable 1.2: its bootstraps draw from numpy's global random state (the ``random_state`` they are given is
    not used for the draws), so the same files gave other intervals on every run; and its two-array bootstrap
    resamples the method and the wave independently, which drops the pairing on starting seeds."""
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    n_seeds, n_runs = scores.shape
    score_iqm = iqm(scores.ravel())
    wave_iqm = 0.0 if wave is None else iqm(wave)
    paired = wave_iqm > 0
    bounded = True
    samples, ratios, improvements = [], [], []
    for first in range(0, reps, BOOTSTRAP_CHUNK):
        # Each run is a stratum: its test seeds are drawn with replacement, and the wave gets the same seeds.
        index = rng.integers(n_seeds, size=(min(BOOTSTRAP_CHUNK, reps - first), n_seeds, n_runs))
        resampled = scores[index, np.arange(n_runs)]
        pooled = resampled.reshape(len(index), -1)  # all (seed, run) pairs of each bootstrap sample
        samples.append((np.median(pooled, axis=1), iqm(pooled)))
        if paired:
            wave_resampled = wave[index]
            wave_iqms = iqm(wave_resampled.reshape(len(index), -1))
            # a bootstrap sample where the wave's IQM is not above 0 leaves the ratio without bound: no interval
            bounded = bounded and bool((wave_iqms > 0).all())
            ratios.append(samples[-1][1] / np.maximum(wave_iqms, 1e-12))
            improvements.append(_improvement(resampled, wave_resampled))
    medians, iqms = (np.concatenate(parts) for parts in zip(*samples))
    row = IntervalRow(
        "",
        "",
        n_runs,
        n_seeds,
        median=_percentile_interval(np.median(scores), medians),
        iqm=_percentile_interval(score_iqm, iqms),
    )
    if paired:
        if bounded:
            row.ratio = _percentile_interval(score_iqm / wave_iqm, np.concatenate(ratios))
        point = probability_of_improvement(scores, np.repeat(wave[:, None], n_runs, axis=1))
        row.p_improvement = _percentile_interval(point, np.concatenate(improvements))
    return row


def interval_rows(methods: dict[str, dict[str, MethodScores]], reps: int = BOOTSTRAP_REPS) -> list[IntervalRow]:
    """Per task (in the given order) and method: the estimates, against the wave where it was scored on the
    same seeds."""
    rows = []
    for task, by_label in methods.items():
        wave = next((m for m in by_label.values() if m.policy == WAVE and m.scores.shape[1] == 1), None)
        for label, method in by_label.items():
            reference = None
            if wave is not None and wave is not method and wave.seeds == method.seeds:
                reference = wave.scores[:, 0]
            row = _estimates(method.scores, reference, reps)
            row.task, row.label = task, label
            rows.append(row)
    return rows


def _interval_text(interval: Interval | None, scale: float = 1.0, unit: str = "", digits: int = 1) -> str:
    if interval is None:
        return "—"
    value, low, high = (scale * v for v in interval)
    return f"{value:.{digits}f}{unit} [{low:.{digits}f}, {high:.{digits}f}]"


def interval_table(rows: list[IntervalRow]) -> str:
    """Markdown: per task and method, runs x seeds, median and IQM with their 95% CIs, the IQM as % of the
    wave's and P(improvement over the wave), each with its CI."""
    lines = [
        "| task | method | runs × seeds | median [95% CI] | IQM [95% CI] | IQM % of wave [95% CI] "
        "| P(> wave) [95% CI] |",
        "|---|---|---|---:|---:|---:|---:|",
    ]
    for row in rows:
        lines.append(
            f"| {row.task} | {row.label} | {row.n_runs} × {row.n_seeds} | {_interval_text(row.median)} | "
            f"{_interval_text(row.iqm)} | {_interval_text(row.ratio, 100, '%', 0)} | "
            f"{_interval_text(row.p_improvement, 1, '', 2)} |"
        )
    return "\n".join(lines)


def interval_figure(rows: list[IntervalRow], path: str | Path) -> Path:
    """Per task, each method's IQM as % of the wave's with its 95% CI (methods without a wave ratio left out)."""
    rows = [row for row in rows if row.ratio is not None]
    tasks = list(dict.fromkeys(row.task for row in rows)) or ["(no ratio to the wave)"]
    labels = list(dict.fromkeys(row.label for row in rows))
    palette = policy_colours(labels)
    figure, axes = new_figure(4.0 * len(tasks), 0.6 * max(len(labels), 2) + 1.2, columns=len(tasks))
    for axis, task in zip(axes, tasks):
        task_rows = [row for row in rows if row.task == task]
        for y, row in enumerate(task_rows):
            value, low, high = (100 * v for v in row.ratio)
            axis.plot([low, high], [y, y], color=palette[row.label], linewidth=6, solid_capstyle="butt", alpha=0.6)
            axis.plot([value], [y], "|", color="black", markersize=14)
        axis.axvline(100, color="grey", linestyle="--", linewidth=1)
        axis.set_yticks(range(len(task_rows)), [row.label for row in task_rows])
        axis.set_title(task)
        axis.set_xlabel("IQM, % of the wave (95% CI)")
    figure.savefig(path, dpi=150)
    return Path(path)


def profile_figure(methods: dict[str, dict[str, MethodScores]], path: str | Path) -> Path:
    """Performance profiles: per task, the fraction of (run, seed) pairs of each method whose displacement
    exceeds x times the wave's median on the task, against x (Dolan and Moré; Agarwal et al.)."""
    tasks = [task for task, by_label in methods.items() if any(m.policy == WAVE for m in by_label.values())]
    tasks = tasks or ["(no wave to compare with)"]
    labels = list(dict.fromkeys(label for by_label in methods.values() for label in by_label))
    palette = policy_colours(labels)
    figure, axes = new_figure(4.0 * len(tasks), 3.4, columns=len(tasks))
    for axis, task in zip(axes, tasks):
        by_label = methods.get(task, {})
        wave = next((m for m in by_label.values() if m.policy == WAVE), None)
        reference = float(np.median(wave.scores)) if wave is not None else 0.0
        if reference > 0:
            for label, method in by_label.items():
                ratios = method.scores.ravel() / reference
                fraction = (ratios[None, :] > PROFILE_RATIOS[:, None]).mean(axis=1)
                axis.plot(100 * PROFILE_RATIOS, fraction, color=palette[label], label=label)
            axis.legend(fontsize=8)
        axis.axvline(100, color="grey", linestyle="--", linewidth=1)
        axis.set_title(task)
        axis.set_xlabel("x: % of the wave's median")
        axis.set_ylabel("fraction of runs × seeds above x")
    figure.savefig(path, dpi=150)
    return Path(path)
