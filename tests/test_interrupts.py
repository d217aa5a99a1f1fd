"""A Ctrl-C that a callback from C code swallowed still stops the work at the next step; a Ctrl-C that arrives while
a result is awaited is raised after the wait, never inside a lock's wait; `dpr evaluate` in worker processes stops at
once (collection: test_collect_interrupts.py)."""

from __future__ import annotations

import os
import signal
import time
from concurrent.futures import ThreadPoolExecutor

import gymnasium as gym
import pytest
from helpers import assert_group_ends, failed_if_left_running, start_dpr_as_typed

import dpr  # noqa: F401
from dpr import interrupts
from dpr.policies.registry import make_policy
from dpr.rollout import roll_out


@pytest.fixture
def installed():
    previous = signal.getsignal(signal.SIGINT)
    interrupts.install()
    yield
    signal.signal(signal.SIGINT, previous)
    interrupts._pending = False


def swallowed_ctrl_c() -> None:
    """SIGINT delivered while Python code runs under C, whose callback machinery prints and drops exceptions."""
    try:
        os.kill(os.getpid(), signal.SIGINT)
        for _ in range(1000):  # the handler runs at the next bytecode boundary
            pass
    except KeyboardInterrupt:
        pass  # what cffi does with an exception raised in a callback


def test_an_episode_stops_at_the_next_step_after_a_swallowed_ctrl_c(installed):
    env = gym.make("dpr/Navigation-v0", robot_model="disk", n_robots=4)
    policy = make_policy("wave", env)
    steps = []

    def on_step(step):
        steps.append(step.index)
        if step.index == 3:
            swallowed_ctrl_c()

    with pytest.raises(KeyboardInterrupt):
        roll_out(env, policy, seed=0, steps=50, on_step=on_step)
    assert steps == [1, 2, 3]
    interrupts.raise_if_interrupted()  # raised once: the note is cleared
    roll_out(env, policy, seed=0, steps=5)  # and the next episode runs


def test_training_stops_at_the_next_step_after_a_swallowed_ctrl_c(installed, tmp_path):
    from dpr.rl.train import TrainConfig, train

    config = TrainConfig("ppo", "dpr/Navigation-v0", n_robots=4, timesteps=4096, steps_per_episode=32, eval_episodes=1)
    swallowed_ctrl_c()
    result = train(config, tmp_path / "run", show_progress=False, log=lambda line: None)
    assert result.interrupted
    assert result.model_path.is_file()  # what was learned so far is kept


def test_ctrl_c_while_awaiting_a_result_is_raised_after_the_wait(installed):
    """Raised inside a lock's wait (a pool's next result, a future's), KeyboardInterrupt can leave the lock released
    twice and surface as RuntimeError("release unlocked lock"): the wait runs to its end first."""
    calls: list[str] = []

    def wait(timeout: float) -> str:
        calls.append("wait")
        if len(calls) == 1:
            raise TimeoutError  # no result yet: waited again
        os.kill(os.getpid(), signal.SIGINT)  # Python would raise at the next bytecode, inside the wait
        calls.append("ran to its end")
        return "result"

    with pytest.raises(KeyboardInterrupt):
        interrupts.wait_deferring_sigint(wait)
    assert calls == ["wait", "wait", "ran to its end"]
    assert signal.getsignal(signal.SIGINT) is interrupts._on_sigint


def test_first_completed_returns_the_finished_futures_and_delivers_a_ctrl_c(installed):
    with ThreadPoolExecutor(2) as pool:
        quick, slow = pool.submit(time.sleep, 0.0), pool.submit(time.sleep, 0.5)
        assert quick in interrupts.first_completed([quick, slow])
        pool.submit(lambda: (time.sleep(0.05), os.kill(os.getpid(), signal.SIGINT)))
        with pytest.raises(KeyboardInterrupt):
            interrupts.first_completed([slow])
        assert interrupts.first_completed([slow]) == {slow}  # the future's lock still works


def test_cli_evaluate_in_workers_stops_at_once_on_ctrl_c(tmp_path):
    """A SIGINT sent to `dpr evaluate` alone (a job manager's, or a terminal's that its workers ignore) ends its
    workers and the run within seconds, not after every queued episode (30 paddle episodes: over a minute), and says
    so instead of a traceback."""
    log = tmp_path / "evaluate.log"
    argv = ["evaluate", "--policy", "wave", "--env", "dpr/Navigation-v0", "--seeds", "0-29", "--workers", "2"]
    process = start_dpr_as_typed(argv, log)
    with failed_if_left_running(process, log, "dpr evaluate did not exit within 15 s of Ctrl-C"):
        deadline = time.monotonic() + 60
        while "1/30" not in log.read_text() and process.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)  # the pool runs: its first episode is scored
        assert process.poll() is None, log.read_text()
        os.kill(process.pid, signal.SIGINT)
        process.wait(timeout=15)
    output = log.read_text()
    assert process.returncode == 130, output
    assert "dpr evaluate: interrupted" in output and "Traceback" not in output
    assert_group_ends(process.pid, "worker processes outlived dpr evaluate")
