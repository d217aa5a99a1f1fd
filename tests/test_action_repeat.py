"""Temporal abstraction: ``action_repeat=k`` applies each action for k physics steps, and every tool that counts
an episode (evaluation, collection, training, the pipeline) counts it in physics steps or derives its env steps."""

import gymnasium as gym
import numpy as np
import pytest

import dpr  # noqa: F401
from dpr.checks import ParameterError
from dpr.datasets.collect import CollectSpec
from dpr.envs import MAX_EPISODE_STEPS, episode_steps
from dpr.envs.particle_env import seconds_per_step, steps_per_second
from dpr.evaluation.scoring import evaluate
from dpr.metrics import MetricTracker
from dpr.pipeline.config import (
    PER_PHASE,
    PIPELINE_ENV_KWARGS,
    PipelineConfig,
    learner_env_kwargs,
    preset_config,
)
from dpr.rl.recipe import physics_discount
from dpr.rl.train import TrainConfig


@pytest.mark.parametrize("env_id", ["dpr/Navigation-v0", "dpr/Manipulation-v0"])
def test_one_repeated_step_is_k_steps_of_the_same_action(env_id):
    kwargs = {"obs_last_action": True}
    if env_id == "dpr/Manipulation-v0":
        kwargs["approach_reward"] = 1.0  # a reward term of the task's own is summed too
    single = gym.make(env_id, **kwargs)
    repeated = gym.make(env_id, action_repeat=4, **kwargs)
    single.reset(seed=3)
    repeated.reset(seed=3)
    rng = np.random.default_rng(0)
    for _ in range(6):
        action = rng.integers(0, 2, 9)
        total = 0.0
        for _ in range(4):
            obs, reward, *_, info = single.step(action)
            total += reward
        obs_k, reward_k, terminated, truncated, info_k = repeated.step(action)
        np.testing.assert_array_equal(obs_k, obs)
        assert reward_k == pytest.approx(total, abs=1e-12)
        assert info_k["projected_displacement"] == info["projected_displacement"]
        assert not (terminated or truncated)
    assert total != 0.0  # the swarm did move: the comparison was not of two still worlds


def test_a_repeated_step_stops_at_the_goal(monkeypatch):
    env = gym.make("dpr/Navigation-v0", action_repeat=50).unwrapped
    env.reset(seed=0)
    # a goal 5 units from the swarm, within the success radius of 10: the first physics step ends the episode
    env._tracker = MetricTracker(env._agent_position(), env._agent_position() + np.array([5.0, 0.0]))
    physics_steps = []
    step = env.world.step
    monkeypatch.setattr(env.world, "step", lambda targets: physics_steps.append(1) or step(targets))
    _, _, terminated, truncated, info = env.step(np.zeros(9, dtype=np.int64))
    assert terminated and not truncated and info["is_success"]
    assert len(physics_steps) == 1


def test_the_held_count_counts_physics_steps():
    env = gym.make("dpr/Navigation-v0", obs_last_action=True, action_repeat=5).unwrapped
    env.reset(seed=0)
    action = np.ones(9, dtype=np.int64)
    obs, *_ = env.step(action)
    assert obs[-1] == pytest.approx(5 / 20)
    obs, *_ = env.step(action)
    assert obs[-1] == pytest.approx(10 / 20)


@pytest.mark.parametrize("bad", [0, -1, 2.5, True, MAX_EPISODE_STEPS + 1])
def test_a_bad_action_repeat_is_refused_by_name(bad):
    with pytest.raises(ValueError, match="action_repeat"):
        gym.make("dpr/Navigation-v0", action_repeat=bad)
    with pytest.raises(ValueError, match="action_repeat"):
        episode_steps({"action_repeat": bad})


def test_episode_steps_divides_the_physics_steps():
    assert episode_steps({}) == MAX_EPISODE_STEPS
    assert episode_steps({"action_repeat": 10}) == MAX_EPISODE_STEPS // 10
    assert episode_steps({"action_repeat": 3}, 10) == 4  # the last decision may run past the end: ceil


@pytest.mark.parametrize(
    "repeat, seconds, rate", [(1, 0.1, 10), (2, 0.2, 5), (6, 0.6, 10 / 6), (7, 0.7, 10 / 7), (10, 1.0, 1)]
)
def test_an_env_step_lasts_its_physics_steps(repeat, seconds, rate):
    """One source of truth for simulated time: an env step is action_repeat physics steps of 0.1 s."""
    kwargs = {"action_repeat": repeat}
    assert seconds_per_step(kwargs) == seconds and steps_per_second(kwargs) == rate
    assert isinstance(steps_per_second(kwargs), int) == (10 % repeat == 0)  # an integer fps where there is one
    env = gym.make("dpr/Navigation-v0", **kwargs)
    assert env.metadata["render_fps"] == rate  # a video of its frames plays in simulated time
    assert gym.make("dpr/Navigation-v0").metadata["render_fps"] == 10  # (the class keeps its own)


def test_the_markov_wave_keeps_its_gait_under_a_repeat_of_its_hold():
    """The wave holds each phase 10 steps, so deciding every 10 steps loses nothing: over the same physics steps
    (evaluate's ``steps``) it moves the swarm exactly as far."""
    every_step, every_tenth = (
        evaluate(["dpr/Navigation-v0"], "wave-markov", [5], steps=300, env_kwargs={**PIPELINE_ENV_KWARGS, **extra})
        for extra in ({}, {"action_repeat": 10})
    )
    assert every_step[0].metrics.projected_displacement == every_tenth[0].metrics.projected_displacement
    assert len(every_step[0].trajectory) == 301 and len(every_tenth[0].trajectory) == 31
    assert abs(every_step[0].metrics.projected_displacement) > 0.5


def test_collection_and_training_default_to_a_whole_episode_of_decisions():
    assert CollectSpec("dpr/Navigation-v0", env_kwargs={"action_repeat": 10}).steps == 250
    assert CollectSpec("dpr/Navigation-v0").steps == MAX_EPISODE_STEPS
    assert TrainConfig("ppo", "dpr/Navigation-v0", env_kwargs={"action_repeat": 5}).steps_per_episode == 500


def test_the_pipeline_budgets_physics_steps_and_refuses_a_repeat_that_breaks_the_teachers_gait():
    config = PipelineConfig(action_repeat=10, finetune_steps=30_000, critic_warmup=10_000, episodes=4)
    assert learner_env_kwargs(10, 10) == {**PIPELINE_ENV_KWARGS, "action_repeat": 10}
    assert learner_env_kwargs(1, 10) == PIPELINE_ENV_KWARGS  # k=1 models keep theirs
    assert learner_env_kwargs(PER_PHASE, 7)["action_repeat"] == 7  # once per phase of the task's teacher
    assert physics_discount(7) == round(0.99**7, 3)
    assert config.rl_steps == 4 * MAX_EPISODE_STEPS + 10_000 + 30_000
    for bad in (3, 4, -1):
        with pytest.raises(ParameterError, match="action_repeat"):
            preset_config("small", action_repeat=bad)


def test_an_evaluation_records_its_episodes_in_physics_steps():
    """`dpr evaluate --json` rows: steps the physics steps an episode lasted, and the path a point every 10 physics
    steps, whether the policy decides every step or every 5."""
    small = {"n_robots": 4, "robot_model": "disk"}
    every_step, every_five = (
        evaluate(["dpr/Navigation-v0"], "wave", seeds=[0], steps=40, env_kwargs={**small, **repeat})[0].as_dict(True)
        for repeat in ({}, {"action_repeat": 5})
    )
    assert every_step["steps"] == every_five["steps"] == 40
    assert "action_repeat" not in every_step and every_five["action_repeat"] == 5
    assert len(every_step["trajectory"]) == len(every_five["trajectory"]) == 5  # physics steps 0, 10, .., 40
