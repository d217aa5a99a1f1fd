"""The batched vector envs (dpr.envs.batched): made by make_vec, the single env's spaces, layouts, rewards and
metrics, Gymnasium's NEXT_STEP autoreset, determinism, torch tensors, and the errors of bad arguments."""

import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

torch = pytest.importorskip("torch")

import dpr  # noqa: E402,F401  (registers the ids)
from dpr.checks import ParameterError  # noqa: E402
from dpr.envs.batched import ParticleSwarmVectorEnv  # noqa: E402
from dpr.metrics import MetricTracker  # noqa: E402

BATCHED_IDS = (
    "dpr/Navigation-v0",
    "dpr/Gate-v0",
    "dpr/Gate-v1",
    "dpr/Gate-v2",
    "dpr/Unresponsive-v0",
    "dpr/Manipulation-v0",
)
K = 3
SMALL = {"n_robots": 4}


def make(env_id="dpr/Navigation-v0", num_envs=K, **kwargs):
    return gym.make_vec(
        env_id, num_envs=num_envs, vectorization_mode="vector_entry_point", robot_model="disk", **{**SMALL, **kwargs}
    )


def single(env_id="dpr/Navigation-v0", **kwargs):
    return gym.make(env_id, robot_model="disk", **{**SMALL, **kwargs})


def assert_info_row(vector_info, row, single_info):
    """The single env's info equals row ``row`` of the vector info (positions: float32 world state)."""
    for key, value in single_info.items():
        assert vector_info["_" + key][row], key
        assert np.allclose(np.asarray(vector_info[key][row], dtype=float), np.asarray(value, dtype=float), atol=1e-3), (
            key,
            vector_info[key][row],
            value,
        )


def test_importing_dpr_does_not_import_torch():
    code = "import sys, dpr, dpr.envs, dpr.policies; print('torch' in sys.modules)"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "False"


@pytest.mark.parametrize("env_id", BATCHED_IDS)
def test_make_vec_gives_the_single_env_spaces_and_starts(env_id):
    """Spaces of the single env, batched; after reset(seed=s) copy i starts as the single env after
    reset(seed=s + i), info included; its next episode is the single env's next unseeded reset."""
    envs = make(env_id)
    assert isinstance(envs, VectorEnv) and isinstance(envs.unwrapped, ParticleSwarmVectorEnv)
    assert envs.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
    reference = single(env_id)
    assert envs.single_observation_space == reference.observation_space
    assert envs.single_action_space == reference.action_space
    assert envs.observation_space == batch_space(reference.observation_space, K)
    assert envs.action_space == batch_space(reference.action_space, K)

    observations, info = envs.reset(seed=20)
    assert envs.observation_space.contains(observations)
    again, _ = envs.reset()  # each copy's generator goes on
    for i in range(K):
        first, first_info = reference.reset(seed=20 + i)
        assert np.allclose(observations[i], first, atol=1e-6), i
        assert_info_row(info, i, first_info)
        second, _ = reference.reset()
        assert np.allclose(again[i], second, atol=1e-6), i
    reference.close()
    envs.close()


def test_dead_robots_of_each_copy_are_the_single_env_draws():
    envs = make("dpr/Unresponsive-v0", n_robots=9)
    _, info = envs.reset(seed=[7, 8, 9])  # a list of seeds: one per copy
    for i, seed in enumerate((7, 8, 9)):
        _, single_info = single("dpr/Unresponsive-v0", n_robots=9).reset(seed=seed)
        assert np.array_equal(info["dead_robots"][i], single_info["dead_robots"])
    assert not envs.unwrapped.world.alive.cpu().numpy()[np.arange(K)[:, None], info["dead_robots"]].any()


def test_next_step_autoreset():
    """After the step that ends a copy's episode, the next step returns its first observation of the next episode
    (the single env's next reset), reward 0, not done, whatever the action; the other copies step on."""
    envs = make(max_episode_steps=3)
    observations, _ = envs.reset(seed=1)
    assert envs.unwrapped.episode_start.all()
    actions = np.ones((K, 4), dtype=np.int8)
    for step in range(3):
        observations, rewards, terminated, truncated, info = envs.step(actions)
        assert not terminated.any()
        assert truncated.all() == (step == 2)
        assert not envs.unwrapped.episode_start.any()
        assert "dead_robots" not in info
    observations, rewards, terminated, truncated, info = envs.step(np.zeros((K, 4), dtype=np.int8))
    assert envs.unwrapped.episode_start.all()
    assert not (terminated.any() or truncated.any()) and np.array_equal(rewards, np.zeros(K))
    assert info["_dead_robots"].all()
    for i in range(K):
        reference = single()
        reference.reset(seed=1 + i)
        next_start, next_info = reference.reset()
        assert np.allclose(observations[i], next_start, atol=1e-6)
        assert_info_row(info, i, next_info)
    observations, *_ = envs.step(actions)  # stepped again: every robot expanding
    assert not envs.unwrapped.episode_start.any()
    assert (observations[:, 5 : 6 * 4 : 6] > 0).all()


def test_termination_at_the_goal_then_reset():
    """A swarm within SUCCESS_RADIUS of the goal terminates with is_success; only that copy resets next."""
    envs = make()
    envs.reset(seed=2)
    world = envs.unwrapped.world
    centres = world.position.clone()
    centres[1] -= centres[1].mean(dim=0)  # copy 1's swarm centred on the goal
    world.reset(torch.tensor([False, True, False]), centres, ~world.alive)
    zeros = np.zeros((K, 4), dtype=np.int8)
    observations, rewards, terminated, truncated, info = envs.step(zeros)
    assert terminated.tolist() == [False, True, False] and not truncated.any()
    assert info["is_success"].tolist() == [False, True, False]
    assert np.linalg.norm(info["agent_position"][1]) < 10.0
    observations, rewards, terminated, truncated, info = envs.step(zeros)
    assert envs.unwrapped.episode_start.tolist() == [False, True, False]
    assert info["_dead_robots"].tolist() == [False, True, False]
    assert rewards[1] == 0.0 and not info["is_success"][1] and info["total_distance"][1] == 0.0
    assert np.linalg.norm(info["agent_position"][1]) > 400.0  # a new start


@pytest.mark.parametrize(
    ("env_id", "kwargs"),
    [
        ("dpr/Navigation-v0", {"reward": "piecewise", "reward_threshold_d": 1000.0}),  # within d: the multiplier
        ("dpr/Navigation-v0", {"reward": "projected"}),
        ("dpr/Navigation-v0", {"reward": "inverse_distance"}),
        ("dpr/Manipulation-v0", {"approach_reward": 2.0}),
    ],
)
def test_rewards_and_metrics_are_the_single_env_definitions(env_id, kwargs):
    """Each step's reward and metrics, recomputed from the agent's positions by the single env's own _reward and
    MetricTracker."""
    envs = make(env_id, **kwargs)
    _, info = envs.reset(seed=5)
    reference = single(env_id, **kwargs).unwrapped
    trackers = [MetricTracker(info["agent_position"][i], reference.goal) for i in range(K)]
    gaps = np.linalg.norm(info["agent_position"] - info["centre_of_mass"], axis=1)
    actions = np.random.default_rng(0).integers(0, 2, (8, K, 4))
    for action in actions:
        _, rewards, _, _, info = envs.step(action)
        for i, tracker in enumerate(trackers):
            previous = tracker.last_position
            tracker.update(info["agent_position"][i])
            reference._tracker = tracker
            expected = reference._reward(previous) if env_id.endswith("Navigation-v0") else None
            if expected is None:  # Manipulation's shaping: the base reward plus the swarm-object gap's decrease
                reference._tracker = tracker
                gap = np.linalg.norm(info["agent_position"][i] - info["centre_of_mass"][i])
                expected = super(type(reference), reference)._reward(previous) + 2.0 * (gaps[i] - gap)
                gaps[i] = gap
            assert rewards[i] == pytest.approx(expected, rel=1e-5, abs=1e-7)
            assert info["total_distance"][i] == pytest.approx(tracker.total_distance, rel=1e-9)
            assert info["net_displacement"][i] == pytest.approx(tracker.net_displacement, rel=1e-9)
            assert info["projected_displacement"][i] == pytest.approx(tracker.projected_displacement, abs=1e-9)


def test_same_seed_same_trajectories():
    def run():
        envs = make("dpr/Gate-v2", n_robots=9)
        trace = [envs.reset(seed=11)[0]]
        rng = np.random.default_rng(3)
        for _ in range(6):
            observations, rewards, *_ = envs.step(rng.integers(0, 2, (K, 9)))
            trace += [observations, rewards]
        return trace

    first, second = run(), run()
    assert all(np.array_equal(a, b) for a, b in zip(first, second))
    assert not np.array_equal(first[0], first[-2])


def test_action_repeat_is_repeated_physics_steps():
    """One env step of action_repeat=3 is three physics steps of the same action: the observation (held steps
    included) and the metrics of three steps of action_repeat=1, and the sum of their rewards."""
    kwargs = {"obs_last_action": True}
    once, thrice = make(**kwargs), make(action_repeat=3, **kwargs)
    once.reset(seed=4)
    thrice.reset(seed=4)
    action = np.array([[1, 0, 0, 1], [0, 1, 1, 0], [1, 1, 1, 1]], dtype=np.int8)
    total = 0.0
    for _ in range(3):
        single_observation, reward, _, _, single_info = once.step(action)
        total = total + reward
    observations, rewards, _, _, info = thrice.step(action)
    assert np.array_equal(observations, single_observation)
    assert np.allclose(rewards, total, rtol=1e-5)
    assert np.array_equal(info["total_distance"], single_info["total_distance"])


def test_step_tensors_are_step_on_torch():
    numpy_envs, torch_envs = make("dpr/Manipulation-v0"), make("dpr/Manipulation-v0")
    numpy_envs.reset(seed=6)
    observations, info = torch_envs.unwrapped.reset_tensors(seed=6)
    assert isinstance(observations, torch.Tensor) and observations.dtype == torch.float32
    action = np.array([[1, 0, 1, 0], [0, 0, 0, 0], [1, 1, 1, 1]], dtype=np.int8)
    expected = numpy_envs.step(action)
    got = torch_envs.unwrapped.step_tensors(torch.as_tensor(action))
    assert [type(value) for value in got[:4]] == [torch.Tensor] * 4
    assert (got[1].dtype, got[2].dtype, got[3].dtype) == (torch.float32, torch.bool, torch.bool)
    for a, b in zip(expected[:4], got[:4]):
        assert np.array_equal(a, b.cpu().numpy())
    assert np.array_equal(expected[4]["object_position"], got[4]["object_position"].cpu().numpy())


@pytest.mark.parametrize("action_type", ["discrete", "continuous"])
def test_other_action_types(action_type):
    envs = make(action_type=action_type)
    envs.reset(seed=0)
    envs.action_space.seed(0)
    observations, *_ = envs.step(envs.action_space.sample())
    assert envs.observation_space.contains(observations)
    bad = np.full(K, 16) if action_type == "discrete" else np.full((K, 4), 1.5)
    with pytest.raises(ValueError, match="actions"):
        envs.step(bad)


def test_returned_arrays_are_not_reused_and_partial_reset():
    envs = make()
    observations, _ = envs.reset(seed=8)
    kept = observations.copy()
    stepped, *_ = envs.step(np.ones((K, 4), dtype=np.int8))
    assert np.array_equal(observations, kept)
    mask = np.array([True, False, False])
    reset, info = envs.reset(seed=8, options={"reset_mask": mask})
    assert np.array_equal(reset[0], kept[0]) and np.array_equal(reset[1:], stepped[1:])
    assert info["_is_success"].tolist() == mask.tolist()


def test_a_blown_up_swarm_is_truncated_with_its_last_observation():
    """As the single env: reward 0, truncated, the previous observation and info["physics_error"]; the copy is
    held at its start and reset at the next step."""
    envs = make()
    envs.reset(seed=9)
    world = envs.unwrapped.world
    zeros = np.zeros((K, 4), dtype=np.int8)
    before, *_ = envs.step(zeros)
    centres = world.position.clone()
    centres[2] = float("nan")
    world.reset(torch.tensor([False, False, True]), centres, ~world.alive)
    observations, rewards, terminated, truncated, info = envs.step(zeros)
    assert truncated.tolist() == [False, False, True] and not terminated.any()
    assert rewards[2] == 0.0 and np.array_equal(observations[2], before[2])
    assert info["_physics_error"].tolist() == [False, False, True] and "exploding" in info["physics_error"][2]
    assert torch.isfinite(world.position).all()
    observations, rewards, terminated, truncated, _ = envs.step(zeros)
    assert envs.unwrapped.episode_start.tolist() == [False, False, True] and np.isfinite(observations).all()


@pytest.mark.parametrize(
    ("kwargs", "parameter"),
    [
        ({"robot_model": "paddle"}, "robot_model"),
        ({"num_envs": 0}, "num_envs"),
        ({"num_envs": 10**9, "n_robots": 1000}, "num_envs"),  # refused before anything is allocated
        ({"obs_type": "pixels"}, "obs_type"),
        ({"render_mode": "rgb_array"}, "render_mode"),
        ({"n_robots": 0}, "n_robots"),
        ({"max_episode_steps": 0}, "max_episode_steps"),
        ({"device": "no-such-device"}, "device"),
    ],
)
def test_bad_arguments_are_refused_by_name(kwargs, parameter):
    kwargs = {"num_envs": 2, "robot_model": "disk", **kwargs}
    with pytest.raises(ParameterError) as error:
        gym.make_vec("dpr/Navigation-v0", vectorization_mode="vector_entry_point", **kwargs)
    assert error.value.parameter == parameter


def test_paddle_error_says_what_to_use():
    with pytest.raises(ValueError, match=r"'paddle'.*'disk'.*sync"):
        gym.make_vec("dpr/Navigation-v0", num_envs=2, vectorization_mode="vector_entry_point", robot_model="paddle")


def test_box_object_and_cuda_without_cuda_are_refused():
    with pytest.raises(ParameterError, match="ball"):
        make("dpr/Manipulation-v0", object_type="box")
    if not torch.cuda.is_available():
        with pytest.raises(ParameterError, match="CUDA"):
            make(device="cuda")


def test_step_before_reset():
    with pytest.raises(RuntimeError, match="reset"):
        make().step(np.zeros((K, 4), dtype=np.int8))


def test_gate_contact_step_is_the_first_physics_step_touching_a_wall():
    envs = make("dpr/Gate-v2", n_robots=9)
    _, info = envs.reset(seed=12)
    assert (info["gate_contact_step"] == -1).all()
    expand = np.ones((K, 9), dtype=np.int8)
    contact = []
    for _ in range(8):  # the front robots stand 5 units short of the walls: expanded, they touch them
        _, _, _, _, info = envs.step(expand)
        contact.append(info["gate_contact_step"].copy())
    assert (contact[-1] > 0).all() and (contact[-1] <= 8).all()
    for step, values in enumerate(contact, start=1):  # set once, at the step it happened
        assert np.all((values == -1) | (values == contact[-1])) and np.all(values <= step)
