"""Decentralised control: the per-robot local observation, and the scripted wave every robot runs on its own."""

import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from helpers import drive, load_tool

with warnings.catch_warnings():
    warnings.simplefilter("ignore", DeprecationWarning)  # pettingzoo.test loads its own deprecated env modules
    from pettingzoo.test import parallel_api_test

from dpr.checks import ParameterError
from dpr.envs import ENV_IDS, parallel_env
from dpr.envs.local_obs import LocalObservation, local_observations
from dpr.policies.decentralised import DecentralisedWavePolicy, PerRobotPolicyAdapter, wave_env_kwargs
from dpr.policies.registry import SCRIPTED_POLICIES, make_policy

DISK = {"robot_model": "disk"}
CLOCK = 16


def disk_state(n_robots: int, seed: int = 0, steps: int = 0, task: str = "navigation") -> tuple[np.ndarray, float]:
    """The global state of a disk swarm after ``steps`` random steps, and its magnet range."""
    env = gym.make(ENV_IDS[task], n_robots=n_robots, **DISK)
    state, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        state, *_ = env.step(rng.integers(0, 2, n_robots).astype(np.int8))
    return state, env.unwrapped.swarm_class.magnet_range


# -- the local observation -----------------------------------------------------------------------------------
def test_local_observation_space_is_the_same_for_every_swarm_size():
    spaces, shapes = [], []
    for n in (4, 9, 25, 100):
        env = parallel_env("navigation", n_robots=n, local_obs=True, clock_period=CLOCK, **DISK)
        observations, _ = env.reset(seed=n)
        spaces.append(env.observation_space("robot_0"))
        shapes.append({obs.shape for obs in observations.values()})
        assert all(env.observation_space(a).contains(o) for a, o in observations.items())
    assert all(space == spaces[0] for space in spaces)
    assert shapes == [{(6 + 7 * 8 + 3 + 2,)}] * 4


def test_layout_parts_goal_signal_clock_and_dead_flag():
    env = parallel_env("unresponsive", n_robots=9, n_dead=2, local_obs=True, clock_period=CLOCK, **DISK)
    layout = env.local_layout
    assert (layout.goal.start, layout.clock.start, layout.dead.start, layout.size) == (62, 65, 67, 68)
    observations, infos = env.reset(seed=3)
    for step in range(CLOCK + 3):
        state = env.state()
        for i, agent in enumerate(env.possible_agents):
            row = observations[agent]
            position = state[6 * i : 6 * i + 2].astype(np.float64)
            distance = np.linalg.norm(position)
            np.testing.assert_allclose(row[layout.goal], [*(-position / distance), distance], rtol=1e-6)
            angle = 2 * np.pi * step / CLOCK
            np.testing.assert_allclose(row[layout.clock], [np.sin(angle), np.cos(angle)], atol=1e-6)
            assert row[layout.dead.start] == float(infos[agent]["dead"])
        observations, _, _, _, infos = env.step(dict.fromkeys(env.agents, 1))
    assert sum(o[layout.dead.start] for o in observations.values()) == 2


def test_mask_with_fewer_robots_than_neighbour_slots():
    k = 8
    for n in (1, 2, 3, 5):  # N - 1 < k
        state, magnet_range = disk_state(n, seed=n, steps=5)
        rows = local_observations(state, n, magnet_range, LocalObservation(k))
        layout = LocalObservation(k)
        positions = state[: 6 * n].reshape(n, 6)[:, 0:2].astype(np.float64) * 1000.0
        distance = np.linalg.norm(positions[:, None] - positions[None], axis=2)
        within = ((distance < magnet_range) & ~np.eye(n, dtype=bool)).sum(axis=1)
        mask = rows[:, layout.mask]
        np.testing.assert_array_equal(mask.sum(axis=1), within)
        for i in range(n):
            assert mask[i, : within[i]].all() and not mask[i, within[i] :].any()  # filled slots come first
            slots = rows[i, layout.neighbours].reshape(k, 6)
            assert not slots[within[i] :].any()  # padding is zeros
        assert (mask.sum(axis=1) <= n - 1).all()
    assert (within > 0).any()  # some robot had neighbours to count


def test_a_robot_does_not_see_a_robot_beyond_its_neighbours():
    n, k = 25, 4
    state, magnet_range = disk_state(n, seed=1, steps=10)
    rows = local_observations(state, n, magnet_range, LocalObservation(k))
    positions = state[: 6 * n].reshape(n, 6)[:, 0:2] * 1000.0
    distance = np.linalg.norm(positions - positions[0], axis=1)
    far = int(np.argmax(distance))
    assert distance[far] > 3 * magnet_range
    moved = state.copy()
    moved[6 * far : 6 * far + 6] += np.float32([0.01, -0.02, 0.3, 0.3, 1.0, 0.0])  # moves 22 units, new velocity
    moved[6 * far + 5] = 1.0 - state[6 * far + 5]  # and flips its expansion
    after = local_observations(moved, n, magnet_range, LocalObservation(k))
    np.testing.assert_array_equal(after[0], rows[0])
    assert not np.array_equal(after[far], rows[far])
    # a robot that is one of robot 0's neighbours changes robot 0's row
    nearest = int(np.argsort(distance)[1])
    moved = state.copy()
    moved[6 * nearest + 5] = 1.0 - state[6 * nearest + 5]
    assert not np.array_equal(local_observations(moved, n, magnet_range, LocalObservation(k))[0], rows[0])


def test_max_neighbours_below_one_is_refused():
    for bad in (0, -1):
        with pytest.raises(ParameterError, match="max_neighbours") as error:
            parallel_env("navigation", n_robots=4, local_obs=True, max_neighbours=bad, **DISK)
        assert error.value.parameter == "max_neighbours"
        with pytest.raises(ParameterError, match="max_neighbours"):
            LocalObservation(max_neighbours=bad)
        with pytest.raises(ParameterError, match="max_neighbours"):
            DecentralisedWavePolicy.for_env(gym.make(ENV_IDS["navigation"], n_robots=4, **DISK), max_neighbours=bad)


def test_clock_needs_local_observations_and_a_period_of_two_or_more():
    with pytest.raises(ParameterError, match="clock_period.*local_obs"):
        parallel_env("navigation", n_robots=4, clock_period=10, **DISK)
    for bad in (1, 0, 2.5, True):
        with pytest.raises(ParameterError, match="clock_period"):
            parallel_env("navigation", n_robots=4, local_obs=True, clock_period=bad, **DISK)


# -- the distance's phase in place of the distance ------------------------------------------------------------
PERIOD = 240.0


def test_distance_period_gives_the_phase_of_the_distance_and_no_position():
    env = parallel_env("navigation", n_robots=9, local_obs=True, clock_period=CLOCK, distance_period=PERIOD, **DISK)
    layout = env.local_layout
    assert (layout.goal.stop - layout.goal.start, layout.size) == (4, 6 + 7 * 8 + 4 + 2)
    observations, _ = env.reset(seed=4)
    for _ in range(3):
        state = env.state()
        for i, agent in enumerate(env.possible_agents):
            row = observations[agent]
            position = state[6 * i : 6 * i + 2].astype(np.float64)
            distance = np.linalg.norm(position)
            angle = 2 * np.pi * distance * 1000.0 / PERIOD
            expected = [*(-position / distance), np.sin(angle), np.cos(angle)]
            np.testing.assert_allclose(row[layout.goal], expected, atol=2e-5)
            assert row[0] == row[1] == 0.0  # the own x, y: a robot does not know where it stands
            assert env.observation_space(agent).contains(row)
        observations, *_ = env.step(dict.fromkeys(env.agents, 1))


def test_with_a_distance_period_nothing_in_a_row_grows_with_the_distance():
    periodic, raw = LocalObservation(distance_period=PERIOD), LocalObservation()
    rows = {layout: [] for layout in (periodic, raw)}
    for periods in (1, 4, 40):  # one robot on the same ray, whole periods farther from the goal
        state = np.zeros(6, dtype=np.float32)
        state[0:2] = np.array([0.6, -0.8]) * (100.0 + periods * PERIOD) / 1000.0
        for layout in rows:
            rows[layout].append(layout.observe(state, 1, 60.0)[0])
    np.testing.assert_allclose(rows[periodic][0], rows[periodic][2], atol=1e-5)
    np.testing.assert_allclose(rows[periodic][0], rows[periodic][1], atol=1e-5)
    assert rows[raw][2][raw.goal.start + 2] > 9 * rows[raw][0][raw.goal.start + 2]  # the raw distance grows


@pytest.mark.parametrize("robot_model", ["disk", "paddle"])
def test_the_wave_acts_the_same_on_the_distance_s_phase_as_on_the_distance(robot_model):
    kwargs = {"n_robots": 25, "robot_model": robot_model, **wave_env_kwargs(robot_model)}
    raw, periodic = parallel_env("navigation", **kwargs), parallel_env("navigation", distance_period=PERIOD, **kwargs)
    on_raw, on_periodic = (DecentralisedWavePolicy.from_parallel_env(env) for env in (raw, periodic))
    raw_observations, _ = raw.reset(seed=3)
    periodic_observations, _ = periodic.reset(seed=3)
    expanded = 0
    for _ in range(120):
        actions = on_raw.act_agents(raw_observations)
        assert on_periodic.act_agents(periodic_observations) == actions
        expanded += sum(actions.values())
        raw_observations, *_ = raw.step(actions)
        periodic_observations, *_ = periodic.step(actions)
    assert 0 < expanded < 25 * 120


def test_bad_distance_periods_are_refused_by_name():
    with pytest.raises(ParameterError, match="distance_period.*local_obs"):
        parallel_env("navigation", n_robots=4, distance_period=PERIOD, **DISK)
    for bad in (0, -240.0, float("nan"), float("inf"), "240", True):
        with pytest.raises(ParameterError, match="distance_period") as error:
            parallel_env("navigation", n_robots=4, local_obs=True, distance_period=bad, **DISK)
        assert error.value.parameter == "distance_period"
    # the wave reads its band number mod n_phases from the phase: the period must hold whole cycles of bands
    for period in (200.0, 180.0):
        with pytest.raises(ParameterError, match="distance_period.*multiple of n_phases x bin_width"):
            DecentralisedWavePolicy(LocalObservation(clock_period=8, distance_period=period), n_phases=4)
    DecentralisedWavePolicy(LocalObservation(clock_period=8, distance_period=480.0), n_phases=4)


@pytest.mark.parametrize(
    "task, options",
    [
        ("navigation", {"clock_period": CLOCK, "max_neighbours": 3}),
        ("unresponsive", {"clock_period": CLOCK}),
        ("navigation", {"clock_period": CLOCK, "distance_period": 240.0}),
        ("manipulation", {"clock_period": CLOCK, "action_type": "continuous"}),
    ],
)
def test_pettingzoo_api_test_passes_with_the_local_observation_options(task, options):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env = parallel_env(task, n_robots=4, local_obs=True, max_episode_steps=25, **DISK, **options)
        parallel_api_test(env, num_cycles=40)


# -- the decentralised wave ------------------------------------------------------------------------------------
def test_the_adapter_gives_each_robot_what_the_parallel_env_gives_it():
    kwargs = {"n_robots": 9, "n_dead": 2, **DISK}
    single = gym.make(ENV_IDS["unresponsive"], **kwargs)
    adapter = DecentralisedWavePolicy.for_env(single)
    parallel = parallel_env("unresponsive", **kwargs, **wave_env_kwargs("disk"))
    policy = DecentralisedWavePolicy.from_parallel_env(parallel)
    assert parallel.local_layout == adapter.layout
    obs, _ = single.reset(seed=4)
    adapter.reset(4)
    pobs, _ = parallel.reset(seed=4)
    for _ in range(30):
        rows = adapter.local_observations(obs)
        np.testing.assert_array_equal(rows, np.stack([pobs[a] for a in parallel.possible_agents]))
        action = adapter(obs)
        per_agent = policy.act_agents(pobs)
        assert [per_agent[a] for a in parallel.possible_agents] == action.tolist()
        obs, *_ = single.step(action)
        pobs, *_ = parallel.step(per_agent)


def test_each_robot_decides_from_its_own_observation_only():
    n = 25
    env = gym.make(ENV_IDS["navigation"], n_robots=n, **DISK)
    adapter = DecentralisedWavePolicy.for_env(env)
    policy = adapter.policy
    state, _ = env.reset(seed=2)
    rng = np.random.default_rng(0)
    perm = rng.permutation(n)
    permuted = state.reshape(n, 6)[perm].ravel()
    for step in range(2 * adapter.layout.clock_period):
        adapter._steps = step
        rows = adapter.local_observations(state)
        actions = policy.act(rows)
        np.testing.assert_array_equal(policy.act(rows[perm]), actions[perm])  # per row, whatever the order
        assert [policy(row) for row in rows] == actions.tolist()  # one robot alone decides the same
        np.testing.assert_array_equal(adapter(permuted), actions[perm])  # robots renumbered: actions follow
    # a robot's action is blind to every other robot: change all of them, keep its row's own parts
    rows = adapter.local_observations(state)
    scrambled = rows.copy()
    scrambled[1:] = rng.normal(size=scrambled[1:].shape)
    scrambled[0, adapter.layout.neighbours] = rng.normal(size=6 * adapter.layout.max_neighbours)
    assert policy.act(scrambled)[0] == policy.act(rows)[0]


def test_the_wave_expands_bands_in_turn():
    layout = LocalObservation(max_neighbours=1, clock_period=8)
    policy = DecentralisedWavePolicy(layout, n_phases=4, bin_width=60.0, start_side="near")
    rows = np.zeros((6, layout.size), dtype=np.float32)
    rows[:, layout.goal.start + 2] = np.array([500, 530, 560, 620, 680, 740]) / 1000.0  # bands 8, 8, 9, 10, 11, 12
    expanded = []
    for step in range(8):
        angle = 2 * np.pi * step / 8
        rows[:, layout.clock] = np.float32([np.sin(angle), np.cos(angle)])
        expanded.append(policy.expand(rows).tolist())
    # phase p (2 steps each) expands bands p mod 4: the wave starts near the goal and runs away from it
    assert expanded[0] == expanded[1] == [True, True, False, False, False, True]
    assert expanded[2] == [False, False, True, False, False, False]
    assert expanded[4] == [False, False, False, True, False, False]
    assert expanded[6] == [False, False, False, False, True, False]
    far = DecentralisedWavePolicy(layout, n_phases=4, start_side="far")
    rows[:, layout.clock] = np.float32([1.0, 0.0])  # step 2: phase 1 expands bands -1 mod 4 (11) in the far wave
    assert far.expand(rows).tolist() == [False, False, False, False, True, False]


def test_the_decentralised_wave_moves_a_disk_swarm_toward_the_goal():
    env = parallel_env("navigation", n_robots=9, max_episode_steps=1000, **DISK, **wave_env_kwargs("disk"))
    policy = DecentralisedWavePolicy.from_parallel_env(env)
    observations, infos = env.reset(seed=0)
    while env.agents:
        observations, _, _, _, infos = env.step(policy.act_agents(observations))
    assert infos["robot_0"]["projected_displacement"] > 10.0


@pytest.mark.parametrize("action_type", ["multibinary", "continuous", "discrete"])
def test_registry_makes_the_decentralised_wave_for_every_action_type(action_type):
    assert "decentralised-wave" in SCRIPTED_POLICIES
    env = gym.make(ENV_IDS["navigation"], n_robots=4, action_type=action_type, **DISK)
    policy = make_policy("decentralised-wave", env)
    assert isinstance(policy, PerRobotPolicyAdapter)
    drive(env, policy, steps=10, seed=0)


def test_the_registry_name_carries_the_number_of_phases_and_the_hold():
    env = gym.make(ENV_IDS["navigation"], n_robots=9, **DISK)
    wave = make_policy("decentralised-wave:n_phases=6,hold_steps=3", env).policy
    assert (wave.n_phases, wave.clock_period) == (6, 18)
    default = make_policy("decentralised-wave", env).policy
    assert (default.n_phases, default.clock_period) == (4, wave_env_kwargs("disk")["clock_period"])
    drive(env, make_policy("decentralised-wave:n_phases=6", env), steps=10, seed=0)


def test_bad_policy_arguments():
    with pytest.raises(ParameterError, match="local_obs"):
        DecentralisedWavePolicy.from_parallel_env(parallel_env("navigation", n_robots=4, **DISK))
    with pytest.raises(ParameterError, match="clock_period"):
        DecentralisedWavePolicy.from_parallel_env(parallel_env("navigation", n_robots=4, local_obs=True, **DISK))
    with pytest.raises(ParameterError, match="obs_type"):
        DecentralisedWavePolicy.for_env(gym.make(ENV_IDS["navigation"], n_robots=4, obs_type="pixels", **DISK))
    layout = LocalObservation(clock_period=8)
    for kwargs, name in [
        ({"n_phases": 1}, "n_phases"),
        ({"bin_width": 0}, "bin_width"),
        ({"start_side": "up"}, "start_side"),
    ]:
        with pytest.raises(ParameterError, match=name):
            DecentralisedWavePolicy(layout, **kwargs)
    with pytest.raises(ParameterError, match="clock_period"):
        DecentralisedWavePolicy(LocalObservation(clock_period=3), n_phases=4)


@pytest.fixture(scope="module")
def sweep_tool():
    return load_tool("decentralised_sweep")


def test_decentralised_sweep_tool_prints_its_table_caches_and_plots(sweep_tool, tmp_path, capsys):
    import json

    cache, rows_file, plot = tmp_path / "episodes.jsonl", tmp_path / "rows.json", tmp_path / "sweep.png"
    argv = ["--models", "disk", "--sizes", "4", "--seeds", "0-1", "--steps", "20", "--workers", "1"]
    argv += ["--cache", str(cache), "--json", str(rows_file), "--plot", str(plot)]
    assert sweep_tool.main(argv) == 0
    out = capsys.readouterr()
    assert "20 steps, seeds 0-1 (2)" in out.out and "0 episodes cached, 4 to run" in out.err
    assert "| disk | 4 | centralised wave |" in out.out and "| disk | 4 | decentralised wave (4 phases) |" in out.out
    rows = json.loads(rows_file.read_text())
    assert [row["policy"] for row in rows] == ["centralised wave", "decentralised wave (4 phases)"]
    assert rows[0]["of_centralised"] == 1.0 and all(row["us_per_robot_step"] > 0 for row in rows)
    assert plot.stat().st_size > 1000 and len(cache.read_text().splitlines()) == 4
    assert sweep_tool.main(argv) == 0  # a rerun takes every episode from the cache
    assert "4 episodes cached, 0 to run" in capsys.readouterr().err


def test_decentralised_sweep_tool_runs_a_model_file_again_when_it_is_replaced(sweep_tool, tmp_path, capsys):
    """The cache knows a model file by its content: another model under the same path does not take its episodes."""
    import shutil

    models = Path(__file__).resolve().parents[1] / "models"
    policy = tmp_path / "per-robot.zip"
    argv = ["--models", "disk", "--sizes", "4", "--seeds", "0", "--steps", "10", "--workers", "1"]
    argv += ["--policies", str(policy), "--cache", str(tmp_path / "episodes.jsonl")]
    runs = []
    for source in ("decentralised-disk-bc.zip", "decentralised-disk-bc-ppo.zip", "decentralised-disk-bc.zip"):
        shutil.copyfile(models / source, policy)
        assert sweep_tool.main(argv) == 0
        runs.append(capsys.readouterr().err.splitlines()[0])
    assert runs == ["0 episodes cached, 1 to run", "0 episodes cached, 1 to run", "1 episodes cached, 0 to run"]


def test_decentralised_sweep_tool_refuses_a_policy_that_is_not_one(sweep_tool, tmp_path, capsys):
    with pytest.raises(SystemExit):
        sweep_tool.main(["--policies", "centralised", str(tmp_path / "missing.zip")])
    assert "--policies" in capsys.readouterr().err


def test_decentralised_sweep_tool_runs_a_centralised_swarm_model_at_any_size(sweep_tool, tmp_path, capsys):
    """A centralised model whose actor the robots share runs at every N, on both robot models, with its own env
    kwargs; one made for a fixed N is refused, named, before any episode."""
    import json

    from stable_baselines3.common.vec_env import DummyVecEnv

    from dpr.policies.hyperparams import load_hyperparams
    from dpr.policies.model_file import ModelInfo
    from dpr.policies.sb3 import build_model, save_model

    canonical = Path(__file__).resolve().parents[1] / "models" / "navigation-bc-ppo.zip"
    rows_file = tmp_path / "rows.json"
    argv = ["--models", "paddle", "disk", "--sizes", "4", "7", "--seeds", "0", "--steps", "12", "--workers", "1"]
    assert sweep_tool.main([*argv, "--policies", "centralised", str(canonical), "--json", str(rows_file)]) == 0
    rows = json.loads(rows_file.read_text())
    ran = {(row["robot_model"], row["n_robots"]) for row in rows if row["policy"] == canonical.name}
    assert ran == {("paddle", 4), ("paddle", 7), ("disk", 4), ("disk", 7)}
    capsys.readouterr()

    env_id = "dpr/Navigation-v0"
    env = gym.make(env_id, n_robots=5, **DISK)
    mlp = build_model(load_hyperparams("ppo", env_id), DummyVecEnv([lambda: env]), 0, None)
    fixed = save_model(mlp, tmp_path / "mlp.zip", ModelInfo("ppo", env_id, {"n_robots": 5, **DISK}))
    with pytest.raises(SystemExit):
        sweep_tool.main([*argv, "--policies", str(fixed)])
    assert f"{fixed} is a centralised model for 5 robots only" in capsys.readouterr().err


SHIPPED_PER_ROBOT = sorted((Path(__file__).resolve().parents[1] / "models").glob("decentralised*.zip"))


@pytest.mark.parametrize("path", SHIPPED_PER_ROBOT, ids=lambda path: path.name)
def test_every_shipped_per_robot_model_drives_swarms_of_any_size(path):
    """The per-robot models in models/ load as what they are and act at sizes they never trained on."""
    from dpr.policies.per_robot_model import RobotModelPolicy

    spec = RobotModelPolicy.load(path).spec
    assert set(spec.trained_n_robots) <= {9, 25, 100}
    for n_robots in (4, 36):  # sizes no shipped model trained on
        env = gym.make(ENV_IDS["navigation"], n_robots=n_robots, robot_model=spec.robot_model, max_episode_steps=20)
        drive(env, make_policy(str(path), env), steps=20, seed=0)


@pytest.mark.parametrize("env_id", ["dpr/Gate-v1", "dpr/Unresponsive-v0"])
def test_a_per_robot_model_runs_any_task_without_an_object(env_id):
    """As models/README.md says: a Navigation per-robot model drives Gate and Unresponsive; Manipulation's object
    is not in its observation, and is refused."""
    from pathlib import Path

    from dpr.checks import ParameterError
    from dpr.evaluation.scoring import run_episode

    model = str(Path(__file__).resolve().parents[1] / "models" / "decentralised-disk-bc.zip")
    result = run_episode(env_id, model, seed=0, steps=20)
    assert result.metrics.steps == 20
    with pytest.raises(ParameterError, match="cannot be run on dpr/Manipulation-v0"):
        run_episode("dpr/Manipulation-v0", model, seed=0, steps=20)
