"""The paper's episode metrics on hand-made trajectories, the step-wise tracker, and summaries."""

import math

import numpy as np
import pytest

from dpr import metrics as M

GOAL = np.array([0.0, 0.0])


def test_straight_line_toward_goal():
    start = np.array([300.0, 400.0])  # 500 from the goal
    steps = np.linspace(0.0, 0.6, 13)[:, None]
    path = start * (1 - steps)  # 60% of the way to the goal, in 12 equal steps
    assert M.total_distance(path) == pytest.approx(300.0)
    assert M.net_displacement(path) == pytest.approx(300.0)
    assert M.projected_displacement(path, GOAL) == pytest.approx(300.0)
    assert M.success(path, GOAL) is False
    m = M.episode_metrics(path, GOAL)
    assert m.steps == 12
    assert m.as_dict() == {
        "projected_displacement": pytest.approx(300.0),
        "net_displacement": pytest.approx(300.0),
        "total_distance": pytest.approx(300.0),
        "success": False,
        "steps": 12,
    }


@pytest.mark.parametrize("side", [1.0, 7.5, 120.0])
def test_square_loop(side):
    start = np.array([-400.0, 250.0])
    corners = np.array([(0, 0), (side, 0), (side, side), (0, side), (0, 0)], dtype=float)
    # subdivide each edge so the path has many points
    path = np.concatenate(
        [np.linspace(a, b, 5, endpoint=False) for a, b in zip(corners[:-1], corners[1:])] + [corners[-1:]]
    )
    path = path + start
    assert M.total_distance(path) == pytest.approx(4 * side)
    assert M.net_displacement(path) == pytest.approx(0.0, abs=1e-9)
    assert M.projected_displacement(path, GOAL) == pytest.approx(0.0, abs=1e-9)


def test_perpendicular_motion_projects_to_zero():
    start = np.array([500.0, 0.0])
    path = np.array([start, start + (0, 30.0), start + (0, 80.0)])
    assert M.projected_displacement(path, GOAL) == pytest.approx(0.0, abs=1e-12)
    assert M.net_displacement(path) == pytest.approx(80.0)
    assert M.total_distance(path) == pytest.approx(80.0)


def test_moving_away_is_negative():
    start = np.array([0.0, -300.0])
    path = np.array([start, start + (0.0, -50.0)])
    assert M.projected_displacement(path, GOAL) == pytest.approx(-50.0)
    assert M.net_displacement(path) == pytest.approx(50.0)


def test_projection_uses_start_to_goal_direction():
    goal = np.array([100.0, 100.0])
    start = np.array([100.0, -200.0])  # goal straight up, 300 away
    path = np.array([start, (140.0, -150.0)])  # 50 up, 40 sideways
    assert M.projected_displacement(path, goal) == pytest.approx(50.0)
    assert M.net_displacement(path) == pytest.approx(math.hypot(40.0, 50.0))


@pytest.mark.parametrize("radius, expected", [(9.99, True), (10.01, False), (0.0, True), (50.0, False)])
def test_success_only_within_10(radius, expected):
    angle = 0.7
    closest = radius * np.array([math.cos(angle), math.sin(angle)])
    path = np.array([(500.0, 0.0), (100.0, 0.0), closest, (200.0, 0.0)])  # passes by and leaves again
    assert M.success(path, GOAL) is expected
    assert M.episode_metrics(path, GOAL).success is expected


def test_success_at_start_counts():
    assert M.success(np.array([(3.0, 4.0)]), GOAL) is True
    tracker = M.MetricTracker((3.0, 4.0), GOAL)
    assert tracker.success is True
    tracker = M.MetricTracker((30.0, 40.0), GOAL)
    assert tracker.success is False


def test_single_point_trajectory():
    path = np.array([(10.0, 20.0)])
    assert M.total_distance(path) == 0.0
    assert M.net_displacement(path) == 0.0
    assert M.projected_displacement(path, GOAL) == 0.0
    assert M.episode_metrics(path, GOAL).steps == 0


def test_start_on_goal_projection_is_zero():
    path = np.array([(0.0, 0.0), (5.0, 5.0)])
    assert M.projected_displacement(path, GOAL) == 0.0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_tracker_agrees_with_array_functions(seed):
    rng = np.random.default_rng(seed)
    goal = rng.uniform(-100, 100, 2)
    start = goal + rng.uniform(-600, 600, 2)
    path = start + np.cumsum(np.concatenate([[[0.0, 0.0]], rng.normal(0.0, 15.0, (300, 2))]), axis=0)
    tracker = M.MetricTracker(path[0], goal)
    for t, point in enumerate(path[1:], start=1):
        tracker.update(point)
        if t % 50 == 0 or t == len(path) - 1:
            prefix = path[: t + 1]
            assert tracker.total_distance == pytest.approx(M.total_distance(prefix), rel=1e-9)
            assert tracker.net_displacement == pytest.approx(M.net_displacement(prefix), rel=1e-9)
            assert tracker.projected_displacement == pytest.approx(
                M.projected_displacement(prefix, goal), rel=1e-9, abs=1e-9
            )
            assert tracker.success == M.success(prefix, goal)
            assert tracker.steps == t
    assert tracker.as_metrics() == M.EpisodeMetrics(
        tracker.projected_displacement, tracker.net_displacement, tracker.total_distance, tracker.success, 300
    )
    full = M.episode_metrics(path, goal)
    mine = tracker.as_metrics()
    assert mine.total_distance == pytest.approx(full.total_distance, rel=1e-9)
    assert mine.projected_displacement == pytest.approx(full.projected_displacement, rel=1e-9, abs=1e-9)
    assert mine.success == full.success and mine.steps == full.steps


def test_tracker_success_sticks():
    tracker = M.MetricTracker((100.0, 0.0), GOAL)
    tracker.update((5.0, 0.0))
    assert tracker.success
    tracker.update((300.0, 0.0))
    assert tracker.success  # success is "came within 10 at any step"


def test_tracker_does_not_alias_inputs():
    start = np.array([100.0, 0.0])
    tracker = M.MetricTracker(start, GOAL)
    point = np.array([90.0, 0.0])
    tracker.update(point)
    start[:] = 0.0
    point[:] = 1000.0
    assert tracker.net_displacement == pytest.approx(10.0)
    assert tracker.projected_displacement == pytest.approx(10.0)


def test_summarize():
    values = [3.0, -1.0, 10.0, 4.0]
    s = M.summarize(values)
    assert s["n"] == 4
    assert s["median"] == pytest.approx(3.5)
    assert s["min"] == -1.0 and s["max"] == 10.0
    assert s["mean"] == pytest.approx(4.0)
    assert s["std"] == pytest.approx(np.std(values))
    assert all(isinstance(s[k], float) for k in ("median", "min", "max", "mean", "std"))
    assert isinstance(s["n"], int)


def test_summarize_generator_and_bools():
    s = M.summarize(x > 1 for x in [0, 2, 3, 4])
    assert s["n"] == 4 and s["mean"] == pytest.approx(0.75) and s["median"] == 1.0


def test_summarize_single_and_empty():
    s = M.summarize([7.0])
    assert s == {"n": 1, "median": 7.0, "min": 7.0, "max": 7.0, "mean": 7.0, "std": 0.0}
    assert M.summarize([])["n"] == 0
