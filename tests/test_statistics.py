"""Interval estimates in `dpr report`: training runs under one label, IQM and median with stratified bootstrap
CIs, the IQM ratio to the wave (paired on test seeds) and the probability of improvement."""

import numpy as np
import pytest
from PIL import Image
from test_report import _episode, _write

from dpr.evaluation.report import load_evaluation, method_scores, results_table, write_report
from dpr.evaluation.statistics import interval_rows, interval_table, probability_of_improvement

NAV = "dpr/Navigation-v0"
SEEDS = range(100, 120)
REPS = 300  # enough for a stable interval in a test; reports use 2000


def _evaluations(tmp_path, runs: dict[str, list[float]], wave=lambda seed: 10.0 + seed % 7):
    """A wave file and one file per (label, run): run r of a method scores ``factor * wave`` on every seed."""
    paths, labels = [_write(tmp_path / "wave.json", "wave", [_episode(NAV, s, wave(s)) for s in SEEDS])], ["wave"]
    for label, factors in runs.items():
        for run, factor in enumerate(factors):
            episodes = [_episode(NAV, s, factor * wave(s)) for s in SEEDS]
            paths.append(_write(tmp_path / f"{label}-{run}.json", f"models/{label}-seed{run}.zip", episodes))
            labels.append(label)
    return paths, labels


def test_runs_sharing_a_label_are_one_method(tmp_path):
    paths, labels = _evaluations(tmp_path, {"bc-ppo": [1.2, 1.3, 1.4]})
    evaluations = [load_evaluation(path, label) for path, label in zip(paths, labels)]
    methods = method_scores(evaluations)["Navigation"]
    assert methods["bc-ppo"].scores.shape == (len(SEEDS), 3)
    assert methods["wave"].scores.shape == (len(SEEDS), 1)
    assert "| Navigation | bc-ppo |" in results_table(evaluations)  # the classic table pools the runs
    wave_row, method_row = interval_rows(method_scores(evaluations), reps=REPS)
    assert wave_row.ratio is None and method_row.n_runs == 3 and method_row.n_seeds == len(SEEDS)
    value, low, high = method_row.ratio
    assert value == pytest.approx(1.3, abs=0.02)  # the middle run's factor: the IQM of scaled copies
    assert low <= value <= high and 1.15 < low and high < 1.45
    assert method_row.p_improvement[0] > 0.6
    for value, low, high in (method_row.median, method_row.iqm):
        assert low <= value <= high


def test_a_method_equal_to_the_wave_is_even():
    scores = np.arange(30, dtype=float)[:, None]
    assert probability_of_improvement(scores, scores) == pytest.approx(0.5)
    assert probability_of_improvement(scores + 1, scores) > 0.5 > probability_of_improvement(scores - 1, scores)


def test_runs_on_different_seeds_are_refused(tmp_path):
    paths, labels = _evaluations(tmp_path, {"bc": [1.0]})
    other = _write(tmp_path / "bc-other.json", "models/bc-seed9.zip", [_episode(NAV, s, 5.0) for s in range(5)])
    with pytest.raises(ValueError, match="every run must be scored once on the same seeds"):
        write_report([*paths, other], tmp_path / "report", labels=[*labels, "bc"])
    assert not (tmp_path / "report").exists()


def test_report_writes_the_interval_section_and_figures(tmp_path):
    paths, labels = _evaluations(tmp_path, {"bc": [0.9, 1.0, 1.1], "ppo": [0.1, 0.2, 0.0]})
    written = write_report(paths, tmp_path / "report", labels=labels, bootstrap_reps=REPS)
    text = (tmp_path / "report" / "results.md").read_text()
    assert "## Interval estimates" in text and "| Navigation | bc | 3 × 20 |" in text
    for name in ("intervals.png", "profile.png"):
        assert tmp_path / "report" / name in written
        assert Image.open(tmp_path / "report" / name).size[0] > 300


def test_the_estimates_are_rliables_statistics():
    from rliable import metrics

    from dpr.evaluation.statistics import iqm

    rng = np.random.default_rng(3)
    for n in (1, 4, 7, 50, 150):
        values = rng.normal(size=n)
        assert iqm(values) == pytest.approx(metrics.aggregate_iqm(values))
    x, y = rng.integers(0, 5, size=(20, 3)).astype(float), rng.integers(0, 5, size=(20, 3)).astype(float)
    assert probability_of_improvement(x, y) == pytest.approx(metrics.probability_of_improvement(x, y))


def _interval_rows(paths, labels):
    """The report's interval rows of freshly loaded evaluation files."""
    return interval_rows(method_scores([load_evaluation(p, label) for p, label in zip(paths, labels)]), reps=REPS)


def test_the_same_scores_give_the_same_intervals(tmp_path):
    paths, labels = _evaluations(tmp_path, {"bc": [0.8, 1.1, 1.3]}, wave=lambda seed: 10.0 + (seed * 7919) % 13)
    rows = [_interval_rows(paths, labels), _interval_rows(paths, labels)]
    assert rows[0] == rows[1]
    assert rows[0][1].iqm[1] < rows[0][1].iqm[2]  # an interval, not a point


def test_the_ratio_to_the_wave_is_paired_on_seeds(tmp_path):
    # Starts differ a lot in difficulty, and the method moves 1.2 times as far as the wave on every one of them:
    # resampling both on the same seeds leaves no doubt about the ratio, while the IQM itself is uncertain.
    paths, labels = _evaluations(tmp_path, {"bc-ppo": [1.2]}, wave=lambda seed: 5.0 + 3.0 * (seed % 10))
    _, row = _interval_rows(paths, labels)
    assert row.ratio == pytest.approx((1.2, 1.2, 1.2))
    assert row.iqm[2] - row.iqm[1] > 5.0


def test_no_ratio_interval_where_the_waves_iqm_can_fall_to_zero(tmp_path):
    # A wave that barely moves (a few starts forward, most at 0 or behind): some bootstrap samples give it an IQM
    # of 0 or less, and a ratio to that is unbounded. The ratio is left out; P(> wave) stays.
    paths, labels = _evaluations(tmp_path, {"bc": [1.0]}, wave=lambda seed: [-0.2, 0.0, 0.0, 0.1, 0.9][seed % 5])
    wave_row, row = _interval_rows(paths, labels)
    assert row.ratio is None and row.p_improvement is not None
    assert "| Navigation | bc | 1 × 20 |" in interval_table([wave_row, row])
    assert "| — |" in interval_table([row])
