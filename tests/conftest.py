"""Shared set-up for the fast test suite: headless pygame, the registered ids, small env factories, a tiny
three-seed pipeline run."""

import os

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

import gymnasium as gym  # noqa: E402
import pytest  # noqa: E402
from helpers import THREE_SEEDS, run_tiny  # noqa: E402

import dpr  # noqa: E402,F401  (registers the ids)


@pytest.fixture
def make_env():
    """``make_env(env_id, **kwargs)``: gym.make with small defaults (disk model, 4 robots); closes them all."""
    made = []

    def factory(env_id="dpr/Navigation-v0", **kwargs):
        kwargs.setdefault("robot_model", "disk")
        kwargs.setdefault("n_robots", 4)
        env = gym.make(env_id, **kwargs)
        made.append(env)
        return env

    yield factory
    for env in made:
        env.close()


@pytest.fixture(scope="session")
def three_seeds(tmp_path_factory):
    """A tiny pipeline run with three training seeds, for tests that read it or copy it: (its folder, report, log
    lines)."""
    out = tmp_path_factory.mktemp("three_seeds") / "run"
    return out, *run_tiny(THREE_SEEDS, out)
