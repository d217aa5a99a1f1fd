"""The hand-crafted wave policy: binning, phases, wave direction, output types, and short locomotion runs."""

import gymnasium as gym
import numpy as np
import pytest
from helpers import drive

from dpr.envs.particle_env import HELD_STEPS_CAP
from dpr.policies.wave import MODEL_DEFAULTS, MarkovWavePolicy, WavePolicy, encode_action

# Robots along the goal direction (+x before rotation), y summing to 0 so that the swarm centre lies on it.
XS = np.array([440.0, 470.0, 520.0, 590.0, 650.0, 700.0])
YS = np.array([-50.0, 30.0, 0.0, 80.0, -20.0, -40.0])


def _rotate(points, angle):
    c, s = np.cos(angle), np.sin(angle)
    return points @ np.array([[c, s], [-s, c]])


def _observation(points, extra=0):
    """A state observation (goal frame, / 1000) with the given robot positions and zero velocities."""
    n = len(points)
    rows = np.zeros((n, 6))
    rows[:, 0:2] = points / 1000.0
    rows[:, 5] = 0.5
    return np.concatenate([rows.ravel(), np.full(extra, 0.123)]).astype(np.float32)


def _expected_bins(points, bin_width=60.0):
    """Distance of each robot to the line through the goal perpendicular to the goal->centre direction."""
    centre = points.mean(axis=0)
    u = centre / np.linalg.norm(centre)
    v = np.array([-u[1], u[0]])  # the line's direction
    distance = np.abs(v[0] * points[:, 1] - v[1] * points[:, 0])  # |cross(v, p)|
    return np.floor((distance - distance.min()) / bin_width).astype(int)


def _run(policy, obs, steps):
    return np.array([np.asarray(policy(obs)) for _ in range(steps)])


@pytest.mark.parametrize("angle", [0.0, 0.4, 2.0, -2.7])
@pytest.mark.parametrize("hold_steps", [1, 3, 10])
def test_phases_follow_bins_near(angle, hold_steps):
    points = _rotate(np.stack([XS, YS], axis=1), angle)
    bins = _expected_bins(points)
    assert bins.tolist() == [0, 0, 1, 2, 3, 4]  # by construction of XS
    n_phases = bins.max() + 1
    policy = WavePolicy(len(points), "multibinary", hold_steps=hold_steps, start_side="near")
    actions = _run(policy, _observation(points), n_phases * hold_steps * 2)
    for t, action in enumerate(actions):
        phase = (t // hold_steps) % n_phases
        assert np.array_equal(action, (bins == phase).astype(np.int8)), (t, action)
    # the nearest robots expand first
    assert np.array_equal(actions[0], [1, 1, 0, 0, 0, 0])


@pytest.mark.parametrize("angle", [0.0, 1.1])
def test_far_start_reverses_the_wave(angle):
    points = _rotate(np.stack([XS, YS], axis=1), angle)
    bins = _expected_bins(points)
    n_phases = bins.max() + 1
    hold = 4
    policy = WavePolicy(len(points), "multibinary", hold_steps=hold, start_side="far")
    actions = _run(policy, _observation(points), n_phases * hold)
    for t, action in enumerate(actions):
        phase = t // hold
        assert np.array_equal(action, (bins == n_phases - 1 - phase).astype(np.int8))
    assert np.array_equal(actions[0], [0, 0, 0, 0, 0, 1])  # the farthest robot expands first


def test_bin_width_parameter():
    points = np.stack([XS, YS], axis=1)
    policy = WavePolicy(len(points), "multibinary", hold_steps=1, bin_width=1000.0)
    actions = _run(policy, _observation(points), 3)
    assert np.all(actions == 1)  # one bin: everyone expands in every phase
    policy = WavePolicy(len(points), "multibinary", hold_steps=1, bin_width=27.0)
    bins = _expected_bins(points, 27.0)  # no robot on a bin edge (float32 obs)
    actions = _run(policy, _observation(points), bins.max() + 1)
    for t, action in enumerate(actions):
        assert np.array_equal(action, (bins == t).astype(np.int8))


def test_plan_is_kept_for_the_whole_cycle():
    points = np.stack([XS, YS], axis=1)
    policy = WavePolicy(len(points), "multibinary", hold_steps=2)
    first = policy(_observation(points))
    # mid-cycle, the swarm turns around the goal: the cycle's bins stay those planned at its start
    moved = _rotate(points[::-1], 1.0)
    rest = _run(policy, _observation(moved), 2 * 5 - 1)
    bins = _expected_bins(points)
    assert np.array_equal(first, (bins == 0).astype(np.int8))
    for t, action in enumerate(rest, start=1):
        assert np.array_equal(action, (bins == t // 2).astype(np.int8))
    # the next cycle is planned from the observation it starts with
    assert np.array_equal(policy(_observation(moved)), (_expected_bins(moved) == 0).astype(np.int8))


def test_reset_restarts_the_cycle():
    points = np.stack([XS, YS], axis=1)
    obs = _observation(points)
    policy = WavePolicy(len(points), "multibinary", hold_steps=2)
    fresh = _run(WavePolicy(len(points), "multibinary", hold_steps=2), obs, 4)
    _run(policy, obs, 5)
    policy.reset()
    assert np.array_equal(_run(policy, obs, 4), fresh)


def test_output_types():
    points = np.stack([XS, YS], axis=1)
    n = len(points)
    obs = _observation(points)
    mb = WavePolicy(n, "multibinary", hold_steps=1)
    disc = WavePolicy(n, "discrete", hold_steps=1)
    cont = WavePolicy(n, "continuous", hold_steps=1)
    for _ in range(6):
        a, d, c = mb(obs), disc(obs), cont(obs)
        assert isinstance(a, np.ndarray) and a.dtype == np.int8 and a.shape == (n,)
        assert isinstance(d, int) and not isinstance(d, bool)
        assert 0 <= d < 2**n
        assert isinstance(c, np.ndarray) and c.dtype == np.float32 and c.shape == (n,)
        # robot 0 is the most significant bit, as in the env
        assert d == int("".join(str(int(x)) for x in a), 2)
        assert np.array_equal(c, a.astype(np.float32))


def test_accepts_pixels_state_dicts_and_object_features():
    points = np.stack([XS, YS], axis=1)
    state = _observation(points, extra=4)  # Manipulation: 6N + 4
    a = _run(WavePolicy(len(points), hold_steps=1), state, 5)
    b = _run(WavePolicy(len(points), hold_steps=1), {"pixels": np.zeros((8, 8, 3), np.uint8), "state": state}, 5)
    assert np.array_equal(a, b)


@pytest.mark.parametrize("robot_model", ["paddle", "disk"])
@pytest.mark.parametrize("action_type", ["multibinary", "discrete", "continuous"])
@pytest.mark.parametrize("obs_type", ["state", "pixels_state"])
def test_from_env(robot_model, action_type, obs_type):
    env = gym.make(
        "dpr/Manipulation-v0",
        robot_model=robot_model,
        n_robots=4,
        action_type=action_type,
        obs_type=obs_type,
        image_size=32,
    )
    policy = WavePolicy.from_env(env)
    assert policy.n_robots == 4 and policy.action_type == action_type
    assert policy.hold_steps == MODEL_DEFAULTS[robot_model]["hold_steps"]
    assert policy.start_side == MODEL_DEFAULTS[robot_model]["start_side"]
    assert WavePolicy.from_env(env, hold_steps=7).hold_steps == 7
    assert WavePolicy.from_env(env.unwrapped, start_side="far").start_side == "far"
    drive(env, policy, steps=12, seed=0)


def test_paddle_default_is_the_papers():
    assert MODEL_DEFAULTS["paddle"] == {"hold_steps": 10, "start_side": "near"}
    policy = WavePolicy(9)
    assert policy.hold_steps == 10 and policy.start_side == "near" and policy.bin_width == 60.0


def test_disk_defaults_hold_at_every_swarm_size():
    """Hold 4 from the near side at every N (tools/model_agreement.py: no size switch on either model); an
    explicit start_side or hold_steps wins."""
    assert MODEL_DEFAULTS["disk"] == {"hold_steps": 4, "start_side": "near"}
    for n in (9, 199, 200, 1000):
        env = gym.make("dpr/Navigation-v0", robot_model="disk", n_robots=n, obs_last_action=True)
        for cls in (WavePolicy, MarkovWavePolicy):
            policy = cls.from_env(env)
            assert (policy.n_robots, policy.start_side, policy.hold_steps) == (n, "near", 4), (cls, n)
            assert cls.from_env(env, start_side="far").start_side == "far"
            assert cls.from_env(env.unwrapped, hold_steps=10).hold_steps == 10
        env.close()


# ---------------------------------------------------------------------------------------------------------
# Locomotion on a short horizon


def _wave_episode(robot_model, seed, steps, env_id="dpr/Navigation-v0", **policy_kwargs):
    env = gym.make(env_id, robot_model=robot_model, n_robots=9)
    obs, info = env.reset(seed=seed)
    policy = WavePolicy.from_env(env, **policy_kwargs)
    key = "object_position" if env_id == "dpr/Manipulation-v0" else "centre_of_mass"
    start = info[key].copy()
    for t in range(steps):
        obs, _, terminated, truncated, info = env.step(policy(obs))
        assert "physics_error" not in info
        assert not truncated or t + 1 == steps == env.spec.max_episode_steps
        if terminated:
            break
    env.close()
    end = info[key]
    unit = -start / np.linalg.norm(start)
    projected = float((end - start) @ unit)
    assert projected == pytest.approx(info["projected_displacement"], rel=1e-9, abs=1e-9)
    return projected


def test_paddle_wave_moves_toward_goal():
    assert _wave_episode("paddle", seed=0, steps=400, hold_steps=10, start_side="near") > 0.0


def test_disk_wave_with_model_defaults_moves_toward_goal():
    assert _wave_episode("disk", seed=0, steps=400) > 0.0


# ---------------------------------------------------------------------------------------------------------
# Long runs (pytest -m slow)


@pytest.mark.slow
@pytest.mark.parametrize("robot_model", ["paddle", "disk"])
def test_wave_moves_toward_goal_over_full_episodes(robot_model):
    results = [_wave_episode(robot_model, seed, 2500) for seed in range(3)]
    assert all(r > 0.0 for r in results), results


@pytest.mark.slow
def test_paddle_wave_from_the_far_side_moves_away():
    results = [_wave_episode("paddle", seed, 2500, start_side="far") for seed in range(3)]
    assert np.median(results) < 0.0, results


@pytest.mark.slow
@pytest.mark.parametrize("robot_model", ["paddle", "disk"])
def test_wave_moves_the_swarm_in_gate_and_unresponsive(robot_model):
    for env_id in ("dpr/Gate-v0", "dpr/Unresponsive-v0"):
        results = [_wave_episode(robot_model, seed, 1000, env_id=env_id) for seed in range(3)]
        assert np.median(results) > 0.0, (env_id, results)


# ---------------------------------------------------------------------------------------------------------
# The Markov wave: phase read from the observation (obs_last_action=True)


def _markov_observation(points, last=None, held=0, extra=0):
    """A state observation with obs_last_action's N + 1 values at its end: ``last`` (the previous action,
    default none) and ``held`` steps (as the env writes it, held / 20)."""
    n = len(points)
    last = np.zeros(n) if last is None else np.asarray(last, dtype=float)
    memory = np.concatenate([last, [min(held, HELD_STEPS_CAP) / HELD_STEPS_CAP]])
    return np.concatenate([_observation(points, extra), memory]).astype(np.float32)


def _markov_env(robot_model="disk", n_robots=4, **kwargs):
    return gym.make("dpr/Navigation-v0", robot_model=robot_model, n_robots=n_robots, obs_last_action=True, **kwargs)


@pytest.mark.parametrize("hold_steps", [1, 3, 10])
def test_markov_wave_holds_the_previous_action_for_hold_steps_then_expands_the_next_bin(hold_steps):
    points = np.stack([XS, YS], axis=1)
    bins = _expected_bins(points)  # [0, 0, 1, 2, 3, 4]
    policy = MarkovWavePolicy(len(points), "multibinary", hold_steps=hold_steps)
    for phase in range(bins.max() + 1):
        expanded = (bins == phase).astype(np.int8)
        for held in range(1, hold_steps):
            np.testing.assert_array_equal(policy(_markov_observation(points, expanded, held)), expanded)
        following = (bins == (phase + 1) % (bins.max() + 1)).astype(np.int8)  # after the last bin: the first
        np.testing.assert_array_equal(policy(_markov_observation(points, expanded, hold_steps)), following)
        np.testing.assert_array_equal(policy(_markov_observation(points, expanded, hold_steps + 5)), following)


def test_markov_wave_starts_with_the_first_bin_when_nothing_is_expanded():
    points = _rotate(np.stack([XS, YS], axis=1), 0.7)
    first = (_expected_bins(points) == 0).astype(np.int8)
    policy = MarkovWavePolicy(len(points), hold_steps=4)
    for held in (0, 1, 3, 4, 20):  # after reset (0), or the all-contracted action held any number of steps
        np.testing.assert_array_equal(policy(_markov_observation(points, held=held)), first)
    far = MarkovWavePolicy(len(points), hold_steps=4, start_side="far")
    np.testing.assert_array_equal(far(_markov_observation(points)), [0, 0, 0, 0, 0, 1])


def test_markov_wave_goes_on_after_the_nearest_expanded_robots_bin_skipping_empty_bins():
    points = np.stack([XS, YS], axis=1)
    bins = _expected_bins(points)  # [0, 0, 1, 2, 3, 4]
    policy = MarkovWavePolicy(len(points), hold_steps=2)
    # robots of bins 1 and 3 expanded (one drifted over an edge): the wave goes on after bin 1
    last = ((bins == 1) | (bins == 3)).astype(np.int8)
    np.testing.assert_array_equal(policy(_markov_observation(points, last, 2)), (bins == 2).astype(np.int8))
    # bins 0, 3 and 4 hold robots, 1 and 2 none: after bin 0 comes bin 3
    gap = np.stack([[440.0, 470.0, 640.0, 700.0], [-20.0, 20.0, 10.0, -10.0]], axis=1)
    assert _expected_bins(gap).tolist() == [0, 0, 3, 4]
    gap_policy = MarkovWavePolicy(4, hold_steps=2)
    np.testing.assert_array_equal(gap_policy(_markov_observation(gap, [1, 1, 0, 0], 2)), [0, 0, 1, 0])
    np.testing.assert_array_equal(gap_policy(_markov_observation(gap, [0, 0, 0, 1], 2)), [1, 1, 0, 0])


def test_markov_wave_reads_manipulation_and_pixels_state_observations():
    points = np.stack([XS, YS], axis=1)
    bins = _expected_bins(points)
    state = _markov_observation(points, (bins == 1).astype(np.int8), 10, extra=4)  # 6N + 4 object values + N + 1
    policy = MarkovWavePolicy(len(points))
    expected = (bins == 2).astype(np.int8)
    np.testing.assert_array_equal(policy(state), expected)
    np.testing.assert_array_equal(policy({"pixels": np.zeros((8, 8, 3), np.uint8), "state": state}), expected)


def test_markov_wave_is_a_function_of_the_observation():
    env = _markov_env("disk", 9)
    obs, _ = env.reset(seed=3)
    a, b = MarkovWavePolicy.from_env(env), MarkovWavePolicy.from_env(env)
    history, actions = [], []
    for _ in range(30):
        history.append(obs)
        actions.append(a(obs))
        obs, *_ = env.step(actions[-1])
    # b sees the same observations in another order, a sees them again: the same answers
    for seen, action in zip(history[::-1], actions[::-1]):
        np.testing.assert_array_equal(b(seen), action)
        np.testing.assert_array_equal(a(seen), action)
    b.reset()  # nothing to reset
    np.testing.assert_array_equal(b(history[0]), actions[0])


@pytest.mark.parametrize("hold_steps", [4, 7])
def test_markov_wave_in_the_env_switches_every_hold_steps(hold_steps):
    env = _markov_env("disk", 4)
    obs, _ = env.reset(seed=0)
    policy = MarkovWavePolicy.from_env(env, hold_steps=hold_steps)
    actions = []
    for _ in range(6 * hold_steps):
        actions.append(policy(obs))
        obs, *_ = env.step(actions[-1])
        assert round(obs[-1] * HELD_STEPS_CAP) == len(actions) - hold_steps * ((len(actions) - 1) // hold_steps)
    changes = [t for t in range(1, len(actions)) if not np.array_equal(actions[t], actions[t - 1])]
    assert changes == list(range(hold_steps, len(actions), hold_steps))
    assert all(action.any() for action in actions)  # some robot always expands


@pytest.mark.parametrize("robot_model, n_robots", [("paddle", 9), ("disk", 4)])
def test_markov_wave_acts_as_the_wave_policy_from_rest(robot_model, n_robots):
    """Navigation, seed 0: the two waves take the same 200 actions (measured: 400 on these settings; at disk
    N=9 they part after 28 steps, as the Markov wave re-plans its bins at every phase)."""
    markov_env, wave_env = _markov_env(robot_model, n_robots), _markov_env(robot_model, n_robots)
    markov_obs, _ = markov_env.reset(seed=0)
    wave_obs, _ = wave_env.reset(seed=0)
    markov, wave = MarkovWavePolicy.from_env(markov_env), WavePolicy.from_env(wave_env)
    for t in range(200):
        a, b = markov(markov_obs), wave(wave_obs)
        np.testing.assert_array_equal(a, b, err_msg=f"step {t}")
        markov_obs, *_ = markov_env.step(a)
        wave_obs, *_ = wave_env.step(b)
    np.testing.assert_array_equal(markov_obs, wave_obs)


@pytest.mark.parametrize("action_type", ["discrete", "continuous"])
def test_markov_wave_encodes_every_action_type(action_type):
    reference, env = _markov_env("disk", 4), _markov_env("disk", 4, action_type=action_type)
    ref_obs, _ = reference.reset(seed=1)
    obs, _ = env.reset(seed=1)
    ref_policy, policy = MarkovWavePolicy.from_env(reference), MarkovWavePolicy.from_env(env)
    for _ in range(20):  # the held action is read back from the observation in every action type
        expected, action = ref_policy(ref_obs), policy(obs)
        assert env.action_space.contains(action)
        np.testing.assert_array_equal(action, encode_action(expected, action_type))
        ref_obs, *_ = reference.step(expected)
        obs, *_ = env.step(action)
    np.testing.assert_array_equal(obs, ref_obs)


@pytest.mark.parametrize("hold_steps", [0, HELD_STEPS_CAP + 1, 50])
def test_markov_wave_refuses_a_hold_it_cannot_count(hold_steps):
    with pytest.raises(ValueError, match="hold_steps"):
        MarkovWavePolicy(9, hold_steps=hold_steps)
    assert MarkovWavePolicy(9, hold_steps=HELD_STEPS_CAP).hold_steps == HELD_STEPS_CAP


def test_markov_wave_needs_obs_last_action():
    env = gym.make("dpr/Navigation-v0", robot_model="disk", n_robots=4)
    with pytest.raises(ValueError, match="obs_last_action"):
        MarkovWavePolicy.from_env(env)
    from dpr.policies.registry import make_policy

    with pytest.raises(ValueError, match="obs_last_action"):
        make_policy("wave-markov", env)
    assert MarkovWavePolicy.from_env(_markov_env("paddle", 4)).hold_steps == 10
    assert MarkovWavePolicy.from_env(_markov_env("paddle", 4), hold_steps=6).hold_steps == 6


def test_markov_wave_moves_the_paddle_swarm_toward_the_goal():
    env = _markov_env("paddle", 9)
    obs, info = env.reset(seed=0)
    policy = MarkovWavePolicy.from_env(env)
    for _ in range(400):
        obs, _, terminated, truncated, info = env.step(policy(obs))
    assert info["projected_displacement"] > 0.0


@pytest.mark.parametrize(
    "name, cls, hold", [("wave:hold_steps=6", WavePolicy, 6), ("wave-markov", MarkovWavePolicy, 10)]
)
def test_a_waves_name_carries_its_hold(name, cls, hold):
    """make_policy("wave-markov:hold_steps=7", env) is the Markov wave holding 7 steps; a plain name keeps the
    robot model's hold (paddle 10)."""
    from dpr.policies.registry import make_policy

    env = _markov_env("paddle", 4)
    policy = make_policy(name, env).policy
    assert type(policy) is cls and policy.hold_steps == hold
    obs, _ = env.reset(seed=0)
    markov = make_policy("wave-markov:hold_steps=7", env)
    actions = []
    for _ in range(21):
        actions.append(markov(obs))
        obs, *_ = env.step(actions[-1])
    assert [t for t in range(1, 21) if not np.array_equal(actions[t], actions[t - 1])] == [7, 14]


def test_a_waves_name_carries_its_bin_width():
    """wave_name and make_policy round-trip the bin width: "wave-markov:hold_steps=6,bin_width=50" is the
    Markov wave holding 6 steps with 50-unit bins, which plans more bins than the 60-unit wave on the same swarm."""
    from dpr.policies.registry import make_policy, parse_scripted_name, wave_name

    name = wave_name("wave-markov", 6, 50.0)
    assert name == "wave-markov:hold_steps=6,bin_width=50"
    assert parse_scripted_name(name) == ("wave-markov", {"hold_steps": 6, "bin_width": 50.0})
    assert parse_scripted_name("wave:bin_width=45.5") == ("wave", {"bin_width": 45.5})
    env = _markov_env("paddle", 9)
    policy = make_policy(name, env).policy
    assert type(policy) is MarkovWavePolicy and (policy.hold_steps, policy.bin_width) == (6, 50.0)
    points = np.array([[0.0, 100.0 + 55.0 * k] for k in range(5)])  # 55 apart along the goal direction
    assert policy.plan(points).tolist() == [0, 1, 2, 3, 4]
    assert make_policy("wave-markov", env).policy.plan(points).tolist() == [0, 0, 1, 2, 3]


@pytest.mark.parametrize(
    "name, message",
    [
        ("wave-markov:hold_steps=0", "hold_steps must be an integer >= 1 and <= 20, got '0'"),
        ("wave-markov:hold_steps=21", "hold_steps must be an integer >= 1 and <= 20, got '21'"),
        ("wave:hold_steps=seven", "hold_steps must be an integer >= 1, got 'seven'"),
        ("wave:bins=3", "the settings are hold_steps and bin_width, each once"),
        ("wave:hold_steps=6,hold_steps=7", "the settings are hold_steps and bin_width, each once"),
        ("wave-markov:hold_steps=6,bin_width=0", "bin_width must be a number > 0, got '0'"),
        ("wave-markov:bin_width=wide", "bin_width must be a number > 0, got 'wide'"),
        ("wave-markov:bin_width=inf", "bin_width must be a number > 0, got 'inf'"),
        ("random:hold_steps=3", "only 'wave', 'wave-markov', 'decentralised-wave' take settings"),
        ("decentralised-wave:n_phases=1", "n_phases must be an integer >= 2, got '1'"),
        ("decentralised-wave:bin_width=50", "the settings are hold_steps and n_phases, each once"),
        ("waves:hold_steps=3", "policy must be one of"),
    ],
)
def test_a_bad_setting_in_a_waves_name_is_refused(name, message):
    from dpr.policies.registry import check_policy_name

    with pytest.raises(ValueError, match=message):
        check_policy_name(name)


@pytest.mark.parametrize("run_folder", [False, True], ids=["policy-folder", "lerobot-train-output"])
def test_a_lerobot_policy_is_refused_with_how_to_score_it(tmp_path, run_folder: bool) -> None:
    """dpr does not import LeRobot: a LeRobot checkpoint as --policy says where it runs instead of failing later."""
    from dpr.policies.registry import LEROBOT_RUN_FOLDER, check_policy_name

    folder = tmp_path / LEROBOT_RUN_FOLDER if run_folder else tmp_path
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "config.json").write_text('{"type": "diffusion"}')
    (folder / "model.safetensors").write_bytes(b"")
    with pytest.raises(
        ValueError, match=r"LeRobot policy \(diffusion\).*make lerobot-env.*lerobot_policies.py evaluate"
    ):
        check_policy_name(str(tmp_path))
