"""`dpr view`: datasets, MCAP logs and live rollouts written to .rrd files and read back with rerun's own reader."""

from __future__ import annotations

import json
from collections import defaultdict

import numpy as np
import pytest
from helpers import run_cli as run
from rerun.chunk import RrdReader

import dpr.viz
from dpr.datasets.collect import CollectSpec, collect
from dpr.datasets.lerobot import LeRobotReader
from dpr.datasets.mcap import read_mcap
from dpr.envs.particle_env import LENGTH_SCALE
from dpr.metrics import episode_metrics
from dpr.viz import ViewRollout, episode_from_dataset, episode_from_mcap, rollout_episode, running_metrics

STEPS = 50
SMALL = ["--robot-model", "disk", "--n-robots", "4"]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """Two 50-step disk episodes (seeds 0 and 1) with their MCAP logs."""
    root = tmp_path_factory.mktemp("viz") / "ds"
    spec = CollectSpec("dpr/Navigation-v0", robot_model="disk", n_robots=4, steps=STEPS, mcap=True)
    collect(root, spec, episodes=2)
    return root


def read_rrd(path) -> tuple[dict[str, dict[str, list]], list[str]]:
    """The recording in ``path`` as {entity: {column: values}}, temporal rows in step order (an entity logged
    only statically holds its one static row), and the origins of the blueprint's views."""
    reader = RrdReader(path)
    temporal: dict[str, list[dict]] = defaultdict(list)
    static: dict[str, list[dict]] = defaultdict(list)
    for chunk in reader.stream():
        (static if chunk.is_static else temporal)[chunk.entity_path].extend(chunk.to_record_batch().to_pylist())
    entities = {}
    for entity, rows in {**static, **temporal}.items():
        rows.sort(key=lambda row: row.get("step", 0))
        keys = {key for row in rows for key in row} - {"rerun.controls.RowId"}
        entities[entity] = {key: [row.get(key) for row in rows] for key in keys}
    origins = []
    for chunk in reader.stream(store=reader.blueprints()[0]):
        batch = chunk.to_record_batch()
        if "ViewBlueprint:space_origin" in batch.schema.names:
            origins += [value[0] for value in batch.column("ViewBlueprint:space_origin").to_pylist()]
    return entities, origins


def assert_timelines(columns: dict[str, list], first: int, last: int, every: int = 1) -> None:
    """States ``first .. last`` logged at their physics steps (``every`` physics steps a state) and 0.1 s each."""
    steps = [state * every for state in range(first, last + 1)]
    assert columns["step"] == steps
    assert [t.value for t in columns["sim_time"]] == [step * 100_000_000 for step in steps]


# -- datasets -----------------------------------------------------------------------------------------------------
def test_view_dataset_episodes_side_by_side(dataset, tmp_path):
    out = tmp_path / "ds.rrd"
    assert run(["view", str(dataset), "--episode", "0", "1", "--save", str(out)]) == 0
    entities, origins = read_rrd(out)
    assert {"/episode_0", "/episode_1"} <= set(origins)
    reader = LeRobotReader(dataset)
    for index in (0, 1):
        base = f"/episode_{index}"
        robots = entities[f"{base}/scene/robots"]
        assert_timelines(robots, 0, STEPS - 1)  # a T-frame episode holds the states before each action
        assert f"{base}/scene/magnets" not in entities  # datasets hold no magnets
        recorded = reader.episode(index)
        state = recorded["observation.state"].astype(np.float64).reshape(STEPS, 4, 6)
        t = 17
        np.testing.assert_allclose(robots["Points2D:positions"][t][2], state[t, 2, 0:2] / LENGTH_SCALE, atol=1e-3)
        radii = np.array(robots["Points2D:radii"][t])
        assert radii.min() >= 27.5 - 1e-4 and radii.max() <= 52.5 + 1e-4  # the disk model's radius range
        reward = entities[f"{base}/metrics/reward"]
        assert_timelines(reward, 1, STEPS - 1)
        np.testing.assert_allclose(
            np.ravel(reward["Scalars:scalars"]), recorded["next.reward"][: STEPS - 1, 0], rtol=1e-6
        )
        for metric in ("distance_to_goal", "projected_displacement", "net_displacement", "total_distance"):
            assert_timelines(entities[f"{base}/metrics/{metric}"], 0, STEPS - 1)
        assert entities[f"{base}/scene/goal"]["Points2D:positions"] == [[[0.0, 0.0]]]


def test_dataset_states_match_the_mcap_log_of_the_same_episode(dataset):
    from_dataset = episode_from_dataset(LeRobotReader(dataset), 1)
    from_mcap = episode_from_mcap(dataset / "mcap" / "seed-000001.mcap")
    assert from_dataset.n_states == STEPS and from_mcap.n_states == STEPS + 1
    # float32 observations scaled by 1/1000: positions come back to about 1e-4 units
    np.testing.assert_allclose(from_dataset.positions, from_mcap.positions[:-1], atol=1e-3)
    np.testing.assert_allclose(from_dataset.expansions, from_mcap.expansions[:-1], atol=1e-6)
    np.testing.assert_allclose(from_dataset.rewards, from_mcap.rewards[:-1], rtol=1e-5, atol=1e-6)


# -- MCAP ---------------------------------------------------------------------------------------------------------
def test_view_mcap_file(dataset, tmp_path):
    source = dataset / "mcap" / "seed-000000.mcap"
    out = tmp_path / "mcap.rrd"
    assert run(["view", str(source), "--save", str(out)]) == 0
    entities, origins = read_rrd(out)
    episode = read_mcap(source)
    base = "/seed_000000"
    assert base in origins
    robots = entities[f"{base}/scene/robots"]
    assert_timelines(robots, 0, STEPS)
    for t in (0, 25, STEPS):
        np.testing.assert_allclose(robots["Points2D:positions"][t], episode.positions[t], rtol=1e-6)
    magnets = entities[f"{base}/scene/magnets"]
    assert_timelines(magnets, 0, STEPS)
    assert [len(strips) for strips in magnets["LineStrips2D:strips"]] == [len(m) for m in episode.magnets]
    assert sum(len(m) for m in episode.magnets) > 0
    centre = entities[f"{base}/scene/centre_of_mass"]
    np.testing.assert_allclose(np.array(centre["Points2D:positions"])[:, 0], episode.centres_of_mass, rtol=1e-6)
    # the metrics recomputed from the trajectory agree with those the env reported at every step
    for key in ("projected_displacement", "net_displacement", "total_distance"):
        logged = np.ravel(entities[f"{base}/metrics/{key}"]["Scalars:scalars"])
        np.testing.assert_allclose(logged[1:], episode.metrics[key], rtol=1e-9, atol=1e-9)
        assert logged[0] == 0.0


# -- live rollouts ------------------------------------------------------------------------------------------------
def test_view_policies_side_by_side_on_gate(tmp_path):
    out = tmp_path / "live.rrd"
    steps = 30
    argv = [
        "view",
        "--env",
        "dpr/Gate-v0",
        "--policies",
        "wave,random",
        "--seed",
        "3",
        "--steps",
        str(steps),
        *SMALL,
        "--save",
        str(out),
    ]
    assert run(argv) == 0
    entities, origins = read_rrd(out)
    assert {"/wave", "/random"} <= set(origins)
    for policy in ("wave", "random"):
        for entity in ("robots", "magnets", "centre_of_mass"):
            assert_timelines(entities[f"/{policy}/scene/{entity}"], 0, steps)
        assert len(entities[f"/{policy}/scene/walls"]["LineStrips2D:strips"][0]) == 2  # Gate's two walls
    wave, random = (np.array(entities[f"/{p}/scene/robots"]["Points2D:positions"]) for p in ("wave", "random"))
    np.testing.assert_array_equal(wave[0], random[0])  # the same start
    expected = rollout_episode(ViewRollout("dpr/Gate-v0", "wave", 3, n_robots=4, robot_model="disk", steps=steps))
    np.testing.assert_allclose(wave[20], expected.positions[20], rtol=1e-6)  # float32 in the .rrd


@pytest.fixture(scope="module")
def every_six(tmp_path_factory):
    """A dataset of the wave deciding every 6 physics steps (two episodes of 10 decisions) and a one-epoch
    `dpr bc` clone of it, which decides every 6 steps too."""
    root = tmp_path_factory.mktemp("every_six")
    spec = CollectSpec("dpr/Navigation-v0", robot_model="disk", n_robots=4, steps=10, env_kwargs={"action_repeat": 6})
    collect(root / "ds", spec, episodes=2)
    argv = ["bc", "--dataset", str(root / "ds"), "--env", "dpr/Navigation-v0", "--epochs", "1"]
    assert run([*argv, "--out", str(root / "run")]) == 0
    return root / "ds", root / "run" / "model.zip"


class _Bar:
    """tqdm's interface as `dpr view` uses it, keeping every bar's count and total."""

    bars: list[_Bar] = []

    def __init__(self, total=None, **kwargs):
        self.total, self.n = total, 0
        _Bar.bars.append(self)

    def update(self, n=1):
        self.n += n

    def refresh(self):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        pass


def test_a_model_deciding_every_six_steps_shares_the_waves_clock(every_six, tmp_path, monkeypatch):
    """Side by side, both rollouts log `step` as the physics step and `sim_time` in simulated seconds: the model
    at every decision (steps 0, 6, .., 60), both ending at step 60 and 6.0 s; each progress bar counts to 60."""
    import tqdm

    _, model = every_six
    monkeypatch.setattr(tqdm, "tqdm", _Bar)
    _Bar.bars = []
    out = tmp_path / "x.rrd"
    steps = 60
    argv = ["view", "--env", "dpr/Navigation-v0", "--policies", f"wave,{model}", "--steps", str(steps), *SMALL]
    assert run([*argv, "--save", str(out)]) == 0
    entities, origins = read_rrd(out)
    name = dpr.viz.episodes.entity_name(str(model))
    assert {"/wave", f"/{name}"} <= set(origins)
    wave, clone = entities["/wave/scene/robots"], entities[f"/{name}/scene/robots"]
    assert_timelines(wave, 0, steps)
    assert_timelines(clone, 0, steps // 6, every=6)  # its state at each decision, at the physics step it belongs to
    assert wave["step"][-1] == clone["step"][-1] == steps  # the last states: the same step and simulated second
    assert wave["sim_time"][-1].value == clone["sim_time"][-1].value == 6_000_000_000
    for metric in ("reward", "distance_to_goal"):  # the shared plots compare the same times
        assert entities[f"/{name}/metrics/{metric}"]["step"][-1] == entities[f"/wave/metrics/{metric}"]["step"][-1]
    assert [(bar.n, bar.total) for bar in _Bar.bars] == [(steps, steps), (steps, steps)]


def test_a_dataset_of_decisions_every_six_steps_is_viewed_in_its_own_time(every_six, tmp_path):
    dataset, _ = every_six
    out = tmp_path / "ds6.rrd"
    assert run(["view", str(dataset), "--episode", "1", "--save", str(out)]) == 0
    entities, _ = read_rrd(out)
    assert_timelines(entities["/episode_1/scene/robots"], 0, 9, every=6)  # frame t at t / fps = 0.6 t s
    assert_timelines(entities["/episode_1/metrics/reward"], 1, 9, every=6)


def test_a_dataset_of_the_old_fps_is_refused_by_the_viewer_with_what_to_do(tmp_path, capsys, monkeypatch):
    import dpr.datasets.collect as collect_module

    old = tmp_path / "old"  # recorded as dpr did before it kept simulated time: fps 10, timestamps 0.1 s apart
    monkeypatch.setattr(collect_module, "dataset_fps", lambda env_kwargs: 10)
    monkeypatch.setattr(collect_module, "time_info", lambda env_kwargs: {})
    spec = CollectSpec("dpr/Navigation-v0", robot_model="disk", n_robots=4, steps=10, env_kwargs={"action_repeat": 6})
    collect(old, spec, episodes=1)
    monkeypatch.undo()
    assert run(["view", str(old), "--save", str(tmp_path / "old.rrd")]) == 2
    err = capsys.readouterr().err
    assert str(old) in err and "action_repeat=6" in err and "into a new folder" in err
    assert not (tmp_path / "old.rrd").exists()


def test_view_manipulation_logs_the_object(tmp_path):
    out = tmp_path / "box.rrd"
    argv = [
        "view",
        "--env",
        "dpr/Manipulation-v0",
        "--env-kwarg",
        "object_type=box",
        "--steps",
        "8",
        *SMALL,
        "--save",
        str(out),
    ]
    assert run(argv) == 0
    entities, _ = read_rrd(out)
    outlines = entities["/wave/scene/object"]
    assert_timelines(outlines, 0, 8)
    expected = rollout_episode(
        ViewRollout(
            "dpr/Manipulation-v0", "wave", 0, n_robots=4, robot_model="disk", steps=8, env_kwargs={"object_type": "box"}
        )
    )
    square = np.array(outlines["LineStrips2D:strips"][5][0])  # one closed 5-point outline per step
    assert square.shape == (5, 2)
    np.testing.assert_allclose(square[:4].mean(axis=0), expected.object_poses[5, 0:2], atol=1e-3)
    np.testing.assert_allclose(np.linalg.norm(square[1] - square[0]), 2 * 30.0, rtol=1e-5)  # default half side 30


def test_without_save_the_episodes_go_to_a_spawned_viewer(monkeypatch, tmp_path):
    shown = []
    monkeypatch.setattr(dpr.viz, "spawn_viewer", lambda episodes, title: shown.append(episodes))
    assert run(["view", "--env", "dpr/Navigation-v0", "--steps", "5", *SMALL]) == 0
    assert [e.name for e in shown[0]] == ["wave"] and shown[0][0].n_states == 6


def test_running_metrics_equal_the_episode_metrics_of_every_prefix():
    rng = np.random.default_rng(0)
    trajectory = np.cumsum(rng.normal(size=(40, 2)), axis=0) + [300.0, -200.0]
    goal = np.array([5.0, 7.0])
    running = running_metrics(trajectory, goal)
    for t in (0, 1, 13, 39):
        metrics = episode_metrics(trajectory[: t + 1], goal)
        assert running["projected_displacement"][t] == pytest.approx(metrics.projected_displacement, abs=1e-9)
        assert running["net_displacement"][t] == pytest.approx(metrics.net_displacement, abs=1e-9)
        assert running["total_distance"][t] == pytest.approx(metrics.total_distance, abs=1e-9)
        assert running["distance_to_goal"][t] == pytest.approx(np.linalg.norm(trajectory[t] - goal))


# -- bad input ----------------------------------------------------------------------------------------------------
@pytest.fixture
def no_viewer(monkeypatch):
    """Fails the test if a viewer or server would start."""

    def refuse(*args, **kwargs):
        raise AssertionError("a viewer was started")

    monkeypatch.setattr(dpr.viz, "spawn_viewer", refuse)
    monkeypatch.setattr(dpr.viz, "serve", refuse)


@pytest.mark.parametrize(
    "argv, message",
    [
        (["{tmp}/missing"], "does not exist"),
        (["{tmp}/broken.mcap"], "not a readable MCAP file"),
        (["{tmp}/not_a_dataset"], "info.json"),
        (["{tmp}/notes.txt"], "neither a dataset folder nor a .mcap file"),
        (["{ds}", "--episode", "2"], "--episode: 2 is not in the dataset"),
        (["{ds}", "--episode", "0", "0"], "--episode lists an episode twice"),
        (["{ds}", "--episode", "-1"], "--episode takes episode indices >= 0"),
        (["{ds}/mcap/seed-000000.mcap", "--episode", "0"], "an MCAP file holds one episode"),
        (["{ds}", "--policies", "wave"], "--policies rolls policies out with --env"),
        (["--env", "dpr/Navigation-v0", "--policies", "wave,expert"], "policy must be one of"),
        (["--env", "dpr/Navigation-v0", "--policies", "models/ppo.zip"], "models/ppo.zip"),
        (["--env", "dpr/Navigation-v0", "--policies", "wave,wave"], "lists a policy twice"),
        (["--env", "dpr/Navigation-v0", "--env-kwarg", "bogus=1"], "unexpected keyword argument 'bogus'"),
        (["--env", "dpr/Navigation-v0", "--env-kwarg", "n_robots=3"], "must not set ['n_robots']"),
        (["--env", "dpr/Nowhere-v0"], "--env: unknown env id"),
        ([], "give either SOURCE"),
        (["{ds}", "--env", "dpr/Navigation-v0"], "give either SOURCE"),
        (["{ds}", "--save", "{tmp}/out.txt"], "must end in .rrd"),
        (["{ds}", "--save", "{tmp}/no/such/folder/out.rrd"], "does not exist"),
        (["{ds}", "--save", "{tmp}/out.rrd", "--serve"], "choose one"),
    ],
)
def test_view_refuses_bad_input(argv, message, dataset, tmp_path, capsys, no_viewer):
    (tmp_path / "not_a_dataset").mkdir()
    (tmp_path / "notes.txt").write_text("hello")
    source = (dataset / "mcap" / "seed-000000.mcap").read_bytes()
    (tmp_path / "broken.mcap").write_bytes(source[: len(source) // 2])
    argv = [part.format(tmp=tmp_path, ds=dataset) for part in argv]
    assert run(["view", *argv, *SMALL, "--steps", "5"]) == 2
    assert message in capsys.readouterr().err
    assert not list(tmp_path.glob("*.rrd*"))


def test_view_never_overwrites_a_file(dataset, tmp_path, capsys, no_viewer):
    out = tmp_path / "earlier.rrd"
    out.write_text("earlier recording")
    assert run(["view", str(dataset), "--save", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err
    assert out.read_text() == "earlier recording"


def test_a_failed_save_leaves_no_file(dataset, tmp_path, monkeypatch):
    def broken(recording, episodes):
        raise RuntimeError("disk full")

    monkeypatch.setattr(dpr.viz.rerun_log, "log_all", broken)
    out = tmp_path / "out.rrd"
    with pytest.raises(RuntimeError, match="disk full"):
        dpr.viz.save_rrd([episode_from_mcap(dataset / "mcap" / "seed-000000.mcap")], out)
    assert list(tmp_path.iterdir()) == []


def test_a_gate_v2_dataset_with_the_last_action_shows_the_robots_where_they_were(tmp_path):
    """Gate-v2's state holds the opening between the robots and the last action: the view finds the robots."""
    root = tmp_path / "gate"
    spec = CollectSpec(
        "dpr/Gate-v2",
        policy="wave-markov",
        robot_model="disk",
        n_robots=4,
        steps=20,
        env_kwargs={"obs_last_action": True},
        mcap=True,
    )
    collect(root, spec, episodes=1)
    from_dataset = episode_from_dataset(LeRobotReader(root), 0)
    from_mcap = episode_from_mcap(root / "mcap" / "seed-000000.mcap")
    np.testing.assert_allclose(from_dataset.positions, from_mcap.positions[:-1], atol=1e-3)


def test_dataset_without_dpr_metadata_is_refused(dataset):
    reader = LeRobotReader(dataset)
    del reader.episodes[0]["env_id"]  # as in a dataset recorded by another tool
    with pytest.raises(dpr.viz.ViewError, match="not recorded by dpr collect"):
        episode_from_dataset(reader, 0)


# -- dpr evaluate --rerun -----------------------------------------------------------------------------------------
def test_evaluate_saves_every_episode_to_rerun(tmp_path, capsys):
    out = tmp_path / "eval.rrd"
    argv = [
        "evaluate",
        "--env",
        "dpr/Navigation-v0",
        "dpr/Gate-v0",
        "--seeds",
        "0-1",
        "--robot-model",
        "disk",
        "--n-robots",
        "4",
        "--steps",
        str(STEPS),
        "--workers",
        "1",
        "--json",
        str(tmp_path / "eval.json"),
        "--rerun",
        str(out),
    ]
    assert run(argv) == 0, capsys.readouterr().err
    entities, origins = read_rrd(out)
    names = ["/navigation_seed0", "/navigation_seed1", "/gate_seed0", "/gate_seed1"]
    assert set(names) <= set(origins)
    episodes = {e["env_id"] + str(e["seed"]): e for e in json.loads((tmp_path / "eval.json").read_text())["episodes"]}
    for name, env_id in zip(names, ["dpr/Navigation-v0"] * 2 + ["dpr/Gate-v0"] * 2):
        seed = name[-1]
        assert_timelines(entities[f"{name}/scene/robots"], 0, STEPS)
        logged = entities[f"{name}/metrics/projected_displacement"]["Scalars:scalars"][-1][0]
        assert logged == pytest.approx(episodes[env_id + seed]["projected_displacement"], rel=1e-9, abs=1e-12)


def test_evaluate_refuses_an_existing_rerun_file(tmp_path, capsys):
    out = tmp_path / "eval.rrd"
    out.write_bytes(b"earlier")
    assert run(["evaluate", "--seeds", "0", "--steps", "5", "--rerun", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err
    assert out.read_bytes() == b"earlier"


# -- dpr train / finetune --rerun ---------------------------------------------------------------------------------
@pytest.mark.parametrize("action_repeat", [1, 2])
def test_train_saves_its_checkpoints_and_final_model_rollouts_to_rerun(tmp_path, capsys, action_repeat):
    """Each rollout is a whole training episode of the model's decisions, whatever its action_repeat."""
    out = tmp_path / "train.rrd"
    argv = [
        "train",
        "--env-kwarg",
        f"action_repeat={action_repeat}",
        "--algo",
        "ppo",
        "--env",
        "dpr/Navigation-v0",
        "--n-robots",
        "4",
        "--robot-model",
        "disk",
        "--timesteps",
        "128",
        "--steps-per-episode",
        str(STEPS),
        "--hyperparam",
        "n_steps=32",
        "--hyperparam",
        "batch_size=32",
        "--eval-episodes",
        "1",
        "--out",
        str(tmp_path / "run"),
        "--rerun",
        str(out),
    ]
    assert run(argv) == 0, capsys.readouterr().err
    checkpoints = sorted((tmp_path / "run" / "checkpoints").glob("*.zip"))
    assert checkpoints
    entities, origins = read_rrd(out)
    steps = sorted(int(path.stem.split("_")[1]) for path in checkpoints)
    assert {f"/step_{n}" for n in steps} | {"/final"} == {o for o in origins if o.startswith(("/step_", "/final"))}
    assert_timelines(entities["/final/scene/robots"], 0, STEPS, every=action_repeat)


def test_train_refuses_a_rerun_path_that_is_not_rrd_before_training(tmp_path, capsys):
    argv = [
        "train",
        "--algo",
        "ppo",
        "--env",
        "dpr/Navigation-v0",
        "--out",
        str(tmp_path / "run"),
        "--rerun",
        str(tmp_path / "x.txt"),
    ]
    assert run(argv) == 2
    assert "must end in .rrd" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


def test_the_viewer_draws_gate_v1s_walls_where_they_stand():
    import gymnasium as gym
    import numpy as np

    from dpr.viz import ViewRollout, rollout_episode

    walls = {}
    for env_id in ("dpr/Gate-v0", "dpr/Gate-v1"):
        episode = rollout_episode(ViewRollout(env_id, "wave", 300, n_robots=9, robot_model="disk", steps=5))
        env = gym.make(env_id, robot_model="disk").unwrapped
        env.reset(seed=300)
        assert [np.asarray(w)[:4].tolist() for w in episode.walls] == [w.tolist() for w in env.world.walls]
        walls[env_id] = np.asarray(episode.walls[0])[:4]
    assert not np.allclose(walls["dpr/Gate-v0"], walls["dpr/Gate-v1"])
