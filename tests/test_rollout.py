"""The one rollout loop (dpr.rollout.roll_out): its hooks, its physics-error rule, the info keys it reads, and
that evaluation, collection, the viewer and replay, which all run on it, see the same episode."""

import gymnasium as gym
import numpy as np
import pytest

import dpr.datasets.collect as collect_module
import dpr.evaluation.scoring as evaluation_module
from dpr.datasets.collect import CollectSpec, rollout
from dpr.datasets.mcap import read_mcap
from dpr.envs import AGENT_POSITION, PHYSICS_ERROR
from dpr.evaluation.scoring import run_episode
from dpr.metrics import episode_metrics
from dpr.policies import registry
from dpr.rollout import ReplayPolicy, RolloutResult, Step, roll_out
from dpr.viz import ViewRollout, rollout_episode

SMALL = {"n_robots": 4, "robot_model": "disk"}
STEPS = 30
BLOW_UP_AT = 12  # the env step whose physics blows up in the physics-error tests


def make_env(env_id="dpr/Navigation-v0", steps=STEPS, **kwargs):
    return gym.make(env_id, max_episode_steps=steps, **{**SMALL, **kwargs})


class BlowsUp:
    """``policy``, except that just before its ``at``-th action the world is given a non-finite velocity, so
    that the ``at``-th env step raises a physics error."""

    def __init__(self, policy, env, at: int = BLOW_UP_AT):
        self.policy, self.env, self.at, self.calls = policy, env, at, 0

    def reset(self, seed=None):
        self.calls = 0
        self.policy.reset(seed)

    def __call__(self, observation):
        self.calls += 1
        if self.calls == self.at:
            self.env.unwrapped.world.swarm.robot_bodies[0].velocity = (float("nan"), float("nan"))
        return self.policy(observation)


@pytest.fixture
def blowing_up(monkeypatch):
    """Every policy the registry makes blows up at step BLOW_UP_AT (for evaluate, collect and view alike)."""
    real = registry.make_policy

    def make_policy(name, env, *args):
        return BlowsUp(real(name, env, *args), env)

    monkeypatch.setattr(registry, "make_policy", make_policy)
    monkeypatch.setattr(collect_module, "make_policy", make_policy)
    monkeypatch.setattr(evaluation_module, "make_policy", make_policy)


# -- the loop ---------------------------------------------------------------------------------------------------
def test_hooks_see_the_reset_and_every_step_in_order():
    env = make_env()
    resets, steps = [], []
    result = roll_out(
        env,
        registry.make_policy("wave", env),
        3,
        on_reset=lambda observation, info: resets.append((observation.copy(), dict(info))),
        on_step=steps.append,
    )
    env.close()
    assert len(resets) == 1 and len(steps) == result.steps == STEPS
    assert [s.index for s in steps] == list(range(1, STEPS + 1))
    assert all(isinstance(s, Step) for s in steps)
    # each step's observation is what the previous step returned (the reset's for the first)
    np.testing.assert_array_equal(steps[0].observation, resets[0][0])
    for before, after in zip(steps, steps[1:]):
        assert after.observation is before.next_observation
    assert [s.done for s in steps] == [False] * (STEPS - 1) + [True]
    assert steps[-1].truncated and not steps[-1].terminated and result.truncated and not result.terminated
    np.testing.assert_array_equal(result.rewards, [s.reward for s in steps])
    np.testing.assert_array_equal(result.trajectory[0], resets[0][1][AGENT_POSITION])
    np.testing.assert_array_equal(result.trajectory[1:], [s.info[AGENT_POSITION] for s in steps])
    assert result.physics_error is None
    assert result.metrics == episode_metrics(result.trajectory, result.goal)


def test_the_same_seed_gives_the_same_episode_and_another_seed_another():
    def run(seed):
        env = make_env()
        try:
            return roll_out(env, registry.make_policy("random", env), seed)
        finally:
            env.close()

    a, b, c = run(5), run(5), run(6)
    np.testing.assert_array_equal(a.trajectory, b.trajectory)
    np.testing.assert_array_equal(a.rewards, b.rewards)
    assert not np.array_equal(a.trajectory, c.trajectory)


def test_steps_caps_the_episode_without_truncating_it():
    env = make_env()
    result = roll_out(env, registry.make_policy("wave", env), 0, 7)
    env.close()
    assert result.steps == 7 and result.trajectory.shape == (8, 2)
    assert not result.truncated and not result.terminated


@pytest.mark.parametrize(
    "env_id, same_as",
    [
        ("dpr/Navigation-v0", "centre_of_mass"),
        ("dpr/Gate-v0", "centre_of_mass"),
        ("dpr/Manipulation-v0", "object_position"),
    ],
)
def test_info_carries_the_agent_position(env_id, same_as):
    env = make_env(env_id)
    _, info = env.reset(seed=1)
    assert info[AGENT_POSITION].shape == (2,)
    np.testing.assert_array_equal(info[AGENT_POSITION], info[same_as])
    for _ in range(3):
        _, _, _, _, info = env.step(np.ones(4, dtype=np.int8))
        np.testing.assert_array_equal(info[AGENT_POSITION], info[same_as])
        np.testing.assert_array_equal(info[AGENT_POSITION], env.unwrapped._agent_position())
        assert info[AGENT_POSITION] is not info[same_as]  # a copy of its own: callers may keep or change it
    env.close()


def test_a_physics_error_stops_the_episode_before_the_step_that_blew_up():
    env = make_env()
    resets, steps = [], []
    policy = BlowsUp(registry.make_policy("wave", env), env)
    result = roll_out(env, policy, 0, on_reset=lambda o, i: resets.append(i), on_step=steps.append)
    env.close()
    assert policy.calls == BLOW_UP_AT  # the env did take the blown-up step ...
    assert result.physics_error and "non-finite" in result.physics_error
    assert result.truncated and not result.terminated
    # ... but it is not part of the episode: the hooks, the trajectory and the rewards end at the last sane state
    assert len(steps) == result.steps == len(result.rewards) == BLOW_UP_AT - 1
    assert result.trajectory.shape == (BLOW_UP_AT, 2) and np.isfinite(result.trajectory).all()
    assert all(PHYSICS_ERROR not in s.info for s in steps) and not steps[-1].done
    assert result.metrics.steps == BLOW_UP_AT - 1


def test_replay_policy_replays_an_episode():
    env = make_env()
    steps = []
    original = roll_out(env, registry.make_policy("random", env), 2, on_step=steps.append)
    replay = ReplayPolicy([s.action for s in steps])
    replayed = roll_out(env, replay, 2, len(replay))
    env.close()
    np.testing.assert_array_equal(replayed.trajectory, original.trajectory)
    np.testing.assert_array_equal(replayed.rewards, original.rewards)
    with pytest.raises(IndexError, match="recorded actions"):
        replay(None)
    replay.reset()
    assert replay(None) is steps[0].action


# -- every caller sees the same episode ------------------------------------------------------------------------
def _three_ways(env_id: str, seed: int, tmp_path) -> tuple:
    """The agent's trajectory of the wave on ``env_id`` from ``seed`` as evaluate, collect and view see it."""
    evaluated = run_episode(env_id, "wave", seed, steps=STEPS, env_kwargs=SMALL)
    spec = CollectSpec(env_id, policy="wave", steps=STEPS, **SMALL)
    collected = rollout(spec, seed, tmp_path / f"{seed}.mcap")
    viewed = rollout_episode(ViewRollout(env_id, "wave", seed, steps=STEPS, **SMALL))
    return evaluated, collected, viewed, read_mcap(tmp_path / f"{seed}.mcap")


@pytest.mark.parametrize("env_id", ["dpr/Navigation-v0", "dpr/Manipulation-v0"])
def test_evaluate_collect_and_view_give_the_same_trajectory(env_id, tmp_path):
    evaluated, collected, viewed, logged = _three_ways(env_id, 4, tmp_path)
    assert evaluated.trajectory.shape == (STEPS + 1, 2)
    np.testing.assert_array_equal(collected.trajectory, evaluated.trajectory)
    np.testing.assert_array_equal(viewed.agent, evaluated.trajectory)
    agent = logged.object_poses[:, 0:2] if logged.object_poses is not None else logged.centres_of_mass
    np.testing.assert_array_equal(agent, evaluated.trajectory)
    assert collected.metrics == evaluated.metrics
    assert collected.frames == evaluated.metrics.steps == len(viewed.rewards) == STEPS
    np.testing.assert_array_equal(viewed.rewards.astype(np.float32), collected.rewards)


def test_evaluate_collect_and_view_apply_the_same_physics_error_rule(blowing_up, tmp_path):
    evaluated, collected, viewed, logged = _three_ways("dpr/Navigation-v0", 1, tmp_path)
    sane = BLOW_UP_AT - 1
    assert evaluated.trajectory.shape == (sane + 1, 2) and np.isfinite(evaluated.trajectory).all()
    np.testing.assert_array_equal(collected.trajectory, evaluated.trajectory)
    np.testing.assert_array_equal(viewed.agent, evaluated.trajectory)
    np.testing.assert_array_equal(logged.centres_of_mass, evaluated.trajectory)  # the MCAP log holds sane states
    assert collected.physics_error and "non-finite" in collected.physics_error
    assert collected.frames == len(collected.observations) == len(collected.rewards) == sane
    assert collected.metrics == evaluated.metrics and evaluated.metrics.steps == sane
    assert not collected.dones.any()  # the episode did not end in a recorded step: it ended in the blown-up one
    assert len(viewed.rewards) == sane


def test_collect_with_pixels_keeps_one_image_per_frame_after_a_physics_error(blowing_up):
    record = rollout(CollectSpec("dpr/Navigation-v0", steps=STEPS, pixels=True, image_size=32, **SMALL), 0)
    assert record.physics_error
    assert record.images.shape == (BLOW_UP_AT - 1, 32, 32, 3) == (record.frames, 32, 32, 3)


def test_rollout_result_metrics_follow_its_trajectory():
    trajectory = np.array([[0.0, 100.0], [0.0, 50.0], [0.0, 5.0]])
    result = RolloutResult(seed=0, trajectory=trajectory, rewards=np.zeros(2), goal=np.zeros(2))
    assert result.steps == 2
    assert result.metrics.projected_displacement == pytest.approx(95.0)
    assert result.metrics.success
