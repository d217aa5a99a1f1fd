"""Property-based checks (hypothesis) that keep whole classes of defects closed, not just their examples:

- any env kwargs give either a working env or a ValueError/TypeError at construction, never a crash later;
- an accepted env gives finite observations inside its observation space and finite rewards, for any action
  its action space holds, and replays identically from the same seed;
- malformed actions are refused with a ValueError/TypeError, never passed to the physics;
- a refused command line leaves every file in its way untouched.
"""

from __future__ import annotations

import math
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from helpers import tree_hash
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import dpr  # noqa: F401  (registers the env ids)
from dpr.envs.tasks import TASKS

STEPS = 4
PROPERTY_SETTINGS = settings(
    max_examples=40, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow]
)

# Numbers that broke envs before: infinities, NaN, zero, negatives, tiny and astronomic magnitudes, strings.
HOSTILE_NUMBERS = st.sampled_from(
    [math.inf, -math.inf, math.nan, 0.0, -1.0, 1e-300, 1e300, 1e6, "3", None, True, [1.0]]
)
PLAUSIBLE_FLOATS = st.floats(min_value=-1e4, max_value=1e4, allow_nan=False)
FLOAT_VALUES = st.one_of(HOSTILE_NUMBERS, PLAUSIBLE_FLOATS)
INT_VALUES = st.one_of(st.integers(min_value=-5, max_value=20), st.sampled_from([2.5, "4", None, True, 10**12]))

COMMON_KWARGS = {
    "n_robots": INT_VALUES,
    "robot_model": st.sampled_from(["paddle", "disk", "wheel", 3]),
    "action_type": st.sampled_from(["multibinary", "discrete", "continuous", "binary"]),
    "reward": st.sampled_from(["piecewise", "projected", "inverse_distance", "sparse"]),
    "reward_threshold_d": FLOAT_VALUES,
    "start_radius": st.one_of(st.tuples(FLOAT_VALUES, FLOAT_VALUES), HOSTILE_NUMBERS),
    "obs_last_action": st.sampled_from([False, True, 1, "yes"]),
    "image_size": st.sampled_from([16, 32, 8, 100_000, 24.0]),
}
TASK_KWARGS = {
    "dpr/Navigation-v0": {},
    "dpr/Gate-v0": {"gate_width": FLOAT_VALUES},
    "dpr/Gate-v1": {"gate_width": FLOAT_VALUES, "gate_distance": st.one_of(st.none(), FLOAT_VALUES)},
    "dpr/Gate-v2": {
        "gate_width": FLOAT_VALUES,
        "gate_distance": st.one_of(st.none(), FLOAT_VALUES),
        "observe_opening": st.sampled_from([True, False, 1, "yes"]),
    },
    "dpr/Unresponsive-v0": {"n_dead": st.one_of(st.none(), INT_VALUES)},
    "dpr/Manipulation-v0": {
        "object_type": st.sampled_from(["ball", "box", "cube"]),
        "object_mass": FLOAT_VALUES,
        "object_size": FLOAT_VALUES,
        "object_start": st.sampled_from(["touching", "paper", "far"]),
        "approach_reward": FLOAT_VALUES,
    },
}


@st.composite
def env_kwargs(draw: st.DrawFn, env_id: str) -> dict:
    """A random subset of the task's kwargs, each drawn from plausible and hostile values."""
    choices = {**COMMON_KWARGS, **TASK_KWARGS[env_id]}
    names = draw(st.lists(st.sampled_from(sorted(choices)), unique=True, max_size=4))
    return {name: draw(choices[name]) for name in names}


def make_or_refuse(env_id: str, kwargs: dict) -> gym.Env | None:
    """The env, or None when its constructor refused the kwargs the way it promises to."""
    try:
        return gym.make(env_id, robot_model=kwargs.pop("robot_model", "disk"), **kwargs)
    except (ValueError, TypeError) as error:
        assert str(error), "a refusal must say what is wrong"
        return None


def roll(env: gym.Env, seed: int) -> list[tuple[np.ndarray, float]]:
    """A few steps of seeded random actions; every observation and reward checked finite and in bounds."""
    obs, _ = env.reset(seed=seed)
    env.action_space.seed(seed)
    trace = []
    for _ in range(STEPS):
        assert env.observation_space.contains(obs)
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert "physics_error" not in info, info["physics_error"]
        assert math.isfinite(reward)
        trace.append((np.array(obs, copy=True), float(reward)))
        if terminated or truncated:
            break
    assert env.observation_space.contains(obs)
    return trace


@pytest.mark.parametrize("env_id", sorted(TASKS))  # every registered id, earlier versions too
def test_any_kwargs_give_a_sound_env_or_a_clear_refusal(env_id: str) -> None:
    @PROPERTY_SETTINGS
    @given(kwargs=env_kwargs(env_id), seed=st.integers(0, 2**31 - 1))
    def check(kwargs: dict, seed: int) -> None:
        if isinstance(kwargs.get("n_robots"), int) and kwargs["n_robots"] > 16:
            kwargs["n_robots"] = 16  # keep each example fast; large swarms have their own tests
        env = make_or_refuse(env_id, dict(kwargs))
        if env is None:
            return
        first = roll(env, seed)
        again = roll(env, seed)
        assert len(first) == len(again)
        for (obs_a, reward_a), (obs_b, reward_b) in zip(first, again):
            np.testing.assert_array_equal(obs_a, obs_b)
            assert reward_a == reward_b
        env.close()

    check()


MALFORMED_ACTIONS = st.one_of(
    st.sampled_from([None, "0101", [0, 1], 2**40, -1, 1.5, np.full(9, np.nan), np.full(9, 2), np.zeros((3, 3))]),
    st.lists(st.integers(-3, 3), min_size=0, max_size=12).map(np.array),
)


@pytest.mark.parametrize("action_type", ["multibinary", "discrete", "continuous"])
def test_malformed_actions_are_refused(action_type: str) -> None:
    env = gym.make("dpr/Navigation-v0", robot_model="disk", action_type=action_type)
    env.reset(seed=0)

    @PROPERTY_SETTINGS
    @given(action=MALFORMED_ACTIONS)
    def check(action) -> None:
        if env.action_space.contains(action) if isinstance(action, np.ndarray) else False:
            return  # a valid action drawn by chance
        try:
            _, reward, *_ = env.step(action)
        except (ValueError, TypeError):
            return
        # Accepted: it must have been a sensible encoding of a legal action (e.g. an int array of 0/1).
        assert math.isfinite(reward)

    check()


BAD_COLLECT_ARGUMENTS = st.sampled_from(
    [
        ["--episodes", "0"],
        ["--episodes", "-3"],
        ["--n-robots", "0"],
        ["--n-robots", "100001"],
        ["--seed", "-1"],
        ["--workers", "0"],
        ["--pixels", "--image-size", "100000"],
        ["--env-kwarg", "object_mass=Infinity"],
        ["--env-kwarg", "reward_threshold_d=nan"],
        ["--env-kwarg", "gate_width=wide"],
        ["--env", "dpr/Nowhere-v0"],
        ["--policy", "no-such-policy"],
        ["--steps", "0"],
    ]
)


@PROPERTY_SETTINGS
@given(bad=st.lists(BAD_COLLECT_ARGUMENTS, min_size=1, max_size=2))
def test_a_refused_collect_touches_no_file(bad: list[list[str]], tmp_path_factory: pytest.TempPathFactory) -> None:
    """``dpr collect`` into an existing dataset, with bad arguments: a clear error, exit 2, and the dataset's
    bytes unchanged."""
    from dpr.cli import main

    root = existing_dataset(tmp_path_factory)
    before = tree_hash(root)
    argv = ["collect", "--env", "dpr/Manipulation-v0", "--robot-model", "disk", "--episodes", "2", "--steps", "5"]
    argv += ["--out", str(root)] + [token for pair in bad for token in pair]
    try:
        status = main(argv)
    except SystemExit as exit_:  # argparse refuses malformed flags itself
        status = exit_.code
    assert status == 2
    assert tree_hash(root) == before


_DATASET: dict[str, Path] = {}


def existing_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One small finished dataset shared by every example (built once)."""
    if "root" not in _DATASET:
        from dpr.cli import main

        root = tmp_path_factory.mktemp("properties") / "dataset"
        argv = ["collect", "--env", "dpr/Manipulation-v0", "--robot-model", "disk", "--episodes", "2"]
        assert main(argv + ["--steps", "5", "--out", str(root)]) == 0
        _DATASET["root"] = root
    return _DATASET["root"]
