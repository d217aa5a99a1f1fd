"""Bad arguments and bad actions raise ValueError naming the culprit, before any simulation; physics
blow-ups truncate the episode instead of returning garbage."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.envs.registration import load_env_creator
from helpers import ENV_IDS, ROBOT_MODELS

from dpr.policies.wave import WavePolicy

# ---------------------------------------------------------------------------------------------------------
# Constructor arguments


@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"robot_model": "wheel"}, "robot_model"),
        ({"robot_model": None}, "robot_model"),
        ({"action_type": "box"}, "action_type"),
        ({"obs_type": "rgb"}, "obs_type"),
        ({"reward": "sparse"}, "reward"),
        ({"render_mode": "human"}, "render_mode"),
        ({"render_mode": "rgb"}, "render_mode"),
        ({"n_robots": 0}, "n_robots"),
        ({"n_robots": -1}, "n_robots"),
        ({"n_robots": 2.5}, "n_robots"),
        ({"n_robots": 4.0}, "n_robots"),
        ({"n_robots": True}, "n_robots"),
        ({"n_robots": "4"}, "n_robots"),
        ({"action_type": "discrete", "n_robots": 17}, "n_robots"),
        ({"reward_threshold_d": 0.0}, "reward_threshold_d"),
        ({"reward_threshold_d": -5.0}, "reward_threshold_d"),
        ({"start_radius": (500.0, 400.0)}, "start_radius"),
        ({"image_size": 4}, "image_size"),
        ({"image_size": 100_000}, "image_size"),
        ({"n_robots": 100_000}, "n_robots"),
        ({"render_size": 0}, "render_size"),
    ],
)
def test_bad_common_kwargs(env_id, kwargs, name):
    kwargs = {"robot_model": "disk", **kwargs}
    # the env class itself: gym.make(render_mode="human") would construct it with "rgb_array" and wrap
    # it in gymnasium's HumanRendering instead
    env_class = load_env_creator(gym.spec(env_id).entry_point)
    with pytest.raises(ValueError, match=name):
        env_class(**kwargs)
    if "render_mode" not in kwargs:
        with pytest.raises(ValueError, match=name):
            gym.make(env_id, **kwargs)


def test_discrete_limit_is_16():
    env = gym.make("dpr/Navigation-v0", robot_model="disk", n_robots=16, action_type="discrete")
    assert env.action_space.n == 2**16
    env.close()


def test_numpy_integer_n_robots_is_accepted():
    env = gym.make("dpr/Navigation-v0", robot_model="disk", n_robots=np.int64(3))
    assert env.unwrapped.n_robots == 3
    obs, _ = env.reset(seed=0)
    assert obs.shape == (18,)
    env.close()


@pytest.mark.parametrize("n_dead", [9, 10, -1, 2.5, True])
def test_bad_n_dead(n_dead):
    with pytest.raises(ValueError, match="n_dead"):
        gym.make("dpr/Unresponsive-v0", robot_model="disk", n_robots=9, n_dead=n_dead)


def test_n_dead_edges_are_accepted():
    for n_dead in (0, 8):
        env = gym.make("dpr/Unresponsive-v0", robot_model="disk", n_robots=9, n_dead=n_dead)
        _, info = env.reset(seed=0)
        assert len(info["dead_robots"]) == n_dead
        env.close()


@pytest.mark.parametrize(
    "robot_model, width",
    [
        ("paddle", 77.5),
        ("paddle", 50.0),
        ("paddle", 0.0),
        ("paddle", -10.0),
        ("disk", 77.5),
        ("disk", 60.0),
    ],
)
def test_gate_narrower_than_one_robot(robot_model, width):
    with pytest.raises(ValueError, match="gate_width"):
        gym.make("dpr/Gate-v0", robot_model=robot_model, gate_width=width)


@pytest.mark.parametrize("robot_model, width", [("paddle", 78.0), ("disk", 78.0)])
def test_gate_just_wider_than_one_robot(robot_model, width):
    env = gym.make("dpr/Gate-v0", robot_model=robot_model, n_robots=2, gate_width=width)
    env.reset(seed=0)
    env.close()


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"object_type": "triangle"}, "object_type"),
        ({"object_type": None}, "object_type"),
        ({"object_mass": 0.0}, "object_mass"),
        ({"object_size": -1.0}, "object_size"),
        ({"object_start": "random"}, "object_start"),
        ({"approach_reward": -0.5}, "approach_reward"),
        ({"approach_reward": "1"}, "approach_reward"),
        ({"approach_reward": True}, "approach_reward"),
    ],
)
def test_bad_object_kwargs(kwargs, name):
    with pytest.raises(ValueError, match=name):
        gym.make("dpr/Manipulation-v0", robot_model="disk", **kwargs)


def test_constructor_does_not_simulate():
    env = gym.make("dpr/Navigation-v0", robot_model="disk", n_robots=4)
    assert env.unwrapped.world is None
    env.close()


# ---------------------------------------------------------------------------------------------------------
# Actions


def _snapshot(env):
    world = env.unwrapped.world
    bodies = np.array([(*b.position, *b.velocity, b.angle) for b in world.space.bodies])
    return bodies, world.swarm.target.copy(), env.unwrapped._tracker.steps


N = 4
BAD_ACTIONS = {
    "multibinary": [
        np.ones(N + 1, dtype=np.int8),
        np.ones(N - 1, dtype=np.int8),
        np.ones((1, N), dtype=np.int8),
        np.ones((N, 1), dtype=np.int8),
        np.array(1),
        np.array([0.5, 0, 0, 0]),
        np.array([2, 0, 0, 0]),
        np.array([-1, 0, 0, 0]),
        np.array([np.nan, 0, 0, 0]),
        np.array(["1", "0", "1", "0"]),
        ["a", "b", "c", "d"],
        np.array([None, 1, 1, 1], dtype=object),
        [1, 0, 1],
    ],
    "continuous": [
        np.array([np.nan, 0.0, 0.0, 0.0]),
        np.array([1.5, 0.0, 0.0, 0.0]),
        np.array([-0.1, 0.0, 0.0, 0.0]),
        np.array([np.inf, 0.0, 0.0, 0.0]),
        np.zeros(N + 1, dtype=np.float32),
        np.zeros((2, N), dtype=np.float32),
        np.array(["0.5"] * N),
    ],
    "discrete": [-1, 2**N, 2**N + 7, 0.5, 3.0, "3", None, True, np.array([1, 2]), np.array(-1), np.float32(2.0)],
}


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
@pytest.mark.parametrize(
    "action_type, index", [(t, i) for t, actions in BAD_ACTIONS.items() for i in range(len(actions))]
)
def test_bad_action_raises_before_simulating(robot_model, action_type, index):
    action = BAD_ACTIONS[action_type][index]
    env = gym.make("dpr/Navigation-v0", robot_model=robot_model, n_robots=N, action_type=action_type)
    env.reset(seed=0)
    good = {"multibinary": np.array([1, 0, 1, 0]), "continuous": np.full(N, 0.5, np.float32), "discrete": 5}
    env.step(good[action_type])  # something in motion, so that a simulated step would show
    before = _snapshot(env)
    with pytest.raises(ValueError, match="action"):
        env.unwrapped.step(action)
    after = _snapshot(env)
    assert np.array_equal(before[0], after[0])
    assert np.array_equal(before[1], after[1])
    assert before[2] == after[2]
    # and the env goes on working
    obs, *_ = env.step(good[action_type])
    assert np.all(np.isfinite(obs))
    env.close()


def test_step_before_reset_raises():
    env = gym.make("dpr/Navigation-v0", robot_model="disk", n_robots=2).unwrapped
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(2, dtype=np.int8))


@pytest.mark.parametrize(
    "action", [np.array([True, False, True, False]), [1, 0, 1, 0], (0, 0, 0, 1), np.array([1.0, 0.0, 0.0, 1.0])]
)
def test_multibinary_accepts_equivalent_forms(action):
    env = gym.make("dpr/Navigation-v0", robot_model="disk", n_robots=N)
    env.reset(seed=0)
    env.step(action)
    env.close()


# ---------------------------------------------------------------------------------------------------------
# Wave policy arguments


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"hold_steps": 0}, "hold_steps"),
        ({"hold_steps": -3}, "hold_steps"),
        ({"start_side": "x"}, "start_side"),
        ({"start_side": None}, "start_side"),
        ({"bin_width": 0.0}, "bin_width"),
        ({"action_type": "box"}, "action_type"),
        ({"n_robots": 0}, "n_robots"),
    ],
)
def test_bad_wave_policy_args(kwargs, name):
    args = {"n_robots": 4, **kwargs}
    with pytest.raises(ValueError, match=name):
        WavePolicy(**args)


def test_wave_from_env_rejects_pixels():
    env = gym.make("dpr/Navigation-v0", robot_model="disk", n_robots=4, obs_type="pixels", image_size=32)
    with pytest.raises(ValueError, match="pixels"):
        WavePolicy.from_env(env)
    env.close()


def test_wave_from_env_overrides_are_validated():
    env = gym.make("dpr/Navigation-v0", robot_model="disk", n_robots=4)
    with pytest.raises(ValueError, match="hold_steps"):
        WavePolicy.from_env(env, hold_steps=0)
    env.close()


# ---------------------------------------------------------------------------------------------------------
# Physics blow-up


def _corrupt(world, how):
    body = world.swarm.robot_bodies[0]
    if how == "nan_velocity":
        body.velocity = (float("nan"), float("nan"))
    elif how == "huge_position":
        body.position = (1e12, 1e12)
    elif how == "inf_angular_velocity":
        body.angular_velocity = float("inf")
    elif how == "object_nan":
        world.object_body.velocity = (float("nan"), 0.0)


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
@pytest.mark.parametrize(
    "env_id, how",
    [
        ("dpr/Navigation-v0", "nan_velocity"),
        ("dpr/Navigation-v0", "huge_position"),
        ("dpr/Navigation-v0", "inf_angular_velocity"),
        ("dpr/Gate-v0", "nan_velocity"),
        ("dpr/Manipulation-v0", "object_nan"),
        ("dpr/Manipulation-v0", "huge_position"),
    ],
)
def test_physics_blow_up_truncates(robot_model, env_id, how):
    env = gym.make(env_id, robot_model=robot_model, n_robots=4)
    env.reset(seed=0)
    env.step(np.ones(4, dtype=np.int8))
    _corrupt(env.unwrapped.world, how)
    obs, reward, terminated, truncated, info = env.step(np.ones(4, dtype=np.int8))
    assert truncated is True
    assert not terminated
    assert "physics_error" in info
    assert np.all(np.isfinite(obs))
    assert np.isfinite(reward)
    for key in ("projected_displacement", "net_displacement", "total_distance"):
        assert np.isfinite(info[key])
    env.close()


def test_physics_blow_up_obs_is_a_fresh_array():
    """Gymnasium asks for new observation data on every call (users keep what they are given); the
    observation returned on a blow-up must not be the very array returned by the previous call."""
    env = gym.make("dpr/Navigation-v0", robot_model="disk", n_robots=4).unwrapped
    obs0, _ = env.reset(seed=0)
    obs1, *_ = env.step(np.ones(4, dtype=np.int8))
    kept = obs1.copy()
    env.world.swarm.robot_bodies[0].velocity = (float("nan"), float("nan"))
    obs2, _, _, truncated, _ = env.step(np.ones(4, dtype=np.int8))
    assert truncated
    assert np.array_equal(obs2, kept)  # the last good state
    assert not np.shares_memory(obs2, obs1)


def test_evaluate_refuses_repeated_seeds():
    """A repeated seed would count its episode twice in every statistic."""
    from dpr.evaluation.scoring import evaluate

    with pytest.raises(ValueError, match=r"seeds: each seed must appear once; repeated: \[3\]"):
        evaluate(["dpr/Navigation-v0"], "wave", seeds=[1, 3, 3], steps=5)


def test_a_corrupt_model_file_is_one_clear_error(tmp_path):
    """A truncated policy.pth inside a model zip: refused before any worker starts, naming the policy."""
    import zipfile

    from stable_baselines3.common.vec_env import DummyVecEnv

    from dpr.evaluation.scoring import evaluate
    from dpr.policies.hyperparams import load_hyperparams
    from dpr.policies.model_file import ModelInfo
    from dpr.policies.sb3 import build_model, save_model

    kwargs = {"n_robots": 4, "robot_model": "disk"}
    env = gym.make("dpr/Navigation-v0", **kwargs)
    model = build_model(load_hyperparams("ppo", "dpr/Navigation-v0"), DummyVecEnv([lambda: env]), 0, None)
    good = save_model(model, tmp_path / "good.zip", ModelInfo("ppo", "dpr/Navigation-v0", kwargs, 20))
    corrupt = tmp_path / "corrupt.zip"
    with zipfile.ZipFile(good) as source, zipfile.ZipFile(corrupt, "w") as target:
        for item in source.infolist():
            data = source.read(item.filename)
            target.writestr(item, data[: len(data) // 2] if item.filename == "policy.pth" else data)
    with pytest.raises(ValueError, match="policy: cannot load ppo model"):
        evaluate(["dpr/Navigation-v0"], str(corrupt), seeds=[0, 1], steps=5, workers=2)


def test_a_very_large_paddle_swarm_is_announced():
    """Building thousands of paddle robots takes seconds per reset: said up front, not left to look like a hang."""
    with pytest.warns(UserWarning, match="n_robots=1000 paddle robots: every reset builds them"):
        gym.make("dpr/Navigation-v0", n_robots=1000, robot_model="paddle").close()


@pytest.mark.parametrize("size", [8, 100000])
def test_collect_names_the_image_size_flag_for_a_frame_size_out_of_range(size, tmp_path, capsys):
    from dpr.cli import main

    out = tmp_path / "ds"
    with pytest.raises(SystemExit) as exit_info:
        main(["collect", "--env", "dpr/Navigation-v0", "--pixels", "--image-size", str(size), "--out", str(out)])
    assert exit_info.value.code == 2
    assert "--image-size: must be" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize(
    "width, message",
    [
        ([150.0], "gate_width: expected a number or \\[low, high\\]"),
        ([250.0, 150.0], "gate_width: expected \\[low, high\\] with low <= high"),
        ([150.0, float("inf")], "gate_width: must be finite"),
        ([150.0, 1e9], "gate_width: must be <= 100000"),
        ([50.0, 250.0], "gate_width must be wider than one expanded robot"),
    ],
)
def test_gate_width_range_out_of_range_is_one_error_naming_it(width, message):
    with pytest.raises(ValueError, match=message):
        gym.make("dpr/Gate-v2", gate_width=width)


@pytest.mark.parametrize(
    "distance, message",
    [
        (-1.0, "gate_distance: must be >= 0"),
        (float("nan"), "gate_distance: must be finite"),
        (float("inf"), "gate_distance: must be finite"),
        (1e9, "gate_distance: must be <= 450"),
        ("10", "gate_distance: expected a number"),
        (True, "gate_distance: expected a number"),
        ([5.0], "gate_distance: expected a number or \\[low, high\\]"),
        ([200.0, 5.0], "gate_distance: expected \\[low, high\\] with low <= high"),
        ([5.0, 1e9], "gate_distance: must be <= 450"),
        ([-1.0, 5.0], "gate_distance: must be >= 0"),
    ],
)
def test_gate_distance_out_of_range_is_one_error_naming_it(distance, message):
    with pytest.raises(ValueError, match=message):
        gym.make("dpr/Gate-v1", gate_distance=distance)
