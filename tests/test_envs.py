"""The four Gymnasium tasks: API conformance, spaces, observation and reward content, rendering, action decoding
(the task rules are in test_task_rules.py)."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from gymnasium.utils.env_checker import check_env
from helpers import ACTION_TYPES, ENV_IDS, OBS_TYPES, ROBOT_MODELS, expansions, positions

# ---------------------------------------------------------------------------------------------------------
# Gymnasium API conformance


@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize("action_type", ACTION_TYPES)
@pytest.mark.parametrize("obs_type", OBS_TYPES)
def test_check_env_disk(env_id, action_type, obs_type):
    env = gym.make(
        env_id,
        robot_model="disk",
        n_robots=4,
        action_type=action_type,
        obs_type=obs_type,
        image_size=32,
        render_size=64,
        render_mode="rgb_array",
    )
    check_env(env.unwrapped, skip_render_check=False)
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_check_env_paddle(env_id):
    env = gym.make(env_id, robot_model="paddle", n_robots=4, action_type="multibinary", obs_type="state")
    check_env(env.unwrapped, skip_render_check=False)
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_check_env_paddle_pixels_discrete_with_render(env_id):
    env = gym.make(
        env_id,
        robot_model="paddle",
        n_robots=2,
        action_type="discrete",
        obs_type="pixels_state",
        image_size=32,
        render_size=64,
        render_mode="rgb_array",
    )
    check_env(env.unwrapped, skip_render_check=False)
    env.close()


def test_registered_ids_have_2500_step_limit():
    for env_id in ENV_IDS:
        assert gym.spec(env_id).max_episode_steps == 2500


# ---------------------------------------------------------------------------------------------------------
# Spaces


@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize("n_robots", [1, 4, 7])
def test_state_observation_space(make_env, env_id, n_robots):
    env = make_env(env_id, n_robots=n_robots)
    extra = 4 if env_id == "dpr/Manipulation-v0" else 0
    space = env.observation_space
    assert isinstance(space, spaces.Box)
    assert space.shape == (6 * n_robots + extra,)
    assert space.dtype == np.float32
    obs, _ = env.reset(seed=0)
    assert obs.shape == (6 * n_robots + extra,)
    assert obs.dtype == np.float32
    assert space.contains(obs)
    obs, *_ = env.step(env.action_space.sample())
    assert obs.dtype == np.float32 and space.contains(obs)


@pytest.mark.parametrize("n_robots", [1, 3, 9])
def test_action_spaces(make_env, n_robots):
    mb = make_env(n_robots=n_robots, action_type="multibinary").action_space
    assert isinstance(mb, spaces.MultiBinary) and mb.n == n_robots
    d = make_env(n_robots=n_robots, action_type="discrete").action_space
    assert isinstance(d, spaces.Discrete) and d.n == 2**n_robots and d.start == 0
    c = make_env(n_robots=n_robots, action_type="continuous").action_space
    assert isinstance(c, spaces.Box) and c.shape == (n_robots,)
    assert np.all(c.low == 0.0) and np.all(c.high == 1.0)


def test_default_action_space_is_multibinary_9():
    env = gym.make("dpr/Navigation-v0")
    assert isinstance(env.action_space, spaces.MultiBinary) and env.action_space.n == 9
    assert env.unwrapped.robot_model == "paddle"
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize("image_size", [24, 48])
def test_pixel_observations(make_env, env_id, image_size):
    env = make_env(env_id, obs_type="pixels", image_size=image_size)
    assert env.observation_space.shape == (image_size, image_size, 3)
    assert env.observation_space.dtype == np.uint8
    obs, _ = env.reset(seed=1)
    assert obs.shape == (image_size, image_size, 3) and obs.dtype == np.uint8
    assert obs.min() < obs.max()  # something is drawn
    obs, *_ = env.step(env.action_space.sample())
    assert obs.shape == (image_size, image_size, 3) and obs.dtype == np.uint8

    env = make_env(env_id, obs_type="pixels_state", image_size=image_size)
    assert isinstance(env.observation_space, spaces.Dict)
    obs, _ = env.reset(seed=1)
    assert set(obs) == {"pixels", "state"}
    assert obs["pixels"].shape == (image_size, image_size, 3) and obs["pixels"].dtype == np.uint8
    assert obs["state"].dtype == np.float32
    assert env.observation_space.contains(obs)


# ---------------------------------------------------------------------------------------------------------
# Observation content


@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
def test_reset_observation_matches_world(make_env, env_id, robot_model):
    n = 4
    env = make_env(env_id, robot_model=robot_model, n_robots=n)
    for seed in (0, 1, 2):
        obs, info = env.reset(seed=seed)
        base = env.unwrapped
        assert np.array_equal(base.goal, [0.0, 0.0])
        world_pos = np.array([tuple(b.position) for b in base.world.swarm.robot_bodies])
        np.testing.assert_allclose(positions(obs, n), world_pos / 1000.0, rtol=1e-6, atol=1e-9)
        exp = expansions(obs, n)
        assert np.all((exp >= 0.0) & (exp <= 1.0))
        np.testing.assert_allclose(exp, 0.0, atol=1e-6)
        # robots start at rest
        np.testing.assert_allclose(obs[: 6 * n].reshape(n, 6)[:, 2:5], 0.0, atol=1e-9)
        # start circle 450-550 around the goal, square grid of pitch 77.5
        centre = world_pos.mean(axis=0)
        assert 450.0 - 1e-6 <= np.linalg.norm(centre) <= 550.0 + 1e-6
        np.testing.assert_allclose(info["centre_of_mass"], centre, atol=1e-9)
        gaps = np.linalg.norm(world_pos[:, None] - world_pos[None], axis=-1) + np.eye(n) * 1e9
        np.testing.assert_allclose(gaps.min(axis=1), 77.5, atol=1e-6)
        if env_id == "dpr/Manipulation-v0":
            obj = np.array(tuple(base.world.object_body.position))
            np.testing.assert_allclose(obs[6 * n : 6 * n + 2], obj / 1000.0, rtol=1e-6)
            np.testing.assert_allclose(obs[6 * n + 2 :], 0.0, atol=1e-9)
            np.testing.assert_allclose(info["object_position"], obj, atol=1e-9)


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
@pytest.mark.parametrize("action_type", ACTION_TYPES)
def test_expanding_everyone_reaches_full_expansion(make_env, robot_model, action_type):
    n = 4
    env = make_env(robot_model=robot_model, n_robots=n, action_type=action_type)
    obs, _ = env.reset(seed=0)
    all_on = {"multibinary": np.ones(n, dtype=np.int8), "discrete": 2**n - 1, "continuous": np.ones(n, np.float32)}
    history = []
    for _ in range(5):
        obs, *_ = env.step(all_on[action_type])
        e = expansions(obs, n)
        assert np.all((e >= 0.0) & (e <= 1.0))
        history.append(e.copy())
    assert np.all(history[0] > 0.0)  # started moving in the first step
    assert np.all(history[-1] > 0.8), history[-1]
    assert np.all(np.diff(np.array(history), axis=0) > -1e-6)  # expansion does not go back while commanded


@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
def test_observation_is_state_after_the_step(make_env, env_id, robot_model):
    n = 4
    env = make_env(env_id, robot_model=robot_model, n_robots=n)
    env.reset(seed=3)
    world = env.unwrapped.world
    before = world.swarm.position.copy()
    obs, *_ = env.step(np.ones(n, dtype=np.int8))
    swarm = env.unwrapped.world.swarm
    after = np.array([tuple(b.position) for b in swarm.robot_bodies])
    velocity = np.array([tuple(b.velocity) for b in swarm.robot_bodies])
    spin = np.array([b.angular_velocity for b in swarm.robot_bodies])
    assert not np.allclose(after, before, rtol=0, atol=1e-9)  # the step did move the robots
    rows = obs[: 6 * n].reshape(n, 6)
    np.testing.assert_allclose(rows[:, 0:2], after / 1000.0, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(rows[:, 2:4], velocity / 1000.0, rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(rows[:, 4], spin, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(rows[:, 5], swarm.expansion, rtol=1e-6, atol=1e-7)
    alive = ~env.unwrapped.world.dead
    assert alive.any()
    assert np.all(rows[alive, 5] > 0.0)  # expansion after (not before, when it was 0)
    if env_id == "dpr/Manipulation-v0":
        body = env.unwrapped.world.object_body
        np.testing.assert_allclose(obs[6 * n : 6 * n + 2], np.array(tuple(body.position)) / 1000.0, rtol=1e-6)
        np.testing.assert_allclose(obs[6 * n + 2 :], np.array(tuple(body.velocity)) / 1000.0, rtol=1e-5, atol=1e-9)


# ---------------------------------------------------------------------------------------------------------
# Rewards


def _agent(info, env_id):
    return info["object_position"] if env_id == "dpr/Manipulation-v0" else info["centre_of_mass"]


@pytest.mark.parametrize("env_id", ["dpr/Navigation-v0", "dpr/Manipulation-v0"])
@pytest.mark.parametrize("d", [450.0, 2000.0])
def test_piecewise_and_projected_rewards(make_env, env_id, d):
    rewards = {}
    agents = {}
    for kind in ("piecewise", "projected"):
        env = make_env(env_id, robot_model="disk", n_robots=4, reward=kind, reward_threshold_d=d)
        env.action_space.seed(7)
        _, info = env.reset(seed=11)
        agents[kind] = [np.array(_agent(info, env_id), dtype=float)]
        rewards[kind] = []
        for _ in range(25):
            _, r, *_, info = env.step(env.action_space.sample())
            assert isinstance(r, float)
            rewards[kind].append(r)
            agents[kind].append(np.array(_agent(info, env_id), dtype=float))
    # same seeds, same actions: same trajectory whatever the reward
    np.testing.assert_array_equal(np.array(agents["piecewise"]), np.array(agents["projected"]))
    path = np.array(agents["piecewise"])
    goal = np.zeros(2)
    moved = False
    for t in range(25):
        prev, now = path[t], path[t + 1]
        unit = (goal - prev) / np.linalg.norm(goal - prev)
        progress = float((now - prev) @ unit)
        moved |= abs(progress) > 1e-6
        distance = float(np.linalg.norm(now - goal))
        scale = d / distance if distance < d else 1.0
        assert rewards["projected"][t] == pytest.approx(progress, rel=1e-9, abs=1e-12)
        assert rewards["piecewise"][t] == pytest.approx(progress * scale, rel=1e-9, abs=1e-12)
    assert moved, "the random actions should have moved the agent"
    distances = np.linalg.norm(path[1:], axis=1)
    inside = distances < d
    if d > 1000:  # inside d for the whole episode: the multiplier is > 1
        assert inside.all()
        assert np.sum(np.abs(rewards["piecewise"])) > np.sum(np.abs(rewards["projected"]))
    # outside d the two rewards are the same number
    assert np.array_equal(np.array(rewards["piecewise"])[~inside], np.array(rewards["projected"])[~inside])


def test_piecewise_scaling_inside_threshold(make_env):
    # start at exactly 300 from the goal: inside d=450, the multiplier is d / distance ~ 1.5
    env = make_env(reward="piecewise", start_radius=(300.0, 300.0))
    ref = make_env(reward="projected", start_radius=(300.0, 300.0))
    env.reset(seed=5)
    ref.reset(seed=5)
    ratios = []
    rng = np.random.default_rng(3)
    for _ in range(20):
        a = rng.integers(0, 2, 4).astype(np.int8)
        _, r, *_, info = env.step(a)
        _, p, *_ = ref.step(a)
        if abs(p) > 1e-9:
            distance = np.linalg.norm(info["centre_of_mass"])
            ratios.append((r / p, 450.0 / distance))
    assert ratios
    for got, want in ratios:
        assert got == pytest.approx(want, rel=1e-9)
        assert got > 1.4


@pytest.mark.parametrize("env_id", ["dpr/Navigation-v0", "dpr/Manipulation-v0"])
def test_inverse_distance_reward(make_env, env_id):
    env = make_env(env_id, reward="inverse_distance")
    env.action_space.seed(2)
    env.reset(seed=4)
    for _ in range(10):
        _, r, *_, info = env.step(env.action_space.sample())
        assert r == pytest.approx(1.0 / np.linalg.norm(_agent(info, env_id)), rel=1e-9)
        assert 0 < r < 1.0 / 300


def test_info_metrics_follow_the_agent(make_env):
    env = make_env()
    env.action_space.seed(0)
    _, info = env.reset(seed=0)
    start = info["centre_of_mass"].copy()
    path = [start]
    for _ in range(15):
        _, _, _, _, info = env.step(env.action_space.sample())
        path.append(info["centre_of_mass"].copy())
    path = np.array(path)
    assert info["total_distance"] == pytest.approx(np.linalg.norm(np.diff(path, axis=0), axis=1).sum(), rel=1e-9)
    assert info["net_displacement"] == pytest.approx(np.linalg.norm(path[-1] - path[0]), rel=1e-9)
    unit = -start / np.linalg.norm(start)
    assert info["projected_displacement"] == pytest.approx((path[-1] - path[0]) @ unit, rel=1e-9, abs=1e-12)
    assert not info["is_success"]


@pytest.mark.parametrize("env_id", ["dpr/Navigation-v0", "dpr/Manipulation-v0"])
def test_returned_data_is_not_live_env_state(make_env, env_id):
    """Users keep (and sometimes edit) what step/reset return: doing so must not change the episode."""

    def run(scribble):
        env = make_env(env_id)
        obs, info = env.reset(seed=0)
        rng = np.random.default_rng(0)
        out = []
        for _ in range(8):
            if scribble:
                obs[:] = 0.0
                for value in info.values():
                    if isinstance(value, np.ndarray) and value.dtype.kind == "f":
                        value[...] = 0.0
            obs, reward, terminated, truncated, info = env.step(rng.integers(0, 2, 4).astype(np.int8))
            out.append(
                (
                    obs.copy(),
                    reward,
                    info["total_distance"],
                    info["projected_displacement"],
                    np.array(info["centre_of_mass"]).copy(),
                )
            )
        return out

    clean, scribbled = run(False), run(True)
    for a, b in zip(clean, scribbled):
        assert np.array_equal(a[0], b[0])
        assert a[1:4] == b[1:4]
        assert np.array_equal(a[4], b[4])


# ---------------------------------------------------------------------------------------------------------
# Rendering


def _frame(env_id, seed=0, **kwargs):
    kwargs.setdefault("robot_model", "disk")
    kwargs.setdefault("n_robots", 4)
    env = gym.make(env_id, render_mode="rgb_array", render_size=128, **kwargs)
    env.reset(seed=seed)
    frame = env.render()
    env.close()
    return frame


@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
def test_render_rgb_array(env_id, robot_model):
    frame = _frame(env_id, robot_model=robot_model)
    assert isinstance(frame, np.ndarray)
    assert frame.shape == (128, 128, 3) and frame.dtype == np.uint8
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 2  # background plus goal plus robots


def test_render_size_is_honoured():
    env = gym.make("dpr/Navigation-v0", robot_model="disk", n_robots=2, render_mode="rgb_array", render_size=80)
    env.reset(seed=0)
    assert env.render().shape == (80, 80, 3)
    env.close()


def test_render_without_mode_returns_none(make_env):
    env = make_env()
    env.reset(seed=0)
    assert env.unwrapped.render() is None


def test_gate_walls_are_drawn():
    nav = _frame("dpr/Navigation-v0", seed=3)
    gate = _frame("dpr/Gate-v0", seed=3)
    differing = np.any(nav != gate, axis=-1).sum()
    # two walls of 500 x 100 at a scale of 128 px / (2 * ~700 units): hundreds of pixels
    assert differing > 200


def test_manipulation_object_is_drawn():
    nav = _frame("dpr/Navigation-v0", seed=3)
    manip = _frame("dpr/Manipulation-v0", seed=3)
    assert np.any(nav != manip, axis=-1).sum() > 10


def test_render_follows_the_swarm():
    a = _frame("dpr/Navigation-v0", seed=0)
    b = _frame("dpr/Navigation-v0", seed=1)
    assert not np.array_equal(a, b)


def test_paddle_and_disk_frames_differ():
    assert not np.array_equal(_frame("dpr/Navigation-v0", robot_model="paddle"), _frame("dpr/Navigation-v0"))


# ---------------------------------------------------------------------------------------------------------
# Action decoding


def _bits(value, n):
    return np.array([(value >> (n - 1 - i)) & 1 for i in range(n)], dtype=np.int8)


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
def test_discrete_decoding_msb_is_robot_zero(make_env, robot_model):
    n = 4
    env = make_env(robot_model=robot_model, n_robots=n, action_type="discrete")
    for action, expected in (
        (2**n - 1, [1, 1, 1, 1]),
        (0, [0, 0, 0, 0]),
        (2 ** (n - 1), [1, 0, 0, 0]),
        (1, [0, 0, 0, 1]),
    ):
        env.reset(seed=0)
        for _ in range(3):
            obs, *_ = env.step(action)
        e = expansions(obs, n)
        expected = np.array(expected, dtype=bool)
        assert np.all(e[expected] > 0.3), (action, e)
        assert np.all(e[~expected] < 0.05), (action, e)


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
def test_discrete_matches_multibinary(make_env, robot_model):
    n = 3
    disc = make_env(robot_model=robot_model, n_robots=n, action_type="discrete")
    mb = make_env(robot_model=robot_model, n_robots=n, action_type="multibinary")
    cont = make_env(robot_model=robot_model, n_robots=n, action_type="continuous")
    rng = np.random.default_rng(0)
    a, _ = disc.reset(seed=9)
    b, _ = mb.reset(seed=9)
    c, _ = cont.reset(seed=9)
    assert np.array_equal(a, b) and np.array_equal(a, c)
    for value in rng.integers(0, 2**n, size=20):
        a, *_ = disc.step(int(value))
        b, *_ = mb.step(_bits(int(value), n))
        c, *_ = cont.step(_bits(int(value), n).astype(np.float32))
        assert np.array_equal(a, b)
        assert np.array_equal(a, c)


def test_discrete_accepts_numpy_integers(make_env):
    env = make_env(action_type="discrete")
    env.reset(seed=0)
    for action in (np.int64(3), np.array(5), np.array([7]), env.action_space.sample()):
        env.step(action)


@pytest.mark.parametrize("robot_model", ROBOT_MODELS)
def test_continuous_partial_expansion(make_env, robot_model):
    n = 2
    env = make_env(robot_model=robot_model, n_robots=n, action_type="continuous")
    env.reset(seed=0)
    for _ in range(8):
        obs, *_ = env.step(np.array([0.5, 1.0], dtype=np.float32))
    e = expansions(obs, n)
    assert 0.3 < e[0] < 0.7, e
    assert e[1] > 0.85, e


@pytest.mark.parametrize(
    ("env_id", "kwargs", "parameter"),
    [
        ("dpr/Manipulation-v0", {"object_mass": float("inf")}, "object_mass"),
        ("dpr/Manipulation-v0", {"object_mass": float("nan")}, "object_mass"),
        ("dpr/Manipulation-v0", {"object_size": 1e300}, "object_size"),
        ("dpr/Manipulation-v0", {"object_size": 1e-300}, "object_size"),
        ("dpr/Manipulation-v0", {"object_size": "30"}, "object_size"),
        ("dpr/Manipulation-v0", {"approach_reward": float("inf")}, "approach_reward"),
        ("dpr/Navigation-v0", {"reward_threshold_d": float("inf")}, "reward_threshold_d"),
        ("dpr/Navigation-v0", {"start_radius": (450.0, float("inf"))}, "start_radius"),
        ("dpr/Navigation-v0", {"start_radius": (550.0, 450.0)}, "start_radius"),
        ("dpr/Gate-v0", {"gate_width": float("inf")}, "gate_width"),
    ],
)
def test_float_kwargs_must_be_finite_and_in_range(env_id, kwargs, parameter):
    """A non-finite or absurd float kwarg is refused at construction (an infinite mass used to abort the
    interpreter inside chipmunk; an infinite size recorded NaN data)."""
    from dpr.checks import ParameterError

    with pytest.raises(ParameterError, match=f"^{parameter}: ") as error:
        gym.make(env_id, **kwargs)
    assert error.value.parameter == parameter
