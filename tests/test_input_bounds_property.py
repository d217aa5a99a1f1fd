"""Property-based: extreme, negative, zero, NaN, infinite, huge and wrongly typed values of every setting of the
pipeline's config (enumerated from :class:`PipelineConfig`, so that a new setting is covered) and of every numeric
flag of every command (enumerated from the parsers) end either in a clean error naming the input, or in a value
within its bound. Nothing is run: the config is validated, the flags parsed and checked as `dpr` does first."""

from __future__ import annotations

import contextlib
import dataclasses
import io
import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dpr.checks import ParameterError
from dpr.cli.common import FLAG_BOUNDS, INT_FLAG_LIMIT, check_bounds
from dpr.cli.main import build_parser
from dpr.pipeline.config import COUNT_BOUNDS, PipelineConfig, load_config

SETTINGS = settings(max_examples=200, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow])
FIELDS = {field.name: field.type for field in dataclasses.fields(PipelineConfig)}
NAV = "dpr/Navigation-v0"

SPECIAL = [
    0,
    -1,
    1,
    2,
    2**31,
    2**32,
    2**63,
    10**12,
    10**30,
    -(10**30),
    math.nan,
    math.inf,
    -math.inf,
    1e308,
    -0.0,
    None,
    True,
    False,
    "",
    "abc",
    "10",
    [],
    {},
    [1, 2],
    {"a": 1},
]
SCALARS = st.one_of(
    st.sampled_from(SPECIAL), st.integers(-(2**70), 2**70), st.floats(allow_nan=True, allow_infinity=True)
)
HYPERPARAMS = [
    "n_steps",
    "batch_size",
    "n_epochs",
    "learning_rate",
    "gamma",
    "gae_lambda",
    "clip_range",
    "target_kl",
    "ent_coef",
    "vf_coef",
    "max_grad_norm",
    "n_timesteps",
]
ENV_KWARGS = ["reward_threshold_d", "start_radius", "approach_reward", "gate_distance", "action_repeat"]


def values_for(kind: str):
    """Values of the setting of type ``kind``: the right shape with extreme values, or the wrong shape."""
    if kind.startswith("list["):
        return st.one_of(st.lists(SCALARS, min_size=0, max_size=3), SCALARS)
    if kind.startswith("dict["):
        kwargs = st.dictionaries(st.sampled_from(ENV_KWARGS), SCALARS, max_size=2)
        return st.one_of(
            st.dictionaries(st.sampled_from(HYPERPARAMS), SCALARS, max_size=2),
            st.dictionaries(st.sampled_from(["navigation", "gate", "nowhere"]), st.one_of(kwargs, SCALARS), max_size=1),
            SCALARS,
        )
    return SCALARS


SETTING = st.sampled_from(sorted(FIELDS)).flatmap(lambda name: st.tuples(st.just(name), values_for(FIELDS[name])))
tried = {"config": 0, "flags": 0}


@SETTINGS
@given(SETTING)
def test_every_config_setting_is_refused_cleanly_or_within_bounds(setting):
    name, value = setting
    tried["config"] += 1
    overrides = {"tasks": ["navigation"], name: value} if name != "tasks" else {name: value}
    try:
        config = load_config(preset="tiny", **overrides)
    except ParameterError as error:  # names a setting (the one given, or the one it contradicts)
        assert error.parameter in FIELDS, error
        return
    for key, (minimum, maximum) in COUNT_BOUNDS.items():
        assert minimum <= getattr(config, key) <= maximum


# Arguments each command needs before its numeric flags are parsed.
REQUIRED = {
    "report": ["e.json", "--out", "o"],
    "train": ["--algo", "ppo", "--env", NAV],
    "finetune": ["--from", "m.zip", "--env", NAV],
    "finetune-decentralised": ["--from", "m.zip", "--env", NAV],
    "bc": ["--dataset", "d"],
    "bc-decentralised": ["--dataset", "d"],
    "collect": ["--env", NAV, "--out", "o"],
    "replay": ["d"],
}
NUMERIC_TYPES = {"positive_int", "non_negative_int", "int", "float", "parse_seeds", "<lambda>", "episode_index"}


def numeric_flags() -> list[tuple[str, str, str]]:
    """(command, flag, dest) of every option whose values are numbers."""
    parser = build_parser()
    commands = next(action for action in parser._actions if action.dest == "command").choices
    found = []
    for command, command_parser in commands.items():
        command_parser._define()
        for action in command_parser._actions:
            kind = getattr(action.type, "__name__", None)
            if action.option_strings and kind in NUMERIC_TYPES and action.dest not in ("tasks",):
                found.append((command, action.option_strings[0], action.dest))
    return found


FLAGS = numeric_flags()
TEXTS = st.one_of(
    st.integers(-(2**80), 2**80).map(str),
    st.sampled_from(["nan", "inf", "-inf", "1e309", "0", "-1", "", "abc", "1.5", "0x10", "9" * 5000, "0-9999999999"]),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
)


def test_the_flags_cover_every_command_with_numbers():
    commands = {command for command, _, _ in FLAGS}
    assert {"pipeline", "collect", "train", "finetune", "bc", "evaluate", "bench", "view"} <= commands
    assert ("pipeline", "--episodes", "episodes") in FLAGS and ("train", "--n-envs", "n_envs") in FLAGS


@SETTINGS
@given(st.sampled_from(FLAGS), TEXTS)
def test_every_numeric_flag_is_refused_cleanly_or_within_bounds(flag_entry, text):
    command, flag, dest = flag_entry
    tried["flags"] += 1
    parser = build_parser()
    stderr = io.StringIO()
    with contextlib.redirect_stderr(stderr):
        try:
            args = parser.parse_args([command, *REQUIRED.get(command, []), f"{flag}={text}"])
            check_bounds(args, args.command_parser)
        except SystemExit as exit_:
            assert exit_.code == 2
            assert flag in stderr.getvalue(), stderr.getvalue()
            return
    value = getattr(args, dest)
    minimum, maximum = FLAG_BOUNDS.get(dest, (-INT_FLAG_LIMIT, INT_FLAG_LIMIT))
    for item in value if isinstance(value, list) else [value]:
        if isinstance(item, float):
            assert math.isfinite(item)
        else:
            assert minimum <= item <= maximum


@pytest.fixture(scope="module", autouse=True)
def report_cases():
    yield
    print(f"\nhypothesis cases tried: {tried['config']} config settings, {tried['flags']} flag values")
