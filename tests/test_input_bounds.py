"""Every count, size and file a user gives is bounded and checked before any work: each reproduction of issue 75's
resource cases exits 2 with a message naming the input, and leaves nothing written."""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

import pytest
import yaml

from dpr.bounded_io import YamlRefused, load_yaml, load_yaml_text, read_bounded
from dpr.checks import ParameterError
from dpr.cli.main import main
from dpr.limits import MAX_EPISODES, MAX_N_ENVS, MAX_N_ROBOTS, check_workers

ROOT = Path(__file__).resolve().parents[1]
TINY = ["pipeline", "--preset", "tiny", "--tasks", "navigation"]


def run_refused(argv: list[str], capsys) -> str:
    """``dpr argv``'s error line; it must exit 2."""
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2
    return capsys.readouterr().err


@pytest.mark.parametrize(
    ("flags", "names"),
    [
        (["--episodes", "1000000000000"], ["--episodes", "1000000000000", str(MAX_EPISODES)]),
        (["--workers", "1000"], ["--workers", "1000"]),
        (["--n-envs", "100000"], ["--n-envs", "100000", str(MAX_N_ENVS)]),
        (["--steps", "1000000000000"], ["--steps", "1000000000000"]),
        (["--n-robots", "100000"], ["--n-robots", "100000", str(MAX_N_ROBOTS)]),
        (["--finetune-hyperparam", "n_steps=-5"], ["--finetune-hyperparam", "n_steps", "-5"]),
        (["--finetune-hyperparam", "n_epochs=100000000000"], ["--finetune-hyperparam", "n_epochs"]),
        (["--bc-epochs", "10000000000"], ["--bc-epochs"]),
        (["--approach-reward", "nan"], ["--approach-reward", "nan"]),
    ],
)
def test_pipeline_refuses_before_writing(tmp_path, capsys, flags, names):
    out = tmp_path / "run"
    error = run_refused([*TINY, *flags, "--out", str(out)], capsys)
    for name in names:
        assert name in error
    assert "--hyperparam:" not in error  # the flag the user typed, not the library's
    assert not out.exists()


def test_refused_pipeline_leaves_the_folder_to_the_corrected_command(tmp_path, capsys):
    """A refusal writes nothing, so the folder holds no settings that would block the corrected command."""
    out = tmp_path / "run"
    out.mkdir()
    run_refused([*TINY, "--n-robots", "100000", "--out", str(out)], capsys)
    assert list(out.iterdir()) == []


def test_pipeline_config_file_values_are_bounded(tmp_path, capsys):
    config = tmp_path / "settings.yaml"
    config.write_text("tasks: [navigation]\nepisodes: 1000000000000\n")
    error = run_refused(["pipeline", "--config", str(config), "--out", str(tmp_path / "run")], capsys)
    assert "episodes" in error and "1000000000000" in error
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    "text",
    [
        "tasks: [navigation]\ntasks: [gate]\n",  # a duplicate key
        "training_env_kwargs:\n  navigation:\n    a: &a [x, x, x, x, x, x, x, x, x]\n"
        + "".join(f"    {c}: &{c} [{', '.join(['*' + p] * 9)}]\n" for p, c in zip("abcdefgh", "bcdefghi")),
    ],
)
def test_pipeline_config_yaml_refused(tmp_path, capsys, text):
    config = tmp_path / "settings.yaml"
    config.write_text(text)
    error = run_refused(["pipeline", "--config", str(config), "--out", str(tmp_path / "run")], capsys)
    assert str(config) in error
    assert not (tmp_path / "run").exists()


def test_config_from_a_device_is_refused(tmp_path, capsys):
    error = run_refused(["pipeline", "--config", "/dev/zero", "--out", str(tmp_path / "run")], capsys)
    assert "--config: /dev/zero is not a regular file" in error


@pytest.mark.parametrize(
    "argv",
    [
        ["collect", "--env", "dpr/Navigation-v0", "--episodes", "10000000"],
        ["collect", "--env", "dpr/Navigation-v0", "--n-robots", "100000"],
        ["collect", "--env", "dpr/Navigation-v0", "--steps", "10000000"],
        ["collect", "--env", "dpr/Navigation-v0", "--workers", "100000"],
        ["train", "--algo", "ppo", "--env", "dpr/Navigation-v0", "--n-envs", "100000"],
        ["train", "--algo", "ppo", "--env", "dpr/Navigation-v0", "--timesteps", "100000000000"],
        ["train", "--algo", "ppo", "--env", "dpr/Navigation-v0", "--seed", str(2**32)],
        ["train", "--algo", "ppo", "--env", "dpr/Navigation-v0", "--hyperparam", "n_steps=-5"],
        ["finetune", "--from", "models/navigation-bc.zip", "--env", "dpr/Navigation-v0", "--n-envs", "100000"],
        ["finetune", "--from", "models/navigation-bc.zip", "--env", "dpr/Navigation-v0", "--critic-warmup", "-1"],
        ["bc", "--dataset", "nowhere", "--epochs", "100000000"],
        ["bc", "--dataset", "nowhere", "--batch-size", "100000000000"],
        ["bc", "--dataset", "nowhere", "--lr", "inf"],
        ["evaluate", "--steps", "100000000"],
        ["evaluate", "--seeds", "0-10000000"],
        ["bench", "--sizes", "100000"],
        ["view", "--env", "dpr/Navigation-v0", "--steps", "100000000"],
    ],
)
def test_commands_refuse_before_writing(tmp_path, capsys, monkeypatch, argv):
    monkeypatch.chdir(ROOT)
    out = tmp_path / "out"
    out_flag = ["--out", str(out)] if argv[0] in ("collect", "train", "finetune", "bc") else []
    error = run_refused([*argv, *out_flag], capsys)
    flag = next(item for item in reversed(argv) if item.startswith("--"))
    assert flag in error
    assert not out.exists()


def test_workers_bounded_by_the_machine_or_the_cluster():
    with pytest.raises(ParameterError, match="this machine has"):
        check_workers("--workers", 10**6)
    assert check_workers("--workers", 1000, "ray") == 1000


def test_model_zip_member_over_its_bound_is_refused(tmp_path, capsys):
    bomb = tmp_path / "bomb.zip"
    with zipfile.ZipFile(ROOT / "models" / "navigation-bc.zip") as source, zipfile.ZipFile(bomb, "w") as target:
        for info in source.infolist():
            if info.filename != "data":
                target.writestr(info, source.read(info.filename))
        with target.open("data", "w", force_zip64=True) as data:  # declares 65 MiB of JSON: over the 64 MiB bound
            data.write(source.read("data"))
            for _ in range(65):
                data.write(b" " * 2**20)
    error = run_refused(["evaluate", "--policy", str(bomb), "--seeds", "0", "--steps", "5"], capsys)
    assert "--policy" in error and "'data' declares" in error


def test_yaml_loader_refusals(tmp_path):
    with pytest.raises(YamlRefused, match="line 3: key 'a' appears twice"):
        load_yaml_text("a: 1\nb: 2\na: 3\n", "x.yaml")
    with pytest.raises(YamlRefused, match="recursive"):
        load_yaml_text("a: &x [*x]\n")
    with pytest.raises(YamlRefused, match="aliases"):
        load_yaml_text("a: &x 1\nb: [" + ", ".join(["*x"] * 101) + "]\n")
    with pytest.raises(YamlRefused, match="nested too deeply"):
        load_yaml_text("[" * 100_000)
    assert load_yaml_text("<<: {a: 1}\na: 2\n") == {"a": 2}  # a merge key is not a duplicate
    assert isinstance(YamlRefused("config", "x"), yaml.YAMLError)
    big = tmp_path / "big.yaml"
    big.write_text("a: " + "x" * 2000)
    with pytest.raises(YamlRefused, match="more than"):
        load_yaml(big, limit=1000)
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    for path in ("/dev/zero", fifo):
        with pytest.raises(ParameterError, match="not a regular file"):
            read_bounded(path, 10)


def test_shipped_yaml_files_load():
    files = [*ROOT.glob("dpr/**/*.yml"), *ROOT.glob("dpr/**/*.yaml"), ROOT / "models" / "card.yaml"]
    assert len(files) >= 7
    for path in files:
        assert load_yaml(path) is not None
