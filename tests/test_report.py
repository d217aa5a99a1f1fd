"""`dpr report`: trajectories in `dpr evaluate --json`, the results table, the figures, and bad input refused."""

import json
import re

import numpy as np
import pytest
from helpers import run_cli as run
from PIL import Image

from dpr.evaluation.report import load_evaluation, policy_label, results_table, trajectory_figure, write_report
from dpr.evaluation.scoring import evaluation_json, run_episode, subsample_trajectory

SWARM = ["--robot-model", "disk", "--n-robots", "4"]
STEPS = 25  # not a multiple of the subsampling step: the last position must still be stored


@pytest.fixture(scope="module")
def evaluated(tmp_path_factory):
    """`dpr evaluate --json` of wave and random on Navigation, seeds 0-1: {policy: path}."""
    folder = tmp_path_factory.mktemp("evaluate")
    paths = {}
    for policy in ("wave", "random"):
        paths[policy] = folder / f"{policy}.json"
        argv = [
            "evaluate",
            "--policy",
            policy,
            "--env",
            "dpr/Navigation-v0",
            "--seeds",
            "0-1",
            "--steps",
            str(STEPS),
            "--workers",
            "1",
            *SWARM,
            "--json",
            str(paths[policy]),
        ]
        assert run(argv) == 0
    return paths


def _episode(env_id, seed, displacement, success=False, trajectory=True):
    episode = {
        "env_id": env_id,
        "policy": "?",
        "seed": seed,
        "projected_displacement": displacement,
        "net_displacement": abs(displacement),
        "total_distance": abs(displacement),
        "success": success,
        "steps": 100,
    }
    if trajectory:
        episode["goal"] = [0.0, 0.0]
        episode["trajectory"] = [[100.0 + seed, 50.0], [100.0 + seed - displacement, 50.0]]
    return episode


def _write(path, policy, episodes, steps=100):
    env_ids = list(dict.fromkeys(e["env_id"] for e in episodes))
    seeds = sorted({e["seed"] for e in episodes})
    path.write_text(
        json.dumps(
            {
                "policy": policy,
                "env_ids": env_ids,
                "env_kwargs": {},
                "steps": steps,
                "seeds": seeds,
                "episodes": episodes,
                "summary": {},
            }
        )
    )
    return path


NAV, GATE = "dpr/Navigation-v0", "dpr/Gate-v2"


@pytest.fixture
def synthetic(tmp_path):
    """Wave on Navigation and Gate; a model on Navigation (same seeds) and Gate (fewer seeds), in two files."""
    return [
        _write(
            tmp_path / "wave.json",
            "wave",
            [_episode(NAV, s, d, success=s == 2) for s, d in zip((0, 1, 2), (10.0, 20.0, 40.0))]
            + [_episode(GATE, s, d) for s, d in zip((0, 1, 2), (8.0, 4.0, 6.0))],
        ),
        _write(
            tmp_path / "bc-gate.json",
            "models/navigation-bc-ppo.zip",
            [_episode(GATE, s, d) for s, d in zip((0, 1), (1.0, 3.0))],
        ),
        _write(
            tmp_path / "bc-nav.json",
            "models/navigation-bc-ppo.zip",
            [_episode(NAV, s, d) for s, d in zip((0, 1, 2), (5.0, 15.0, 30.0))],
        ),
    ]


def _rows(table: str) -> list[list[str]]:
    return [[cell.strip() for cell in line.strip("|").split("|")] for line in table.splitlines()[2:]]


def test_subsample_keeps_every_tenth_and_the_last_position():
    trajectory = np.arange(26 * 2, dtype=float).reshape(26, 2) / 3
    kept = subsample_trajectory(trajectory)
    assert kept == np.round(trajectory[[0, 10, 20, 25]], 1).tolist()
    assert len(subsample_trajectory(trajectory[:21])) == 3  # the last is index 20: not stored twice


def test_evaluation_json_round_trips_with_pairs_on_one_line():
    payload = {"name": "a [\n 1,\n 2\n] b", "episodes": [{"trajectory": [[1.5, -2.0], [3.0, 4.25]]}], "seeds": [0]}
    text = evaluation_json(payload)
    assert json.loads(text) == payload
    assert "[1.5, -2.0]" in text and "[3.0, 4.25]" in text


def test_evaluate_json_holds_goal_and_trajectory_ending_at_the_last_position(evaluated):
    payload = json.loads(evaluated["wave"].read_text())
    for episode in payload["episodes"]:
        result = run_episode(
            "dpr/Navigation-v0", "wave", episode["seed"], steps=STEPS, env_kwargs={"robot_model": "disk", "n_robots": 4}
        )
        assert episode["goal"] == pytest.approx(result.goal.tolist())
        assert len(episode["trajectory"]) == len(range(0, STEPS + 1, 10)) + 1
        assert episode["trajectory"][0] == pytest.approx(result.trajectory[0], abs=0.05)
        assert episode["trajectory"][-1] == pytest.approx(result.trajectory[-1], abs=0.05)
        assert episode["trajectory"][-1] == np.round(result.trajectory[-1], 1).tolist()


def test_report_from_evaluate_files(evaluated, tmp_path, capsys):
    out = tmp_path / "report"
    assert run(["report", str(evaluated["wave"]), str(evaluated["random"]), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    for name in ("results.md", "bars.png", "trajectories.png"):
        assert f"wrote {out / name}" in printed
    for name in ("bars.png", "trajectories.png"):
        assert (out / name).stat().st_size > 0
        with Image.open(out / name) as image:
            assert image.format == "PNG" and image.width > 0 and image.height > 0
            image.verify()
    rows = {row[1]: row for row in _rows((out / "results.md").read_text().split("\n\n")[2])}
    for policy in ("wave", "random"):
        displacements = [e["projected_displacement"] for e in json.loads(evaluated[policy].read_text())["episodes"]]
        assert rows[policy][0] == "Navigation"
        assert rows[policy][2] == f"{np.median(displacements):.1f}"
        assert rows[policy][7:9] == ["2", "0-1"]
    assert rows["wave"][9] == "100%"
    assert re.fullmatch(r"-?\d+%|—", rows["random"][9])
    assert f"`{evaluated['wave']}`" in (out / "results.md").read_text()  # the sources line


def test_table_rows_medians_and_percent_of_wave(synthetic):
    rows = _rows(results_table([load_evaluation(path) for path in synthetic]))
    # on Navigation the model is named by its method; on another task it keeps its whole name
    assert [row[:2] for row in rows] == [
        ["Navigation", "wave"],
        ["Navigation", "bc-ppo"],
        ["Gate", "wave"],
        ["Gate", "navigation-bc-ppo"],
    ]
    nav_wave, nav_bc, gate_wave, gate_bc = rows
    assert nav_wave[2:] == ["20.0", "10.0", "40.0", f"23.3 ± {np.std([10, 20, 40]):.1f}", "33%", "3", "0-2", "100%"]
    assert nav_bc[2] == "15.0" and nav_bc[9] == "75%"  # 15 / 20
    assert gate_wave[2] == "6.0" and gate_wave[9] == "100%"
    assert gate_bc[2] == "2.0" and gate_bc[7:] == ["2", "0-1", "—"]  # other seeds than wave's: no ratio


def test_labels_override_policy_names(synthetic, tmp_path):
    write_report(synthetic, tmp_path / "out", labels=["paper wave", "BC", "BC"])
    table = (tmp_path / "out" / "results.md").read_text()
    assert "| Navigation | paper wave | 20.0 |" in table and "| Navigation | BC | 15.0 |" in table
    assert "| 75% |" in table  # wave is found by its policy name, whatever its label
    with pytest.raises(ValueError, match="one label per file"):
        write_report(synthetic, tmp_path / "other", labels=["BC"])


def test_same_policy_and_task_on_the_same_seed_in_two_files_is_refused(synthetic, tmp_path):
    copy = _write(tmp_path / "wave-again.json", "wave", [_episode(NAV, 2, 1.0)])
    with pytest.raises(ValueError, match=r"in both .*wave.json and .*wave-again.json \(seeds 2\)"):
        results_table([load_evaluation(path) for path in [*synthetic, copy]])
    longer = _write(tmp_path / "wave-longer.json", "wave", [_episode(NAV, 3, 1.0)], steps=200)
    with pytest.raises(ValueError, match=r"wave-longer.json \(200 steps, not 100\)"):
        results_table([load_evaluation(path) for path in [*synthetic, longer]])


def test_one_run_scored_in_parts_is_one_run(synthetic, tmp_path):
    """The same policy in two files on other seeds each (a run scored on more seeds later) is one run of its
    label: its episodes together, as if scored in one file."""
    more = _write(tmp_path / "wave-more.json", "wave", [_episode(NAV, 3, 30.0)])
    table = results_table([load_evaluation(path) for path in [*synthetic, more]])
    assert "| Navigation | wave | 25.0 | 10.0 | 40.0 |" in table and "| 4 | 0-3 |" in table  # its 4 episodes
    assert "| Gate | wave | 6.0 |" in table and "| 3 | 0-2 |" in table  # the other task keeps its own


def test_report_never_overwrites(synthetic, tmp_path, capsys):
    out = tmp_path / "report"
    out.mkdir()
    (out / "bars.png").write_bytes(b"earlier figure")
    with pytest.raises(FileExistsError, match="bars.png"):
        write_report(synthetic, out)
    assert sorted(p.name for p in out.iterdir()) == ["bars.png"]  # nothing else written
    assert run(["report", *map(str, synthetic), "--out", str(out)]) == 2
    assert f"{out / 'bars.png'} already exists" in capsys.readouterr().err
    assert (out / "bars.png").read_bytes() == b"earlier figure"


@pytest.mark.parametrize(
    "text, message",
    [
        ("not json {", "not a JSON file"),
        ("[1, 2]", "expected a JSON object"),
        (json.dumps({"policy": "wave", "episodes": []}), "missing key(s) ['env_ids', 'steps', 'seeds']"),
        (json.dumps({"policy": "wave", "env_ids": [], "steps": 10, "seeds": [0], "episodes": []}), "no episodes"),
        (
            json.dumps({"policy": "wave", "env_ids": [], "steps": 10, "seeds": [0], "episodes": [{"seed": 0}]}),
            "episode 0 lacks ['env_id', 'projected_displacement', 'success']",
        ),
    ],
)
def test_bad_file_is_named(text, message, synthetic, tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text(text)
    with pytest.raises(ValueError) as error:
        load_evaluation(bad)
    assert str(error.value).startswith(f"{bad}: ") and message in str(error.value)
    assert run(["report", str(synthetic[0]), str(bad), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and message in err
    assert not (tmp_path / "out").exists()


def test_files_without_trajectories(tmp_path):
    old = _write(tmp_path / "old.json", "random", [_episode(NAV, s, 1.0, trajectory=False) for s in (0, 1)])
    new = _write(tmp_path / "new.json", "wave", [_episode(NAV, s, 5.0) for s in (1, 2)])
    assert "| Navigation | random | 1.0 |" in results_table([load_evaluation(old)])
    with pytest.raises(ValueError, match="no evaluation has trajectories"), pytest.warns(UserWarning):
        trajectory_figure([load_evaluation(old)], tmp_path / "none.png")
    assert not (tmp_path / "none.png").exists()
    with pytest.warns(UserWarning, match="old.json: random on Navigation has no trajectories"):
        trajectory_figure([load_evaluation(new), load_evaluation(old)], tmp_path / "mixed.png")
    assert (tmp_path / "mixed.png").stat().st_size > 0


def test_trajectories_without_a_common_seed_ask_for_one(tmp_path):
    first = _write(tmp_path / "first.json", "wave", [_episode(NAV, s, 5.0) for s in (0, 1)])
    second = _write(tmp_path / "second.json", "random", [_episode(NAV, s, 1.0) for s in (2, 3)])
    evaluations = [load_evaluation(first), load_evaluation(second)]
    with pytest.raises(ValueError, match=r"^seed: Navigation: no seed was evaluated for all of") as error:
        trajectory_figure(evaluations, tmp_path / "none.png")
    assert error.value.parameter == "seed" and not (tmp_path / "none.png").exists()
    with pytest.warns(UserWarning, match="random on Navigation has no episode of seed 1"):
        assert trajectory_figure(evaluations, tmp_path / "one.png", seed=1).stat().st_size > 0


def test_a_model_named_after_its_task_is_labelled_by_its_method():
    assert policy_label("models/navigation-bc-ppo.zip", {"Navigation"}) == "bc-ppo"
    assert policy_label("models/gate-dqn.zip", {"Gate"}) == "dqn"
    assert policy_label("models/gate-dqn.zip", {"Navigation"}) == "gate-dqn"  # another task's model keeps its name
    assert policy_label("models/gate-dqn.zip") == "gate-dqn" and policy_label("wave", {"Gate"}) == "wave"


def test_gate_evaluations_carry_the_passage_measure_into_the_report(tmp_path):
    """An evaluation on the gate stores each episode's passage measure, summarises it, and the report shows it."""
    path = tmp_path / "gate.json"
    kwargs = ["--robot-model", "disk", "--n-robots", "9"]
    argv = [
        "evaluate",
        "--policy",
        "wave",
        "--env",
        "dpr/Gate-v2",
        "--seeds",
        "3-4",
        "--steps",
        "400",
        "--workers",
        "1",
    ]
    assert run([*argv, *kwargs, "--json", str(path)]) == 0
    payload = json.loads(path.read_text())
    for episode in payload["episodes"]:
        result = run_episode(
            "dpr/Gate-v2", "wave", episode["seed"], steps=400, env_kwargs={"robot_model": "disk", "n_robots": 9}
        )
        assert episode["gate_passage"] == result.measures["gate_passage"]
        assert episode["gate_contact_step"] == result.measures["gate_contact_step"]
    touched = [e["gate_contact_step"] >= 0 for e in payload["episodes"]]
    assert payload["summary"]["gate_touched"]["mean"] == np.mean(touched)
    out = tmp_path / "report"
    assert run(["report", str(path), "--out", str(out)]) == 0
    section = (out / "results.md").read_text().split("## Passage through the gate\n\n")[1].split("\n\n")[0]
    (row,) = _rows(section)
    assert row[:2] == ["Gate", "wave"]
    assert row[3] == f"{sum(touched)} of 2"


@pytest.mark.parametrize("field", ["projected_displacement", "trajectory"])
def test_a_nan_episode_is_refused_naming_the_file_and_nothing_is_written(tmp_path, capsys, field):
    episode = _episode(NAV, 0, 10.0)
    if field == "trajectory":
        episode["trajectory"][1][0] = float("nan")
    else:
        episode[field] = float("nan")
    path = _write(tmp_path / "nan.json", "wave", [episode])
    out = tmp_path / "report"
    assert run(["report", str(path), "--out", str(out)]) == 2
    assert f"{path}: episode 0" in capsys.readouterr().err
    assert not out.exists() or not any(out.iterdir())


def test_models_of_two_run_folders_are_two_methods_without_labels(tmp_path):
    """`dpr train` names every run's model model.zip: the report names each by its run folder, not one 'model'."""
    runs = ("runs/ft/nav9", "runs/ft/nav9-lr", "runs/bc/nav9")  # the last two share their folder's name
    paths = [
        _write(tmp_path / f"{i}.json", f"{run}/model.zip", [_episode(NAV, s, 10.0 + s) for s in (0, 1)])
        for i, run in enumerate(runs)
    ]
    rows = _rows(results_table([load_evaluation(path) for path in paths]))
    assert [row[1] for row in rows] == [f"{run}/model" for run in runs]
